"""The full-screen SLM window on a virtual X server with two screens (Xvfb), the
displayed pixels read back from the X server (XGetImage through libX11), not from Qt.

Needs Debian's xvfb and Qt's xcb libraries (.ci/run installs them) and PySide6.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from drivers.errors import DeviceDisconnectedError, DeviceValueError, SlmTimeoutError
from drivers.slm import TWO_PI
from drivers.slm_window import FullscreenSlm
from tests.drivers.conformance import SlmConformance

ROOT = Path(__file__).resolve().parents[2]

SCREEN0 = (240, 320)  # (rows, cols) of the virtual monitors
SLM = (150, 200)


class _XImage(ctypes.Structure):
    _fields_ = [("width", ctypes.c_int), ("height", ctypes.c_int), ("xoffset", ctypes.c_int),
                ("format", ctypes.c_int), ("data", ctypes.c_void_p),
                ("byte_order", ctypes.c_int), ("bitmap_unit", ctypes.c_int),
                ("bitmap_bit_order", ctypes.c_int), ("bitmap_pad", ctypes.c_int),
                ("depth", ctypes.c_int), ("bytes_per_line", ctypes.c_int),
                ("bits_per_pixel", ctypes.c_int), ("red_mask", ctypes.c_ulong),
                ("green_mask", ctypes.c_ulong), ("blue_mask", ctypes.c_ulong)]


class XScreens:
    """Xvfb with two screens, and a reader of what a screen shows."""

    def __init__(self) -> None:
        read, write = os.pipe()
        self.proc = subprocess.Popen(
            ["Xvfb", "-displayfd", str(write), "-nolisten", "tcp",
             "-screen", "0", f"{SCREEN0[1]}x{SCREEN0[0]}x24",
             "-screen", "1", f"{SLM[1]}x{SLM[0]}x24"],
            pass_fds=(write,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(write)
        number = b""
        deadline = time.monotonic() + 20.0
        while not number.endswith(b"\n") and time.monotonic() < deadline:
            chunk = os.read(read, 16)
            if not chunk:
                break
            number += chunk
        os.close(read)
        if not number.strip():
            self.proc.kill()
            raise RuntimeError("Xvfb did not start")
        self.display = f":{int(number)}"
        self._xlib = ctypes.CDLL(ctypes.util.find_library("X11"))
        x = self._xlib
        x.XOpenDisplay.restype = ctypes.c_void_p
        x.XOpenDisplay.argtypes = [ctypes.c_char_p]
        x.XRootWindow.restype = ctypes.c_ulong
        x.XRootWindow.argtypes = [ctypes.c_void_p, ctypes.c_int]
        x.XGetImage.restype = ctypes.POINTER(_XImage)
        x.XGetImage.argtypes = [ctypes.c_void_p, ctypes.c_ulong, ctypes.c_int, ctypes.c_int,
                                ctypes.c_uint, ctypes.c_uint, ctypes.c_ulong, ctypes.c_int]
        x.XCloseDisplay.argtypes = [ctypes.c_void_p]
        self._dpy = x.XOpenDisplay(self.display.encode())
        assert self._dpy, f"cannot open X display {self.display}"

    def grab(self, screen: int, shape: tuple[int, int]) -> np.ndarray:
        """``(rows, cols, 3)`` uint8 RGB of X screen ``screen``'s root window."""
        root = self._xlib.XRootWindow(self._dpy, screen)
        rows, cols = shape
        img = self._xlib.XGetImage(self._dpy, root, 0, 0, cols, rows, ~0 & 0xFFFFFFFF, 2)
        im = img.contents
        assert im.bits_per_pixel == 32 and im.red_mask == 0xFF0000, "expected a 24-bit visual"
        buf = ctypes.string_at(im.data, im.bytes_per_line * rows)
        px = np.frombuffer(buf, np.uint32).reshape(rows, im.bytes_per_line // 4)[:, :cols]
        return np.stack([(px >> 16) & 0xFF, (px >> 8) & 0xFF, px & 0xFF], -1).astype(np.uint8)

    def close(self) -> None:
        self._xlib.XCloseDisplay(self._dpy)
        self.proc.terminate()
        self.proc.wait(timeout=5)


@pytest.fixture(scope="module")
def xscreens():
    if shutil.which("Xvfb") is None:
        pytest.fail("Xvfb is missing: apt-get install xvfb (see .ci/run)")
    x = XScreens()
    yield x
    x.close()


def open_slm(xscreens, **kw) -> FullscreenSlm:
    kw = {"screen": 1, "shape_px": SLM, "display": xscreens.display, "settle_s": 0.0, **kw}
    slm = FullscreenSlm("slm", **kw)
    slm.open(timeout_s=15.0)
    return slm


def shown(xscreens, slm) -> np.ndarray:
    """The gray levels on the SLM's screen; R, G and B must agree (no colour handling)."""
    rgb = xscreens.grab(1, SLM)
    assert np.array_equal(rgb[..., 0], rgb[..., 1]) and np.array_equal(rgb[..., 0], rgb[..., 2])
    return rgb[..., 0]


class TestFullscreenSlm(SlmConformance):
    _restore = None

    @pytest.fixture
    def device(self, xscreens):
        self.x = xscreens
        slm = open_slm(xscreens)
        yield slm
        slm.close()

    def provoke_timeout(self, device):
        pid = device.status()["window_pid"]
        os.kill(pid, signal.SIGSTOP)  # the window process freezes (a hung display)
        self._restore = lambda: os.kill(pid, signal.SIGCONT)

    def blocking_call(self, device):
        try:
            return super().blocking_call(device)
        finally:
            restore, self._restore = self._restore, None
            if restore is not None:
                restore()

    def assert_settings_in_effect(self, device, settings):
        super().assert_settings_in_effect(device, settings)
        assert np.all(shown(self.x, device) == 77)


def test_pixels_on_screen_are_the_image_exactly(xscreens):
    slm = open_slm(xscreens)
    try:
        rng = np.random.default_rng(3)
        for img in (rng.integers(0, 256, SLM, dtype=np.uint8),
                    (np.indices(SLM).sum(0) % 2 * 255).astype(np.uint8),  # 1-px checkerboard
                    np.tile(np.arange(256, dtype=np.uint8), 1)[None, :SLM[1]].repeat(SLM[0], 0)):
            slm.show_image(img)
            np.testing.assert_array_equal(shown(xscreens, slm), img)  # read back at once
        # the primary screen is untouched
        assert not xscreens.grab(0, SCREEN0).any()
    finally:
        slm.close()


def test_phase_through_a_nonlinear_lut_on_screen(xscreens):
    lut = TWO_PI * (np.arange(256) / 256) ** 1.4
    slm = open_slm(xscreens, lut_rad=lut)
    try:
        grays = (np.arange(SLM[0] * SLM[1]).reshape(SLM) * 7 % 256).astype(np.uint8)
        slm.show_phase(lut[grays] + 2 * TWO_PI)  # wrapped, then the LUT inverse
        np.testing.assert_array_equal(shown(xscreens, slm), grays)
    finally:
        slm.close()


def test_settle_time_is_waited(xscreens):
    slm = open_slm(xscreens, settle_s=0.2)
    try:
        t0 = time.monotonic()
        slm.show_image(np.full(SLM, 9, np.uint8))
        assert time.monotonic() - t0 >= 0.2
        assert np.all(shown(xscreens, slm) == 9)
    finally:
        slm.close()


def test_window_closed_is_a_clear_error_then_reconnect_restores(xscreens):
    slm = open_slm(xscreens)
    try:
        img = (np.indices(SLM)[1] % 256).astype(np.uint8)
        slm.show_image(img)
        pid = slm.status()["window_pid"]
        os.kill(pid, signal.SIGKILL)  # the window is gone
        hang_guard = time.monotonic() + 30.0  # it is dead (a zombie, or reaped) however
        while time.monotonic() < hang_guard:  # late a loaded host gets to it
            try:
                with open(f"/proc/{pid}/stat") as f:
                    if f.read().rsplit(")", 1)[1].split()[0] in "ZX":
                        break
            except FileNotFoundError:
                break
            time.sleep(0.01)
        with pytest.raises(DeviceDisconnectedError, match="reconnect"):
            slm.show_image(img)
        assert slm.status()["disconnected"] is True
        slm.reconnect(timeout_s=15.0)
        np.testing.assert_array_equal(shown(xscreens, slm), img)  # the pattern is back
        np.testing.assert_array_equal(slm.current_image(), img)
    finally:
        slm.close()


def test_hung_window_times_out_and_recovers(xscreens):
    slm = open_slm(xscreens)
    try:
        pid = slm.status()["window_pid"]
        os.kill(pid, signal.SIGSTOP)
        try:
            t0 = time.monotonic()
            with pytest.raises(SlmTimeoutError, match="SLM window"):
                slm.show_image(np.full(SLM, 50, np.uint8), timeout_s=0.3)
            assert 0.3 <= time.monotonic() - t0 < 30.0  # waited its 0.3 s; a hang guard
        finally:
            os.kill(pid, signal.SIGCONT)
        slm.show_image(np.full(SLM, 60, np.uint8), timeout_s=5.0)
        assert np.all(shown(xscreens, slm) == 60)
    finally:
        slm.close()


def test_screen_checks(xscreens):
    with pytest.raises(DeviceValueError, match="shape_px"):
        open_slm(xscreens, screen=0)  # 240 x 320, not the 150 x 200 configured
    with pytest.raises(DeviceDisconnectedError, match="does not exist"):
        open_slm(xscreens, screen=4)
    slm = open_slm(xscreens, shape_px=None)  # the size read from the screen
    try:
        assert slm.resolution == SLM and slm.info["screen"]["depth"] >= 24
    finally:
        slm.close()


def test_constructor_refuses_bad_parameters():
    with pytest.raises(DeviceValueError, match="bit_depth"):
        FullscreenSlm("slm", bit_depth=10)
    with pytest.raises(DeviceValueError, match="screen"):
        FullscreenSlm("slm", screen=-1)
    with pytest.raises(DeviceValueError, match="shape_px"):
        FullscreenSlm("slm", shape_px=[0, 10])


def test_the_window_process_waits_for_the_window_to_be_on_screen(xscreens):
    """A pattern painted before the X server has mapped and exposed the window is not
    on screen, yet was answered "shown" (a loaded full-suite run grabbed a black screen
    after it). The window process waits for the exposure, and says when it never comes."""
    script = textwrap.dedent("""
        import sys
        from PySide6 import QtWidgets
        from drivers.slm_window_app import _wait_exposed
        app = QtWidgets.QApplication(["t"])
        w = QtWidgets.QWidget()
        hidden = _wait_exposed(app, w, 0.3)
        w.setGeometry(0, 0, 64, 48)
        w.show()
        shown = _wait_exposed(app, w, 10.0)
        print(hidden, shown, w.windowHandle().isExposed())
    """)
    env = {**os.environ, "DISPLAY": xscreens.display, "QT_QPA_PLATFORM": "xcb"}
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True,
                         text=True, timeout=60, cwd=ROOT)
    assert out.stdout.split() == ["False", "True", "True"], out.stderr
