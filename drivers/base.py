"""The device lifecycle shared by every interface: :class:`Device`.

The public methods of a device validate their arguments, keep state, log, and
call private ``_do_*`` hooks that a driver implements (the pattern of
python-microscope's ``microscope.abc``). A driver therefore never re-implements
argument checks, the open/close bookkeeping or the settings cache.

Hooks every driver implements (called only while open, except ``_do_open``):

``_do_open(timeout_s)``
    Connect; raise :class:`~drivers.errors.DeviceDisconnectedError` when the
    device is absent or the kind's timeout error when it does not answer.
``_do_close()``
    Release the connection; must tolerate a device that has gone away.
``_do_get_info() -> Mapping``
    Fixed properties read once per open (sensor shape, axes, geometry, ...).
``_do_get_settings() -> Mapping``
    The device's current value of every setting the kind declares (``SETTINGS``).
``_do_apply(name, value) -> value | None``
    Send one validated setting; return the value the device actually took
    (read back) or None when it took ``value`` as given.

Optional hooks: ``_do_check_connection()``, ``_do_status()``, ``_before_close()``,
``_on_open()``, ``_save_state()`` / ``_restore_state()`` (non-setting state such as
a displayed pattern, re-established after a reconnect),
``_now_s()`` and ``_sleep_s()`` (a simulated device runs them on its clock).
"""

from __future__ import annotations

import abc
import contextlib
import logging
import math
import threading
import time
from collections.abc import Iterator, Mapping
from typing import Any, ClassVar

import numpy as np

from diffuserlab.jsonio import jsonable
from drivers.errors import (
    DeviceCancelledError,
    DeviceDisconnectedError,
    DeviceError,
    DeviceStateError,
    DeviceTimeoutError,
    DeviceValueError,
)
from drivers.settings import Setting

__all__ = ["Device"]


class Device(abc.ABC):
    """A device with one lifecycle: open -> use -> close.

    Parameters
    ----------
    device_id : str
        Name of this device instance, used in every log line and error message.
    **params
        Driver-specific connection parameters (port, serial number, ...), kept in
        ``params``.

    Notes
    -----
    ``close()`` is idempotent and never raises for a vanished device; ``open()`` on
    an open device does nothing. The device is a context manager (opens on entry,
    closes on exit). Every public method other than ``open``, ``close``,
    ``reconnect``, ``status`` and ``is_open`` raises
    :class:`~drivers.errors.DeviceStateError` when the device is not open and
    :class:`~drivers.errors.DeviceDisconnectedError` once a disconnection has been
    seen, until :meth:`reconnect` succeeds.
    """

    #: Kind of device: "camera", "stage", "led_array" or "slm".
    kind: ClassVar[str] = "device"
    #: Exception raised when a blocking call of this kind times out.
    timeout_error: ClassVar[type[DeviceTimeoutError]] = DeviceTimeoutError
    #: The settings, declared once (:class:`~drivers.settings.Setting`), in the order
    #: :meth:`apply_settings` applies them; validation, :meth:`setting_specs` and the
    #: documentation's tables come from it. A driver may extend or narrow its kind's
    #: table (:func:`~drivers.settings.with_settings`).
    SETTINGS: ClassVar[tuple[Setting, ...]] = ()
    #: Names of the writable settings, in order (derived from ``SETTINGS``).
    _SETTINGS: ClassVar[tuple[str, ...]] = ()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "SETTINGS" in cls.__dict__:
            names = [s.name for s in cls.SETTINGS]
            if len(set(names)) != len(names):
                raise TypeError(f"{cls.__name__}.SETTINGS declares a name twice: {names}")
            cls._SETTINGS = tuple(s.name for s in cls.SETTINGS if not s.read_only)
            cls._SPECS = {s.name: s for s in cls.SETTINGS}

    _SPECS: ClassVar[dict[str, Setting]] = {}

    @classmethod
    def setting(cls, name: str) -> Setting:
        """The declaration of setting ``name`` (KeyError if the class has none)."""
        return cls._SPECS[name]

    @classmethod
    def setting_specs(cls, info: Mapping[str, Any] | None = None) -> list[dict[str, Any]]:
        """The declared settings, machine-readable, in the order of application.

        Parameters
        ----------
        info : Mapping, optional
            An open device's :attr:`info` (``device.setting_specs(device.info)``):
            limits and choices are then numbers and lists; without it they name the
            info entries they come from.

        Returns
        -------
        list of dict
            One :meth:`~drivers.settings.Setting.describe` per setting (name, dtype,
            unit, description, limits, read-only, ...).
        """
        return [jsonable(s.describe(info)) for s in cls.SETTINGS]

    def __init__(self, device_id: str, **params: Any) -> None:
        if not isinstance(device_id, str) or not device_id.strip():
            raise DeviceValueError(
                repr(device_id), "device_id must be a non-empty string", "pass a name like 'cam0'"
            )
        self.device_id = device_id
        self.params = dict(params)
        self._is_open = False
        self._disconnected = False
        self._info: dict[str, Any] = {}
        self._values: dict[str, Any] = {}
        self._log = logging.getLogger(f"drivers.{self.kind}")

    def __repr__(self) -> str:
        state = "open" if self._is_open else "closed"
        return f"<{type(self).__name__} {self.device_id!r} ({state})>"

    @property
    def info(self) -> dict[str, Any]:
        """Fixed properties read when the device opened (JSON-able copy): ranges and
        geometry the settings are validated against, e.g. a camera's
        ``exposure_range_s``, ``frame_rate_range_hz`` and ``gain_range_db``, a stage's
        ``axes`` with their ``travel`` and ``max_velocity`` (see each kind's
        ``_do_get_info``). Operator interfaces show them as the settings' limits.

        Raises
        ------
        DeviceStateError
            The device is not open.
        """
        self._require_open()
        return jsonable(self._info)

    # ------------------------------------------------------------------ lifecycle
    @property
    def is_open(self) -> bool:
        """True between a successful :meth:`open` and :meth:`close`."""
        return self._is_open

    def open(self, timeout_s: float | None = None, *,
             cancel: threading.Event | None = None) -> None:
        """Connect to the device and read its fixed properties and current settings.

        Parameters
        ----------
        timeout_s : float, optional
            Longest time the whole open may take, in seconds, waits for a homing the
            driver starts at open (``home_on_open``) included. None (the default): 5 s
            for the device to answer, and the driver's own ``home_timeout_s`` for such
            a homing.
        cancel : threading.Event, optional
            Set by another thread (a GUI's cancel button) to end the open early: it is
            checked before connecting, after connecting and every 0.1 s of a homing
            at open (which it stops); the open's other waits are single replies,
            each bounded by the driver's reply timeout cut to what is left of
            ``timeout_s``.

        Raises
        ------
        DeviceDisconnectedError
            The device is absent.
        DeviceTimeoutError
            The kind's timeout error: the device did not answer in time; a reply
            wait that ran out at the end of ``timeout_s`` (cut to it) is reported as
            the open not finishing "within the open's timeout_s", not as a silent
            device.
        DeviceCancelledError
            ``cancel`` was set before the open finished; the device is closed.
        """
        bounded = timeout_s is not None
        timeout_s = self._check_timeout(5.0 if timeout_s is None else timeout_s)
        if self._is_open:
            return
        deadline = time.monotonic() + timeout_s if bounded else None
        self._open_bounds = (deadline, cancel)
        try:
            self._check_cancel("before opening")
            with self._io():
                self._do_open(timeout_s)
                try:
                    self._check_cancel("while opening")
                    self._info = dict(self._do_get_info())
                    self._values = dict(self._do_get_settings())
                except BaseException:
                    with contextlib.suppress(DeviceError):
                        self._do_close()
                    raise
        except DeviceTimeoutError as exc:
            if (deadline is None or "the open's timeout_s" in exc.problem
                    or time.monotonic() < deadline - self._LAST_WAIT_S):
                raise
            # a reply wait cut short by the open's deadline ran out: the open's timeout
            # ended it, not a silent device (a loaded host answers late)
            raise self._timeout(
                f"the open did not finish within the open's timeout_s = {timeout_s:g} s "
                f"(its last wait: {exc.problem})",
                "open again with a longer timeout_s; if it keeps failing, " + exc.fix,
            ) from exc
        finally:
            self._open_bounds = (None, None)
        self._is_open = True
        self._disconnected = False
        self._on_open()
        self._log.info("%s: opened (%s)", self.device_id, type(self).__name__)

    def close(self) -> None:
        """Release the device. Idempotent; a vanished device is logged, not raised."""
        if not self._is_open:
            return
        try:
            self._before_close()
            self._do_close()
        except DeviceError as exc:
            self._log.warning("%s: error while closing, ignored: %s", self.device_id, exc)
        finally:
            self._is_open = False
        self._log.info("%s: closed", self.device_id)

    def reconnect(self, timeout_s: float | None = None) -> None:
        """Close, open again (``open(timeout_s)``) and re-apply the last settings.

        The settings are the ones in effect before the reconnect (the cache the
        device kept), so a device that lost power comes back configured. Motion is
        never replayed: a stage's position is not part of its settings.

        Raises
        ------
        DeviceDisconnectedError
            The device is still absent; try again later.
        """
        last = dict(self._values)
        state = self._save_state()
        self.close()
        self.open(timeout_s)
        if last:
            self.apply_settings(last)
        with self._io():
            self._restore_state(state)
        self._log.info("%s: reconnected, %d settings re-applied", self.device_id, len(last))

    def __enter__(self) -> Device:
        self.open()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # ------------------------------------------------------------------ settings
    def settings(self) -> dict[str, Any]:
        """Return a JSON-able snapshot of every settable property.

        Returns
        -------
        dict
            ``{name: value}`` for every name in the order of application; feeding it
            to :meth:`apply_settings` restores the device's configuration.
        """
        self._require_open()
        return jsonable({name: self._values[name] for name in self._SETTINGS})

    def setting_values(self) -> dict[str, Any]:
        """Every declared setting's value, the read-only ones included (JSON-able), in
        declaration order; what an operator interface shows (:meth:`settings` holds
        only the writable ones, to feed back to :meth:`apply_settings`)."""
        self._require_open()
        return jsonable({s.name: self._values.get(s.name) for s in self.SETTINGS})

    def apply_settings(self, settings: Mapping[str, Any]) -> None:
        """Validate all of ``settings``, then apply them in the defined order.

        Parameters
        ----------
        settings : Mapping
            A subset of :meth:`settings` (JSON types are accepted).

        Raises
        ------
        DeviceValueError
            An unknown name or a bad value; nothing is applied then.
        """
        for name, value in self.check_settings(settings).items():
            with self._io():
                applied = self._do_apply(name, value)
            self._values[name] = value if applied is None else applied
            self._log.debug("%s: %s = %r", self.device_id, name, self._values[name])

    def check_settings(self, settings: Mapping[str, Any]) -> dict[str, Any]:
        """Validate ``settings`` as :meth:`apply_settings` would, applying nothing
        (e.g. a plan's exposures checked before a run starts).

        Returns
        -------
        dict
            The validated values, normalised, in the order they would be applied.

        Raises
        ------
        DeviceValueError
            An unknown name or a bad value.
        """
        self._require_open()
        if not isinstance(settings, Mapping):
            raise self._error(
                DeviceValueError, f"settings must be a mapping, got {type(settings).__name__}",
                "pass a dict such as the one settings() returns",
            )
        read_only = sorted(n for n in settings if n in self._SPECS and self._SPECS[n].read_only)
        if read_only:
            raise self._error(
                DeviceValueError, f"settings {read_only} are read-only on this device",
                f"leave them out; settable are {list(self._SETTINGS)}",
            )
        unknown = sorted(set(settings) - set(self._SETTINGS))
        if unknown:
            raise self._error(
                DeviceValueError, f"unknown settings {unknown}",
                f"use only {list(self._SETTINGS)}",
            )
        pending = dict(self._values)
        validated: dict[str, Any] = {}
        for name in self._SETTINGS:
            if name in settings:
                value = self._validate_setting(name, settings[name], pending)
                pending[name] = validated[name] = value
        self._check_settings(pending)
        return validated

    def _set(self, name: str, value: Any) -> None:
        """Property setters go through :meth:`apply_settings`."""
        self.apply_settings({name: value})

    def _get(self, name: str) -> Any:
        self._require_open()
        return self._values[name]

    def _validate_setting(self, name: str, value: Any, pending: dict[str, Any]) -> Any:
        """Return ``value`` normalised, or raise DeviceValueError. ``pending`` holds the
        settings as they will be once the names before ``name`` are applied.

        Checks the declaration (:meth:`~drivers.settings.Setting.validate`); a kind or
        driver overrides it only for what one setting cannot say (a camera's stream
        lock, a driver's hardware restriction), calling this first or after."""
        spec = self._SPECS.get(name)
        return value if spec is None else spec.validate(self, value, pending)

    def _check_settings(self, pending: dict[str, Any]) -> None:  # noqa: B027 (optional hook)
        """Check constraints between settings (raise DeviceValueError)."""

    # ------------------------------------------------------------------ status
    def status(self) -> dict[str, Any]:
        """Return a JSON-able status summary; works on a closed device too.

        Returns
        -------
        dict
            ``device_id``, ``kind``, ``driver``, ``is_open``, ``disconnected`` and,
            when open, the driver's details (counters, motion state, ...). The
            connection is checked first, as before every call (a serial port whose
            other end hung up): a device gone since the last call is reported
            ``disconnected`` with the ``error``, whether or not it was talked to, and
            so is one lost while its status is read (a LightCrafter unplugged: the
            status read's transfer fails); it does not raise.
        """
        out: dict[str, Any] = {
            "device_id": self.device_id,
            "kind": self.kind,
            "driver": type(self).__name__,
            "is_open": self._is_open,
            "disconnected": self._disconnected,
        }
        if self._is_open and not self._disconnected:
            try:  # every device's connection checked as before each call; a device
                with self._io():  # lost while its status is read is reported too
                    self._do_check_connection()
                    out.update(self._do_status())
            except DeviceDisconnectedError as exc:
                out.update(disconnected=True, error=str(exc))
        return jsonable(out)

    # ------------------------------------------------------------------ helpers
    def _require_open(self) -> None:
        if self._disconnected:
            raise self._error(
                DeviceDisconnectedError, "the device stopped answering",
                "check cable and power, then call reconnect()",
            )
        if not self._is_open:
            raise self._error(
                DeviceStateError, "the device is not open",
                "call open() first or use the device as a context manager",
            )
        with self._io():
            self._do_check_connection()

    @contextlib.contextmanager
    def _io(self) -> Iterator[None]:
        """Wrap hook calls: a disconnection seen here is remembered."""
        try:
            yield
        except DeviceDisconnectedError as exc:
            if not self._disconnected:
                self._log.error("%s: disconnected: %s", self.device_id, exc)
            self._disconnected = True
            raise

    def _error(self, cls: type[DeviceError], problem: str, fix: str) -> DeviceError:
        return cls(self.device_id, problem, fix)

    def _timeout(self, problem: str, fix: str) -> DeviceTimeoutError:
        exc = self.timeout_error(self.device_id, problem, fix)
        self._log.warning("%s: %s", self.device_id, problem)
        return exc

    #: (deadline from ``time.monotonic()`` or None, cancel event or None) of the open
    #: in progress; read by the waits a driver makes while opening.
    _open_bounds: tuple[float | None, threading.Event | None] = (None, None)

    #: The shortest reply wait an open's deadline leaves (s): a wait that runs out this
    #: close to the deadline ends as the kind's timeout error.
    _LAST_WAIT_S = 0.05

    @property
    def _reply_timeout(self) -> float:
        """The driver's reply timeout (``reply_timeout_s``, s), cut to what is left of an
        open's ``timeout_s`` while one is in progress, so the caller's timeout bounds
        each single reply of the open too (not only a homing at open)."""
        wait = self.__dict__.get("_reply_timeout_s", 2.0)
        deadline = self._open_bounds[0]
        if deadline is None:
            return wait
        return min(wait, max(self._LAST_WAIT_S, deadline - time.monotonic()))

    @_reply_timeout.setter
    def _reply_timeout(self, seconds: float) -> None:
        self.__dict__["_reply_timeout_s"] = seconds

    def _check_cancel(self, doing: str) -> None:
        """Raise :class:`DeviceCancelledError` when the open's cancel event is set."""
        cancel = self._open_bounds[1]
        if cancel is not None and cancel.is_set():
            raise DeviceCancelledError(self.device_id, f"open cancelled {doing}",
                                       "open it again when ready")

    def _check_timeout(self, timeout_s: Any) -> float:
        return self._float("timeout_s", timeout_s, low=0.0, low_open=True)

    def _float(
        self, name: str, value: Any, *, low: float | None = None, high: float | None = None,
        low_open: bool = False,
    ) -> float:
        """Return ``value`` as a finite float within [low, high] or raise DeviceValueError."""
        ok = isinstance(value, int | float | np.integer | np.floating) and not isinstance(
            value, bool
        )
        v = float(value) if ok else math.nan
        bad = not math.isfinite(v)
        bad = bad or (low is not None and (v <= low if low_open else v < low))
        bad = bad or (high is not None and v > high)
        if bad:
            lo = "-inf" if low is None else f"{low:g}"
            hi = "inf" if high is None else f"{high:g}"
            op = "<" if low_open else "<="
            raise self._error(
                DeviceValueError, f"{name}={value!r} is not a number in range",
                f"use a finite number with {lo} {op} {name} <= {hi}",
            )
        return v

    def _int(
        self, name: str, value: Any, *, low: int | None = None, high: int | None = None
    ) -> int:
        """Return ``value`` as an int within [low, high] or raise DeviceValueError."""
        ok = isinstance(value, int | np.integer) and not isinstance(value, bool)
        if not ok and isinstance(value, float | np.floating) and float(value).is_integer():
            ok = True
        if ok and (low is None or value >= low) and (high is None or value <= high):
            return int(value)
        raise self._error(
            DeviceValueError, f"{name}={value!r} is not an integer in range",
            f"use an integer with {low if low is not None else '-inf'} <= {name} <= "
            f"{high if high is not None else 'inf'}",
        )

    def _int_pair(self, name: str, value: Any, *, low: int = 1,
                  high: int | None = None) -> tuple[int, int]:
        """Return ``value`` as ``(rows, cols)`` ints within [low, high] or raise
        DeviceValueError (also for a string or a sequence of another length)."""
        if isinstance(value, str) or not hasattr(value, "__len__") or len(value) != 2:
            raise self._error(DeviceValueError, f"{name}={value!r} is not (rows, cols)",
                              f"give two integers, e.g. {name} = [480, 640]")
        return (self._int(f"{name} rows", value[0], low=low, high=high),
                self._int(f"{name} cols", value[1], low=low, high=high))

    def _choice(self, name: str, value: Any, choices: Any) -> Any:
        if isinstance(value, str) and value in choices:
            return value
        raise self._error(
            DeviceValueError, f"{name}={value!r} is not supported", f"use one of {sorted(choices)}"
        )

    # ------------------------------------------------------------------ hooks
    @abc.abstractmethod
    def _do_open(self, timeout_s: float) -> None: ...

    @abc.abstractmethod
    def _do_close(self) -> None: ...

    @abc.abstractmethod
    def _do_get_info(self) -> Mapping[str, Any]: ...

    @abc.abstractmethod
    def _do_get_settings(self) -> Mapping[str, Any]: ...

    @abc.abstractmethod
    def _do_apply(self, name: str, value: Any) -> Any: ...

    def _do_check_connection(self) -> None:  # noqa: B027 (optional hook)
        """Raise DeviceDisconnectedError if the device is known to be gone (cheap)."""

    def _do_status(self) -> dict[str, Any]:
        return {}

    def _on_open(self) -> None:  # noqa: B027 (optional hook)
        """Reset the interface's state caches after a successful open."""

    def _save_state(self) -> Any:
        """Non-setting state to re-establish after a reconnect (e.g. a displayed pattern)."""
        return None

    def _restore_state(self, state: Any) -> None:  # noqa: B027 (optional hook)
        """Re-establish what :meth:`_save_state` returned, after a reconnect."""

    def _before_close(self) -> None:  # noqa: B027 (optional hook)
        """Called by close() before _do_close (e.g. to stop a stream)."""

    def _now_s(self) -> float:
        """Monotonic time in seconds used for timeout budgets."""
        return time.monotonic()

    def _sleep_s(self, seconds: float) -> None:
        """Wait ``seconds``; a simulated device advances its clock instead."""
        if seconds > 0:
            time.sleep(seconds)
