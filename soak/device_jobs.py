"""Jobs the window's tests and benchmarks add to its bench process
(:data:`gui.session.BENCH_JOBS`, before the bench opens): what they do to a device that
no operator command does (a simulated device's fault, a move not waited for)."""

from __future__ import annotations


def device_fault(ctx, *, device: str, action: str) -> None:
    """``disconnect`` or ``allow_reconnect`` a simulated device (its ``faults``)."""
    getattr(ctx.bench.devices[device].faults, action)()


def start_move(ctx, *, stage: str, targets: dict) -> None:
    """Start a move of ``stage`` and return while it moves."""
    ctx.bench.devices[stage].move_to(targets, wait=False)


def is_moving(ctx, *, stage: str) -> bool:
    return ctx.bench.devices[stage].is_moving()


JOBS = {"device_fault": device_fault, "start_move": start_move, "is_moving": is_moving}


def twin_psf(session, xyz_mm) -> tuple:
    """The on-bench PSF at ``xyz_mm`` of a window's built-in simulated bench, from its
    twin here (the same configuration and seed), and its camera's dark offset, DN."""
    from instrument.config import default_bench
    from instrument.devices.virtual_bench import VirtualBench

    psf = VirtualBench(default_bench(), seed=session.seed).psf(tuple(xyz_mm))
    return psf, float(session.service.camera_format().dark_offset_dn)
