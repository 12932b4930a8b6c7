"""Screenshots of every panel and tool in a real window (Xvfb, the xcb platform, openbox).

Runs ``python -m soak.screenshots`` on an Xvfb display with a window manager
(:func:`soak.soak.x_display`; scripts/system-deps.sh installs them). The PNGs go to a
temporary folder; ``DIFFUSERLAB_SCREENSHOT_DIR=docs/images`` writes the documentation's, and
``DIFFUSERLAB_ALIGNMENT_RECORD`` shows a finished alignment record (``diffuserlab align
mask --simulate --out DIR``) in the alignment panel.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

PANELS = ("devices", "live", "calibration", "alignment", "record", "results", "window",
          "tools", "disconnected", "log")
#: Details for the operator's guide: a device's box, the Acquire menu.
DETAILS = ("presets", "positions", "shortcuts")


def test_every_panel_renders_in_a_real_window(tmp_path):
    import cv2

    from soak.soak import x_display

    out = Path(os.environ.get("DIFFUSERLAB_SCREENSHOT_DIR") or tmp_path / "shots").resolve()
    cmd = [sys.executable, "-m", "soak.screenshots", str(out)]
    if os.environ.get("DIFFUSERLAB_ALIGNMENT_RECORD"):
        cmd += ["--alignment-record", os.environ["DIFFUSERLAB_ALIGNMENT_RECORD"]]
    with x_display() as (display, _):
        env = {**os.environ, "QT_QPA_PLATFORM": "xcb", "DISPLAY": display,
               "DIFFUSERLAB_GUI_SETTINGS": str(tmp_path / "gui.ini"),
               # benchmarks/ is not installed: the checkout on the path
               "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parents[2]),
                                              os.environ.get("PYTHONPATH", "")])}
        run = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env,
                             cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "platform xcb" in run.stdout
    for name in PANELS:
        image = cv2.imread(str(out / f"gui-{name}.png"))
        assert image is not None, f"gui-{name}.png was not written"
        rows, cols, _ = image.shape
        assert rows >= 600 and cols >= 500, (name, image.shape)
        # drawn: widgets and plots, not one flat colour
        assert float(image.std()) > 20, name
        assert len(np.unique(image.reshape(-1, 3), axis=0)) > 50, name
    for name in DETAILS:
        image = cv2.imread(str(out / f"gui-{name}.png"))
        assert image is not None, f"gui-{name}.png was not written"
        assert image.shape[0] >= 150 and image.shape[1] >= 300, (name, image.shape)
        assert float(image.std()) > 20, name


@pytest.fixture(autouse=True)
def _no_offscreen(monkeypatch):
    monkeypatch.delenv("QT_QPA_PLATFORM", raising=False)
