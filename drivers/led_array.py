"""Programmable LED array interface: :class:`LedArray`.

Geometry: ``positions_mm`` is ``(N, 2)`` with columns ``(x, y)`` in the array plane,
x to the right and y towards the *top* of the array, origin on the optical axis;
the sample plane is ``distance_mm`` away. The illumination NA of LED ``i`` is
``sin(theta_i) = r_i / sqrt(r_i**2 + distance_mm**2)`` with ``r_i`` its distance to
the axis (:attr:`LedArray.na_per_led`).

Patterns (for an illumination NA ``na``, default the ``na_illum`` setting):

- "brightfield": LEDs with ``sin(theta) <= na``;
- "darkfield": all the others (disjoint from brightfield, together all LEDs);
- "dpc_top" / "dpc_bottom": brightfield LEDs with ``y >= 0`` / ``y < 0``;
- "dpc_right" / "dpc_left": brightfield LEDs with ``x >= 0`` / ``x < 0``.

LEDs on an axis (``y == 0`` or ``x == 0``) go to the top / right half, so each
DPC pair partitions the brightfield set exactly.

Brightness is in [0, 1] of the LED's full drive; 0 means off. Opening the array
switches every LED off; :meth:`~drivers.base.Device.reconnect` lights again what was lit.
"""

from __future__ import annotations

import abc
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from drivers.base import Device
from drivers.errors import DeviceValueError, LedArrayTimeoutError
from drivers.settings import Setting, info

if TYPE_CHECKING:
    from drivers.transports import SerialLink

__all__ = ["PATTERNS", "LedArray", "SerialLedArray", "grid_positions"]

#: Pattern names understood by :meth:`LedArray.set_pattern`.
PATTERNS: tuple[str, ...] = (
    "brightfield", "darkfield", "dpc_top", "dpc_bottom", "dpc_left", "dpc_right",
)


def grid_positions(rows: int, cols: int, pitch_mm: float) -> np.ndarray:
    """``(rows * cols, 2)`` float positions ``(x, y)`` in mm of a rectangular LED grid
    centred on the optical axis.

    LED ``i * cols + j`` sits in grid row ``i`` (row 0 at the top, largest y) and
    column ``j`` (column 0 at the left, smallest x): ``x = (j - (cols - 1) / 2) *
    pitch_mm``, ``y = ((rows - 1) / 2 - i) * pitch_mm``.
    """
    i, j = np.divmod(np.arange(rows * cols), cols)
    return np.stack([(j - (cols - 1) / 2) * pitch_mm, ((rows - 1) / 2 - i) * pitch_mm], axis=1)


class LedArray(Device):
    """Abstract LED array.

    Settings (pattern defaults): ``na_illum`` (0 < na <= 1), ``colour`` (a name in
    :attr:`colours`), ``brightness`` ([0, 1]).

    Driver hooks, besides :class:`~drivers.base.Device`'s: ``_do_show(state,
    timeout_s)`` displays ``state = {index: (colour, brightness)}`` (every LED not
    in it off) and waits for the acknowledgement. ``_do_get_info()`` returns
    ``positions_mm``, ``pitch_mm``, ``distance_mm`` and ``colours`` (name ->
    wavelength in nm, None for white).
    """

    kind: ClassVar[str] = "led_array"
    timeout_error = LedArrayTimeoutError
    SETTINGS = (
        Setting("na_illum", "float", "", "default illumination NA of the patterns "
                "(sin of the largest angle lit)", low=0.0, low_open=True, high=1.0),
        Setting("colour", "str", "", "default colour of the patterns",
                choices=info("colours")),
        Setting("brightness", "float", "", "default brightness of the patterns, fraction "
                "of full", low=0.0, high=1.0),
    )

    def __init__(self, device_id: str, **params: Any) -> None:
        super().__init__(device_id, **params)
        self._lit: dict[int, tuple[str, float]] = {}
        self._pattern: str | None = None

    # ----------------------------------------------------------- geometry
    @property
    def n_leds(self) -> int:
        """Number of LEDs."""
        return len(self.positions_mm)

    @property
    def positions_mm(self) -> np.ndarray:
        """``(N, 2)`` LED positions ``(x, y)`` in mm, origin on the optical axis."""
        self._require_open()
        return np.array(self._info["positions_mm"], dtype=float).reshape(-1, 2)

    @property
    def pitch_mm(self) -> float:
        """LED pitch in mm."""
        self._require_open()
        return float(self._info["pitch_mm"])

    @property
    def distance_mm(self) -> float:
        """Distance from the array to the sample plane in mm."""
        self._require_open()
        return float(self._info["distance_mm"])

    @property
    def colours(self) -> dict[str, float | None]:
        """Colour channels ``{name: wavelength_nm}`` (None for white)."""
        self._require_open()
        return dict(self._info["colours"])

    @property
    def na_per_led(self) -> np.ndarray:
        """``(N,)`` illumination NA ``sin(theta)`` of each LED."""
        pos = self.positions_mm
        r = np.hypot(pos[:, 0], pos[:, 1])
        return r / np.hypot(r, self.distance_mm)

    # ----------------------------------------------------------- settings
    @property
    def na_illum(self) -> float:
        """Default illumination NA of the patterns (0 < na <= 1)."""
        return self._get("na_illum")

    @na_illum.setter
    def na_illum(self, value: float) -> None:
        self._set("na_illum", value)

    @property
    def colour(self) -> str:
        """Default colour of the patterns."""
        return self._get("colour")

    @colour.setter
    def colour(self, value: str) -> None:
        self._set("colour", value)

    @property
    def brightness(self) -> float:
        """Default brightness of the patterns, in [0, 1]."""
        return self._get("brightness")

    @brightness.setter
    def brightness(self, value: float) -> None:
        self._set("brightness", value)

    # ----------------------------------------------------------- patterns
    def pattern_indices(self, name: str, na: float | None = None) -> np.ndarray:
        """Sorted LED indices of pattern ``name`` at illumination NA ``na``.

        Parameters
        ----------
        name : str
            One of :data:`PATTERNS`.
        na : float, optional
            Illumination NA; default the ``na_illum`` setting.

        Returns
        -------
        ndarray of int
        """
        self._require_open()
        name = self._choice("pattern", name, PATTERNS)
        na = self.na_illum if na is None else self._float("na", na, low=0.0, low_open=True,
                                                           high=1.0)
        pos = self.positions_mm
        bright = self.na_per_led <= na * (1 + 1e-12)
        eps = 1e-9 * max(self.pitch_mm, 1.0)
        masks = {
            "brightfield": bright,
            "darkfield": ~bright,
            "dpc_top": bright & (pos[:, 1] >= -eps),
            "dpc_bottom": bright & (pos[:, 1] < -eps),
            "dpc_right": bright & (pos[:, 0] >= -eps),
            "dpc_left": bright & (pos[:, 0] < -eps),
        }
        return np.flatnonzero(masks[name])

    def set_pattern(
        self, name: str, *, na: float | None = None, colour: str | None = None,
        brightness: float | None = None, timeout_s: float = 1.0,
    ) -> np.ndarray:
        """Light pattern ``name`` (all other LEDs off).

        Parameters
        ----------
        name : str
            One of :data:`PATTERNS`.
        na, colour, brightness : optional
            Override the ``na_illum``, ``colour`` and ``brightness`` settings.
        timeout_s : float
            Longest wait for the array's acknowledgement, in seconds.

        Returns
        -------
        ndarray of int
            The LED indices lit.

        Raises
        ------
        LedArrayTimeoutError
            The array did not acknowledge in time.
        """
        idx = self.pattern_indices(name, na)
        self.set_leds(
            idx, self.colour if colour is None else colour,
            self.brightness if brightness is None else brightness, timeout_s=timeout_s,
        )
        self._pattern = name
        return idx

    def set_leds(
        self, indices: int | Iterable[int] | np.ndarray, colour: str = "white",
        brightness: float = 1.0, *, additive: bool = False, timeout_s: float = 1.0,
    ) -> None:
        """Light LEDs ``indices`` in ``colour`` at ``brightness``.

        Parameters
        ----------
        indices : int, iterable of int, or bool mask of length N
            LEDs to light (0-based).
        colour : str
            A name in :attr:`colours`.
        brightness : float
            In [0, 1]; 0 turns the LEDs off.
        additive : bool
            Keep the other lit LEDs; by default every other LED is turned off.
        timeout_s : float
            Longest wait for the array's acknowledgement, in seconds.

        Raises
        ------
        DeviceValueError
            Bad index, colour or brightness (nothing changes).
        LedArrayTimeoutError
            The array did not acknowledge in time.
        """
        self._require_open()
        timeout_s = self._check_timeout(timeout_s)
        idx = self._indices(indices)
        colour = self._choice("colour", colour, self._info["colours"])
        brightness = self._float("brightness", brightness, low=0.0, high=1.0)
        state = dict(self._lit) if additive else {}
        for i in idx:
            if brightness > 0:
                state[int(i)] = (colour, brightness)
            else:
                state.pop(int(i), None)
        self._show(state, timeout_s)

    def all_off(self, timeout_s: float = 1.0) -> None:
        """Turn every LED off.

        Raises
        ------
        LedArrayTimeoutError
            The array did not acknowledge in time.
        """
        self._require_open()
        self._show({}, self._check_timeout(timeout_s))

    def lit(self) -> dict[int, tuple[str, float]]:
        """Return the lit LEDs ``{index: (colour, brightness)}``."""
        self._require_open()
        return dict(self._lit)

    @property
    def pattern(self) -> str | None:
        """Name of the displayed pattern, None after :meth:`set_leds` or :meth:`all_off`."""
        self._require_open()
        return self._pattern

    def _show(self, state: dict[int, tuple[str, float]], timeout_s: float) -> None:
        with self._io():
            self._do_show(dict(state), timeout_s)
        self._lit = state
        self._pattern = None
        self._log.debug("%s: %d LEDs lit", self.device_id, len(state))

    def _indices(self, indices: Any) -> np.ndarray:
        n = self.n_leds
        arr = np.atleast_1d(np.asarray(indices))
        if arr.dtype == bool:
            if arr.shape != (n,):
                raise self._error(
                    DeviceValueError, f"boolean mask of shape {arr.shape}",
                    f"pass a mask of shape ({n},) or integer indices",
                )
            return np.flatnonzero(arr)
        if arr.size == 0:
            return np.zeros(0, dtype=int)
        if arr.ndim != 1 or not np.issubdtype(arr.dtype, np.integer) or (
            arr.min() < 0 or arr.max() >= n
        ):
            raise self._error(
                DeviceValueError, f"LED indices {indices!r} are invalid",
                f"pass integers in [0, {n - 1}]",
            )
        return arr

    def _on_open(self) -> None:
        self._lit, self._pattern = {}, None  # drivers switch every LED off on open

    def _save_state(self) -> Any:
        return dict(self._lit), self._pattern

    def _restore_state(self, state: Any) -> None:
        lit, pattern = state
        if lit:
            self._do_show(dict(lit), 5.0)
        self._lit, self._pattern = lit, pattern

    def _do_status(self) -> dict[str, Any]:
        return {"n_lit": len(self._lit), "pattern": self._pattern}

    # ----------------------------------------------------------- hooks
    @abc.abstractmethod
    def _do_show(self, state: dict[int, tuple[str, float]], timeout_s: float) -> None: ...


class SerialLedArray(LedArray):
    """An LED array board on a serial port whose settings are kept on the host.

    For the drivers of real boards: the subclass opens ``self._link`` and fills
    ``self._hw`` (the pattern defaults) at open, and implements ``_clear``.
    Closing clears the board, then closes the port (a clear that fails, a board that
    went away, is logged at warning level: the LEDs may still be lit); a port whose
    other end hung up is a disconnected array.
    """

    _link: SerialLink
    _hw: dict[str, Any]

    @abc.abstractmethod
    def _clear(self) -> None:
        """Turn every LED off (one command to the board); may raise if it is gone."""

    def _do_close(self) -> None:
        if self._link.is_open:
            try:
                self._clear()  # before the port closes: the clear needs it
            except Exception as exc:  # the port is closed all the same
                self._log.warning("%s: the LEDs could not be cleared on close, they may "
                                  "still be lit: %s", self.device_id, exc)
        self._link.close()

    def _do_check_connection(self) -> None:
        """A port whose other end hung up is a disconnected array (seen by the status
        poll without a command sent)."""
        self._link.check_hangup()

    def _do_get_settings(self) -> dict[str, Any]:
        return dict(self._hw)
