"""Phase SLM driven as an extra monitor (HDMI/DVI/DisplayPort panels: Holoeye PLUTO and
GAEA, Meadowlark HDMI models, Santec, ...): :class:`FullscreenSlm`.

The pattern is shown by a frameless full-screen Qt window on the SLM's screen, painted
pixel for pixel (no scaling, no dithering, no colour management; R = G = B = gray). The
window runs in its own process (:mod:`drivers.slm_window_app`, PySide6 from the ``gui``
extra), so the caller needs no Qt event loop, the operator GUI and this driver never
share a Qt thread, and a crashed or closed window is a disconnection the driver can
recover from (:meth:`Device.reconnect` starts it again and shows the last pattern).

Every exchange with the window process has a deadline: a pattern not on screen within
``timeout_s`` is a :class:`~drivers.errors.SlmTimeoutError`; a process that ended is a
:class:`~drivers.errors.DeviceDisconnectedError`. Settings, facts and pitfalls:
docs/drivers/slm-window.md.
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import os
import select
import subprocess
import sys
import time
from typing import Any

import numpy as np

from drivers.errors import (
    DeviceDisconnectedError,
    DeviceValueError,
    MissingDependencyError,
)
from drivers.slm import Slm, linear_lut

__all__ = ["FullscreenSlm"]


class FullscreenSlm(Slm):
    """An SLM that is a monitor of the computer, driven by a full-screen window.

    Parameters
    ----------
    device_id : str
        Name of the SLM.
    screen : int
        Index of the SLM's screen in Qt's screen list (0 is usually the primary
        monitor; ``xrandr --listmonitors`` shows the order on X11).
    shape_px : (int, int), optional
        Panel ``(rows, cols)``; checked against the screen's size at open (default:
        the screen's size, read at open).
    pixel_pitch_um : float
        Panel pixel pitch in micrometres.
    wavelength_nm : float
        Wavelength the LUT is calibrated for, in nm.
    bit_depth : int
        Gray-level bits the panel takes through the video link (only 8 is supported).
    lut_rad : array_like, optional
        Initial LUT (256 phases, rad); default linear 0..2 pi.
    settle_s : float
        Time waited after each new pattern for the liquid crystal (s).
    display : str, optional
        X display of the SLM (e.g. ``":0"`` or ``":0.1"`` for a second X screen);
        default ``$DISPLAY``.

    Raises
    ------
    DeviceValueError
        A parameter is invalid (the constructor opens nothing).
    """

    def __init__(
        self, device_id: str, *, screen: int = 1, shape_px: Any = None,
        pixel_pitch_um: float = 8.0, wavelength_nm: float = 532.0, bit_depth: int = 8,
        lut_rad: Any = None, settle_s: float = 0.1, display: str | None = None,
    ) -> None:
        super().__init__(device_id)
        self._screen = self._int("screen", screen, low=0, high=63)
        self._shape = None if shape_px is None else self._int_pair("shape_px", shape_px,
                                                                   high=16384)
        self._pitch = self._float("pixel_pitch_um", pixel_pitch_um, low=0.0, low_open=True)
        self._wl = self._float("wavelength_nm", wavelength_nm, low=0.0, low_open=True)
        if self._int("bit_depth", bit_depth, low=1, high=16) != 8:
            raise self._error(
                DeviceValueError, f"bit_depth={bit_depth} is not supported",
                "drive the panel with 8-bit gray levels (bit_depth = 8); panels with "
                "10-bit links need their vendor SDK",
            )
        self._lut0 = self._validate_setting(
            "lut_rad", linear_lut() if lut_rad is None else lut_rad, {})
        self._settle0 = self._validate_setting("settle_s", settle_s, {})
        if display is not None and (not isinstance(display, str) or not display.strip()):
            raise self._error(DeviceValueError, f"display={display!r} is not a display name",
                              "give an X display such as ':0', or leave it out")
        self._x_display = display
        self._proc: subprocess.Popen | None = None
        self._facts: dict[str, Any] = {}
        self._hw: dict[str, Any] = {}
        self._shown = 0
        self._out = bytearray()

    # ------------------------------------------------------------------ process
    def _do_open(self, timeout_s: float) -> None:
        try:
            self._connect(timeout_s)
        except BaseException:
            self._do_close()  # release the window process if the open failed half-way
            raise

    def _connect(self, timeout_s: float) -> None:
        if importlib.util.find_spec("PySide6") is None:
            raise MissingDependencyError(
                self.device_id, "PySide6 is not installed (the SLM window is a Qt window)",
                "pip install 'diffuserlab[gui]'; on a bare Debian system also apt-get install "
                "libegl1 libxkbcommon-x11-0 libxcb-cursor0 (Qt's xcb libraries)",
            )
        env = dict(os.environ)
        if self._x_display is not None:
            env["DISPLAY"] = self._x_display
        if not env.get("DISPLAY") and not env.get("WAYLAND_DISPLAY"):
            raise self._error(
                DeviceDisconnectedError, "no display: DISPLAY is not set",
                "run on the bench computer's desktop session or set params.display "
                "(e.g. ':0')",
            )
        env["QT_QPA_PLATFORM"] = "xcb" if env.get("DISPLAY") else "wayland"
        rows, cols = self._shape or (0, 0)
        if self._shape is None:
            rows, cols = self._probe_screen_size(env, timeout_s)
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "drivers.slm_window_app", str(self._screen), str(rows),
             str(cols)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
        )
        reply = self._reply(timeout_s, "the SLM window to open")
        if "error" in reply:
            self._kill()
            text = reply["error"]
            if "rows x cols" in text:
                fix = ("set params.shape_px to the screen's size, or pick the SLM's screen "
                       "with params.screen")
            elif "not mapped" in text:
                fix = ("check that the SLM's screen is on and that the display accepts new "
                       "windows, then reconnect")
            else:
                fix = ("set the SLM's desktop scaling to 100 % and its colour depth to 24 "
                       "bits, or pick another params.screen")
            gone = "exist" in text or "not mapped" in text  # no screen, or never shown
            raise self._error(DeviceDisconnectedError if gone else DeviceValueError, text, fix)
        self._facts = reply["ready"]
        self._res = (rows, cols)
        self._hw = {"lut_rad": self._lut0, "settle_s": self._settle0}
        self._shown = 0
        self._out = bytearray()
        os.set_blocking(self._proc.stdin.fileno(), False)

    def _probe_screen_size(self, env: dict[str, str], timeout_s: float) -> tuple[int, int]:
        """Start the window process once with a size of 0 x 0 to learn the screen's."""
        proc = subprocess.Popen(
            [sys.executable, "-m", "drivers.slm_window_app", str(self._screen), "0", "0"],
            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
        self._proc = proc
        try:
            reply = self._reply(timeout_s, "the SLM's screen size")
        finally:
            self._kill()
        facts = reply.get("facts")
        if facts is None:
            raise self._error(DeviceDisconnectedError, reply.get("error", str(reply)),
                              "pick the SLM's screen with params.screen")
        return int(facts["height"]), int(facts["width"])

    def _reply(self, timeout_s: float, what: str) -> dict[str, Any]:
        """The next JSON line from the window process, within ``timeout_s``."""
        proc = self._proc
        deadline = time.monotonic() + timeout_s
        line = b""
        fd = proc.stdout.fileno()
        while not line.endswith(b"\n"):
            left = deadline - time.monotonic()
            if left <= 0:
                raise self._timeout(f"no answer from the SLM window within {timeout_s:g} s "
                                    f"(waiting for {what})",
                                    "check the display; raise timeout_s")
            ready, _, _ = select.select([fd], [], [], left)
            if not ready:
                continue
            chunk = os.read(fd, 1)
            if not chunk:
                err = b""
                with contextlib.suppress(Exception):
                    proc.wait(timeout=1.0)
                    err = proc.stderr.read()[-400:]
                raise self._error(
                    DeviceDisconnectedError,
                    f"the SLM window process ended (exit status {proc.poll()}) while "
                    f"waiting for {what}: {err.decode(errors='replace').strip()}",
                    "check the SLM's monitor connection and display, then call reconnect()",
                )
            line += chunk
        return json.loads(line)

    def _kill(self) -> None:
        proc, self._proc = self._proc, None
        if proc is None:
            return
        with contextlib.suppress(Exception):
            if proc.poll() is None and proc.stdin is not None and not self._out:
                os.write(proc.stdin.fileno(), b'{"quit": true}\n')
            proc.wait(timeout=2.0)
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=5.0)
        for stream in (proc.stdin, proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()

    def _do_close(self) -> None:
        self._kill()

    def _do_check_connection(self) -> None:
        if self._proc is None or self._proc.poll() is not None:
            raise self._error(
                DeviceDisconnectedError, "the SLM window is closed (its process ended)",
                "check the SLM's monitor connection and display, then call reconnect()",
            )

    # ------------------------------------------------------------------ hooks
    def _do_get_info(self) -> dict[str, Any]:
        return {"resolution": self._res, "pixel_pitch_um": self._pitch,
                "wavelength_nm": self._wl, "screen": dict(self._facts)}

    def _do_get_settings(self) -> dict[str, Any]:
        return dict(self._hw)

    def _do_apply(self, name: str, value: Any) -> Any:
        self._hw[name] = value
        return None

    def _do_show(self, gray: np.ndarray, timeout_s: float) -> None:
        self._do_check_connection()
        deadline = time.monotonic() + timeout_s
        self._shown += 1
        self._out += json.dumps({"show": self._shown}).encode() + b"\n"
        self._out += np.ascontiguousarray(gray, np.uint8).tobytes()
        self._flush(deadline, timeout_s)
        while True:  # answers to patterns that timed out earlier come first
            reply = self._reply(max(deadline - time.monotonic(), 1e-3),
                                f"pattern {self._shown} on screen")
            if reply.get("shown") == self._shown:
                return
            if not isinstance(reply.get("shown"), int) or reply["shown"] > self._shown:
                raise self._error(DeviceDisconnectedError,
                                  f"the SLM window answered {reply} to pattern {self._shown}",
                                  "call reconnect()")

    def _flush(self, deadline: float, timeout_s: float) -> None:
        """Write the pending bytes to the window process before ``deadline``; what is
        left on a timeout is written before the next pattern (the stream stays whole)."""
        fd = self._proc.stdin.fileno()
        while self._out:
            left = deadline - time.monotonic()
            if left <= 0:
                raise self._timeout(
                    f"the SLM window took no pattern within {timeout_s:g} s "
                    f"({len(self._out)} bytes not yet taken)",
                    "check that the display is running; raise timeout_s")
            _, ready, _ = select.select([], [fd], [], left)
            if not ready:
                continue
            try:
                n = os.write(fd, self._out[:65536])
            except OSError as exc:  # BrokenPipeError: the process is gone
                raise self._error(
                    DeviceDisconnectedError, f"the SLM window process is gone ({exc})",
                    "check the SLM's monitor connection and display, then call reconnect()",
                ) from exc
            del self._out[:n]

    def _do_status(self) -> dict[str, Any]:
        return {**super()._do_status(), "screen": self._facts.get("name"),
                "window_pid": None if self._proc is None else self._proc.pid}
