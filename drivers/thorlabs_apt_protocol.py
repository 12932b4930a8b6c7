"""Thorlabs APT host-controller protocol: messages, framing and one controller link.

Protocol (Thorlabs "Motion Controllers Host-Controller Communications Protocol";
notes in docs/drivers/thorlabs-apt.md): every message starts with a 6-byte header,
little-endian: message id (u16), param1, param2, destination, source. When bit 7 of
the destination is set, param1|param2 is the length of a data packet that follows.
The host is 0x01; a single-channel K-/T-cube is 0x50; the bays of a BSC20x rack
(0x11) are 0x21 + bay.

:class:`AptFramer` splits the byte stream a controller sends into :class:`AptMessage`
by the header's data flag and length (a stepper's GET_STATUSUPDATE is 14 bytes in
older documents and 28 in the 2025 one: the length decides). It frames only messages
addressed to the host with an id a controller sends and a length that id can have,
and resynchronises a byte at a time on anything else (as thorlabs_apt_device's
``Unpacker`` does), so stray bytes cannot pose as a header whose length swallows the
next reply.
:class:`AptController` owns one serial port and one reader thread that frames every
message and routes it: a reply to the request waiting for it, anything else (move
completed, homed, stopped, status updates, error reports) to the event handler, so
events interleaved with replies are never lost or mistaken for replies. It also sends
the status-update keepalive (MGMSG_MOT_ACK_USTATUSUPDATE) while updates are on.
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from drivers.errors import DeviceDisconnectedError, DeviceTimeoutError
from drivers.transports import SerialLink

__all__ = [
    "HOST",
    "INBOUND",
    "LATE_READER_S",
    "MSG",
    "STATUS",
    "AptController",
    "AptFramer",
    "AptMessage",
    "pack_message",
]

log = logging.getLogger("drivers.thorlabs_apt")

#: Longest a request past its deadline waits for the reader thread to read the port
#: once more, s: a reply is called missing only after the reader has looked after the
#: deadline, so a reader kept from a core (a loaded machine) is not a silent controller;
#: a reader that cannot run for this long is a failure too.
LATE_READER_S = 10.0

HOST = 0x01
RACK = 0x11
USB_UNIT = 0x50

#: Message ids used by the stage driver (MGMSG_ names without the prefix).
MSG: dict[str, int] = {
    "HW_DISCONNECT": 0x0002, "HW_REQ_INFO": 0x0005, "HW_GET_INFO": 0x0006,
    "HW_START_UPDATEMSGS": 0x0011, "HW_STOP_UPDATEMSGS": 0x0012,
    "HW_RESPONSE": 0x0080, "HW_RICHRESPONSE": 0x0081,
    "MOD_SET_CHANENABLESTATE": 0x0210, "MOD_REQ_CHANENABLESTATE": 0x0211,
    "MOD_GET_CHANENABLESTATE": 0x0212, "MOD_IDENTIFY": 0x0223,
    "MOT_REQ_POSCOUNTER": 0x0411, "MOT_GET_POSCOUNTER": 0x0412,
    "MOT_SET_VELPARAMS": 0x0413, "MOT_REQ_VELPARAMS": 0x0414, "MOT_GET_VELPARAMS": 0x0415,
    "MOT_REQ_STATUSBITS": 0x0429, "MOT_GET_STATUSBITS": 0x042A,
    "MOT_SET_GENMOVEPARAMS": 0x043A, "MOT_REQ_GENMOVEPARAMS": 0x043B,
    "MOT_GET_GENMOVEPARAMS": 0x043C,
    "MOT_SET_HOMEPARAMS": 0x0440, "MOT_REQ_HOMEPARAMS": 0x0441, "MOT_GET_HOMEPARAMS": 0x0442,
    "MOT_MOVE_HOME": 0x0443, "MOT_MOVE_HOMED": 0x0444, "MOT_MOVE_RELATIVE": 0x0448,
    "MOT_MOVE_ABSOLUTE": 0x0453, "MOT_MOVE_COMPLETED": 0x0464, "MOT_MOVE_STOP": 0x0465,
    "MOT_MOVE_STOPPED": 0x0466, "MOT_GET_STATUSUPDATE": 0x0481,
    "MOT_GET_USTATUSUPDATE": 0x0491, "MOT_ACK_USTATUSUPDATE": 0x0492,
}

#: Status bits (dword) of GET_STATUSBITS and the status blocks.
STATUS: dict[str, int] = {
    "FWD_LIMIT": 0x1, "REV_LIMIT": 0x2, "MOVING_FWD": 0x10, "MOVING_REV": 0x20,
    "JOG_FWD": 0x40, "JOG_REV": 0x80, "HOMING": 0x200, "HOMED": 0x400,
    "POSITION_ERROR": 0x4000, "ERROR": 0x40000000, "ENABLED": 0x80000000,
}
MOVING_MASK = 0x10 | 0x20 | 0x40 | 0x80 | 0x200
_EVENTS = {0x0080, 0x0081, 0x0444, 0x0464, 0x0466, 0x0481, 0x0491}
_SOURCES = {0x00, RACK, USB_UNIT, *range(0x21, 0x2B)}
#: Messages a controller sends to the host: id -> data lengths it may carry (0: the
#: header-only form). Status blocks are 14 bytes (DC servo), 20 (brushless) or 28
#: (stepper, 2025 document).
INBOUND: dict[int, frozenset[int]] = {
    0x0006: frozenset({84}),            # HW_GET_INFO
    0x0080: frozenset({0}),             # HW_RESPONSE
    0x0081: frozenset({68}),            # HW_RICHRESPONSE
    0x0212: frozenset({0}),             # MOD_GET_CHANENABLESTATE
    0x0412: frozenset({6}),             # MOT_GET_POSCOUNTER
    0x040B: frozenset({6}),             # MOT_GET_ENCCOUNTER
    0x0415: frozenset({14}),            # MOT_GET_VELPARAMS
    0x0418: frozenset({22}),            # MOT_GET_JOGPARAMS
    0x0425: frozenset({16}),            # MOT_GET_LIMSWITCHPARAMS
    0x042A: frozenset({6}),             # MOT_GET_STATUSBITS
    0x043C: frozenset({6}),             # MOT_GET_GENMOVEPARAMS
    0x0442: frozenset({14}),            # MOT_GET_HOMEPARAMS
    0x0444: frozenset({0}),             # MOT_MOVE_HOMED
    0x0447: frozenset({6}),             # MOT_GET_MOVERELPARAMS
    0x0452: frozenset({6}),             # MOT_GET_MOVEABSPARAMS
    0x0464: frozenset({14, 20, 28}),    # MOT_MOVE_COMPLETED
    0x0466: frozenset({14, 20, 28}),    # MOT_MOVE_STOPPED
    0x0481: frozenset({14, 28}),        # MOT_GET_STATUSUPDATE
    0x0491: frozenset({14}),            # MOT_GET_DCSTATUSUPDATE
}


@dataclass(frozen=True)
class AptMessage:
    """One APT message: id, header params (header-only form) or data, addresses."""

    msg_id: int
    dest: int
    source: int
    param1: int = 0
    param2: int = 0
    data: bytes | None = None

    def pack(self) -> bytes:
        """The message as sent on the wire."""
        return pack_message(self.msg_id, self.dest, self.source, self.param1, self.param2,
                            self.data)


def pack_message(msg_id: int, dest: int, source: int = HOST, param1: int = 0,
                 param2: int = 0, data: bytes | None = None) -> bytes:
    """Bytes of an APT message.

    Parameters
    ----------
    msg_id : int
        Message id (u16).
    dest, source : int
        Endpoint addresses; bit 7 of ``dest`` is set here when ``data`` is given.
    param1, param2 : int
        Header parameters of a header-only message (e.g. the channel).
    data : bytes, optional
        The data packet (at most 255 bytes).

    Returns
    -------
    bytes
        6 bytes, or 6 + len(data).
    """
    if data is None:
        return struct.pack("<HBBBB", msg_id, param1 & 0xFF, param2 & 0xFF, dest & 0x7F, source)
    if len(data) > 255:
        raise ValueError(f"APT data packet of {len(data)} bytes is longer than 255")
    return struct.pack("<HHBB", msg_id, len(data), (dest & 0x7F) | 0x80, source) + bytes(data)


class AptFramer:
    """Split a controller's byte stream into :class:`AptMessage`.

    A 6-byte window is a header only if its id is in :data:`INBOUND`, it is addressed
    to the host (0x01; 0x00 accepted), its source is a controller endpoint (or 0, which
    some units put in move-completed messages) and its form and length are ones that
    id has. Anything else is skipped one byte at a time (counted in :attr:`resyncs`),
    so garbage between messages costs only the garbage and cannot swallow a reply.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.resyncs = 0

    @staticmethod
    def plausible(header: bytes | bytearray) -> bool:
        """True when 6 bytes can start a message a controller sends to the host."""
        msg_id, p1, p2, dest, src = struct.unpack_from("<HBBBB", header)
        lengths = INBOUND.get(msg_id)
        if lengths is None or (dest & 0x7F) not in (HOST, 0x00) or src not in _SOURCES:
            return False
        n = (p1 | p2 << 8) if dest & 0x80 else 0
        return n in lengths

    def feed(self, data: bytes) -> list[AptMessage]:
        """Add received bytes; return the complete messages, in order."""
        self._buf += data
        out = []
        while len(self._buf) >= 6:
            if not self.plausible(self._buf):
                del self._buf[0]
                self.resyncs += 1
                continue
            msg_id, p1, p2, dest, src = struct.unpack_from("<HBBBB", self._buf)
            long = bool(dest & 0x80)
            n = (p1 | p2 << 8) if long else 0
            if len(self._buf) < 6 + n:
                break
            data_ = bytes(self._buf[6:6 + n]) if long else None
            del self._buf[:6 + n]
            out.append(AptMessage(msg_id, dest & 0x7F, src, 0 if long else p1, 0 if long else p2,
                                  data_))
        return out


class AptController:
    """One APT controller on one serial port, with a reader thread routing its messages.

    Parameters
    ----------
    device_id : str
        The driver's device (named in errors).
    link : SerialLink
        The port (115200 8N1, RTS/CTS, RTS set), opened by :meth:`open`.
    on_event : callable
        ``on_event(message)`` for every message no request waits for (called on the
        reader thread).
    timeout_error : type
        The kind's timeout error for unanswered requests.
    keepalive_s : float
        Period of MGMSG_MOT_ACK_USTATUSUPDATE while status updates are on.
    """

    def __init__(self, device_id: str, link: SerialLink, *,
                 on_event: Callable[[AptMessage], None],
                 timeout_error: type[DeviceTimeoutError], keepalive_s: float = 0.9) -> None:
        self.device_id = device_id
        self.link = link
        self.on_event = on_event
        self.timeout_error = timeout_error
        self.keepalive_s = float(keepalive_s)
        self.framer = AptFramer()
        self.updates = False
        self.keepalives_sent = 0
        self._cond = threading.Condition()
        self._waiting: dict[tuple[int, int], list[list[AptMessage]]] = {}
        self._write_lock = threading.Lock()
        self._request_lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._lost: DeviceDisconnectedError | None = None
        self._updates_dest: tuple[int, ...] = ()
        self._last_ack = 0.0
        #: Reads of the port the reader thread has completed, and the requests past
        #: their deadline waiting for one more (:data:`LATE_READER_S`).
        self._polls = 0
        self._late = 0

    # ------------------------------------------------------------------ lifecycle
    def open(self) -> None:
        """Open the port and start the reader thread."""
        self.link.open()
        self._lost = None
        self._stop.clear()
        self._thread = threading.Thread(target=self._read_loop, daemon=True,
                                        name=f"apt-{self.device_id}")
        self._thread.start()

    def close(self) -> None:
        """Stop updates (if the port still works), the reader thread and the port."""
        if self.updates and self._lost is None:
            for dest in self._updates_dest:
                try:
                    self.send(MSG["HW_STOP_UPDATEMSGS"], dest)
                except DeviceDisconnectedError:
                    break
        self.updates = False
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(2.0)
        self._thread = None
        self.link.close()

    @property
    def alive(self) -> bool:
        """False once the port failed (unplugged)."""
        return self._lost is None and self.link.is_open

    def check(self) -> None:
        """Raise DeviceDisconnectedError if the port failed."""
        if self._lost is not None:
            raise self._lost
        if not self.link.is_open:
            raise DeviceDisconnectedError(self.device_id, "the APT controller's port is closed",
                                          "call reconnect()")
        if self.link.hung_up():
            raise DeviceDisconnectedError(self.device_id, "the APT controller's port hung up "
                                          "(unplugged or powered off)", "call reconnect()")

    # ------------------------------------------------------------------ I/O
    def send(self, msg_id: int, dest: int, param1: int = 0, param2: int = 0,
             data: bytes | None = None) -> None:
        """Send one message (header-only with params, or with data)."""
        self.check()
        raw = pack_message(msg_id, dest, HOST, param1, param2, data)
        with self._write_lock:
            self.link.write(raw)

    def request(self, msg_id: int, reply_id: int, dest: int, *, param1: int = 0,
                param2: int = 0, data: bytes | None = None, timeout_s: float = 1.0) -> AptMessage:
        """Send a REQ message and return the GET reply from ``dest``.

        Safe from several threads at once, also for the same message: every request
        waits in its own box, queued per (reply id, source) in the order the requests
        were sent, and the controller's replies fill the boxes in that order (a GUI's
        status poll and a running plan both asking MOT_REQ_STATUSBITS each get one).

        Raises
        ------
        DeviceTimeoutError
            The controller's ``timeout_error``: no reply within ``timeout_s``.
        DeviceDisconnectedError
            The port failed before the reply came.
        """
        key = (reply_id, dest)
        box: list[AptMessage] = []
        # Registering the waiter and sending the request happen under one lock, so the
        # waiters of one key are queued in the order their requests went out; the
        # controller answers in that order and each reply fills the oldest empty box.
        with self._request_lock:
            with self._cond:
                self._waiting.setdefault(key, []).append(box)
            try:
                self.send(msg_id, dest, param1, param2, data)
            except BaseException:
                self._forget(key, box)
                raise
        late_at = None  # the reader's polls when the deadline passed
        try:
            deadline = time.monotonic() + timeout_s
            with self._cond:
                while not box:
                    if self._lost is not None:
                        raise self._lost
                    now = time.monotonic()
                    if now < deadline:
                        self._cond.wait(deadline - now)
                        continue
                    if late_at is None:
                        late_at = self._polls
                        self._late += 1
                    if self._polls < late_at + 2 and now < deadline + LATE_READER_S:
                        # the reader has not read the port since the deadline (kept
                        # from a core on a loaded machine): the reply may be there
                        self._cond.wait(0.05)
                        continue
                    raise self.timeout_error(
                        self.device_id,
                        f"the APT controller on {self.link.path} did not answer message "
                        f"0x{msg_id:04x} (to 0x{dest:02x}) within {timeout_s:g} s",
                        "check that the controller is powered and its USB cable; "
                        "raise reply_timeout_s for a slow controller",
                    )
                return box[0]
        finally:
            if late_at is not None:
                with self._cond:
                    self._late -= 1
            self._forget(key, box)

    def _forget(self, key: tuple[int, int], box: list[AptMessage]) -> None:
        """Remove one request's box from the table (the key when it was the last)."""
        with self._cond:
            boxes = self._waiting.get(key, [])
            if any(b is box for b in boxes):
                boxes[:] = [b for b in boxes if b is not box]
            if not boxes:
                self._waiting.pop(key, None)

    def start_updates(self, dests: tuple[int, ...]) -> None:
        """Turn the controller's status updates on; the keepalive runs from now on."""
        self._updates_dest = tuple(dests)
        for dest in dests:
            self.send(MSG["HW_START_UPDATEMSGS"], dest)
        self.updates = True
        self._last_ack = time.monotonic()

    def wait_event(self, timeout_s: float) -> None:
        """Sleep until the reader routes any event or ``timeout_s`` passes."""
        with self._cond:
            self._cond.wait(timeout_s)

    # ------------------------------------------------------------------ reader thread
    def _read_loop(self) -> None:
        while not self._stop.is_set():
            try:
                chunk = self.link.read_some()
                if self.updates and time.monotonic() - self._last_ack >= self.keepalive_s:
                    self._last_ack = time.monotonic()
                    for dest in self._updates_dest:
                        self.send(MSG["MOT_ACK_USTATUSUPDATE"], dest)
                    self.keepalives_sent += 1
            except DeviceDisconnectedError as exc:
                if not self._stop.is_set():
                    log.error("%s: %s", self.device_id, exc)
                with self._cond:
                    self._lost = exc
                    self._cond.notify_all()
                return
            for msg in self.framer.feed(chunk) if chunk else ():
                self._route(msg)
            self._polls += 1  # only this thread writes it
            if self._late:
                with self._cond:
                    self._cond.notify_all()

    def _route(self, msg: AptMessage) -> None:
        with self._cond:
            boxes = self._waiting.get((msg.msg_id, msg.source))
            if boxes is None and msg.source == 0:  # lenient: some units send source 0
                boxes = next((b for (m, _), b in self._waiting.items() if m == msg.msg_id), None)
            box = next((b for b in boxes or () if not b), None)  # the oldest unanswered
            delivered = box is not None
            if delivered:
                box.append(msg)
            self._cond.notify_all()
        if not delivered or msg.msg_id in _EVENTS:
            try:
                self.on_event(msg)
            except Exception:  # a handler bug must not stop the reader
                log.exception("%s: event handler failed on %r", self.device_id, msg)
            with self._cond:
                self._cond.notify_all()
