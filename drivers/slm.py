"""Phase spatial light modulator interface: :class:`Slm`.

The SLM shows 8-bit gray images. Its lookup table ``lut_rad`` maps each of the 256
gray levels to the phase delay it produces at ``wavelength_nm``, in radians; it is
monotone (calibrated per device, e.g. by the SLM phase-LUT routine). To show a phase
map, :meth:`Slm.show_phase` wraps it to [0, 2 pi) and picks for each pixel the gray
level whose LUT phase is nearest modulo 2 pi (the LUT inverse). Every displayed
image gets a new :attr:`Slm.pattern_id` (1, 2, ...; 0 before the first), and every
display call waits ``settle_s`` for the liquid crystal to settle.
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np

from drivers.base import Device
from drivers.errors import DeviceValueError, SlmTimeoutError
from drivers.settings import Setting

__all__ = ["TWO_PI", "Slm", "linear_lut"]

TWO_PI = 2.0 * np.pi


def linear_lut(max_phase_rad: float = TWO_PI) -> np.ndarray:
    """Linear LUT ``phase[g] = max_phase_rad * g / 256`` for g in 0..255, in radians.

    With the default the 256 levels tile [0, 2 pi) without repeating 0 and 2 pi.
    """
    return max_phase_rad * np.arange(256) / 256.0


def _check_lut(device: Device, label: str, value: Any, low: Any, high: Any
               ) -> tuple[float, ...]:
    """The ``lut_rad`` setting: 256 finite, monotone, non-constant phases (rad)."""
    try:
        lut = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        lut = np.zeros(0)
    d = np.diff(lut) if lut.shape == (256,) else np.zeros(0)
    ok = lut.shape == (256,) and np.all(np.isfinite(lut))
    ok = ok and (np.all(d >= 0) or np.all(d <= 0)) and np.ptp(lut) > 0
    if not ok:
        raise device._error(
            DeviceValueError, "lut_rad is not 256 finite, monotone, non-constant phases",
            "pass the calibrated phase (rad) of gray levels 0..255, e.g. linear_lut()",
        )
    return tuple(float(v) for v in lut)


class Slm(Device):
    """Abstract phase SLM.

    Settings: ``lut_rad`` (256 phases in radians, monotone) and ``settle_s``
    (seconds waited after each new image, >= 0).

    Driver hooks, besides :class:`~drivers.base.Device`'s: ``_do_show(gray,
    timeout_s)`` displays a ``(rows, cols)`` uint8 image and returns once it is on
    the panel. ``_do_get_info()`` returns ``resolution`` (rows, cols),
    ``pixel_pitch_um`` and ``wavelength_nm``. Drivers show a gray-0 image on open.
    """

    kind: ClassVar[str] = "slm"
    timeout_error = SlmTimeoutError
    SETTINGS = (
        Setting("lut_rad", "float[256]", "rad", "phase delay of each gray level 0..255 at "
                "the device's wavelength (calibrated per device)", check=_check_lut,
                bounds="256 finite, monotone, non-constant phases"),
        Setting("settle_s", "float", "s", "time waited after each new image for the "
                "liquid crystal to settle", low=0.0, high=60.0),
    )

    def __init__(self, device_id: str, **params: Any) -> None:
        super().__init__(device_id, **params)
        self._image: np.ndarray | None = None
        self._pattern_id = 0
        self._inverse: tuple[tuple[float, ...], np.ndarray, np.ndarray] | None = None

    # ----------------------------------------------------------- fixed properties
    @property
    def resolution(self) -> tuple[int, int]:
        """Panel size ``(rows, cols)`` in pixels."""
        self._require_open()
        return tuple(int(v) for v in self._info["resolution"])

    @property
    def pixel_pitch_um(self) -> float:
        """Pixel pitch in micrometres."""
        self._require_open()
        return float(self._info["pixel_pitch_um"])

    @property
    def wavelength_nm(self) -> float:
        """Wavelength the LUT is calibrated for, in nm."""
        self._require_open()
        return float(self._info["wavelength_nm"])

    # ----------------------------------------------------------- settings
    @property
    def lut_rad(self) -> np.ndarray:
        """``(256,)`` phase in radians for each gray level (a copy)."""
        return np.array(self._get("lut_rad"), dtype=float)

    @lut_rad.setter
    def lut_rad(self, value: Any) -> None:
        self._set("lut_rad", value)

    @property
    def settle_s(self) -> float:
        """Time waited after each new image, in seconds."""
        return self._get("settle_s")

    @settle_s.setter
    def settle_s(self, value: float) -> None:
        self._set("settle_s", value)

    # ----------------------------------------------------------- conversion
    def phase_to_gray(self, phase_rad: Any) -> np.ndarray:
        """Gray levels (uint8) whose LUT phase is nearest ``phase_rad`` modulo 2 pi."""
        lut = self._get("lut_rad")
        if self._inverse is None or self._inverse[0] != lut:
            psi = np.mod(np.asarray(lut), TWO_PI)
            ext = np.concatenate([psi - TWO_PI, psi, psi + TWO_PI])
            order = np.argsort(ext, kind="stable")
            self._inverse = (lut, ext[order], np.tile(np.arange(256), 3)[order])
        _, ext, grays = self._inverse
        theta = self._wrap(np.asarray(phase_rad, dtype=float))
        i = np.clip(np.searchsorted(ext, theta), 1, ext.size - 1)
        upper = (ext[i] - theta) < (theta - ext[i - 1])
        return np.where(upper, grays[i], grays[i - 1]).astype(np.uint8)

    def gray_to_phase(self, gray: Any) -> np.ndarray:
        """LUT phase in radians of gray levels ``gray``."""
        return self.lut_rad[np.asarray(gray, dtype=np.uint8)]

    @staticmethod
    def _wrap(phase: np.ndarray) -> np.ndarray:
        w = np.mod(phase, TWO_PI)
        return np.where(w >= TWO_PI, 0.0, w)  # mod can round tiny negatives up to 2 pi

    # ----------------------------------------------------------- display
    @property
    def pattern_id(self) -> int:
        """Number of the displayed pattern; increments on every new image (0 = none yet)."""
        return self._pattern_id

    def show_phase(self, phase_rad: Any, timeout_s: float = 1.0) -> int:
        """Display a phase map, wrapped to [0, 2 pi) and converted by the LUT inverse.

        Parameters
        ----------
        phase_rad : array_like
            ``(rows, cols)`` finite phases in radians.
        timeout_s : float
            Longest wait for the panel update, in seconds (the settle time is extra).

        Returns
        -------
        int
            The new pattern id (:attr:`pattern_id`).

        Raises
        ------
        DeviceValueError
            Wrong shape or non-finite values.
        SlmTimeoutError
            The image did not reach the panel in time.
        """
        def gray() -> np.ndarray:
            phase = np.asarray(phase_rad)
            if phase.shape != self.resolution or not np.issubdtype(phase.dtype, np.number) or (
                np.iscomplexobj(phase) or not np.all(np.isfinite(phase))
            ):
                raise self._error(
                    DeviceValueError,
                    f"phase of shape {phase.shape} dtype {phase.dtype} is invalid",
                    f"pass finite real phases of shape {self.resolution} in radians",
                )
            return self.phase_to_gray(phase)

        return self._show(gray, timeout_s)

    def show_image(self, gray: np.ndarray, timeout_s: float = 1.0) -> int:
        """Display a ``(rows, cols)`` uint8 gray image as is.

        Returns
        -------
        int
            The new pattern id.

        Raises
        ------
        DeviceValueError
            Not uint8 or wrong shape.
        SlmTimeoutError
            The image did not reach the panel in time.
        """
        def checked() -> np.ndarray:
            image = np.asarray(gray)
            if image.dtype != np.uint8 or image.shape != self.resolution:
                raise self._error(
                    DeviceValueError,
                    f"image of shape {image.shape} dtype {image.dtype} is invalid",
                    f"pass a uint8 array of shape {self.resolution}",
                )
            return image

        return self._show(checked, timeout_s)

    def _show(self, gray: Callable[[], np.ndarray], timeout_s: float) -> int:
        """Display ``gray()`` (checked by it) once the device is open and ``timeout_s``
        valid; returns the new pattern id."""
        self._require_open()
        timeout_s = self._check_timeout(timeout_s)
        return self._display(gray(), timeout_s)

    def current_image(self) -> np.ndarray:
        """The displayed gray image (a copy)."""
        self._require_open()
        return self._image.copy()

    def current_phase(self) -> np.ndarray:
        """The displayed phase in radians (the LUT applied to :meth:`current_image`)."""
        return self.gray_to_phase(self.current_image())

    def _display(self, gray: np.ndarray, timeout_s: float) -> int:
        gray = np.array(gray, dtype=np.uint8, copy=True)
        with self._io():
            self._do_show(gray, timeout_s)
        self._image = gray
        self._pattern_id += 1
        self._sleep_s(self.settle_s)
        self._log.debug("%s: pattern %d shown", self.device_id, self._pattern_id)
        return self._pattern_id

    def _on_open(self) -> None:
        self._image = np.zeros(self.resolution, dtype=np.uint8)

    def _save_state(self) -> Any:
        return None if self._image is None else self._image.copy()

    def _restore_state(self, state: Any) -> None:
        if state is not None and state.any():
            self._do_show(state, 5.0)
            self._sleep_s(self.settle_s)
            self._image = state

    def _do_status(self) -> dict[str, Any]:
        return {"pattern_id": self._pattern_id}

    # ----------------------------------------------------------- hooks
    @abc.abstractmethod
    def _do_show(self, gray: np.ndarray, timeout_s: float) -> None: ...
