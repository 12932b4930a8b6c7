"""Two real ``diffuserlab`` processes writing the same output: one wins, the other is
refused in one line (exit 2) and touches nothing of the winner's.

For every command that creates a store (``capture video``, ``calibrate``, ``runs
import-psf``, ``recon3d --out V.zarr``) and for ``recon-run`` (a product in a run),
the race is made certain with events, not delays: a small driver runs the command
with a pause at its creation point (``RunStore.create``, ``write_volume``,
``RunStore.lock``) that waits for a flag file. The loser passes its output checks
and waits *before* creating; the winner creates and waits *after* (so its run is
still empty and unfinished, as when the two start together); only then is the loser
let go. The loser must exit 2 with one line and leave the winner's output intact
(what ``runs verify`` checks, or its bytes).
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import tifffile

from .conftest import REPO

#: ``python DRIVER FLAGS ROLE POINT ARGV...``: ``diffuserlab ARGV`` with a pause at
#: ``POINT``; ROLE ``loser`` waits for ``loser-go`` before the call (after writing
#: ``loser-ready``), ``winner`` for ``winner-go`` after it (after ``winner-created``),
#: ``plain`` runs unchanged; ARGV ``api RUN.zarr``: the Python API creating RUN.zarr with
#: ``overwrite=True`` and writing two frames
DRIVER = '''import sys, time
from pathlib import Path


def main():
    flags, role, point, argv = Path(sys.argv[1]), sys.argv[2], sys.argv[3], sys.argv[4:]

    def wait(name):
        deadline = time.monotonic() + 120  # a hang guard, never the verdict
        while not (flags / name).exists():
            if time.monotonic() > deadline:
                sys.exit(f"race driver: no {name}")
            time.sleep(0.02)

    def paused(func):
        def call(*args, **kwargs):
            if role == "loser":
                (flags / "loser-ready").touch()
                wait("loser-go")
                return func(*args, **kwargs)
            result = func(*args, **kwargs)
            (flags / "winner-created").touch()
            wait("winner-go")
            return result
        return call

    from instrument.runs.runstore import RunStore, RunStoreError
    if argv[:1] == ["api"]:  # the Python API: RunStore.create(overwrite=True), 2 frames
        import numpy as np
        create = paused(RunStore.create) if point == "create" else RunStore.create
        try:
            store = create(argv[1], plan_name="p", plan_params={}, points=[{}],
                           frame_tags=[["f", "f"]], frame_shape=(4, 6),
                           frame_dtype="uint16", coord_names=["exposure_s"],
                           overwrite=True)
        except RunStoreError as exc:
            sys.exit(print(f"diffuserlab: error: {exc}", file=sys.stderr) or 2)
        store.write_frames(0, np.ones((2, 4, 6), np.uint16), np.zeros((2, 1)))
        store.update_attrs(status="complete")
        store.unlock()
        return 0
    if role == "plain":
        pass
    elif point == "create":
        RunStore.create = classmethod(paused(RunStore.create.__func__))
    elif point == "lock":
        RunStore.lock = paused(RunStore.lock)
    elif point == "write_volume":
        import instrument.writer.products as files
        files.write_volume = paused(files.write_volume)
    from instrument.cli import main as diffuserlab
    return diffuserlab(argv)


if __name__ == "__main__":
    sys.exit(main())
'''

SHAPE = (32, 32)


@pytest.fixture
def race(tmp_path):
    """Inputs (a small PSF stack and raw image) and a starter of driven processes."""
    rng = np.random.default_rng(1)
    stack = rng.random((3, *SHAPE)).astype(np.float32)
    tifffile.imwrite(tmp_path / "stack.tif", stack, metadata={"depths_mm": [2.0, 4.0, 8.0]},
                     photometric="minisblack")
    tifffile.imwrite(tmp_path / "raw.tif", (100 * rng.random(SHAPE)).astype(np.float32))
    (tmp_path / "driver.py").write_text(DRIVER)
    (tmp_path / "flags").mkdir()
    env = {**os.environ, "PYTHONPATH": str(REPO), "PYTHONDONTWRITEBYTECODE": "1",
           "NUMBA_CACHE_DIR": str(tmp_path / "numba")}

    started: list[subprocess.Popen] = []

    def start(role: str, point: str, argv: list) -> subprocess.Popen:
        started.append(subprocess.Popen(
            [sys.executable, str(tmp_path / "driver.py"), str(tmp_path / "flags"), role,
             point, *map(str, argv)], cwd=tmp_path, env=env, stdout=subprocess.PIPE,
            stderr=subprocess.PIPE, text=True))
        return started[-1]

    start.dir = tmp_path
    start.env = env
    yield start
    for proc in started:  # a failed test leaves none waiting for its flag
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def _flag(start, name: str) -> Path:
    return start.dir / "flags" / name


def _cpu_s(procs: list[subprocess.Popen]) -> float | None:
    """CPU seconds the processes used so far (Linux ``/proc``), None where unknown."""
    total = 0.0
    for proc in procs:
        try:
            fields = Path(f"/proc/{proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            return None
        total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return total


def _wait_flag(start, name: str, procs: list[subprocess.Popen]) -> None:
    """Until the flag exists; a process that ended first fails the test with its output.

    Hang guards: 120 s in which the processes used no CPU (a hang, not a loaded host,
    whose 2 cores shared by many took a starting process past a fixed 180 s), and
    1200 s in all."""
    start_t = last_t = time.monotonic()
    last_cpu = _cpu_s(procs)
    while not _flag(start, name).exists():
        for proc in procs:
            if proc.poll() is not None:
                out, err = proc.communicate()
                pytest.fail(f"a process ended (exit {proc.returncode}) before {name}:\n"
                            f"{out}\n{err}")
        now, cpu = time.monotonic(), _cpu_s(procs)
        if cpu is None or last_cpu is None or cpu > last_cpu:  # working (unknown: 1200 s)
            last_t, last_cpu = now, cpu
        assert now - last_t < 120, f"no {name}: the processes used no CPU for 120 s"
        assert now - start_t < 1200, f"no {name} after 1200 s"
        time.sleep(0.05)


def _finish(proc: subprocess.Popen) -> tuple[int, str, str]:
    out, err = proc.communicate(timeout=1200)  # a hang guard only
    return proc.returncode, out, err


def _error_lines(err: str) -> list[str]:
    """stderr without the log records and progress bars a command may print."""
    return [line for line in err.replace("\r", "\n").splitlines() if line.strip()
            and "%|" not in line and not line.startswith(("INFO ", "WARNING ", "DEBUG "))]


def _assert_refused(result: tuple[int, str, str], words: list[str]) -> None:
    code, out, err = result
    lines = _error_lines(err)
    assert code == 2 and len(lines) == 1, (code, out, err)
    assert lines[0].startswith("diffuserlab: error: ") and "Traceback" not in err, err
    for word in words:
        assert word in lines[0], lines[0]


def _verify(run: Path) -> None:
    """What ``runs verify`` checks (in this process: one start less), and finished."""
    from instrument.runs.runstore import RunStore

    store = RunStore.open(run)
    assert store.verify() == [] and store.status == "complete", store.attrs


def _store_race(start, argv: list, out: Path) -> None:
    """The loser (waiting at RunStore.create after its output checks) is let go once
    the winner has created ``out`` and waits, unfinished, after RunStore.create."""
    loser = start("loser", "create", argv)
    _wait_flag(start, "loser-ready", [loser])
    assert not out.exists()  # the loser passed its checks before the winner created
    winner = start("winner", "create", argv)
    _wait_flag(start, "winner-created", [loser, winner])
    token = (out / "zarr.json").read_bytes()
    _flag(start, "loser-go").touch()
    refused = _finish(loser)
    assert out.is_dir() and (out / "zarr.json").read_bytes() == token, refused  # untouched
    _assert_refused(refused, [f"{out.name} already exists", "choose another --out"])
    _flag(start, "winner-go").touch()
    code, stdout, err = _finish(winner)
    assert code == 0, (stdout, err)
    _verify(out)
    assert not [p for p in start.dir.iterdir() if p.name.startswith(f".{out.name}")]


@pytest.mark.parametrize("command", [
    ["capture", "video", "--simulate", "--frames", "4"],
    ["calibrate", "dark", "--simulate", "--frames", "2"],
    ["runs", "import-psf", "stack.tif"],
], ids=["capture-video", "calibrate", "import-psf"])
def test_a_refused_run_keeps_the_winners_run(race, command):
    out = race.dir / "r.zarr"
    _store_race(race, [*command, "--out", out], out)


def _tree_digest(path: Path) -> dict[str, str]:
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    return {str(p.relative_to(path.parent)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in files}


def test_a_refused_volume_keeps_the_winners_volume(race):
    """recon3d --out V.zarr: the loser solved, then found V.zarr written meanwhile; it
    keeps the winner's volume and projections (before: replaced them, exit 0)."""
    argv = ["recon3d", "--psf-stack", "stack.tif", "--raw", "raw.tif", "--method", "fista",
            "--out", "v.zarr", "--metrics-json", "m.json"]
    loser = race("loser", "write_volume", [*argv, "--iterations", "3"])
    _wait_flag(race, "loser-ready", [loser])
    assert not (race.dir / "v.zarr").exists()
    winner = race("plain", "-", [*argv, "--iterations", "2"])
    code, out, err = _finish(winner)
    assert code == 0, (out, err)
    outputs = ["v.zarr", "v_mip_xy.png", "v_mip_xz.png", "v_mip_yz.png", "m.json"]
    before = {k: v for name in outputs for k, v in _tree_digest(race.dir / name).items()}
    _flag(race, "loser-go").touch()
    refused = _finish(loser)
    after = {k: v for name in outputs for k, v in _tree_digest(race.dir / name).items()}
    assert after == before, refused
    _assert_refused(refused, ["v.zarr already exists", "another process",
                              "choose another --out"])
    assert not [p for p in race.dir.iterdir() if p.name.startswith(".")]


def test_a_second_recon_run_keeps_the_first_ones_product(race):
    """recon-run writes a product into a run under the run's lock: a second one started
    while the first holds it is refused before anything else."""
    run = race.dir / "v.zarr"
    rec = subprocess.run([sys.executable, "-m", "instrument.cli", "capture", "video",
                          "--simulate", "--frames", "3", "--out", str(run)], cwd=race.dir,
                         env=race.env, capture_output=True, text=True, timeout=300)
    assert rec.returncode == 0, rec.stderr
    from instrument.runs.runstore import RunStore

    np.save(race.dir / "psf.npy", RunStore.open(run).frame(0).image.astype(np.float32))
    argv = ["recon-run", run, "--psf", "psf.npy", "--method", "wiener", "--workers", "1"]
    winner = race("winner", "lock", argv)
    _wait_flag(race, "winner-created", [winner])
    loser = race("plain", "-", argv)
    _assert_refused(_finish(loser), ["v.zarr", "is writing it"])
    _flag(race, "winner-go").touch()
    code, out, err = _finish(winner)
    assert code == 0, (out, err)
    assert RunStore.open(run).product_frames_done("recon_wiener").all()
    _verify(run)


@pytest.mark.parametrize("command", [
    ["capture", "video", "--simulate", "--frames", "4"],
    ["calibrate", "psf-sweep", "--simulate", "--frames", "1", "--n-depths", "2"],
    ["runs", "import-psf", "stack.tif"],
    ["api"],
], ids=["capture-video", "calibrate-psf-sweep", "import-psf", "python-api"])
def test_two_overwrite_writers_the_second_is_refused_naming_the_first(race, command):
    """Two writers replacing one run at once (--overwrite, RunStore.create(overwrite=
    True)): the first locks the old run, replaces it and holds its new run's lock; the
    second, let go after its checks once the first created its run, is refused in one
    line naming the holder and never removes the first one's new run (before: it
    deleted it, both failed with internal errors, leaving a damaged husk)."""
    out = race.dir / "r.zarr"
    argv = ([*command, out] if command == ["api"] else
            [*command, "--out", out, "--overwrite"])
    made = _finish(race("plain", "-", argv))  # the run both replace
    assert made[0] == 0 and out.is_dir(), made
    loser = race("loser", "create", argv)
    _wait_flag(race, "loser-ready", [loser])
    old = (out / "zarr.json").read_bytes()
    winner = race("winner", "create", argv)
    _wait_flag(race, "winner-created", [loser, winner])
    token = (out / "zarr.json").read_bytes()
    assert token != old  # the winner's new run, not finished yet
    _flag(race, "loser-go").touch()
    refused = _finish(loser)
    assert out.is_dir() and (out / "zarr.json").read_bytes() == token, refused
    _assert_refused(refused, [f"not replacing {out}", f"process {winner.pid}",
                              "is writing it"])
    _flag(race, "winner-go").touch()
    code, stdout, err = _finish(winner)
    assert code == 0, (stdout, err)
    _verify(out)
    assert not (out / ".lock").exists()
    assert not [p for p in race.dir.iterdir() if p.name.startswith(f".{out.name}")]
