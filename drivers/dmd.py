"""Digital micromirror device interface: :class:`Dmd`, a pattern sequencer.

A DMD projector such as the TI LightCrafter 4500 is not driven like a phase SLM:
it does not take arbitrary gray images from the host, it plays a *sequence* of
binary (or few-bit) patterns taken from its pattern source (images stored in its
flash, or the bit planes of the frames on its video port), each shown for
``exposure_s`` within a ``period_s`` and lit by chosen LEDs at ``led_currents``.
Hence a kind of its own (docs/architecture.md, "a simulated device kind").

A sequence entry (:class:`PatternEntry`) names the source ``image`` (flash image index,
or 0 for the video frame), the ``bit`` plane (for ``bit_depth`` > 1 the pattern number:
bits ``bit * bit_depth .. (bit + 1) * bit_depth - 1``), the ``bit_depth`` (1..8), the
``colour`` of the LED that lights it and ``invert``. :meth:`Dmd.load_sequence`
validates and loads a sequence (stopping a running one), :meth:`Dmd.start` plays it
(repeating if loaded with ``repeat=True``), :meth:`Dmd.stop` stops it. A reconnect
loads the sequence again and restarts it if it was running.

Settings: ``exposure_s`` and ``period_s`` (exposure <= period), ``led_currents``
(``{colour: fraction 0..1 of the maximum current}``).

Driver hooks, besides :class:`~drivers.base.Device`'s: ``_do_load(entries, repeat,
source, timeout_s)``, ``_do_start(timeout_s)``, ``_do_stop(timeout_s)``,
``_do_running() -> bool``. ``_do_get_info()`` returns ``resolution`` (rows, cols),
``colours`` (name -> nm), ``max_entries``, ``max_image``, ``sources``.
"""

from __future__ import annotations

import abc
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass
from typing import Any, ClassVar

from drivers.base import Device
from drivers.errors import DeviceStateError, DeviceValueError, DmdTimeoutError
from drivers.settings import Setting, setting_property

__all__ = ["Dmd", "PatternEntry"]


@dataclass(frozen=True)
class PatternEntry:
    """One pattern of a DMD sequence.

    Attributes
    ----------
    image : int
        Source image: flash image index (flash source) or 0 (video source).
    bit : int
        Pattern number within the 24-bit image: bit plane for 1-bit patterns,
        ``0 .. 24 // bit_depth - 1`` otherwise.
    bit_depth : int
        Bits per pattern, 1..8.
    colour : str
        LED colour lighting it (a name in the device's ``colours``).
    invert : bool
        Show the inverted pattern.
    """

    image: int
    bit: int
    bit_depth: int = 1
    colour: str = "blue"
    invert: bool = False


class Dmd(Device):
    """Abstract DMD pattern sequencer (see the module docstring)."""

    kind: ClassVar[str] = "dmd"
    timeout_error = DmdTimeoutError
    SETTINGS = (
        Setting("exposure_s", "float", "s", "time each pattern is shown (<= period_s)",
                low=0.0, low_open=True, high=10.0),
        Setting("period_s", "float", "s", "time between patterns (>= exposure_s)",
                low=0.0, low_open=True, high=10.0),
        Setting("led_currents", "float", "", "LED current per colour, fraction of the "
                "maximum", per="colours", key_name="colour", low=0.0, high=1.0),
    )

    def __init__(self, device_id: str, **params: Any) -> None:
        super().__init__(device_id, **params)
        self._sequence: tuple[PatternEntry, ...] = ()
        self._repeat = True
        self._source = "flash"
        self._started = False  # what the host asked last: start() and not stopped since

    # ----------------------------------------------------------- fixed properties
    @property
    def resolution(self) -> tuple[int, int]:
        """Mirror array ``(rows, cols)``."""
        self._require_open()
        return tuple(int(v) for v in self._info["resolution"])

    @property
    def colours(self) -> dict[str, float]:
        """LED colours ``{name: wavelength_nm}``."""
        self._require_open()
        return dict(self._info["colours"])

    # ----------------------------------------------------------- settings
    exposure_s = setting_property("exposure_s", "Time each pattern is shown, s.")

    period_s = setting_property("period_s", "Time between patterns, s (>= exposure_s).")

    @property
    def led_currents(self) -> dict[str, float]:
        """LED current per colour, fraction of the maximum; set with a partial dict."""
        return dict(self._get("led_currents"))

    @led_currents.setter
    def led_currents(self, value: Mapping[str, float]) -> None:
        self._set("led_currents", value)

    def _check_settings(self, pending: dict[str, Any]) -> None:
        if pending["exposure_s"] > pending["period_s"]:
            raise self._error(
                DeviceValueError, f"exposure_s={pending['exposure_s']:g} is longer than "
                f"period_s={pending['period_s']:g}", "give exposure_s <= period_s")

    # ----------------------------------------------------------- sequences
    @property
    def sequence(self) -> tuple[PatternEntry, ...]:
        """The loaded sequence (empty before :meth:`load_sequence`)."""
        self._require_open()
        return self._sequence

    @property
    def running(self) -> bool:
        """True while the sequence plays."""
        self._require_open()
        with self._io():
            return bool(self._do_running())

    def load_sequence(self, entries: Iterable[PatternEntry | Mapping[str, Any]], *,
                      repeat: bool = True, source: str = "flash",
                      timeout_s: float = 5.0) -> tuple[PatternEntry, ...]:
        """Validate and load a pattern sequence; a running sequence is stopped first.

        Parameters
        ----------
        entries : iterable of PatternEntry or mapping
            The patterns in display order (mappings take PatternEntry's fields).
        repeat : bool
            Play the sequence in a loop (else once per start).
        source : {"flash", "video"}
            Where the patterns come from: images in the projector's flash, or the
            frames on its video port (then ``image`` must be 0).
        timeout_s : float
            Longest wait for the device to accept the sequence.

        Returns
        -------
        tuple of PatternEntry

        Raises
        ------
        DeviceValueError
            An invalid entry (nothing is sent).
        DmdTimeoutError
            The device did not accept the sequence in time.
        """
        self._require_open()
        timeout_s = self._check_timeout(timeout_s)
        source = self._choice("source", source, self._info["sources"])
        seq = tuple(self._entry(i, e, source) for i, e in enumerate(entries))
        if not 0 < len(seq) <= self._info["max_entries"]:
            raise self._error(DeviceValueError, f"a sequence of {len(seq)} patterns",
                              f"give 1 to {self._info['max_entries']} patterns")
        self._started = False
        with self._io():
            self._do_load(seq, bool(repeat), source, timeout_s)
        self._sequence, self._repeat, self._source = seq, bool(repeat), source
        return seq

    def start(self, timeout_s: float = 2.0) -> None:
        """Play the loaded sequence.

        Raises
        ------
        DeviceStateError
            No sequence is loaded.
        """
        self._require_open()
        timeout_s = self._check_timeout(timeout_s)
        if not self._sequence:
            raise self._error(DeviceStateError, "no pattern sequence is loaded",
                              "call load_sequence() first")
        with self._io():
            self._do_start(timeout_s)
        self._started = True

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop the sequence (the mirrors park on the last pattern)."""
        self._require_open()
        timeout_s = self._check_timeout(timeout_s)
        self._started = False
        with self._io():
            self._do_stop(timeout_s)

    def _entry(self, i: int, e: Any, source: str) -> PatternEntry:
        try:
            entry = e if isinstance(e, PatternEntry) else PatternEntry(**dict(e))
        except (TypeError, ValueError) as exc:
            raise self._error(DeviceValueError, f"pattern {i} ({e!r}) is not a pattern entry",
                              "give PatternEntry(image, bit, bit_depth, colour, invert) or a "
                              f"mapping of those fields ({exc})") from exc
        depth = self._int(f"pattern {i} bit_depth", entry.bit_depth, low=1, high=8)
        self._int(f"pattern {i} bit", entry.bit, low=0, high=24 // depth - 1)
        high = 0 if source == "video" else self._info["max_image"]
        self._int(f"pattern {i} image", entry.image, low=0, high=high)
        self._choice(f"pattern {i} colour", entry.colour, self._info["colours"])
        if not isinstance(entry.invert, bool):
            raise self._error(DeviceValueError, f"pattern {i} invert={entry.invert!r}",
                              "give true or false")
        return entry

    def _on_open(self) -> None:
        self._sequence = ()

    def _save_state(self) -> Any:
        running = self._started  # the device gone: what the host asked last
        if self._is_open and not self._disconnected:
            try:
                running = bool(self._do_running())
            except Exception as exc:
                self._log.debug("%s: running state unknown (%s)", self.device_id, exc)
        return self._sequence, self._repeat, self._source, running

    def _restore_state(self, state: Any) -> None:
        seq, repeat, source, running = state
        if seq:
            self._do_load(seq, repeat, source, 5.0)
            self._sequence, self._repeat, self._source = seq, repeat, source
            if running:
                self._do_start(2.0)
            self._started = running

    def _do_status(self) -> dict[str, Any]:
        return {"patterns": len(self._sequence), "running": bool(self._do_running()),
                "source": self._source}

    @staticmethod
    def entries_as_dicts(entries: Iterable[PatternEntry]) -> list[dict[str, Any]]:
        """JSON-able form of a sequence."""
        return [asdict(e) for e in entries]

    # ----------------------------------------------------------- hooks
    @abc.abstractmethod
    def _do_load(self, entries: tuple[PatternEntry, ...], repeat: bool, source: str,
                 timeout_s: float) -> None: ...

    @abc.abstractmethod
    def _do_start(self, timeout_s: float) -> None: ...

    @abc.abstractmethod
    def _do_stop(self, timeout_s: float) -> None: ...

    @abc.abstractmethod
    def _do_running(self) -> bool: ...
