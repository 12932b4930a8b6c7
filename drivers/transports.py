"""Transports of the hardware drivers: serial ports (pyserial); USB HID and raw USB
are in :mod:`drivers.usb_transports`.

The libraries are optional (the ``hardware`` extra) and imported when a device opens
(:func:`import_optional`), so ``import drivers`` works without them and a missing
one is a :class:`~drivers.errors.MissingDependencyError` naming the extra.

:class:`SerialLink` wraps one ``serial.Serial``:

- the port is resolved on every :meth:`~SerialLink.open`: an explicit path (best a
  stable ``/dev/serial/by-id/...`` link) or a USB serial number, looked up with
  pyserial's ``list_ports`` and then in the by-id directories (a serial number found
  again after an unplug may sit on a new ``/dev/ttyUSBn``);
- every read has a deadline (:meth:`~SerialLink.read_until`,
  :meth:`~SerialLink.read_exactly`; the port itself polls with a short timeout);
- an I/O error (a yanked USB adapter: pyserial's "device reports readiness to read
  but returned no data", ``EIO`` on write) becomes
  :class:`~drivers.errors.DeviceDisconnectedError`;
- modem-line ioctls (RTS, DTR) are guarded: a pseudo-terminal refuses them with
  ``ENOTTY`` (:func:`set_modem_line`);
- the port is opened exclusively: refused while another process has it open (named,
  where ``/proc`` tells: :func:`port_holders`), locked with ``flock`` (pyserial's
  ``exclusive=True``, which other pyserial users that ask for it respect) and marked
  ``TIOCEXCL``, so a later plain ``open()`` by another user's program fails with
  ``EBUSY`` (as thorlabs-apt-device and pylablib open ports, without asking; root
  passes ``TIOCEXCL``);
- a port the user may not open (``EACCES``) is a
  :class:`~drivers.errors.DevicePermissionError` naming the group to join
  (:func:`drivers.device_access.permission_error`), not a disconnection.

"""

from __future__ import annotations

import errno
import importlib
import logging
import os
import re
import select
import stat
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from types import ModuleType
from typing import Any

from drivers.device_access import is_permission_denied, permission_error
from drivers.errors import (
    DeviceDisconnectedError,
    DeviceTimeoutError,
    MissingDependencyError,
)

__all__ = [
    "BY_ID_DIR",
    "HARDWARE_EXTRA",
    "SerialLink",
    "WRITE_TIMEOUT_S",
    "find_serial_port",
    "import_optional",
    "port_holders",
    "set_modem_line",
]

log = logging.getLogger("drivers.transports")

#: Longest a serial write may wait for the port to take its bytes, s: a device that
#: stopped reading (flow control held) fails within it. Generous, because pyserial
#: also raises "Write timeout" when the *writing thread* was descheduled this long
#: after the bytes went out (it checks the clock after the write): on a loaded
#: machine (two busy loops and the test suite on 2 cores) the window's threads waited
#: over 5 s for a core, and a 2 s limit called a working stage unplugged. A device
#: that stops answering is caught sooner by its reply timeouts.
WRITE_TIMEOUT_S = 10.0

#: The pip extra holding pyserial, pyusb and hidapi.
HARDWARE_EXTRA = "diffuserlab[hardware]"
#: Where udev puts stable links to USB serial ports, named after the device's serial.
BY_ID_DIR = "/dev/serial/by-id"

_PACKAGES = {"serial": "pyserial", "hid": "hidapi", "hidraw": "hidapi", "usb": "pyusb"}


def import_optional(module: str, device_id: str) -> ModuleType:
    """Import an optional transport library, or raise an error naming the extra.

    Parameters
    ----------
    module : str
        ``"serial"`` (pyserial), ``"hid"`` or ``"hidraw"`` (hidapi) or ``"usb"`` (pyusb); a dotted
        submodule such as ``"serial.tools.list_ports"`` is allowed.
    device_id : str
        The device asking (named in the error).

    Returns
    -------
    module

    Raises
    ------
    MissingDependencyError
        The library is not installed.
    """
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        package = _PACKAGES.get(module.split(".")[0], module)
        raise MissingDependencyError(
            device_id, f"the Python package {package} is not installed ({exc})",
            f"pip install '{HARDWARE_EXTRA}' (or pip install {package})",
        ) from exc


def set_modem_line(port: Any, name: str, value: bool) -> bool:
    """Set a modem control line (``"rts"`` or ``"dtr"``) of an open pyserial port.

    A pseudo-terminal (an emulator, a virtual port) has no modem lines and refuses the
    ioctl with ``ENOTTY``/``EINVAL``; that is ignored. Other errors propagate.

    Returns
    -------
    bool
        True when the line was set, False when the port has no modem lines.
    """
    try:
        setattr(port, name, value)
    except OSError as exc:
        if exc.errno not in (errno.ENOTTY, errno.EINVAL):
            raise
        log.debug("%s: no modem lines (%s), %s not set", getattr(port, "port", "?"), exc, name)
        return False
    return True


def find_serial_port(
    serial_number: str, search_dirs: Iterable[str | Path] = (BY_ID_DIR,), *,
    device_id: str = "serial",
) -> str | None:
    """The port of the USB serial device with ``serial_number``, or None.

    pyserial's ``list_ports.comports()`` is asked first (its ``serial_number`` is the
    USB iSerial string, e.g. ``27500101`` for a Thorlabs KDC101); then the entries of
    ``search_dirs`` whose name holds the serial number as a whole word (udev's
    ``/dev/serial/by-id/usb-Thorlabs_..._27500101-if00-port0``; an emulator's link
    directory).

    Parameters
    ----------
    serial_number : str
        The serial number, compared as text.
    search_dirs : iterable of str or Path
        Directories of port links to search after ``list_ports``.
    device_id : str
        Named in the error if pyserial is missing.

    Returns
    -------
    str or None
        A device path (``/dev/ttyUSB3`` or a link to it).
    """
    list_ports = import_optional("serial.tools.list_ports", device_id)
    for info in list_ports.comports():
        if info.serial_number and str(info.serial_number) == str(serial_number):
            return info.device
    word = re.compile(rf"(?<![0-9A-Za-z]){re.escape(str(serial_number))}(?![0-9A-Za-z])")
    for directory in search_dirs:
        d = Path(directory).expanduser()
        if not d.is_dir():
            continue
        for entry in sorted(d.iterdir()):
            if word.search(entry.name) and entry.exists():
                return str(entry)
    return None


def port_holders(path: str | Path, proc: str | Path = "/proc") -> list[tuple[int, str]]:
    """Other processes that have the device ``path`` open, where the OS can tell.

    Scans ``/proc/<pid>/fd`` (Linux; processes of other users are visible to root
    only) for a descriptor of the same character device. For a pseudo-terminal, the
    process holding its master side too (an emulator, a terminal) is the device's
    other end, not a competing client, and is left out.

    Parameters
    ----------
    path : str or Path
        A device node or a link to one (``/dev/serial/by-id/...``).
    proc : str or Path
        The proc file system.

    Returns
    -------
    list of (int, str)
        ``(pid, command line)`` of each other process holding it; empty where the OS
        does not tell (no ``/proc``) or nobody does.
    """
    try:
        st = os.stat(path)
    except OSError:
        return []
    if not stat.S_ISCHR(st.st_mode) or not Path(proc).is_dir():
        return []
    real = os.path.realpath(path)
    pts = int(real.rsplit("/", 1)[1]) if re.fullmatch(r"/dev/pts/\d+", real) else None
    out = []
    for entry in Path(proc).iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            fds = list((entry / "fd").iterdir())
        except OSError:
            continue
        for fd in fds:
            try:
                fst = os.stat(fd)
            except OSError:
                continue
            if stat.S_ISCHR(fst.st_mode) and fst.st_rdev == st.st_rdev:
                if pts is not None and _holds_master(entry, fds, pts):
                    break
                try:
                    cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(
                        "utf-8", "replace").strip()
                except OSError:
                    cmd = "?"
                out.append((int(entry.name), cmd or "?"))
                break
    return out


def _holds_master(entry: Path, fds: list[Path], index: int) -> bool:
    """True when the process ``entry`` holds the master side of pty ``index``."""
    for fd in fds:
        try:
            info = (entry / "fdinfo" / fd.name).read_text()
        except OSError:
            continue
        if re.search(rf"^tty-index:\s*{index}$", info, re.MULTILINE):
            return True
    return False


def _holders_text(path: str) -> str:
    holders = port_holders(path)
    if not holders:
        return ""
    return "; held by " + ", ".join(f"process {pid} ({cmd[:60]})" for pid, cmd in holders)


def _set_exclusive(ser: Any, on: bool) -> None:
    """TIOCEXCL / TIOCNXCL on an open port (ignored where unsupported)."""
    try:
        import fcntl
        import termios
        fcntl.ioctl(ser.fileno(), termios.TIOCEXCL if on else termios.TIOCNXCL)
    except (ImportError, AttributeError, OSError, ValueError) as exc:
        log.debug("%s: TIOC%sEXCL not set: %s", getattr(ser, "port", "?"),
                  "" if on else "N", exc)


def _tail(data: bytes, n: int = 80) -> str:
    """``data`` for a message: its last ``n`` bytes and how many came before."""
    if len(data) <= n:
        return repr(data)
    return f"{len(data)} bytes ending {data[-n:]!r}"


class SerialLink:
    """One serial port (pyserial) with deadlines on every read and typed errors.

    Parameters
    ----------
    device_id : str
        The device using the link (named in errors and logs).
    port : str, optional
        Device path; a ``/dev/serial/by-id/...`` link survives re-enumeration.
    serial_number : str, optional
        USB serial number, resolved on every open (:func:`find_serial_port`); used
        when ``port`` is not given.
    search_dirs : sequence of str
        Link directories searched for ``serial_number`` after ``list_ports``.
    baudrate : int
        Line speed; 8 data bits, no parity, 1 stop bit.
    rtscts, xonxoff : bool
        Hardware / software flow control.
    rts : bool, optional
        Assert (True) or clear RTS after opening (guarded on pseudo-terminals).
    timeout_error : type
        The kind's timeout error raised by the reads.
    poll_s : float
        Timeout of one ``Serial.read`` call; reads loop until their deadline.
    """

    def __init__(
        self, device_id: str, *, port: str | None = None, serial_number: str | None = None,
        search_dirs: Sequence[str] = (BY_ID_DIR,), baudrate: int = 115200,
        rtscts: bool = False, xonxoff: bool = False, rts: bool | None = None,
        timeout_error: type[DeviceTimeoutError] = DeviceTimeoutError, poll_s: float = 0.02,
    ) -> None:
        self.device_id = device_id
        self.port = port
        self.serial_number = None if serial_number is None else str(serial_number)
        self.search_dirs = tuple(str(d) for d in search_dirs)
        self.baudrate = int(baudrate)
        self.rtscts, self.xonxoff, self.rts = bool(rtscts), bool(xonxoff), rts
        self.timeout_error = timeout_error
        self.poll_s = float(poll_s)
        self.path: str | None = None
        self._serial: Any = None
        self._buffer = bytearray()

    # ------------------------------------------------------------------ lifecycle
    @property
    def is_open(self) -> bool:
        """True while the port is open and no I/O error has been seen."""
        return self._serial is not None

    def hung_up(self) -> bool:
        """True when the port's other end went away (a yanked USB adapter, an
        emulator's pty closed): the kernel's hang-up on the open file, seen without a
        byte exchanged, so a device nobody talks to is seen gone as soon as one that is
        polled. False on a closed port or where ``poll`` is not available."""
        ser = self._serial
        if ser is None or not hasattr(select, "poll"):
            return False
        try:
            fd = ser.fileno()
        except Exception:  # noqa: BLE001 (a port object without a descriptor)
            return False
        poller = select.poll()
        poller.register(fd, select.POLLHUP | select.POLLERR)
        return any(ev & (select.POLLHUP | select.POLLERR | select.POLLNVAL)
                   for _, ev in poller.poll(0))

    def check_hangup(self) -> None:
        """Close the port and raise when :meth:`hung_up` (nothing when it did not).

        Raises
        ------
        DeviceDisconnectedError
            The other end hung up.
        """
        if self.hung_up():
            self._lost(OSError(errno.EIO, "the device hung up (unplugged or powered off)"))

    def resolve(self) -> str:
        """The path to open now: ``port``, else the port of ``serial_number``.

        Raises
        ------
        DeviceDisconnectedError
            No port given and no device with the serial number is plugged in.
        """
        if self.port:
            return self.port
        if not self.serial_number:
            raise DeviceDisconnectedError(
                self.device_id, "no serial port given", "set port or serial_number in params"
            )
        path = find_serial_port(self.serial_number, self.search_dirs, device_id=self.device_id)
        if path is None:
            raise DeviceDisconnectedError(
                self.device_id,
                f"no serial device with serial number {self.serial_number} is plugged in "
                f"(looked in list_ports and {', '.join(self.search_dirs) or 'no directory'})",
                "plug it in and power it on, check the serial number (dmesg, "
                "ls /dev/serial/by-id) and the udev rules in docs/drivers/",
            )
        return path

    def open(self) -> None:
        """Resolve the port and open it (exclusively); flushes both buffers.

        Raises
        ------
        MissingDependencyError
            pyserial is not installed.
        DeviceDisconnectedError
            The port is absent or busy (another process holds it).
        DevicePermissionError
            The user may not open it (the message names the group to join).
        """
        serial = import_optional("serial", self.device_id)
        path = self.resolve()
        held = _holders_text(path)
        if held:
            raise DeviceDisconnectedError(
                self.device_id, f"serial port {path} is open in another program{held}",
                "close that program: two programs on one port take each other's replies",
            )
        try:
            ser = serial.Serial(
                path, baudrate=self.baudrate, bytesize=8, parity="N", stopbits=1,
                timeout=self.poll_s, write_timeout=WRITE_TIMEOUT_S, rtscts=self.rtscts,
                xonxoff=self.xonxoff, exclusive=True,
            )
        except (serial.SerialException, OSError) as exc:
            if is_permission_denied(exc):
                raise permission_error(self.device_id, path, "serial port", "dialout",
                                       exc) from exc
            raise DeviceDisconnectedError(
                self.device_id, f"cannot open serial port {path}: {exc}{_holders_text(path)}",
                "check the cable, that no other program holds the port, and the permissions "
                "(group dialout, udev rules in docs/drivers/)",
            ) from exc
        _set_exclusive(ser, True)
        self._serial = ser
        self.path = path
        self._buffer.clear()
        try:
            if self.rts is not None:
                set_modem_line(ser, "rts", self.rts)
            ser.reset_input_buffer()
            ser.reset_output_buffer()
        except (serial.SerialException, OSError) as exc:
            self._lost(exc)
        log.debug("%s: opened %s", self.device_id, path)

    def close(self) -> None:
        """Close the port; never raises (a vanished port is fine)."""
        ser, self._serial = self._serial, None
        self._buffer.clear()
        if ser is not None:
            _set_exclusive(ser, False)  # the tty may outlive us (a pty's other end)
            try:
                ser.close()
            except Exception as exc:  # a yanked adapter may fail on close
                log.debug("%s: close: %s", self.device_id, exc)

    # ------------------------------------------------------------------ I/O
    def write(self, data: bytes) -> None:
        """Write all of ``data``.

        Raises
        ------
        DeviceDisconnectedError
            The port is closed or the write failed (unplugged).
        """
        ser = self._require()
        try:
            ser.write(bytes(data))
            ser.flush()
        except Exception as exc:
            self._lost(exc)

    def read_some(self, timeout_s: float | None = None) -> bytes:
        """The bytes received within one poll (or ``timeout_s``), possibly none.

        Raises
        ------
        DeviceDisconnectedError
            The port failed (unplugged).
        """
        if self._buffer:
            out = bytes(self._buffer)
            self._buffer.clear()
            return out
        ser = self._require()
        try:
            if timeout_s is not None and timeout_s != ser.timeout:
                ser.timeout = timeout_s
            n = ser.in_waiting
            return ser.read(max(n, 1))
        except Exception as exc:
            self._lost(exc)
        return b""  # not reached

    def read_until(self, terminator: bytes, timeout_s: float, what: str = "a reply") -> bytes:
        """Read up to and including ``terminator``, within ``timeout_s`` seconds.

        Returns
        -------
        bytes
            The data with the terminator; bytes after it stay buffered.

        Raises
        ------
        DeviceTimeoutError
            The link's ``timeout_error``: no terminator in time.
        DeviceDisconnectedError
            The port failed.
        """
        deadline = time.monotonic() + timeout_s
        data = bytearray()
        while True:
            i = data.find(terminator)
            if i >= 0:
                end = i + len(terminator)
                self._buffer[:0] = data[end:]
                return bytes(data[:end])
            if time.monotonic() > deadline:
                data += self.discard_input()  # a reader late past its deadline (a
                if data.find(terminator) >= 0:    # loaded machine) takes what came
                    continue
                self._buffer[:0] = data
                raise self.timeout_error(
                    self.device_id,
                    f"no {what} within {timeout_s:g} s on {self.path} (received "
                    f"{_tail(bytes(data))})",
                    "check that the device is powered and is the expected model, "
                    "and the baud rate",
                )
            data += self.read_some()

    def read_exactly(self, n: int, timeout_s: float, what: str = "a reply") -> bytes:
        """Read exactly ``n`` bytes within ``timeout_s`` seconds (see :meth:`read_until`)."""
        deadline = time.monotonic() + timeout_s
        data = bytearray()
        while len(data) < n:
            if time.monotonic() > deadline:
                data += self.discard_input()  # as read_until: what came meanwhile
                if len(data) >= n:
                    break
                self._buffer[:0] = data
                raise self.timeout_error(
                    self.device_id,
                    f"no {what} within {timeout_s:g} s on {self.path} ({len(data)} of {n} "
                    "bytes)", "check that the device is powered and is the expected model",
                )
            data += self.read_some()
        self._buffer[:0] = data[n:]
        return bytes(data[:n])

    def discard_input(self) -> bytes:
        """Drop and return whatever has been received and not read yet."""
        out = bytes(self._buffer)
        self._buffer.clear()
        ser = self._require()
        try:
            n = ser.in_waiting
            if n:
                out += ser.read(n)
        except Exception as exc:
            self._lost(exc)
        return out

    # ------------------------------------------------------------------ helpers
    def _require(self) -> Any:
        if self._serial is None:
            raise DeviceDisconnectedError(
                self.device_id, f"serial port {self.path or self.port or '?'} is not open",
                "call reconnect()",
            )
        return self._serial

    def _lost(self, exc: BaseException) -> None:
        path = self.path
        self.close()
        raise DeviceDisconnectedError(
            self.device_id, f"serial port {path} failed: {exc}",
            "check the USB cable and power, then call reconnect() (the port is found "
            "again by its serial number)",
        ) from exc
