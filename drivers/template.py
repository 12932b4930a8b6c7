"""The driver template: a complete stage driver for a line-based serial controller.

**Copy this file to write a new driver** (docs/drivers/writing-a-driver.md walks
through it): rename it ``drivers/<vendor>_<kind>.py``, rename the class, replace the
protocol (the commands in :meth:`TemplateStage._query` callers and the reply
parsing), keep the structure. Everything the interfaces already do (argument
checks, the settings cache, software limits, backlash, reconnect, logging) is not
repeated here: a driver only implements the ``_do_*`` hooks.

Protocol (invented for this template; emulated by
:class:`drivers.emulators.template_stage.TemplateStageEmulator`):
ASCII over a serial port at 115200 baud, 8N1. One command per line ended by
``\\n``; the controller answers every command with exactly one line ended by
``\\r\\n``. Axes are numbered from 1; positions in mm, velocities in mm/s.

=================== ======================================================
command             reply
=================== ======================================================
``*IDN?``           ``TPL-STAGE <serial> <firmware>`` (identifies the model)
``AXES?``           number of axes, e.g. ``3``
``TRAVEL? <n>``     ``<low_mm> <high_mm>``: the axis's mechanical range
``VMAX?``           ``<mm/s>``: largest velocity the controller accepts
``VEL <n> <mm/s>``  ``OK``; the controller keeps 0.001 mm/s steps
``VEL? <n>``        ``<mm/s>``: the velocity in effect
``MOVE <n> <mm>``   ``OK`` at once; the axis starts moving
``HOME <n>``        ``OK`` at once; the axis moves to its low end
``POS? <n>``        ``<mm>``: the current position (also while moving)
``MOVING?``         ``1`` while any axis moves, else ``0``
``STOP``            ``OK``; every axis decelerates and stops
``FAULT? <n>``      ``0``, or ``<code> <text>`` (e.g. ``1 limit switch``): why the
                    last move of the axis ended early; cleared by the next
                    ``MOVE`` or ``HOME``
=================== ======================================================

A refused command gets ``ERR <code> <text>``: 1 unknown command, 2 value out of
range, 3 no such axis. The protocol has no message ids: a reply that arrives
after its command timed out is dropped before the next command is sent.
"""

from __future__ import annotations

# 1. Imports: only the interface of the kind, the errors and a transport. No
#    optional library here (pyserial, hidapi, ...): the transport imports it when
#    the device opens, so `import drivers` works without the `hardware` extra and a
#    missing library is a MissingDependencyError naming the extra.
import threading
import time
from collections.abc import Mapping, Sequence
from typing import Any

from drivers.errors import (
    DeviceDisconnectedError,
    DeviceProtocolError,
    DeviceValueError,
    StageMotionError,
)
from drivers.stage import AXIS_UNITS, HostTableStage
from drivers.transports import BY_ID_DIR, SerialLink

__all__ = ["ERROR_FIXES", "MODEL", "TemplateStage"]

#: First word of the ``*IDN?`` reply of the controllers this driver speaks to.
MODEL = "TPL-STAGE"
#: What to do about each error code of an ``ERR`` reply (the message names the code,
#: the controller's text and this fix).
ERROR_FIXES: dict[int, str] = {
    1: "the controller does not know this command: check its firmware version",
    2: "the value is out of range: check the axis's travel (TRAVEL?) and VMAX?",
    3: "the controller has no such axis: check axis_numbers",
}


# 2. The class: pick the interface of the kind (drivers/camera.py, stage.py,
#    led_array.py, slm.py, dmd.py). A stage whose limits and backlash are kept by the
#    host, as most controllers' are, derives from HostTableStage: it then supplies
#    only the travel, the velocity and the motion commands.
class TemplateStage(HostTableStage):
    """Stage on a line-based serial controller (the template's protocol, see the module).

    Every constructor keyword is a parameter a bench file may set in the device's
    ``params`` table (``diffuserlab validate`` checks them against this signature).

    Parameters
    ----------
    device_id : str
        Name of the stage, in every log line and error message.
    axes : sequence of str
        Axis names, each ``"x"``, ``"y"`` or ``"z"`` (the protocol speaks mm).
    port : str, optional
        Serial port; best a stable ``/dev/serial/by-id/...`` link.
    serial_number : str, optional
        USB serial number of the port's adapter, looked up on every open (so the
        stage is found again after an unplug); used when ``port`` is not given.
    baudrate : int
        Line speed (the protocol's default is 115200).
    axis_numbers : Mapping[str, int], optional
        ``{axis: controller axis number}``; default 1, 2, ... in the order of
        ``axes``.
    limits_mm : Mapping[str, (float, float)], optional
        Travel per axis narrower than the controller's (e.g. a mount in the way).
    velocity_mm_s : float, optional
        Velocity set at open, mm/s; default the velocity the controller has.
    reply_timeout_s : float
        Longest wait for one reply, seconds.
    poll_s : float
        Polling period while waiting for a move to end, seconds.
    search_dirs : sequence of str
        Link directories searched for ``serial_number``.

    Raises
    ------
    DeviceValueError
        A bad parameter (raised here, before anything is opened).
    """

    # 3. The constructor checks the parameters and stores them; it never touches
    #    the hardware (a bench file is validated by constructing its devices).
    #    Use self._error(cls, problem, fix) for every error: it names the device.
    def __init__(
        self, device_id: str, *, axes: Sequence[str] = ("x",), port: str | None = None,
        serial_number: str | None = None, baudrate: int = 115200,
        axis_numbers: Mapping[str, int] | None = None,
        limits_mm: Mapping[str, Sequence[float]] | None = None,
        velocity_mm_s: float | None = None, reply_timeout_s: float = 1.0, poll_s: float = 0.01,
        search_dirs: Sequence[str] = (BY_ID_DIR,),
    ) -> None:
        super().__init__(device_id)
        if isinstance(axes, str) or not isinstance(axes, Sequence) or not axes:
            raise self._error(DeviceValueError, f"axes={axes!r} is not a list of axis names",
                              'pass e.g. axes = ["x", "y"]')
        bad = [a for a in axes if AXIS_UNITS.get(a) != "mm"]
        if bad or len(set(axes)) != len(axes):
            raise self._error(DeviceValueError, f"axes {list(axes)} are not distinct "
                              "linear axes", 'use each of "x", "y", "z" at most once')
        numbers = dict(axis_numbers or {a: i + 1 for i, a in enumerate(axes)})
        missing = [a for a in axes if a not in numbers]
        if missing:
            raise self._error(DeviceValueError, f"axes {missing} have no axis number",
                              "add them to axis_numbers, e.g. { x = 1 }")
        self._num = {a: self._int(f"axis_numbers[{a}]", numbers[a], low=1, high=99)
                     for a in axes}
        if len(set(self._num.values())) != len(self._num):
            raise self._error(DeviceValueError, f"axis_numbers {self._num} repeat a number",
                              "give each axis its own controller axis")
        self._limits_param = {a: tuple(v) for a, v in dict(limits_mm or {}).items()}
        unknown = sorted(set(self._limits_param) - set(self._num))
        if unknown:
            raise self._error(DeviceValueError, f"limits_mm names axes {unknown} the stage "
                              "does not have", f"use axes from {list(self._num)}")
        self._velocity_param = None if velocity_mm_s is None else self._float(
            "velocity_mm_s", velocity_mm_s, low=0.0, low_open=True)
        self._reply_timeout = self._float("reply_timeout_s", reply_timeout_s, low=0.0,
                                          low_open=True)
        self._poll = self._float("poll_s", poll_s, low=0.0, low_open=True, high=1.0)
        # The transport: SerialLink resolves the port on every open, opens it
        # exclusively, puts a deadline on every read and turns an I/O error (a
        # yanked cable) into DeviceDisconnectedError. Its reads raise the kind's
        # timeout error (StageTimeoutError), which the conformance suite expects.
        self._link = SerialLink(device_id, port=port, serial_number=serial_number,
                                search_dirs=search_dirs, baudrate=baudrate,
                                timeout_error=self.timeout_error)
        # One command and its reply at a time: a GUI's status poll and a running
        # plan may call from two threads, and one must not read the other's reply.
        self._lock = threading.RLock()
        # What HostTableStage needs, filled at open (see _do_open).
        self._travel: dict[str, tuple[float, float]] = {}
        self._vmax = 0.0
        self._hw: dict[str, Any] = {}
        self._moving: set[str] = set()  # axes the last move or home started
        self._idn = ""

    # 4. The protocol layer: one function that sends a command and returns its
    #    reply, with a deadline, and turns an error reply into DeviceProtocolError
    #    naming the command, the controller's words and the fix.
    def query(self, command: str, timeout_s: float | None = None) -> str:
        """Send one command and return its reply line (without the line end).

        Parameters
        ----------
        command : str
            The command, e.g. ``"POS? 1"``.
        timeout_s : float, optional
            Longest wait for the reply, seconds; default ``reply_timeout_s``.

        Returns
        -------
        str
            The reply, e.g. ``"12.5"`` or ``"OK"``.

        Raises
        ------
        DeviceProtocolError
            The controller refused the command (``ERR <code> <text>``).
        StageTimeoutError
            No reply in time.
        DeviceDisconnectedError
            The port failed (unplugged).
        """
        with self._lock:
            # A late reply to an earlier, timed-out command would otherwise be read
            # as this command's reply (the protocol has no message ids).
            self._link.discard_input()
            self._link.write(f"{command}\n".encode("ascii"))
            raw = self._link.read_until(b"\n", self._reply_timeout if timeout_s is None
                                        else timeout_s, what=f"reply to {command!r}")
        reply = raw.decode("ascii", "replace").strip()
        if reply.startswith("ERR"):
            code, _, text = reply[3:].strip().partition(" ")
            fix = ERROR_FIXES.get(int(code) if code.isdigit() else -1,
                                  "check the command against the protocol")
            raise self._error(DeviceProtocolError,
                              f"the controller refused {command!r}: {reply}", fix)
        return reply

    def _number(self, command: str) -> float:
        """The reply to ``command`` as one number (a malformed reply is named)."""
        reply = self.query(command)
        try:
            return float(reply)
        except ValueError:
            raise self._error(DeviceProtocolError, f"reply {reply!r} to {command!r} is not "
                              "a number", "check that the port holds this controller "
                              "(*IDN?) and the baud rate") from None

    # 5. Lifecycle hooks (called by Device.open / close / reconnect).
    def _do_open(self, timeout_s: float) -> None:
        """Connect, check the model, read the fixed properties, apply the initial
        velocity. Everything within ``timeout_s`` per reply of the first exchange."""
        self._moving = set()
        self._link.open()  # raises DeviceDisconnectedError: absent, busy, no access
        try:
            # The first exchange tells whether the right device is on the port.
            self._idn = self.query("*IDN?", timeout_s=min(timeout_s, self._reply_timeout))
            if self._idn.split(" ")[0] != MODEL:
                raise self._error(DeviceProtocolError,
                                  f"the device on {self._link.path} is {self._idn!r}, not a "
                                  f"{MODEL} controller", "check the port or serial_number")
            n_axes = int(self._number("AXES?"))
            beyond = {a: n for a, n in self._num.items() if n > n_axes}
            if beyond:
                raise self._error(DeviceValueError, f"axis numbers {beyond} exceed the "
                                  f"controller's {n_axes} axes", "check axis_numbers")
            self._travel = {a: self._read_travel(a) for a in self._num}
            self._vmax = self._number("VMAX?")
            velocity = {}
            for a, n in self._num.items():
                if self._velocity_param is not None:
                    v = self._float(f"velocity_mm_s (max {self._vmax:g})",
                                    self._velocity_param, low=0.0, low_open=True,
                                    high=self._vmax)
                    velocity[a] = self._send_velocity(a, v)
                else:
                    velocity[a] = self._number(f"VEL? {n}")
            # HostTableStage's settings table: the limits start at the travel, the
            # backlash off; Stage applies both on the host.
            self._hw = {"limits": dict(self._travel), "velocity": velocity,
                        "backlash": dict.fromkeys(self._travel, 0.0)}
        except BaseException:
            self._link.close()  # a failed open leaves the port free
            raise

    def _read_travel(self, axis: str) -> tuple[float, float]:
        reply = self.query(f"TRAVEL? {self._num[axis]}")
        try:
            lo, hi = (float(v) for v in reply.split())
        except ValueError:
            raise self._error(DeviceProtocolError, f"reply {reply!r} to TRAVEL? is not two "
                              "numbers", "check the controller's firmware") from None
        if axis in self._limits_param:
            plo, phi = (self._float(f"limits_mm[{axis}]", v) for v in self._limits_param[axis])
            if not lo <= plo < phi <= hi:
                raise self._error(DeviceValueError, f"limits_mm[{axis}] = ({plo:g}, {phi:g}) "
                                  f"is not within the controller's travel ({lo:g}, {hi:g})",
                                  "narrow limits_mm")
            lo, hi = plo, phi
        return lo, hi

    def _do_close(self) -> None:
        self._link.close()  # never raises, also for a port that went away

    def _do_check_connection(self) -> None:
        """Called before each public call: a port closed by an I/O error is named."""
        if not self._link.is_open:
            raise self._error(DeviceDisconnectedError, f"serial port {self._link.path} is "
                              "closed (the device went away)", "call reconnect()")
        self._link.check_hangup()

    # 6. Settings: HostTableStage keeps limits and backlash on the host and calls
    #    this for each velocity that changes; return what the controller took.
    def _send_velocity(self, axis: str, velocity: float) -> float:
        n = self._num[axis]
        self.query(f"VEL {n} {velocity:.6g}")
        return self._number(f"VEL? {n}")  # read back: the controller rounds

    # 7. Motion hooks (Stage.move_to / home / wait_until_idle / stop call them, after
    #    checking the targets against the limits; here they only talk to the device).
    def _do_move(self, targets: dict[str, float]) -> None:
        for a, t in targets.items():
            self._moving.add(a)
            self.query(f"MOVE {self._num[a]} {t:.6f}")

    def _do_home(self, axes: tuple[str, ...]) -> None:
        for a in axes:
            self._moving.add(a)
            self.query(f"HOME {self._num[a]}")

    def _do_is_moving(self) -> bool:
        return self.query("MOVING?") == "1"

    def _do_positions(self) -> dict[str, float]:
        return {a: self._number(f"POS? {n}") for a, n in self._num.items()}

    def _do_positions_of(self, axes: tuple[str, ...]) -> dict[str, float]:
        return {a: self._number(f"POS? {self._num[a]}") for a in axes}

    def _do_stop(self) -> None:
        self.query("STOP")
        self._moving.clear()

    def _do_wait(self, timeout_s: float) -> bool:
        """Poll until idle; False on timeout (Stage then stops the stage and raises
        StageTimeoutError). A move that ended early raises StageMotionError."""
        deadline = time.monotonic() + timeout_s
        while self._do_is_moving():
            if time.monotonic() >= deadline:
                return False
            time.sleep(min(self._poll, max(deadline - time.monotonic(), 0.0)))
        watched, self._moving = sorted(self._moving), set()
        faults = {a: self.query(f"FAULT? {self._num[a]}") for a in watched}
        faults = {a: f for a, f in faults.items() if f != "0"}
        if faults:
            where = "; ".join(f"axis {a}: {f} at {self._do_positions_of((a,))[a]:.6g} mm"
                              for a, f in faults.items())
            raise self._error(StageMotionError, f"move ended early: {where}",
                              "check the travel and for obstructions; the stage is idle")
        return True

    # 8. Optional: details for status() (JSON-able), shown by the GUI and the CLI.
    def _do_status(self) -> dict[str, Any]:
        out = super()._do_status()
        out["port"] = self._link.path
        out["controller"] = self._idn
        return out
