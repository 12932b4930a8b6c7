"""``--simulate`` without a bench file: every command that takes one uses the built-in
simulated bench (what ``examples/bench-simulated.toml`` holds, as ``devices`` always
did); without ``--simulate`` a missing file is one line and exit 2."""

from __future__ import annotations

import pytest

from instrument.cli import main
from instrument.config import default_bench
from instrument.runs.runstore import RunStore


def test_calibrate_psf_sweep_simulate_without_a_file(tmp_path, capsys):
    path = tmp_path / "sweep.zarr"
    assert main(["calibrate", "psf-sweep", "--simulate", "--z-min", "30", "--z-max", "60",
                 "--n-depths", "2", "--frames", "1", "--out", str(path)]) == 0
    assert RunStore.open(path).status == "complete"
    assert "(complete)" in capsys.readouterr().out
    # resume takes the bench the same way (a complete run: nothing left to do)
    assert main(["calibrate", "resume", str(path), "--simulate"]) == 0


def test_the_file_form_still_parses():
    from instrument.cli import build_parser

    args = build_parser().parse_args(["calibrate", "psf-sweep", "B.toml", "--simulate"])
    assert (args.bench, args.simulate) == ("B.toml", True)
    args = build_parser().parse_args(["calibrate", "resume", "R.zarr", "B.toml"])
    assert (args.run, args.bench) == ("R.zarr", "B.toml")
    args = build_parser().parse_args(["align", "mask", "--simulate"])
    assert (args.bench, args.simulate) == (None, True)


@pytest.mark.parametrize("argv", [
    ["calibrate", "dark"],
    ["calibrate", "psf-sweep", "--z-min", "30"],
    ["calibrate", "resume", "R.zarr"],
    ["align", "mask", "--mask-seed", "1"],
    ["validate"],
])
def test_no_file_and_no_simulate_exits_2(argv, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "needs a bench file" in err and "--simulate" in err


def test_validate_and_devices_simulate_without_a_file(capsys):
    n = len(default_bench().devices)
    assert main(["validate", "--simulate"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"ok: {n} devices") and "in built-in simulated bench" in out
    assert main(["devices", "--simulate"]) == 0
    out = capsys.readouterr().out
    assert "from built-in simulated bench (simulated twins)" in out
    assert len(out.strip().splitlines()) == n + 1
