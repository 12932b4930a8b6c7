"""USB transports of the hardware drivers: USB HID (hidapi) and raw USB (pyusb).

:class:`HidLink` does for a USB HID device what :class:`drivers.transports.SerialLink`
does for a serial port, through cython-hidapi (the ``hidapi`` package): found by
vendor/product id, serial number and interface, 64-byte reports written with the
leading report id 0, reads with a timeout, ``IOError`` from hidapi = disconnected.
The ``hidapi`` wheel for Linux holds two modules with one API: ``hid``, built on
libusb (it detaches the kernel's usbhid driver from the interface and claims it while
open, re-attaching it on close; it opens ``/dev/bus/usb/BBB/DDD``; a second claim of
the interface is refused), and ``hidraw``, built on the kernel's hidraw driver (the
kernel driver stays bound; it opens ``/dev/hidrawN``, which any number of programs
may open at once). :class:`UsbLink` reaches the same reports through pyusb (libusb)
on the interrupt endpoints, detaching the kernel driver too.

Both hold a :class:`~drivers.device_access.DeviceLock` on the unit while open (its
USB ids and serial number): replies are matched by a sequence number only, so a
second program (or a second driver object) on the same unit is refused, naming the
holder, whichever module or library it uses here. A node the user may not open is a
:class:`~drivers.errors.DevicePermissionError` naming the group to join.

Both are optional (the ``hardware`` extra), imported when a device opens
(:func:`drivers.transports.import_optional`).
"""

from __future__ import annotations

import logging
import os
import re
from typing import Any

from drivers.device_access import DeviceLock, is_permission_denied, permission_error, usb_node
from drivers.errors import (
    DeviceDisconnectedError,
    DeviceTimeoutError,
    MissingDependencyError,
)
from drivers.transports import _holders_text, import_optional

__all__ = ["HID_MODULES", "HidLink", "UsbLink", "hid_node"]

log = logging.getLogger("drivers.transports")

#: The modules of the ``hidapi`` package, and what each is built on (Linux wheels).
HID_MODULES: dict[str, str] = {"hid": "libusb", "hidraw": "hidraw"}


def hid_node(path: bytes | str, sysfs: str = "/sys/bus/usb/devices") -> str | None:
    """The device node behind a hidapi ``path``: the path itself when absolute (the
    hidraw module's ``/dev/hidrawN``); for the libusb module, whose paths name the USB
    port and interface (``1-2.3:1.0``: bus 1, ports 2 then 3, configuration 1,
    interface 0; hidapi 0.14 and later), ``/dev/bus/usb/BBB/DDD`` from that port's
    ``busnum`` and ``devnum`` in sysfs; None when it cannot tell."""
    text = path.decode("utf-8", "replace") if isinstance(path, bytes) else str(path)
    if text.startswith("/"):
        return text
    m = re.fullmatch(r"(\d+-[\d.]+):\d+\.\d+", text)
    if m is None:
        return None
    try:
        port = os.path.join(sysfs, m.group(1))
        with open(os.path.join(port, "busnum")) as bus, open(os.path.join(port, "devnum")) as dev:
            return usb_node(int(bus.read()), int(dev.read()))
    except (OSError, ValueError):
        return None


def _denied(node: str | None) -> bool:
    """True when ``node`` exists and this user may not read and write it."""
    return bool(node) and os.path.exists(node) and not os.access(node, os.R_OK | os.W_OK)


def _holders(node: str | None) -> str:
    """``"; held by process ..."`` for the other processes holding ``node`` open."""
    return _holders_text(node) if node else ""


class _ReportLink:
    """What :class:`HidLink` and :class:`UsbLink` share: the ids, the open handle, and
    the errors of a link that is closed, lost or silent, and ``write`` and ``read`` (a
    subclass defines ``open``, ``close`` and the transfers ``_write``, ``_read`` and
    the errors ``_io_errors`` that mean the device is lost)."""

    #: The transport, as the error messages name it.
    kind = "USB"

    def __init__(self, device_id: str, vendor_id: int, product_id: int,
                 serial_number: str | None, report_size: int,
                 timeout_error: type[DeviceTimeoutError]) -> None:
        self.device_id = device_id
        self.vendor_id, self.product_id = int(vendor_id), int(product_id)
        self.serial_number = None if serial_number is None else str(serial_number)
        self.report_size = int(report_size)
        self.timeout_error = timeout_error
        self._dev: Any = None
        self._lock: DeviceLock | None = None

    def _take_lock(self, serial: str | None, where: str) -> DeviceLock:
        """Lock the unit (by its serial number, else where it is plugged in)."""
        ids = f"{self.vendor_id:04x}-{self.product_id:04x}"
        what = (f"USB device {ids.replace('-', ':')} "
                + (f"serial {serial}" if serial else f"at {where}"))
        lock = DeviceLock(self.device_id, f"usb-{ids}-{serial or where}", what)
        lock.acquire()
        return lock

    def _drop_lock(self) -> None:
        lock, self._lock = self._lock, None
        if lock is not None:
            lock.release()

    @property
    def is_open(self) -> bool:
        """True while the device is open."""
        return self._dev is not None

    def _require(self) -> Any:
        if self._dev is None:
            raise DeviceDisconnectedError(self.device_id, f"the {self.kind} device is not "
                                          "open", "call reconnect()")
        return self._dev

    def _silent(self, timeout_s: float, hint: str) -> DeviceTimeoutError:
        return self.timeout_error(self.device_id,
                                  f"no {self.kind} report within {timeout_s:g} s", hint)

    def _lost(self, exc: BaseException) -> None:
        self.close()
        raise DeviceDisconnectedError(
            self.device_id, f"{self.kind} I/O failed: {exc}",
            "check the USB cable and power, then call reconnect()",
        ) from exc

    #: What a silent device's timeout error suggests.
    silent_hint = "check that the device is powered"

    def write(self, report: bytes) -> None:
        """Write one report (padded with zeros to ``report_size`` bytes).

        Raises
        ------
        DeviceDisconnectedError
            The link is not open, or the write failed (unplugged).
        """
        dev = self._require()
        data = bytes(report).ljust(self.report_size, b"\0")
        try:
            self._write(dev, data)
        except self._io_errors() as exc:
            self._lost(exc)

    def read(self, timeout_s: float) -> bytes:
        """Read one report within ``timeout_s`` seconds.

        Raises
        ------
        DeviceTimeoutError
            The link's ``timeout_error``: nothing within the timeout.
        DeviceDisconnectedError
            The link is not open, or the read failed (unplugged).
        """
        dev = self._require()
        try:
            data = self._read(dev, max(1, int(round(timeout_s * 1000))))
        except self._io_errors() as exc:
            self._lost(exc)
        if not data:
            raise self._silent(timeout_s, self.silent_hint)
        return bytes(data)

    def _io_errors(self) -> type[BaseException] | tuple[type[BaseException], ...]:
        """The exceptions of a failed transfer (the device is then lost)."""
        raise NotImplementedError

    def _write(self, dev: Any, data: bytes) -> None:
        """Send ``data`` (``report_size`` bytes) on the open handle ``dev``."""
        raise NotImplementedError

    def _read(self, dev: Any, timeout_ms: int) -> bytes:
        """One report from ``dev`` within ``timeout_ms``; empty when none came."""
        raise NotImplementedError


class HidLink(_ReportLink):
    """One USB HID device through cython-hidapi (``pip install hidapi``).

    Parameters
    ----------
    device_id : str
        The device using the link.
    vendor_id, product_id : int
        USB ids (e.g. 0x0451, 0x6401 for a DLPC350 LightCrafter 4500).
    serial_number : str, optional
        Pick this unit when several are plugged in; re-resolved on every open.
    interface : int, optional
        USB interface number to open (TI's host code opens interface 0).
    report_size : int
        Bytes per report without the report id.
    timeout_error : type
        The kind's timeout error.
    module : {"hid", "hidraw"}
        The hidapi module: ``hid`` (libusb: the kernel driver detached and the
        interface claimed while open) or ``hidraw`` (the kernel's hidraw driver stays
        bound); see :data:`HID_MODULES`.
    hid_module : module-like, optional
        Replaces the import of ``module`` (an emulator providing ``enumerate`` and
        ``device``).
    """

    kind = "USB HID"

    def __init__(
        self, device_id: str, *, vendor_id: int, product_id: int,
        serial_number: str | None = None, interface: int | None = 0, report_size: int = 64,
        timeout_error: type[DeviceTimeoutError] = DeviceTimeoutError, module: str = "hid",
        hid_module: Any = None,
    ) -> None:
        super().__init__(device_id, vendor_id, product_id, serial_number, report_size,
                         timeout_error)
        if module not in HID_MODULES:
            raise ValueError(f"module={module!r}: use one of {sorted(HID_MODULES)}")
        self.interface = interface
        self.module = module
        self._hid_module = hid_module
        self.path: bytes | None = None

    def open(self) -> None:
        """Find the device (ids, serial, interface), lock the unit and open it.

        Raises
        ------
        MissingDependencyError
            hidapi is not installed.
        DevicePermissionError
            The user may not open the device node (the message names the group).
        DeviceDisconnectedError
            No such device; or it is in use: by another program or driver object of
            this project (the unit lock names it), or by another program that claimed
            its interface (libusb module).
        """
        hid = self._hid_module or import_optional(self.module, self.device_id)
        if not hasattr(hid, "enumerate") or not hasattr(hid, "device"):
            raise MissingDependencyError(
                self.device_id, f"the module {self.module!r} is not cython-hidapi (the "
                "PyPI package 'hid' has the same import name)",
                "pip uninstall hid; pip install hidapi",
            )
        listed = hid.enumerate(self.vendor_id, self.product_id)
        found = [
            d for d in listed
            if (self.serial_number is None or d.get("serial_number") == self.serial_number)
            and (self.interface is None or d.get("interface_number") in (self.interface, -1))
        ]
        ids = f"{self.vendor_id:04x}:{self.product_id:04x}"
        if not found:
            unread = [d for d in listed if self.serial_number and not d.get("serial_number")]
            if unread and _denied(hid_node(unread[0]["path"])):
                # libusb reads the serial number by opening the device: refused, it is blank
                raise permission_error(self.device_id, hid_node(unread[0]["path"]),
                                       f"USB HID device {ids}", "plugdev")
            raise DeviceDisconnectedError(
                self.device_id, f"no USB HID device {ids}"
                + (f" with serial {self.serial_number}" if self.serial_number else "")
                + " is plugged in", "plug it in and power it on; check lsusb and the udev rules",
            )
        path = found[0]["path"]
        node = hid_node(path)
        self._lock = self._take_lock(found[0].get("serial_number") or self.serial_number,
                                     node or repr(path))
        dev = hid.device()
        try:
            dev.open_path(path)
        except OSError as exc:
            self._drop_lock()
            if _denied(node) or is_permission_denied(exc):
                raise permission_error(self.device_id, node or repr(path),
                                       f"USB HID device {ids}", "plugdev", exc) from exc
            claim = ("it detaches the kernel's usbhid driver and claims interface "
                     f"{self.interface}, which another program holds"
                     if HID_MODULES[self.module] == "libusb" else "hidraw refused it")
            raise DeviceDisconnectedError(
                self.device_id, f"cannot open USB HID device {ids} ({node or path!r}) with "
                f"hidapi's {self.module!r} module: {exc}{_holders(node)}",
                f"another program uses it ({claim}): close it (TI's GUI, a pycrafter4500 "
                "script); or it was unplugged: plug it in",
            ) from exc
        self._dev, self.path = dev, path

    def close(self) -> None:
        """Close the handle and release the unit; never raises."""
        dev, self._dev = self._dev, None
        if dev is not None:
            try:
                dev.close()
            except Exception as exc:
                log.debug("%s: close: %s", self.device_id, exc)
        self._drop_lock()

    silent_hint = "check that the device is powered and not in a firmware-update mode"

    def _io_errors(self) -> tuple[type[BaseException], ...]:
        return (OSError, ValueError)  # hidapi raises IOError after an unplug

    def _write(self, dev: Any, data: bytes) -> None:
        n = dev.write(b"\0" + data)  # report id 0 first
        if n is None or n < 0:
            raise OSError("hidapi's write returned -1 (the report was not sent)")

    def _read(self, dev: Any, timeout_ms: int) -> bytes:
        return dev.read(self.report_size, timeout_ms)


class UsbLink(_ReportLink):
    """One USB device through pyusb (libusb): interrupt/bulk endpoints, kernel driver
    detached, the same ``open/close/write/read`` as :class:`HidLink`.

    Parameters
    ----------
    device_id : str
        The device using the link.
    vendor_id, product_id : int
        USB ids.
    serial_number : str, optional
        Pick this unit (its iSerialNumber string); re-resolved on every open.
    interface : int
        Interface to claim.
    ep_out, ep_in : int
        Endpoint addresses (0x01 and 0x81 on a LightCrafter 4500).
    report_size : int
        Bytes per transfer (padded with zeros on write).
    timeout_error : type
        The kind's timeout error.
    usb_module : module-like, optional
        Replaces ``import usb`` (its ``core`` and ``util``; tests pass a fake).
    """

    def __init__(
        self, device_id: str, *, vendor_id: int, product_id: int,
        serial_number: str | None = None, interface: int = 0, ep_out: int = 0x01,
        ep_in: int = 0x81, report_size: int = 64,
        timeout_error: type[DeviceTimeoutError] = DeviceTimeoutError, usb_module: Any = None,
    ) -> None:
        super().__init__(device_id, vendor_id, product_id, serial_number, report_size,
                         timeout_error)
        self.interface, self.ep_out, self.ep_in = int(interface), int(ep_out), int(ep_in)
        self._usb_module = usb_module
        self._usb: Any = None

    def open(self) -> None:
        """Find the device, detach the kernel driver, configure it and claim the interface.

        Raises
        ------
        MissingDependencyError
            pyusb is not installed.
        DevicePermissionError
            The user may not open the device node (the message names the group).
        DeviceDisconnectedError
            No such device; or it is busy: locked by another program or driver object
            of this project (named), claimed by another program, or held by a kernel
            driver that cannot be detached.
        """
        usb = self._usb_module
        if usb is None:
            import_optional("usb.core", self.device_id)
            import_optional("usb.util", self.device_id)
            usb = import_optional("usb", self.device_id)
        self._usb = usb
        ids = f"{self.vendor_id:04x}:{self.product_id:04x}"

        def wanted(dev: Any) -> bool:
            if self.serial_number is None:
                return True
            try:
                return usb.util.get_string(dev, dev.iSerialNumber) == self.serial_number
            except (usb.core.USBError, ValueError):
                return False

        dev = usb.core.find(idVendor=self.vendor_id, idProduct=self.product_id,
                            custom_match=wanted)
        if dev is None:
            raise DeviceDisconnectedError(
                self.device_id, f"no USB device {ids}" + (
                    f" with serial {self.serial_number}" if self.serial_number else "")
                + " is plugged in", "plug it in and power it on; check lsusb",
            )
        node = (usb_node(dev.bus, dev.address)
                if getattr(dev, "bus", None) is not None else None)
        serial = self.serial_number
        if serial is None:
            try:
                serial = usb.util.get_string(dev, dev.iSerialNumber) or None
            except (usb.core.USBError, ValueError):  # no permission to read it yet
                serial = None
        self._lock = self._take_lock(serial, node or "?")
        try:
            try:
                if dev.is_kernel_driver_active(self.interface):
                    dev.detach_kernel_driver(self.interface)
            except NotImplementedError:  # not on this platform
                pass
            dev.set_configuration()
            usb.util.claim_interface(dev, self.interface)
        except usb.core.USBError as exc:
            usb.util.dispose_resources(dev)
            self._drop_lock()
            if is_permission_denied(exc) or _denied(node):
                raise permission_error(self.device_id, node or "/dev/bus/usb",
                                       f"USB device {ids}", "plugdev", exc) from exc
            raise DeviceDisconnectedError(
                self.device_id, f"cannot claim USB device {ids}: {exc}{_holders(node)}",
                "another program uses it (close it: TI's GUI, a pycrafter4500 script), "
                "or a kernel driver could not be detached",
            ) from exc
        self._dev = dev

    def close(self) -> None:
        """Release the interface; never raises."""
        dev, self._dev = self._dev, None
        if dev is None:
            return
        usb = self._usb
        for step in (lambda: usb.util.release_interface(dev, self.interface),
                     lambda: dev.attach_kernel_driver(self.interface),
                     lambda: usb.util.dispose_resources(dev)):
            try:
                step()
            except Exception as exc:  # a vanished device, or no kernel driver to re-attach
                log.debug("%s: close: %s", self.device_id, exc)
        self._drop_lock()

    def _io_errors(self) -> type[BaseException]:
        return self._usb.core.USBError

    def _write(self, dev: Any, data: bytes) -> None:
        dev.write(self.ep_out, data, 1000)

    def _read(self, dev: Any, timeout_ms: int) -> bytes:
        try:
            return dev.read(self.ep_in, self.report_size, timeout_ms)
        except self._usb.core.USBTimeoutError:
            return b""
