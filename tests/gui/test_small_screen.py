"""The window on a 1366x768 screen (Xvfb with a window manager, the xcb platform): the
first start fits the screen's available geometry, and the bench process killed under
it shows Restart bench inside the window (``python -m soak.small_screen``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path


def _line(stdout: str, key: str) -> dict:
    for line in stdout.splitlines():
        if line.startswith(key + ": "):
            return json.loads(line[len(key) + 2:])
    raise AssertionError(f"no {key!r} line in:\n{stdout[-3000:]}")


def test_first_start_fits_a_laptop_screen_and_the_bench_restart_shows(tmp_path):
    from soak.soak import x_display

    out = Path(os.environ.get("DIFFUSERLAB_SCREENSHOT_DIR") or tmp_path / "shots").resolve()
    with x_display(size="1366x768x24") as (display, _):
        env = {**os.environ, "QT_QPA_PLATFORM": "xcb", "DISPLAY": display,
               "DIFFUSERLAB_GUI_SETTINGS": str(tmp_path / "gui.ini"),
               "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parents[2]),
                                              os.environ.get("PYTHONPATH", "")])}
        run = subprocess.run([sys.executable, "-m", "soak.small_screen", str(out)],
                             capture_output=True, text=True, timeout=600, env=env,
                             cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-3000:]
    geometry = _line(run.stdout, "geometry")
    assert geometry["platform"] == "xcb"
    assert geometry["screen"][2:] == [1366, 768]
    ax, ay, aw, ah = geometry["available"]
    fx, fy, fw, fh = geometry["frame"]
    assert ax <= fx and ay <= fy and fx + fw <= ax + aw and fy + fh <= ay + ah, geometry
    assert fw >= 0.9 * aw and fh >= 0.9 * ah, geometry  # opened at the screen's size
    stopped = _line(run.stdout, "bench-stopped")
    assert "SIGKILL" in stopped["said"] and stopped["restart_in_window"]
    assert Path(stopped["png"]).stat().st_size > 10_000
