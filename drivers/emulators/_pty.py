"""The pseudo-terminal harness every serial emulator runs on.

The emulator owns the master side of a pty; a driver opens the slave path with
pyserial exactly as it would open ``/dev/ttyUSB0`` (hardware-protocols.md, section 0):
the slave is put in raw mode at creation (no echo, no CR/LF translation before the
driver opens it), unplugging closes the master (the driver then sees pyserial's
"device reports readiness to read but returned no data" / ``EIO``), and re-plugging
creates a new pty on a new path. A stable *link* (like udev's
``/dev/serial/by-id/...-<serial>-...``) follows the current pty, so a driver that
resolves its port by serial number finds the device again after a re-plug.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import threading
import time
import tty
from pathlib import Path

__all__ = ["PtyEmulator", "take_lines"]

log = logging.getLogger("drivers.emulators")


def take_lines(buffer: bytearray) -> list[str]:
    """Remove the complete lines from ``buffer`` and return them, stripped, non-empty.

    A line ends at CR, LF or CRLF (an ASCII protocol accepts any of them); an
    unfinished line stays in ``buffer`` for the next bytes.
    """
    lines = []
    while True:
        ends = [i for i in (buffer.find(b"\r"), buffer.find(b"\n")) if i >= 0]
        if not ends:
            return lines
        i = min(ends)
        text = bytes(buffer[:i]).decode("ascii", "replace").strip()
        del buffer[:i + 1]
        if text:
            lines.append(text)


class PtyEmulator:
    """A device model behind a pseudo-terminal, served by one background thread.

    Subclasses implement :meth:`on_bytes` (bytes the driver wrote) and optionally
    :meth:`on_tick` (called every ``tick_s`` for motion and unsolicited messages), and
    send with :meth:`reply` (a reply to a command, subject to :meth:`drop_replies` and
    :meth:`stray_before_reply`) or :meth:`emit` (unsolicited: events, banners,
    garbage). Model state is guarded by :attr:`lock` (held while
    ``on_bytes``/``on_tick`` run), so tests may inspect it.

    Parameters
    ----------
    link : str or Path, optional
        A symlink kept pointing at the current pty (removed while unplugged).
    time_scale : float
        Model seconds per real second (100 makes a 10 s move take 0.1 s).
    tick_s : float
        Period of :meth:`on_tick`, real seconds.
    """

    def __init__(self, *, link: str | Path | None = None, time_scale: float = 1.0,
                 tick_s: float = 0.002) -> None:
        if not time_scale > 0:
            raise ValueError(f"time_scale must be > 0, got {time_scale!r}")
        self.link = None if link is None else Path(link)
        self.time_scale = float(time_scale)
        self.tick_s = float(tick_s)
        self.lock = threading.RLock()
        self.received = bytearray()  # everything the driver wrote, for byte-exact tests
        self._got = threading.Condition(self.lock)  # notified as bytes are received
        self.sent = bytearray()      # everything the emulator wrote
        self._sending = threading.Lock()  # one writer of the pty and of ``sent`` at a time
        self._master: int | None = None
        self._slave: int | None = None
        self.tty: str | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._unplug_request = threading.Event()
        self._unplugged = threading.Event()
        self._drop = 0
        self._delays: list[float] = []
        self._prefix = b""
        self.plug_count = 0

    # ------------------------------------------------------------------ lifecycle
    @property
    def port(self) -> str:
        """The path a driver opens: the link if any, else the current pty."""
        if self.link is not None:
            return str(self.link)
        if self.tty is None:
            raise RuntimeError("the emulator is not started")
        return self.tty

    @property
    def plugged(self) -> bool:
        """True while the pty exists (between start/replug and unplug/stop)."""
        return self._master is not None

    def start(self) -> PtyEmulator:
        """Create the pty and start serving; returns self."""
        if self._thread is not None:
            return self
        self._plug()
        self._stop.clear()
        self._thread = threading.Thread(target=self._serve, name=type(self).__name__,
                                         daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and remove the pty and the link."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        self._close_fds()

    def unplug(self, timeout_s: float = 2.0) -> None:
        """Close the master side, as a yanked USB cable would; the model keeps its state."""
        if self._thread is None or self._master is None:
            self._close_fds()
            return
        self._unplugged.clear()
        self._unplug_request.set()
        if not self._unplugged.wait(timeout_s):
            raise RuntimeError("the emulator thread did not unplug in time")

    def replug(self) -> None:
        """Plug back in: a new pty (a new path), the link moved to it."""
        if self._master is not None:
            return
        self._plug()
        with self.lock:
            self.on_replug()

    def __enter__(self) -> PtyEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ sending
    def reply(self, data: bytes) -> None:
        """Send a reply to a command, unless :meth:`drop_replies` asked to lose it."""
        if self._drop > 0:
            self._drop -= 1
            log.debug("%s: reply dropped: %r", type(self).__name__, bytes(data))
            return
        prefix, self._prefix = self._prefix, b""
        if self._delays:
            delay_s = self._delays.pop(0)
            log.debug("%s: reply delayed %g s: %r", type(self).__name__, delay_s, bytes(data))
            late = threading.Timer(delay_s, self.emit, args=(prefix + bytes(data),))
            late.daemon = True
            late.start()
            return
        self.emit(prefix + bytes(data))

    def stray_before_reply(self, data: bytes) -> None:
        """Send ``data`` (line noise, a glitch on the cable) just before the next reply."""
        with self.lock:
            self._prefix += bytes(data)

    def emit(self, data: bytes) -> None:
        """Send bytes now (unsolicited messages; lost while unplugged or if the driver
        does not read and the pty buffer is full)."""
        fd = self._master
        if fd is None:
            return
        view = memoryview(bytes(data))
        deadline = time.monotonic() + 1.0  # a reader that stops reading: give up then
        while view and time.monotonic() < deadline:
            with self._sending:  # recorded before the driver can read it, the unwritten
                mark = len(self.sent)  # tail taken back after
                self.sent += view
                try:
                    n = os.write(fd, view)
                except OSError as exc:
                    del self.sent[mark:]
                    if isinstance(exc, BlockingIOError):
                        n = None
                    else:
                        log.debug("%s: write lost: %s", type(self).__name__, exc)
                        return
                else:
                    del self.sent[mark + n:]
            if n is None:
                select.select([], [fd], [], 0.05)
                continue
            view = view[n:]
        if view:
            log.debug("%s: %d bytes lost (nobody reads)", type(self).__name__, len(view))

    def wait_received(self, data: bytes, timeout_s: float = 10.0) -> bool:
        """Wait until the bytes ``data`` are among :attr:`received` (the driver's writes
        reach the emulator's thread a moment after the write returns; a message with no
        reply, such as a stop, is only there once that thread has read it).

        Parameters
        ----------
        data : bytes
        timeout_s : float
            The longest wait, s (a hang guard: the wait ends as the bytes arrive).

        Returns
        -------
        bool
            Whether they arrived within ``timeout_s``.
        """
        with self._got:
            return self._got.wait_for(lambda: bytes(data) in self.received, timeout_s)

    def drop_replies(self, n: int = 1) -> None:
        """Lose the replies to the next ``n`` commands (the driver's reads time out)."""
        with self.lock:
            self._drop += int(n)

    def delay_replies(self, delay_s: float, n: int = 1) -> None:
        """Send the replies to the next ``n`` commands ``delay_s`` seconds late, as an
        emulator process starved of the CPU on a loaded host would."""
        if not delay_s >= 0:
            raise ValueError(f"delay_s must be >= 0, got {delay_s!r}")
        with self.lock:
            self._delays += [float(delay_s)] * int(n)

    def now(self) -> float:
        """Model time in seconds (real monotonic time times ``time_scale``)."""
        return time.monotonic() * self.time_scale

    # ------------------------------------------------------------------ subclass hooks
    def on_bytes(self, data: bytes) -> None:
        """Bytes the driver wrote (called with :attr:`lock` held)."""
        raise NotImplementedError

    def on_tick(self, now: float) -> None:
        """Called every ``tick_s`` with the model time (lock held)."""

    def on_replug(self) -> None:
        """Called after a re-plug (e.g. a board that resets prints its banner)."""

    # ------------------------------------------------------------------ internals
    def _plug(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo or newline translation before the driver opens it
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self.tty = os.ttyname(slave)
        self.plug_count += 1
        if self.link is not None:
            self.link.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.link.with_name(f".{self.link.name}.{os.getpid()}.tmp")
            with contextlib.suppress(FileNotFoundError):
                tmp.unlink()
            tmp.symlink_to(self.tty)
            os.replace(tmp, self.link)
        log.debug("%s: plugged on %s", type(self).__name__, self.tty)

    def _close_fds(self) -> None:
        master, slave = self._master, self._slave
        self._master = self._slave = None
        if self.link is not None:
            with contextlib.suppress(FileNotFoundError):
                if self.link.is_symlink() and os.readlink(self.link) == self.tty:
                    self.link.unlink()
        for fd in (master, slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)

    def _serve(self) -> None:
        while not self._stop.is_set():
            if self._unplug_request.is_set():
                self._close_fds()
                self._unplug_request.clear()
                self._unplugged.set()
            fd = self._master
            if fd is None:
                time.sleep(self.tick_s)
                with self.lock:
                    self.on_tick(self.now())
                continue
            try:
                ready, _, _ = select.select([fd], [], [], self.tick_s)
                data = os.read(fd, 4096) if ready else b""
            except (OSError, ValueError):
                data = b""
            with self.lock:
                if data:
                    self.received += data
                    self._got.notify_all()
                    try:
                        self.on_bytes(data)
                    except Exception:  # a model bug must not kill the device
                        log.exception("%s: error handling %r", type(self).__name__, data)
                self.on_tick(self.now())
