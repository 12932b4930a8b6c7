"""Parameters of the SLM-mask alignment (:class:`.procedure.MaskAligner`).

Their own module so that the steps (:mod:`.procedure`, :mod:`.focus`) read them
without importing each other.
"""

from __future__ import annotations

from dataclasses import dataclass

from instrument.acquisition.plan import PlanError

__all__ = ["AlignmentConfig"]


@dataclass(frozen=True)
class AlignmentConfig:
    """Parameters of :class:`.procedure.MaskAligner` (defaults from docs/protocols.md).

    Attributes
    ----------
    sections : (int, int)
        Section grid over the SLM (rows, cols), the dissertation's 3 x 5.
    central_fraction : float
        Area of the coarse-search patch as a fraction of the SLM.
    coarse_range_px : int
        Half-width of the coarse software search (mask px); widened x2 once.
    coarse_step_px : int or None
        Coarse step (default ``max(1, k // 2)``).
    detection_factor : float
        Detection threshold over the scan's median |eta|.
    cross_radius_px : int or None
        Radius of the separable cross (default ``k + 1``).
    translation_tol_px : float
    max_translation_rounds, max_rigid_rounds, max_piecewise_passes : int
    rotation : bool
        Let step 4 rotate the stage (otherwise it only translates).
    rotation_tol_factor : float
        Rotation stop tolerance ``factor * k / half-diagonal`` (rad): the corner
        displacement left, in SLM pixels. The notes' 0.2 leaves 0.8 mask px at the
        corners for k = 4, which integer section shifts cannot remove (up to ~35 %
        of a corner section's spot); 0.05 leaves 0.2 px (< 10 %).
    piecewise_radius_px : int
        Largest per-section integer shift searched around the global one.
    repeats : int
        Captures per pattern where a noise estimate is needed (>= 2).
    verify_fraction : float
        Required eta over the simulated perfectly aligned eta, per section.
    residual_tol_px : float
        Per-section residual offset reported as too large beyond this.
    frames : int
        Frames averaged per reading.
    u0 : (float, float) or None
        Spot frequency (far-field samples); default chosen automatically.
    fourier_tol_px : float
        Largest RMS residual of the camera affine fit (camera px).
    settle_s : float
        Wait after each stage move (bench time).
    timeout_s : float
        Per-device-operation timeout.
    relay_na : float or None
        Image-side NA of the SLM -> mask relay as designed: the simulation that sets
        each section's ceiling includes its pupil, and the first focus sweep spans
        its depth of field ``lambda / NA^2``. None: no pupil.
    focus : bool
        Run step 5 (stage z, tip, tilt).
    focus_range_mm : float or None
        Half-range of the first z sweep (default from ``relay_na``, see
        ``focus.FocusStep.default_range_mm``); doubled at most twice.
    focus_steps : int
        Positions per sweep (the notes' 7-11).
    max_focus_rounds : int
    focus_min_fraction : float
        Fraction of the sections that must show a maximum inside the sweep.
    hologram_min_correlation : float
        Step 7's test hologram (``hologram_check.hologram_check``): a correlation
        with its simulation below this is reported as a warning (measured on the
        virtual bench: 0.999 aligned, 0.96 at 0.5 mask px, 0.85 at 1 px, 0.47 at 2 px).
    """

    sections: tuple[int, int] = (3, 5)
    central_fraction: float = 0.1
    coarse_range_px: int = 12
    coarse_step_px: int | None = None
    detection_factor: float = 20.0
    cross_radius_px: int | None = None
    translation_tol_px: float = 0.05
    max_translation_rounds: int = 3
    max_rigid_rounds: int = 5
    max_piecewise_passes: int = 3
    rotation: bool = True
    rotation_tol_factor: float = 0.05
    piecewise_radius_px: int = 2
    repeats: int = 3
    verify_fraction: float = 0.8
    residual_tol_px: float = 0.25
    frames: int = 3
    u0: tuple[float, float] | None = None
    fourier_tol_px: float = 0.3
    settle_s: float = 0.05
    timeout_s: float = 10.0
    relay_na: float | None = None
    focus: bool = True
    focus_range_mm: float | None = None
    focus_steps: int = 9
    max_focus_rounds: int = 3
    focus_min_fraction: float = 0.5
    hologram_min_correlation: float = 0.9

    def __post_init__(self):
        if self.frames < 1:
            raise PlanError(f"frames must be >= 1 (captures averaged per reading), got "
                            f"{self.frames}")
        if self.repeats < 2:
            raise PlanError("repeats must be >= 2 (a noise estimate needs two captures)")
        if not 0 < self.central_fraction <= 1:
            raise PlanError("central_fraction must be in (0, 1]")
        if self.coarse_range_px < 1 or self.piecewise_radius_px < 0:
            raise PlanError("coarse_range_px must be >= 1 and piecewise_radius_px >= 0")
        if self.relay_na is not None and not 0 < self.relay_na < 1:
            raise PlanError(f"relay_na must be in (0, 1) or None, got {self.relay_na}")
        if self.focus_range_mm is not None and not self.focus_range_mm > 0:
            raise PlanError(f"focus_range_mm must be > 0, got {self.focus_range_mm}")
        if self.focus_steps < 5 or self.max_focus_rounds < 1:
            raise PlanError("focus_steps must be >= 5 (a parabola and its error) and "
                            "max_focus_rounds >= 1")
        if not 0 < self.focus_min_fraction <= 1:
            raise PlanError("focus_min_fraction must be in (0, 1]")
