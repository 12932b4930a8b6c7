"""Who may use a device node, and one program per USB unit.

- :func:`permission_error`: an ``open`` refused with ``EACCES``/``EPERM`` (or a USB
  device node the user cannot read and write) becomes a
  :class:`~drivers.errors.DevicePermissionError` that names the node, its owner, group
  and mode, and the fix: the group to join (the node's group, or ``dialout`` for serial
  ports and ``plugdev`` for USB on Debian/Ubuntu when the node belongs to root), or a
  fresh login when the user was added to it after logging in, or the udev rule.
- :class:`DeviceLock`: an OS-level exclusive lock per unit (``flock`` on a lock file
  named after the unit: its USB ids and serial number), held while the device is
  open. A second process (or a second driver object in the same process) that opens
  the same unit is refused with an error naming the holder (pid and command line, as
  the holder wrote them in the file). ``flock`` locks die with their process, so a
  crashed program leaves nothing to clean up. It guards the USB links
  (:mod:`drivers.usb_transports`), whose replies are matched only by a sequence
  number: two programs on one LightCrafter would take each other's replies.
"""

from __future__ import annotations

import errno
import grp
import os
import pwd
import re
import stat
import tempfile
from pathlib import Path

from drivers.errors import DeviceDisconnectedError, DevicePermissionError

__all__ = ["DeviceLock", "is_permission_denied", "lock_dir", "permission_error",
           "usb_node"]

#: Overrides where the unit lock files live (tests; a lab that shares another directory).
LOCK_DIR_ENV = "DIFFUSERLAB_LOCK_DIR"


def is_permission_denied(exc: BaseException) -> bool:
    """True when ``exc`` (an ``OSError``, a pyserial ``SerialException``, a pyusb
    ``USBError``) is ``EACCES`` or ``EPERM``."""
    return getattr(exc, "errno", None) in (errno.EACCES, errno.EPERM)


def usb_node(bus: int, address: int) -> str:
    """The usbfs node libusb opens for a USB device: ``/dev/bus/usb/BBB/DDD``."""
    return f"/dev/bus/usb/{int(bus):03d}/{int(address):03d}"


def _name(table, key: int) -> str:
    try:
        return table(key)[0]
    except KeyError:
        return str(key)


def permission_error(device_id: str, path: str, what: str, default_group: str,
                     cause: BaseException | None = None) -> DevicePermissionError:
    """The error for a device node the user may not open, with the fix that applies.

    Parameters
    ----------
    device_id : str
        The device (named in the error).
    path : str
        The node (``/dev/ttyUSB0``, ``/dev/bus/usb/001/005``, ``/dev/hidraw3``).
    what : str
        What it is, for the message (``"serial port"``, ``"USB device"``).
    default_group : str
        The group a udev rule gives such nodes on Debian/Ubuntu (``dialout`` for serial
        ports, ``plugdev`` for USB and hidraw), named when the node belongs to root.
    cause : BaseException, optional
        The refusal, quoted in the message.

    Returns
    -------
    DevicePermissionError
    """
    detail = f": {cause}" if cause is not None else ""
    try:
        st = os.stat(path)
    except OSError:
        return DevicePermissionError(
            device_id, f"permission denied on {what} {path}{detail}",
            f"join group {default_group} (sudo usermod -aG {default_group} $USER, then log "
            "out and in) and install the udev rule in docs/drivers/transports.md")
    group = _name(grp.getgrgid, st.st_gid)
    owner = _name(pwd.getpwuid, st.st_uid)
    node = (f"permission denied on {what} {path} (owner {owner}, group {group}, mode "
            f"{stat.filemode(st.st_mode)}){detail}")
    rule = "the udev rule in docs/drivers/transports.md"
    if st.st_gid == 0:
        return DevicePermissionError(
            device_id, node, f"install {rule}, which gives the node group {default_group}, "
            f"and join that group (sudo usermod -aG {default_group} $USER, then log out and "
            "in)")
    if st.st_gid in os.getgroups():
        return DevicePermissionError(
            device_id, node, f"you are in group {group} but the node's mode does not let "
            f"the group read and write it: install {rule} (MODE=\"0660\")")
    try:
        user = pwd.getpwuid(os.geteuid())[0]
        listed = user in grp.getgrgid(st.st_gid).gr_mem
    except KeyError:
        user, listed = "$USER", False
    if listed:
        return DevicePermissionError(
            device_id, node, f"{user} was added to group {group} after this session "
            "started: log out and in again (or run `newgrp " + group + "`)")
    return DevicePermissionError(
        device_id, node, f"join group {group}: sudo usermod -aG {group} {user}, then log "
        "out and in again")


def lock_dir() -> Path:
    """Where the unit lock files live: ``$DIFFUSERLAB_LOCK_DIR``, else ``/run/lock``
    (shared by every user of the machine) where writable, else the temporary directory."""
    env = os.environ.get(LOCK_DIR_ENV)
    if env:
        return Path(env)
    if os.access("/run/lock", os.W_OK | os.X_OK):
        return Path("/run/lock")
    return Path(tempfile.gettempdir())


class DeviceLock:
    """An exclusive lock on one unit, across processes (``flock`` on a lock file).

    Parameters
    ----------
    device_id : str
        The device taking the lock (named in errors).
    key : str
        Names the unit, e.g. ``"usb-0451-6401-LC4500-0001"``; the lock file is
        ``diffuserlab-<key>.lock`` in :func:`lock_dir` (characters other than letters,
        digits, ``.``, ``_`` and ``-`` replaced).
    what : str
        The unit, for the message (``"LightCrafter USB 0451:6401 serial ..."``).
    """

    def __init__(self, device_id: str, key: str, what: str) -> None:
        self.device_id, self.what = device_id, what
        safe = re.sub(r"[^A-Za-z0-9._-]", "_", key)
        self.path = lock_dir() / f"diffuserlab-{safe}.lock"
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        """True while this object holds the lock."""
        return self._fd is not None

    def acquire(self) -> None:
        """Take the lock, or raise naming who holds it.

        Raises
        ------
        DeviceDisconnectedError
            Another process, or another driver object of this one, has the unit open.
        """
        import fcntl

        if self._fd is not None:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o666)
        except PermissionError:  # another user's file in a sticky directory
            fd = os.open(self.path, os.O_RDONLY)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = self.holder()
            os.close(fd)
            if exc.errno not in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                raise
            raise DeviceDisconnectedError(
                self.device_id, f"{self.what} is in use by {holder} (lock {self.path})",
                "close that program (or that device) first: two programs on one unit "
                "take each other's replies") from None
        try:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()} {_cmdline()}\n".encode("utf-8", "replace"))
        except OSError:  # a read-only file of another user: the lock holds all the same
            pass
        self._fd = fd

    def release(self) -> None:
        """Drop the lock (the file stays, empty of meaning); never raises."""
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)  # closing the descriptor releases the flock

    def holder(self) -> str:
        """Who holds the lock, as the holder wrote it: ``process 1234 (python ...)``."""
        try:
            text = self.path.read_text(encoding="utf-8", errors="replace").strip()
        except OSError:
            text = ""
        pid, _, cmd = text.partition(" ")
        if not pid.isdigit():
            return "another program"
        if int(pid) == os.getpid():
            return f"this process (pid {pid}: another driver object opened it)"
        return f"process {pid} ({cmd[:200] or '?'})"


def _cmdline() -> str:
    try:
        return " ".join(Path("/proc/self/cmdline").read_bytes().replace(b"\0", b" ").decode(
            "utf-8", "replace").split())
    except OSError:
        return "?"
