"""Aravis helpers of :mod:`drivers.aravis_camera`: importing PyGObject's Aravis, the
GigE Vision liveness probe, frame-id arithmetic and the pixel-format table."""

from __future__ import annotations

import socket
import struct
from typing import Any

from drivers.errors import MissingDependencyError

__all__ = ["FORMATS", "LOST_CODES", "frames_between", "gvcp_answers", "import_aravis"]

#: Camera pixel formats for each of ours, best first, with their significant bits.
FORMATS: dict[str, tuple[tuple[str, int], ...]] = {
    "mono8": (("Mono8", 8),),
    "mono12": (("Mono12", 12), ("Mono16", 16)),
    "mono16": (("Mono16", 16), ("Mono12", 12)),
}
#: ArvDeviceError codes that mean the camera is gone (NOT_CONNECTED, TRANSFER_ERROR,
#: TIMEOUT, NOT_CONTROLLER).
LOST_CODES = {2, 4, 5, 10}
_APT = "gir1.2-aravis-0.8 (apt-get install gir1.2-aravis-0.8)"


def import_aravis(device_id: str) -> tuple[Any, Any]:
    """Import Aravis 0.8 and GLib through PyGObject (called when a camera opens).

    Parameters
    ----------
    device_id : str
        The device asking (named in the error).

    Returns
    -------
    (module, module)
        ``gi.repository.Aravis`` and ``gi.repository.GLib``.

    Raises
    ------
    MissingDependencyError
        PyGObject (the ``hardware`` extra) or the Aravis typelib (Debian's
        ``gir1.2-aravis-0.8``) is missing; the message names the package to install.
    """
    try:
        import gi
    except ImportError as exc:
        raise MissingDependencyError(
            device_id, f"PyGObject is not installed ({exc})",
            "pip install 'diffuserlab[hardware]' (PyGObject<3.51 builds with apt-get install "
            "libgirepository1.0-dev libcairo2-dev pkg-config)",
        ) from exc
    try:
        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis, GLib
    except (ImportError, ValueError) as exc:
        raise MissingDependencyError(
            device_id, f"the Aravis 0.8 typelib is not installed ({exc})", f"install {_APT}",
        ) from exc
    return Aravis, GLib


def gvcp_answers(ip: str, *, tries: int = 3, wait_s: float = 0.2) -> bool:
    """Whether a GigE Vision camera answers a GVCP READREG of its heartbeat-timeout
    bootstrap register (0x0938); any acknowledge counts (reading needs no control
    privilege). GigE Vision 2.0, GVCP: header 0x42, flags 0x01 (acknowledge wanted),
    command 0x0080, length 4, request id; then the 32-bit address, big-endian.

    Parameters
    ----------
    ip : str
        The camera's IPv4 address (GVCP port 3956).
    tries, wait_s : int, float
        Requests sent and the wait for each answer, in seconds.

    Returns
    -------
    bool
    """
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.settimeout(wait_s)
        for req_id in range(1, tries + 1):
            sock.sendto(struct.pack(">BBHHHI", 0x42, 0x01, 0x0080, 4, req_id, 0x0938),
                        (ip, 3956))
            try:
                reply, _ = sock.recvfrom(64)
            except (TimeoutError, ConnectionRefusedError, OSError):
                continue
            if len(reply) >= 8 and struct.unpack(">H", reply[2:4])[0] == 0x0081:
                return True
    return False


def frames_between(last: int | None, fid: int) -> int:
    """Frames missing between camera frame ids ``last`` and ``fid``: GigE Vision ids
    are 16-bit and wrap from 65535 to 1 (0 is invalid); a step back that is not a
    wrap (a restarted camera) counts as none."""
    if last is None or fid == last:
        return 0
    if fid > last:
        return fid - last - 1
    if last <= 0xFFFF and last >= 0x8000 and fid < 0x8000:
        return (0xFFFF - last) + (fid - 1)
    return 0
