"""Aravis helpers of :mod:`drivers.aravis_camera`: importing PyGObject's Aravis, the
GigE Vision liveness probe, frame-id arithmetic, the pixel-format table and the decoding
of a buffer in each camera format."""

from __future__ import annotations

import socket
import struct
from typing import Any, NamedTuple

import numpy as np

from drivers.camera_image import demosaic, unpack_mono10p, unpack_mono12p
from drivers.errors import MissingDependencyError

__all__ = ["FORMATS", "LOST_CODES", "Source", "decode", "frames_between", "gvcp_answers",
           "import_aravis"]


class Source(NamedTuple):
    """A camera pixel format: its GenICam name, significant bits per channel and how
    its buffer is laid out ("u8", "u16" little-endian words, "p10"/"p12" PFNC packed,
    "rgb" interleaved 8-bit, "bayer8"/"bayer16" a colour mosaic)."""

    name: str
    bits: int
    layout: str


def _bayer(depth: int) -> tuple[Source, ...]:
    return tuple(Source(f"Bayer{p}{depth}", depth, f"bayer{8 if depth == 8 else 16}")
                 for p in ("RG", "GR", "GB", "BG"))


#: Camera pixel formats for each of ours, best first.
FORMATS: dict[str, tuple[Source, ...]] = {
    "mono8": (Source("Mono8", 8, "u8"),),
    "mono10": (Source("Mono10", 10, "u16"), Source("Mono10p", 10, "p10")),
    "mono12": (Source("Mono12", 12, "u16"), Source("Mono12p", 12, "p12"),
               Source("Mono16", 16, "u16")),
    "mono16": (Source("Mono16", 16, "u16"), Source("Mono12", 12, "u16"),
               Source("Mono12p", 12, "p12")),
    "rgb8": (*_bayer(8), Source("RGB8", 8, "rgb")),
    "rgb16": _bayer(16),
    "bayer8": _bayer(8),
    "bayer16": _bayer(16),
}
_LAYOUT_BITS = {"u8": 8, "u16": 16, "p10": 10, "p12": 12, "rgb": 24, "bayer8": 8,
                "bayer16": 16}


def decode(data: bytes, source: Source, shape: tuple[int, int],
           colour: bool) -> np.ndarray | None:
    """The image in a buffer of ``source``'s layout.

    Parameters
    ----------
    data : bytes
        The buffer's data.
    source : Source
        The camera's pixel format.
    shape : (rows, cols)
        The buffer's image size.
    colour : bool
        Demosaic a Bayer mosaic (an rgb format asked for) instead of returning it raw.

    Returns
    -------
    ndarray or None
        ``(rows, cols)`` or ``(rows, cols, 3)`` uint8/uint16; None when ``data`` is
        shorter than the image.
    """
    h, w = shape
    n = h * w
    if len(data) < -(-n * _LAYOUT_BITS[source.layout] // 8):
        return None
    if source.layout == "p10":
        return unpack_mono10p(data, n).reshape(h, w)
    if source.layout == "p12":
        return unpack_mono12p(data, n).reshape(h, w)
    if source.layout == "rgb":
        return np.frombuffer(data, np.uint8, count=3 * n).reshape(h, w, 3)
    dtype = np.uint8 if source.layout in ("u8", "bayer8") else np.dtype("<u2")
    raw = np.frombuffer(data, dtype=dtype, count=n).reshape(h, w)
    if colour and source.layout.startswith("bayer"):
        return demosaic(raw, source.name[5:7])
    return raw
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
