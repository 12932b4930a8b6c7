"""Who may open a device: the permission errors of the serial and USB links, and one
program per LightCrafter (the unit lock, across processes; the libusb claim of the
hidapi wheel's ``hid`` module, emulated by ``FakeHid``)."""

from __future__ import annotations

import errno
import grp
import os
import subprocess
import sys
import textwrap

import pytest

from drivers.device_access import LOCK_DIR_ENV, DeviceLock, permission_error
from drivers.dlp_lightcrafter import LightCrafter4500
from drivers.errors import DeviceDisconnectedError, DevicePermissionError
from drivers.transports import SerialLink
from drivers.usb_transports import HidLink, hid_node
from tests.mocks import Dlpc350Emulator, FakeHid, FakeUsb


@pytest.fixture
def locks(tmp_path, monkeypatch):
    """Unit locks in a directory of this test (shared with its child processes)."""
    monkeypatch.setenv(LOCK_DIR_ENV, str(tmp_path / "locks"))
    return tmp_path / "locks"


def foreign_node(tmp_path, monkeypatch):
    """A device node of group dialout, rw for owner and group only, that this user may
    not open: the test process is not in the group (``os.getgroups`` says none) and
    ``os.access`` says no (root would pass any mode)."""
    node = tmp_path / "ttyUSB0"
    node.write_bytes(b"")
    node.chmod(0o660)
    dialout = grp.getgrnam("dialout").gr_gid
    if os.geteuid() == 0:
        os.chown(node, 0, dialout)
    monkeypatch.setattr(os, "getgroups", lambda: [])
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: False if str(p) == str(node)
                        else real_access(p, mode, **kw))
    return node, grp.getgrgid(os.stat(node).st_gid).gr_name


# ------------------------------------------------------------------ permission denied
def test_serial_permission_denied_names_the_group(tmp_path, monkeypatch):
    """pyserial's refusal of a port the user may not open (``SerialException`` with
    errno 13, as ``serial.Serial`` raises it) is a permission error naming the group,
    not a disconnected device."""
    import serial

    node, group = foreign_node(tmp_path, monkeypatch)

    def refuse(port, **kw):
        raise serial.SerialException(errno.EACCES, f"could not open port {port}: [Errno 13] "
                                     f"Permission denied: '{port}'")

    monkeypatch.setattr(serial, "Serial", refuse)
    link = SerialLink("stage", port=str(node))
    with pytest.raises(DevicePermissionError) as info:
        link.open()
    err = info.value
    assert not isinstance(err, DeviceDisconnectedError) and isinstance(err, PermissionError)
    assert f"permission denied on serial port {node}" in err.problem
    assert f"group {group}" in err.problem and "crw" not in err.problem
    if group != "root":
        assert f"usermod -aG {group}" in err.fix
    assert not link.is_open


def test_permission_fix_for_a_root_owned_node_and_a_stale_login(tmp_path, monkeypatch):
    node = tmp_path / "hidraw0"
    node.write_bytes(b"")
    monkeypatch.setattr(os, "getgroups", lambda: [])
    if os.stat(node).st_gid == 0:  # a node udev left to root: the rule and the group
        err = permission_error("dmd", str(node), "USB device", "plugdev")
        assert "udev rule" in err.fix and "usermod -aG plugdev" in err.fix
    else:
        pytest.skip("needs a node of group root (run as root, as CI does)")
    os.chown(node, 0, grp.getgrnam("dialout").gr_gid)
    monkeypatch.setattr(grp, "getgrgid", lambda gid: grp.struct_group(
        ("dialout", "x", gid, ["root"])))
    err = permission_error("stage", str(node), "serial port", "dialout")
    assert "after this session started: log out and in" in err.fix


def test_hid_permission_denied_names_the_group(tmp_path, monkeypatch, locks):
    """hidapi says only "open failed": a node the user may not read and write makes it
    a permission error naming the node's group."""
    node, group = foreign_node(tmp_path, monkeypatch)
    emu = Dlpc350Emulator()
    hid = FakeHid(emu, backend="hidraw")
    monkeypatch.setattr(hid, "enumerate", lambda v=0, p=0: [{
        "path": str(node).encode(), "serial_number": emu.serial_number,
        "interface_number": 0}])
    monkeypatch.setattr(type(hid.device()), "open_path", lambda self, p: (_ for _ in ()).throw(
        OSError("open failed")))
    with pytest.raises(DevicePermissionError, match=f"group {group}"):
        HidLink("dmd", vendor_id=0x0451, product_id=0x6401, hid_module=hid).open()
    lock = DeviceLock("x", "usb-0451-6401-LC4500-0001", "unit")
    lock.acquire()  # the failed open released the unit
    lock.release()


def test_pyusb_permission_denied_is_not_busy(locks):
    usb = FakeUsb(Dlpc350Emulator())
    usb.util.claim_interface = staticmethod(lambda dev, i: (_ for _ in ()).throw(
        usb.core.USBError("Access denied (insufficient permissions)", errno=13)))
    with pytest.raises(DevicePermissionError, match="USB device 0451:6401"):
        LightCrafter4500("dmd", transport="pyusb", usb_backend=usb).open()


def test_hid_node_of_each_module(tmp_path):
    """The libusb module's paths name the port (``bus-ports:config.interface``, as
    cython-hidapi 0.15 formats them: ``%u-%u``, ``.%u`` per hub port, ``:%u.%u``); the
    node is found through sysfs."""
    port = tmp_path / "1-2.3"
    port.mkdir()
    (port / "busnum").write_text("1\n")
    (port / "devnum").write_text("10\n")
    assert hid_node(b"1-2.3:1.0", sysfs=str(tmp_path)) == "/dev/bus/usb/001/010"
    assert hid_node(b"1-4:1.0", sysfs=str(tmp_path)) is None  # not in sysfs: unknown
    assert hid_node(b"/dev/hidraw3") == "/dev/hidraw3"
    assert hid_node(b"fake-hidraw0") is None


# ------------------------------------------------------------------ one program per unit
def test_libusb_module_detaches_and_claims(locks):
    """The wheel's ``hid`` module (libusb): the kernel's HID driver is detached while
    open and re-attached on close; a program outside this project holding the claim
    makes the open fail with a message that says so, not one about hidraw."""
    emu = Dlpc350Emulator(validation_polls=1)
    hid = FakeHid(emu)
    with LightCrafter4500("dmd", hid_backend=hid, reply_timeout_s=1.0):
        assert emu.claimed is not None and not emu.usbhid_bound
    assert emu.claimed is None and emu.usbhid_bound
    other = hid.device()  # e.g. TI's GUI, not using our lock
    other.open_path(b"fake-hidraw0")
    with pytest.raises(DeviceDisconnectedError) as info:
        LightCrafter4500("dmd", hid_backend=hid).open()
    assert "another program uses it" in info.value.fix and "claims interface 0" in info.value.fix
    assert "/dev/hidraw" not in str(info.value)  # the old hint named the other backend
    other.close()


def test_hidraw_module_keeps_the_kernel_driver(locks):
    emu = Dlpc350Emulator(validation_polls=1)
    with LightCrafter4500("dmd", transport="hidraw", hid_backend=FakeHid(emu, backend="hidraw"),
                          reply_timeout_s=1.0) as dmd:
        assert emu.usbhid_bound and emu.claimed is None
        dmd.led_currents = {"red": 0.5}
    assert emu.led_fractions()[0] == pytest.approx(0.5, abs=1 / 255)


def test_second_driver_object_on_one_unit_is_refused(locks):
    """Through the hidraw module, nothing in the OS stops a second handle: the unit
    lock does, naming this process; closing the first frees the unit."""
    emu = Dlpc350Emulator(validation_polls=1)
    hid = FakeHid(emu, backend="hidraw")
    first = LightCrafter4500("dmd", transport="hidraw", hid_backend=hid, reply_timeout_s=1.0)
    first.open()
    second = LightCrafter4500("dmd2", transport="hidraw", hid_backend=hid)
    with pytest.raises(DeviceDisconnectedError, match=r"in use by this process .*pid "
                       + str(os.getpid())):
        second.open()
    usb = FakeUsb(emu)  # pyusb on the same unit (same serial number): refused as well
    with pytest.raises(DeviceDisconnectedError, match="serial LC4500-0001 is in use"):
        LightCrafter4500("dmd3", transport="pyusb", usb_backend=usb).open()
    first.close()
    second.open()
    second.close()


HOLDER = textwrap.dedent("""
    import sys
    from drivers.dlp_lightcrafter import LightCrafter4500
    from tests.mocks import Dlpc350Emulator, FakeHid
    dmd = LightCrafter4500("dmd", transport="hidraw", reply_timeout_s=1.0,
                           hid_backend=FakeHid(Dlpc350Emulator(validation_polls=1),
                                               backend="hidraw"))
    dmd.open()
    print("open", flush=True)
    sys.stdin.read()  # hold the unit until the test closes our stdin
    dmd.close()
""")


def test_second_process_on_one_unit_is_refused_naming_the_holder(locks, tmp_path):
    """Two processes, one unit (the same serial number): the second is told which
    process holds it; once the holder exits, the unit opens."""
    env = {**os.environ, "PYTHONPATH": os.getcwd() + os.pathsep + os.environ.get(
        "PYTHONPATH", ""), LOCK_DIR_ENV: str(locks)}
    script = tmp_path / "lightcrafter_holder.py"
    script.write_text(HOLDER)
    holder = subprocess.Popen([sys.executable, str(script)],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env,
                              text=True)
    try:
        assert holder.stdout.readline().strip() == "open"
        emu = Dlpc350Emulator(validation_polls=1)
        dmd = LightCrafter4500("dmd", transport="hidraw", reply_timeout_s=1.0,
                               hid_backend=FakeHid(emu, backend="hidraw"))
        with pytest.raises(DeviceDisconnectedError) as info:
            dmd.open()
        assert f"in use by process {holder.pid}" in info.value.problem
        assert "lightcrafter_holder.py" in info.value.problem
        assert not emu.reports  # nothing was sent to the unit
    finally:
        holder.stdin.close()
        holder.wait(10)
    with dmd:
        assert dmd.is_open
