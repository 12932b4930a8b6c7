"""Thorlabs APT stage driver: KDC101 (DC servo), KST101 (stepper) and BSC20x (stepper rack).

One :class:`ThorlabsAptStage` drives several axes: each axis is a single-channel
K-cube found by its USB serial number (``serial_numbers``), or a bay of a BSC20x
on one port (``port`` and ``bays``). Wire protocol, messages and framing:
:mod:`drivers.thorlabs_apt_protocol`; controller models and stage constants:
:mod:`drivers.thorlabs_apt_models`; operator notes: docs/drivers/thorlabs-apt.md.

The controller's scaling follows from the model string it reports (HW_GET_INFO), not
from its serial number (serial prefixes 40/70 also cover the legacy BSC101/BSC103
racks, refused here); a ``profile`` given in the bench file must agree with it.
Positions travel as integer counts; ``counts_per_unit`` (per axis) converts them, or
the constant of a known stage (``stages``, or the stage a KDC101 reports). A rotation
axis needs one of them (a PRM1-Z8 has 1919.64 counts/deg, not the Z8's 34554.96/mm).
Linear axes default to the profile's actuator, which must be calibrated: the Z8
actuators' 34554.96 counts/mm of the 2025 protocol document differ by 0.73 % from the
34304 of older documents (220 µm over 30 mm). Velocities and accelerations are sent
in controller units and read back; the controller's quantisation (within 1 %) is
accepted and the velocity it took becomes the setting.

Motion state is polled (MOT_REQ_STATUSBITS, MOT_REQ_POSCOUNTER), never cached,
because the K-cube's wheel moves the stage too; MOVE_COMPLETED, MOVE_HOMED,
MOVE_STOPPED and the status updates are events that wake a waiting call early. With
``status_updates`` on (K-cubes), the controller's updates are acknowledged every
``keepalive_s`` (it goes silent after 50 unacknowledged ones). An axis found moving
when the stage opens (a reconnect while a move went on) is stopped, and reported
(a warning and ``status()["stopped_at_open"]``), so no stale position is read.

Software limits are the ``limits`` setting (checked before anything moves); a move
that ends farther from its target than ``position_tolerance_counts`` (a hardware limit
switch, a stall, an error reported by the controller) raises
:class:`~drivers.errors.StageMotionError`. Absolute moves are refused until the axis
is homed (``require_homed``; ``home_on_open`` homes at open, within
``home_timeout_s`` and the open's own ``timeout_s`` and cancel event). The stored
homing parameters are left as they are unless ``home_velocity`` is given (then only
the velocity changes).
"""

from __future__ import annotations

import struct
import time
from collections.abc import Mapping, Sequence
from typing import Any

from drivers.errors import (
    DeviceProtocolError,
    DeviceStateError,
    DeviceValueError,
    StageMotionError,
)
from drivers.stage import AXIS_UNITS, HostTableStage
from drivers.thorlabs_apt_models import (
    COUNTS_PER_UNIT,
    KDC_STAGE_IDS,
    POSITION_TOLERANCE_COUNTS,
    STAGES,
    profile_of_model,
    velocity_units,
)
from drivers.thorlabs_apt_protocol import (
    MOVING_MASK,
    MSG,
    STATUS,
    USB_UNIT,
    AptController,
    AptMessage,
)
from drivers.transports import BY_ID_DIR, SerialLink

__all__ = ["COUNTS_PER_UNIT", "STAGES", "ThorlabsAptStage"]

_DEFAULT_MAX_VELOCITY = {"kdc101": 2.6, "kst101": 5.0, "bsc20x": 5.0}
#: Relative difference between the velocity sent and read back taken as quantisation.
_VELOCITY_QUANTUM = 0.01


class ThorlabsAptStage(HostTableStage):
    """Stage on Thorlabs APT controllers (one K-cube per axis, or a BSC20x's bays).

    Parameters
    ----------
    device_id : str
        Name of the stage.
    axes : sequence of str or Mapping[str, (float, float)]
        Axis names (x, y, z in mm; tip, tilt, rotation in degrees), or names with
        their travel.
    port : str, optional
        Serial port of the axes that have no serial number (best a
        ``/dev/serial/by-id/...`` path): one K-cube, or a BSC20x with ``bays``.
    serial_numbers : Mapping[str, str], optional
        ``{axis: USB serial}``: each axis on its own controller, found by serial
        number on every open (so it is found again after an unplug).
    bays : Mapping[str, int], optional
        ``{axis: bay}`` (0-based) of a BSC20x on ``port``.
    profile : str, optional
        "kdc101", "kst101" or "bsc20x". By default the controller's model string
        decides (KDC101/TDC001, KST101/TST101, BSC20x); a profile given here must agree
        with it, and is required for a model the driver does not know.
    counts_per_unit : float or Mapping[str, float], optional
        Encoder counts (microsteps) per mm or degree, per axis. Default: the stage's
        (``stages``, or the stage a KDC101 reports), else for linear axes the
        profile's actuator (:data:`~drivers.thorlabs_apt_models.COUNTS_PER_UNIT`).
        Rotation axes need it or a known stage. Calibrate it.
    stages : Mapping[str, str], optional
        ``{axis: stage model}`` from :data:`~drivers.thorlabs_apt_models.STAGES`
        (e.g. ``{rotation = "PRM1-Z8"}``).
    limits_mm, limits_deg : Mapping[str, (float, float)], optional
        Travel per axis (software limits start there); required for axes given by
        name only.
    speed_mm_s, speed_deg_s : float, optional
        Initial velocity (unit/s); default half the maximum.
    acceleration : float
        Acceleration in unit/s², sent with every velocity.
    max_velocity : float, optional
        Largest velocity allowed (unit/s); default per profile (2.6 DC, 5 steppers).
    home_velocity : float, optional
        Homing velocity (unit/s), written into the controller's stored homing
        parameters (direction, limit switch and offset are kept); by default the
        stored parameters are left alone.
    position_tolerance_counts : int or Mapping[str, int], optional
        Largest distance between a finished move and its target, counts, per axis;
        default 20 for a DC servo, 2 for a stepper.
    require_homed : bool
        Refuse moves of an axis that is not homed (the position is not referenced).
    home_on_open : bool
        Home every axis that is not homed when the stage opens.
    home_timeout_s : float
        Longest wait for that homing, s (default 120); an open given a ``timeout_s``
        (or a cancel event) ends it sooner.
    status_updates : bool, optional
        Ask for the controller's status updates and acknowledge them; default on for
        K-cubes, off for a BSC20x (it ignores the acknowledgement).
    keepalive_s, reply_timeout_s, poll_s : float
        Keepalive period, longest wait for a reply, polling period while moving.
    search_dirs : sequence of str
        Where port links named after serial numbers are looked for (after pyserial's
        ``list_ports``).
    """

    def __init__(
        self, device_id: str, *, axes: Sequence[str] | Mapping[str, Any] = ("x",),
        port: str | None = None, serial_numbers: Mapping[str, str | int] | None = None,
        bays: Mapping[str, int] | None = None, profile: str | None = None,
        counts_per_unit: float | Mapping[str, float] | None = None,
        stages: Mapping[str, str] | None = None,
        limits_mm: Mapping[str, Sequence[float]] | None = None,
        limits_deg: Mapping[str, Sequence[float]] | None = None,
        speed_mm_s: float | None = None, speed_deg_s: float | None = None,
        acceleration: float = 1.5, max_velocity: float | None = None,
        home_velocity: float | None = None,
        position_tolerance_counts: int | Mapping[str, int] | None = None,
        require_homed: bool = True, home_on_open: bool = False,
        home_timeout_s: float = 120.0, status_updates: bool | None = None,
        keepalive_s: float = 0.9,
        reply_timeout_s: float = 1.0, poll_s: float = 0.01,
        search_dirs: Sequence[str] = (BY_ID_DIR,),
    ) -> None:
        super().__init__(device_id)
        travel = self._travel_from(axes, {**dict(limits_mm or {}), **dict(limits_deg or {})})
        serials = {str(a): str(s) for a, s in dict(serial_numbers or {}).items()}
        bays = dict(bays or {})
        stages = {str(a): str(n).strip().upper() for a, n in dict(stages or {}).items()}
        for name, table in (("serial_numbers", serials), ("bays", bays), ("stages", stages)):
            extra = sorted(set(table) - set(travel))
            if extra:
                raise self._error(DeviceValueError, f"{name} names unknown axes {extra}",
                                  f"use axes from {list(travel)}")
        if profile is not None and profile not in COUNTS_PER_UNIT:
            raise self._error(DeviceValueError, f"profile={profile!r} is not supported",
                              f"use one of {sorted(COUNTS_PER_UNIT)}")
        self._axes: dict[str, dict[str, Any]] = {}
        for axis in travel:
            if axis in serials:
                key, sn = f"sn:{serials[axis]}", serials[axis]
            elif port:
                key, sn = f"port:{port}", None
            else:
                raise self._error(DeviceValueError, f"axis {axis!r} has no controller",
                                  "give its serial number in serial_numbers, or a port")
            bay = bays.get(axis)
            dest = USB_UNIT if bay is None else 0x21 + self._int(f"bays[{axis}]", bay, low=0,
                                                                  high=9)
            stage = stages.get(axis)
            if stage is not None:
                if stage not in STAGES:
                    raise self._error(DeviceValueError, f"stages[{axis}] = {stage!r} is not "
                                      "a known stage", f"use one of {sorted(STAGES)}, or give "
                                      "counts_per_unit")
                if STAGES[stage].unit != AXIS_UNITS[axis]:
                    raise self._error(DeviceValueError, f"stage {stage} moves in "
                                      f"{STAGES[stage].unit}, axis {axis} in {AXIS_UNITS[axis]}",
                                      "give the stage to an axis of its unit")
            self._axes[axis] = {"key": key, "serial": sn, "dest": dest, "stage": stage,
                                "profile": None, "cpu": None, "tol": None}
        shared = [a for a in self._axes if self._axes[a]["dest"] == USB_UNIT]
        keys = [self._axes[a]["key"] for a in shared]
        if len(keys) != len(set(keys)):
            raise self._error(DeviceValueError, "several axes share one single-channel port",
                              "give each axis a serial number, or the bays of a BSC20x")
        cpu = counts_per_unit if isinstance(counts_per_unit, Mapping) else dict.fromkeys(
            travel, counts_per_unit)
        self._cpu_param = {a: self._float(f"counts_per_unit[{a}]", cpu[a], low=0.0,
                                          low_open=True)
                           for a in travel if cpu.get(a) is not None}
        tol = (position_tolerance_counts if isinstance(position_tolerance_counts, Mapping)
               else dict.fromkeys(travel, position_tolerance_counts))
        self._tol_param = {a: self._int(f"position_tolerance_counts[{a}]", tol[a], low=0)
                           for a in travel if tol.get(a) is not None}
        self._profile_param = profile
        self._travel = travel
        self._vmax_param = None if max_velocity is None else self._float(
            "max_velocity", max_velocity, low=0.0, low_open=True)
        self._speed_param = {a: (speed_deg_s if AXIS_UNITS[a] == "deg" else speed_mm_s)
                             for a in travel}
        for axis, v in self._speed_param.items():
            if v is not None:
                self._float(f"speed of {axis}", v, low=0.0, low_open=True,
                            high=self._vmax_param or float("inf"))
        self._vmax = self._vmax_param or 0.0
        self._v0: dict[str, float] = {}
        self._accel = self._float("acceleration", acceleration, low=0.0, low_open=True)
        self._home_v = None if home_velocity is None else self._float(
            "home_velocity", home_velocity, low=0.0, low_open=True,
            high=self._vmax_param or float("inf"))
        self.require_homed, self.home_on_open = bool(require_homed), bool(home_on_open)
        self._home_timeout = self._float("home_timeout_s", home_timeout_s, low=0.0,
                                         low_open=True)
        self._status_updates = status_updates
        self._keepalive = self._float("keepalive_s", keepalive_s, low=0.05, high=1.0)
        self._reply_timeout = self._float("reply_timeout_s", reply_timeout_s, low=0.0,
                                          low_open=True)
        self._poll = self._float("poll_s", poll_s, low=0.0, low_open=True, high=1.0)
        self._port = port
        self._search_dirs = tuple(str(d) for d in search_dirs)
        self._ctrl: dict[str, AptController] = {}
        self._targets: dict[str, float] = {}
        self._homing: set[str] = set()
        self._faults: list[str] = []
        self._hw: dict[str, Any] = {}
        self.stopped_at_open: dict[str, float] = {}

    def _travel_from(self, axes: Any, limits: Mapping[str, Any]) -> dict[str, tuple[float, float]]:
        if isinstance(axes, str) or not isinstance(axes, Mapping | Sequence) or not axes:
            raise self._error(DeviceValueError, f"axes={axes!r} is invalid",
                              'pass axis names, e.g. axes = ["x", "y", "z"]')
        table = dict(axes) if isinstance(axes, Mapping) else {a: limits.get(a) for a in axes}
        out = {}
        for name, rng in table.items():
            if name not in AXIS_UNITS:
                raise self._error(DeviceValueError, f"axis name {name!r} is not supported",
                                  f"use names from {list(AXIS_UNITS)}")
            if rng is None:
                unit = AXIS_UNITS[name]
                raise self._error(DeviceValueError, f"axis {name!r} has no travel",
                                  f"give limits_{unit} = {{ {name} = [low, high] }}")
            lo, hi = self._float(f"{name} low", rng[0]), self._float(f"{name} high", rng[1])
            if not lo < hi:
                raise self._error(DeviceValueError, f"travel of {name} ({lo}, {hi}) is empty",
                                  "give low < high")
            out[name] = (lo, hi)
        return out

    # ----------------------------------------------------------- lifecycle hooks
    def _do_open(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        self._ctrl = {}
        self._faults = []
        self.stopped_at_open = {}
        try:
            for info in self._axes.values():
                key = info["key"]
                if key in self._ctrl:
                    continue
                link = SerialLink(
                    self.device_id, port=None if info["serial"] else self._port,
                    serial_number=info["serial"], search_dirs=self._search_dirs,
                    baudrate=115200, rtscts=True, rts=True, timeout_error=self.timeout_error,
                )
                ctrl = AptController(self.device_id, link, on_event=self._on_event,
                                     timeout_error=self.timeout_error,
                                     keepalive_s=self._keepalive)
                ctrl.open()
                self._ctrl[key] = ctrl
                self._identify(ctrl, info, min(timeout_s, self._reply_timeout))
            for axis, info in self._axes.items():
                self._resolve_axis(axis, info)
            self._resolve_velocities()
            self._stop_motion_found(deadline)
            for axis, info in self._axes.items():
                self._prepare_axis(axis, info)
            for key, ctrl in self._ctrl.items():
                profs = {i["profile"] for i in self._axes.values() if i["key"] == key}
                updates = self._status_updates
                if updates is None:
                    updates = "bsc20x" not in profs
                if updates:
                    ctrl.start_updates(tuple(sorted({i["dest"] for i in self._axes.values()
                                                     if i["key"] == key})))
            self._hw = {"limits": dict(self._travel), "velocity": dict(self._v0),
                        "backlash": dict.fromkeys(self._travel, 0.0)}
            if self.home_on_open:
                self._home_at_open()
        except BaseException:
            self._do_close()
            raise

    def _identify(self, ctrl: AptController, info: dict[str, Any], timeout_s: float) -> None:
        dest = 0x11 if info["dest"] != USB_UNIT else USB_UNIT
        reply = ctrl.request(MSG["HW_REQ_INFO"], MSG["HW_GET_INFO"], dest,
                             timeout_s=max(timeout_s, self._reply_timeout))
        data = reply.data or b""
        if len(data) < 12:
            raise self._error(DeviceProtocolError, f"HW_GET_INFO carried {len(data)} bytes",
                              "check that the device is a Thorlabs APT controller")
        serial = struct.unpack_from("<i", data)[0]
        model = data[4:12].split(b"\0")[0].decode("ascii", "replace").strip()
        stage_id = struct.unpack_from("<H", data, 76)[0] if len(data) >= 78 else 0
        ctrl.info = {"serial": serial, "model": model}  # type: ignore[attr-defined]
        if stage_id in KDC_STAGE_IDS:
            ctrl.info["stage"] = KDC_STAGE_IDS[stage_id]  # type: ignore[attr-defined]
        if info["serial"] and str(serial) != info["serial"]:
            raise self._error(DeviceProtocolError,
                              f"controller on {ctrl.link.path} reports serial {serial}, "
                              f"expected {info['serial']}", "check serial_numbers")

    def _resolve_axis(self, axis: str, info: dict[str, Any]) -> None:
        """Profile, counts per unit and position tolerance of an axis, from what its
        controller reported and the bench file's parameters."""
        ctrl_info = getattr(self._ctrl[info["key"]], "info", {})
        model = ctrl_info.get("model", "")
        try:
            profile = profile_of_model(model)
        except ValueError:
            raise self._error(
                DeviceValueError, f"controller {model} (serial {ctrl_info.get('serial')}) is a "
                "legacy stepper controller whose microsteps and velocity scaling this driver "
                "does not support (no 53.68 velocity factor)",
                "use a BSC20x/KST101 controller, or another driver") from None
        if profile is None and self._profile_param is None:
            raise self._error(DeviceValueError, f"controller model {model!r} (serial "
                              f"{ctrl_info.get('serial')}) is not one this driver knows",
                              "set profile = \"kdc101\", \"kst101\" or \"bsc20x\" if it "
                              "uses that scaling")
        if profile is not None and self._profile_param not in (None, profile):
            raise self._error(DeviceValueError, f"profile={self._profile_param!r} contradicts "
                              f"the controller's model {model} (profile {profile!r})",
                              f"remove profile, or set profile = {profile!r}")
        if profile is None:
            self._log.warning("%s: controller model %r unknown; using profile %r as set",
                              self.device_id, model, self._profile_param)
            profile = self._profile_param
        stage = info["stage"] or ctrl_info.get("stage")
        unit = AXIS_UNITS[axis]
        if stage is not None and (STAGES[stage].unit != unit or
                                  profile not in STAGES[stage].profiles):
            if info["stage"] is not None:  # named in the bench file: a contradiction
                raise self._error(DeviceValueError, f"stage {stage} cannot be on a {profile} "
                                  f"axis {axis} in {unit}", "check stages and the controller")
            self._log.warning("%s: controller %s reports stage %s, which does not fit axis %s "
                              "(%s); ignored", self.device_id, model, stage, axis, unit)
            stage = None  # the controller's own stage setting does not fit this axis
        if axis in self._cpu_param:
            cpu = self._cpu_param[axis]
        elif stage is not None:
            cpu = STAGES[stage].counts_per_unit
        elif unit == "deg":
            raise self._error(DeviceValueError, f"rotation axis {axis} has no counts per "
                              "degree (the controller reports no stage this driver knows)",
                              f"give counts_per_unit = {{ {axis} = ... }} or stages = "
                              f"{{ {axis} = \"PRM1-Z8\" }} (1919.64 counts/deg)")
        else:
            cpu = COUNTS_PER_UNIT[profile]
        info.update(profile=profile, cpu=cpu, stage=stage,
                    tol=self._tol_param.get(axis, POSITION_TOLERANCE_COUNTS[profile]))

    def _resolve_velocities(self) -> None:
        prof0 = next(iter(self._axes.values()))["profile"]
        self._vmax = self._vmax_param or _DEFAULT_MAX_VELOCITY[prof0]
        for axis in self._travel:
            v = self._speed_param[axis]
            self._v0[axis] = self._float(f"speed of {axis}", v if v is not None else
                                         self._vmax / 2, low=0.0, low_open=True,
                                         high=self._vmax)
        if self._home_v is not None:
            self._float("home_velocity", self._home_v, high=self._vmax)

    def _stop_motion_found(self, deadline: float) -> None:
        """Stop and report axes that move as the stage opens (the controller went on
        with a move while the host was away); a homing axis is left homing when
        ``home_on_open`` waits for it."""
        moving = {}
        for axis in self._axes:
            bits = self._status(axis)
            if bits & MOVING_MASK and not (self.home_on_open and bits & STATUS["HOMING"]):
                moving[axis] = bits
        if not moving:
            return
        for axis in moving:
            info = self._axes[axis]
            self._ctrl[info["key"]].send(MSG["MOT_MOVE_STOP"], info["dest"], 1, 0x02)
        while any(self._status(a) & MOVING_MASK for a in moving):
            if time.monotonic() > deadline:
                raise self._timeout(f"axes {sorted(moving)} were moving when the stage "
                                    "opened and did not stop", "check the controller")
            time.sleep(self._poll)
        self.stopped_at_open = {a: self._counts(a) / self._axes[a]["cpu"] for a in moving}
        self._log.warning("%s: axes %s were moving when the stage opened (a move went on "
                          "while disconnected); stopped at %s", self.device_id,
                          sorted(moving), self.stopped_at_open)

    def _home_at_open(self) -> None:
        status = {a: self._status(a) for a in self._axes}
        todo = tuple(a for a, s in status.items() if not s & (STATUS["HOMED"] | STATUS["HOMING"]))
        already = {a for a, s in status.items() if s & STATUS["HOMING"]}
        if todo:
            self._do_home(todo)
        self._homing |= already
        if todo or already:
            self._wait_homing_at_open(self._home_timeout)

    def _prepare_axis(self, axis: str, info: dict[str, Any]) -> None:
        ctrl, dest = self._ctrl[info["key"]], info["dest"]
        state = ctrl.request(MSG["MOD_REQ_CHANENABLESTATE"], MSG["MOD_GET_CHANENABLESTATE"],
                             dest, param1=1, timeout_s=self._reply_timeout)
        if state.param2 != 0x01:  # a BSC20x powers up disabled
            ctrl.send(MSG["MOD_SET_CHANENABLESTATE"], dest, 1, 0x01)
            time.sleep(0.05)
        # controller-side backlash off: the Stage interface compensates backlash itself
        ctrl.send(MSG["MOT_SET_GENMOVEPARAMS"], dest, data=struct.pack("<Hi", 1, 0))
        self._v0[axis] = self._send_velocity(axis, self._v0[axis])
        if self._home_v is not None:  # change the velocity only, keep the rest as stored
            reply = ctrl.request(MSG["MOT_REQ_HOMEPARAMS"], MSG["MOT_GET_HOMEPARAMS"], dest,
                                 param1=1, timeout_s=self._reply_timeout)
            _, direction, switch, _, offset = struct.unpack_from("<HHHii",
                                                                 reply.data or bytes(14))
            vel_units = self._velocity_units(axis, self._home_v, self._accel)[0]
            ctrl.send(MSG["MOT_SET_HOMEPARAMS"], dest,
                      data=struct.pack("<HHHii", 1, direction, switch, vel_units, offset))

    def _do_close(self) -> None:
        ctrls, self._ctrl = self._ctrl, {}
        for ctrl in ctrls.values():
            ctrl.close()

    def _do_check_connection(self) -> None:
        for ctrl in self._ctrl.values():
            ctrl.check()

    # ----------------------------------------------------------- units
    def _velocity_units(self, axis: str, velocity: float, accel: float) -> tuple[int, int]:
        info = self._axes[axis]
        return velocity_units(info["profile"], info["cpu"], velocity, accel)

    def _send_velocity(self, axis: str, velocity: float) -> float:
        """Send one axis's velocity and read it back; return the velocity the controller
        took (its quantisation accepted within 1 %). A controller that took less (the
        stage's speed limit) gets the velocity before back and a DeviceValueError naming
        the limit is raised."""
        info = self._axes[axis]
        ctrl, dest = self._ctrl[info["key"]], info["dest"]
        vel, acc = self._velocity_units(axis, velocity, self._accel)
        ctrl.send(MSG["MOT_SET_VELPARAMS"], dest, data=struct.pack("<Hiii", 1, 0, acc, vel))
        back = ctrl.request(MSG["MOT_REQ_VELPARAMS"], MSG["MOT_GET_VELPARAMS"], dest,
                            param1=1, timeout_s=self._reply_timeout)
        got = struct.unpack_from("<Hiii", back.data or bytes(14))
        if got[2] == acc and 0 < got[3] < vel * (1 - _VELOCITY_QUANTUM):
            took = velocity * got[3] / vel
            unit = "deg/s" if AXIS_UNITS[axis] == "deg" else "mm/s"
            before = (getattr(self, "_hw", None) or {}).get("velocity", {}).get(axis)
            if before is not None and before < took:  # the setting stays in effect
                self._send_velocity(axis, before)
            raise self._error(DeviceValueError,
                              f"axis {axis}: the controller took {took:.4g} {unit} of the "
                              f"{velocity:g} {unit} sent: the stage's speed limit",
                              f"set a velocity of at most {took:.4g} {unit} (and max_velocity "
                              "in the bench file to the stage's limit)")
        if not all(abs(g - w) <= max(1, _VELOCITY_QUANTUM * abs(w))
                   for g, w in ((got[2], acc), (got[3], vel))):
            raise self._error(DeviceProtocolError,
                              f"axis {axis}: velocity parameters read back as {got[1:]}, sent "
                              f"(0, {acc}, {vel})", "check the controller model and profile")
        return velocity * got[3] / vel if vel else velocity

    # ----------------------------------------------------------- queries
    def _status(self, axis: str) -> int:
        info = self._axes[axis]
        reply = self._ctrl[info["key"]].request(
            MSG["MOT_REQ_STATUSBITS"], MSG["MOT_GET_STATUSBITS"], info["dest"], param1=1,
            timeout_s=self._reply_timeout)
        return struct.unpack_from("<HI", reply.data or bytes(6))[1]

    def _counts(self, axis: str) -> int:
        info = self._axes[axis]
        reply = self._ctrl[info["key"]].request(
            MSG["MOT_REQ_POSCOUNTER"], MSG["MOT_GET_POSCOUNTER"], info["dest"], param1=1,
            timeout_s=self._reply_timeout)
        return struct.unpack_from("<Hi", reply.data or bytes(6))[1]

    def _on_event(self, msg: AptMessage) -> None:
        if msg.msg_id in (MSG["HW_RICHRESPONSE"], MSG["HW_RESPONSE"]):
            data = msg.data or b""
            code = struct.unpack_from("<H", data, 2)[0] if len(data) >= 4 else 0
            notes = data[4:68].split(b"\0")[0].decode("ascii", "replace")
            text = f"controller 0x{msg.source:02x} reported error {code}: {notes or 'no text'}"
            self._faults.append(text)
            self._log.error("%s: %s", self.device_id, text)

    # ----------------------------------------------------------- motion hooks
    def _do_move(self, targets: dict[str, float]) -> None:
        if self.require_homed:
            for axis in targets:
                if not self._status(axis) & STATUS["HOMED"]:
                    raise self._error(
                        DeviceStateError, f"axis {axis} is not homed (its position is not "
                        "referenced)", "home it first (stage.home()), or set home_on_open = "
                        "true in the bench file")
        self._faults.clear()
        for axis, target in targets.items():
            info = self._axes[axis]
            counts = round(target * info["cpu"])
            self._ctrl[info["key"]].send(MSG["MOT_MOVE_ABSOLUTE"], info["dest"],
                                         data=struct.pack("<Hi", 1, counts))
            self._targets[axis] = target
            self._homing.discard(axis)

    def _do_home(self, axes: tuple[str, ...]) -> None:
        self._faults.clear()
        for axis in axes:
            info = self._axes[axis]
            self._ctrl[info["key"]].send(MSG["MOT_MOVE_HOME"], info["dest"], 1, 0)
            self._homing.add(axis)
            self._targets.pop(axis, None)

    def _do_is_moving(self) -> bool:
        return any(self._status(a) & MOVING_MASK for a in self._axes)

    def _do_positions(self) -> dict[str, float]:
        return self._do_positions_of(tuple(self._axes))

    def _do_positions_of(self, axes: tuple[str, ...]) -> dict[str, float]:
        return {a: self._counts(a) / self._axes[a]["cpu"] for a in axes}

    def _do_stop(self) -> None:
        for info in self._axes.values():
            ctrl = self._ctrl.get(info["key"])
            if ctrl is not None:
                ctrl.send(MSG["MOT_MOVE_STOP"], info["dest"], 1, 0x02)  # profiled stop
        self._targets.clear()
        self._homing.clear()

    def _do_wait(self, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        pending = set(self._targets) | set(self._homing) or set(self._axes)
        while True:
            status = {a: self._status(a) for a in pending}
            pending = {a for a, s in status.items() if s & MOVING_MASK}
            if not pending:
                break
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            ctrl = self._ctrl[self._axes[next(iter(pending))]["key"]]
            ctrl.wait_event(min(self._poll, left))
        self._check_outcome(status)
        return True

    def _check_outcome(self, status: dict[str, int]) -> None:
        """Raise StageMotionError when an axis ended away from its target."""
        problems = list(self._faults)
        for axis in list(self._homing):
            if not self._status(axis) & STATUS["HOMED"]:
                problems.append(f"axis {axis} did not complete homing")
        for axis, target in self._targets.items():
            info = self._axes[axis]
            counts = self._counts(axis)
            want = round(target * info["cpu"])
            bits = status.get(axis, 0)
            if abs(counts - want) > info["tol"]:
                limit = " at a limit switch" if bits & (STATUS["FWD_LIMIT"] |
                                                       STATUS["REV_LIMIT"]) else ""
                problems.append(f"axis {axis} stopped{limit} at {counts / info['cpu']:.6g} "
                                f"{AXIS_UNITS[axis]}, target {target:.6g}")
        self._targets.clear()
        self._homing.clear()
        self._faults.clear()
        if problems:
            raise self._error(StageMotionError, "; ".join(problems),
                              "check the travel, the limit switches and the controller's "
                              "front panel; the stage is idle")

    def _do_status(self) -> dict[str, Any]:
        out = super()._do_status()
        out["homed"] = {a: bool(self._status(a) & STATUS["HOMED"]) for a in self._axes}
        out["axes_setup"] = {a: {"profile": i["profile"], "counts_per_unit": i["cpu"],
                                 "stage": i["stage"], "position_tolerance_counts": i["tol"]}
                             for a, i in self._axes.items()}
        if self.stopped_at_open:
            out["stopped_at_open"] = dict(self.stopped_at_open)
        out["controllers"] = {
            key: {"port": c.link.path, **getattr(c, "info", {}),
                  "keepalives_sent": c.keepalives_sent, "resyncs": c.framer.resyncs}
            for key, c in self._ctrl.items()
        }
        return out
