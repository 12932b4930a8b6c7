"""Exceptions raised by device interfaces and drivers.

Every error names the device, the problem and the fix, so that a message read in
a log or a GUI dialog is enough to act on::

    cam0: exposure_s=-1 is out of range. Fix: use 1e-06 <= exposure_s <= 60.

Hierarchy::

    DeviceError
    +-- DeviceTimeoutError (also TimeoutError)
    |   +-- CameraTimeoutError, StageTimeoutError, LedArrayTimeoutError, SlmTimeoutError,
    |       DmdTimeoutError
    +-- DeviceDisconnectedError (also ConnectionError)
    +-- DevicePermissionError (also PermissionError): the user may not open the port
    +-- DeviceCancelledError        (the caller cancelled an open in progress)
    +-- DeviceStateError            (used before open, snap while streaming, ...)
    |   +-- StageMotionError        (a move ended away from its target: limit switch, stall)
    +-- DeviceValueError (also ValueError): a bad argument or setting
    |   +-- StageLimitError         (a target outside the axis limits)
    +-- DeviceProtocolError         (the device refused a command or replied out of protocol)
    +-- MissingDependencyError (also ImportError): an optional library is not installed
"""

from __future__ import annotations

from diffuserlab.errors import DiffuserLabError

__all__ = [
    "CameraTimeoutError",
    "DeviceCancelledError",
    "DeviceDisconnectedError",
    "DeviceError",
    "DevicePermissionError",
    "DeviceProtocolError",
    "DeviceStateError",
    "DeviceTimeoutError",
    "DeviceValueError",
    "DmdTimeoutError",
    "LedArrayTimeoutError",
    "MissingDependencyError",
    "SlmTimeoutError",
    "StageLimitError",
    "StageMotionError",
    "StageTimeoutError",
]


class DeviceError(DiffuserLabError):
    """Base class of every device error (a :class:`diffuserlab.errors.DiffuserLabError`).

    Parameters
    ----------
    device_id : str
        Identifier of the device that failed (as given to its constructor).
    problem : str
        What went wrong, with the offending values.
    fix : str
        What the operator or the calling code should do about it.

    Attributes
    ----------
    device_id, problem, fix : str
        The parts of the message, for programmatic use.
    """

    def __init__(self, device_id: str, problem: str, fix: str) -> None:
        self.device_id = device_id
        self.problem = problem
        self.fix = fix
        super().__init__(f"{device_id}: {problem}. Fix: {fix}")

    def __reduce__(self):  # keep the three-part constructor picklable (dask, processes)
        return (type(self), (self.device_id, self.problem, self.fix))


class DeviceTimeoutError(DeviceError, TimeoutError):
    """A blocking device operation did not complete within its ``timeout_s``."""


class DeviceDisconnectedError(DeviceError, ConnectionError):
    """The device stopped answering (unplugged, powered off, port lost).

    Every further call raises this error until
    :meth:`Device.reconnect <drivers.base.Device.reconnect>` succeeds.
    """


class DevicePermissionError(DeviceError, PermissionError):
    """The operating system refused to open the device's port or node (``EACCES``):
    the device is there, the user lacks the group or the udev rule. The message names
    the node, its group and mode, and the group to join. Not a disconnection: waiting
    or reconnecting does not help."""


class DeviceCancelledError(DeviceError):
    """The caller cancelled a blocking operation (an open) before it finished; motion
    the operation had started was stopped and the device is left closed."""


class DeviceStateError(DeviceError):
    """The call is not allowed in the device's current state (e.g. not open)."""


class DeviceValueError(DeviceError, ValueError):
    """A bad argument or setting value; nothing was sent to the device."""


class CameraTimeoutError(DeviceTimeoutError):
    """No frame arrived within the timeout."""


class StageTimeoutError(DeviceTimeoutError):
    """A stage motion or homing did not finish within the timeout."""


class LedArrayTimeoutError(DeviceTimeoutError):
    """The LED array did not acknowledge a command within the timeout."""


class SlmTimeoutError(DeviceTimeoutError):
    """The SLM did not display a pattern within the timeout."""


class DmdTimeoutError(DeviceTimeoutError):
    """The DMD did not answer or accept a pattern sequence within the timeout."""


class StageLimitError(DeviceValueError):
    """A stage target lies outside the axis limits; nothing moved.

    A subclass of :class:`DeviceValueError`, hence of ``DeviceError`` and ``ValueError``.
    """


class StageMotionError(DeviceStateError):
    """A stage move or homing ended away from its target: a hardware limit switch, a
    stall, an interruption or a fault the controller reported. The stage is idle."""


class DeviceProtocolError(DeviceError):
    """The device refused a command (a rejection or error reply) or answered something
    the protocol does not allow; the message quotes the reply."""


class MissingDependencyError(DeviceError, ImportError):
    """An optional library a driver needs is not installed; raised when the device is
    opened, never on import. The fix names the extra (``diffuserlab[hardware]``)."""
