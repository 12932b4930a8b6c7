"""The one result of :func:`recon.reconstruct`: :class:`Reconstruction` and its :class:`ReconInfo`.

Every model kind -- one PSF (2D), a PSF stack with depths (3D), a calibrated PSF grid
(spatially varying) -- returns the same :class:`Reconstruction`: the image (or
volume) in the sensor's field of view on the model grid (Kuo 2020, Eq. 3.3: u = -m x,
the scene rotated by 180 degrees, :data:`recon.io.DATA_ORIENTATION`), the whole
estimate, one :class:`recon.solvers.SolveResult` per solve, the forward model and a
typed :class:`ReconInfo` record. :meth:`Reconstruction.upright` is the view a person
in front of the camera sees; :meth:`Reconstruction.metrics` is the JSON record the
command line writes with ``--metrics-json``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields

import numpy as np

from .backend import NUMPY
from .options import KINDS as _KINDS
from .solvers.common import History, SolveResult

__all__ = ["KINDS", "ReconInfo", "Reconstruction"]

#: The model kinds :func:`recon.reconstruct` serves: one PSF, a PSF stack, a PSF grid.
KINDS = _KINDS  # recon.options declares the kinds with the parameters that use them


@dataclass(frozen=True)
class ReconInfo:
    """What a reconstruction did and why: the typed record of a :class:`Reconstruction`.

    Frozen; ``info["name"]`` and ``info.get("name")`` read a field or, failing that,
    an entry of ``extra`` (the kind's preprocessing record), so code written for
    the former dict keeps working. :meth:`as_dict` is the flat JSON-ready mapping.

    Attributes
    ----------
    kind : {"image", "volume", "grid"}
        The model kind (:data:`KINDS`).
    method : str
        The solver that ran (``"admm"``, ``"fista"``, ``"wiener"``, ``"gd"``).
    method_reason : str
        Why: ``"given"``, or the automatic choice's reason.
    iterations : int
        The iterations asked for (1 for Wiener); an automatic weight's path and final
        solve may take more (:mod:`recon.auto.weight`).
    iterations_used : int
        The most any solve ran (automatic stopping ends earlier).
    tv, l1 : float or None
        The weights used, absolute in the scaled problem (``tv`` None where the
        solver has no TV term: FISTA on Eq. 6.2 with a PSF grid).
    auto : tuple of dict
        One record per solve (per colour channel in 2D; one for a volume or a grid)
        of the automatic choices and their reasons (method, weight, stopping, noise);
        empty where nothing was chosen automatically.
    dark_mode : str or None
        How the dark level was found: ``"psf_region"``, ``"none"``, ``"scalar"``,
        ``"vector"``, ``"frame"`` (2D); ``"auto"``, ``"none"``, ``"value"``,
        ``"frame"`` (3D and grid).
    dark_level : float, list of float or None
        The level subtracted (input units, DN; a frame's mean).
    dark_source : str
        Where the dark level came from, in words.
    bin_factor : int
        Lateral box binning applied before the solve.
    raw_scale : float
        The measurement's scale (its largest magnitude after the dark level).
    seconds_total : float
        Preprocessing and solve, wall-clock seconds.
    device : str
        Where the solves ran (``recon.backend.Backend.label``): ``"cpu (numpy)"``
        (the NumPy path, the default), or e.g. ``"cuda:0 (cupy)"`` for the array-API
        path on a GPU (``device=`` of :func:`recon.reconstruct`).
    histories : tuple of History
        The solves' per-iteration histories (objective, data residual, seconds).
    extra : mapping
        The kind's own record (shapes and dtypes in, saturated and clipped fractions,
        ``raw_levels``, ``psf_scale``, ``erased_fraction``, model choice, ...).
    """

    kind: str
    method: str
    method_reason: str
    iterations: int
    iterations_used: int
    tv: float | None
    l1: float | None
    auto: tuple = ()
    dark_mode: str | None = None
    dark_level: float | list | None = None
    dark_source: str = ""
    bin_factor: int = 1
    raw_scale: float = 1.0
    seconds_total: float = 0.0
    device: str = NUMPY.label
    histories: tuple[History, ...] = field(default=(), repr=False)
    extra: Mapping = field(default_factory=dict, repr=False)

    def __post_init__(self):
        object.__setattr__(self, "auto", tuple(self.auto))
        object.__setattr__(self, "histories", tuple(self.histories))
        object.__setattr__(self, "extra", dict(self.extra))

    def _names(self) -> tuple[str, ...]:
        return tuple(f.name for f in fields(self) if f.name not in ("extra", "histories"))

    def __getitem__(self, key: str):
        if key in self._names():
            return getattr(self, key)
        return self.extra[key]

    def __contains__(self, key: str) -> bool:
        return key in self._names() or key in self.extra

    def get(self, key: str, default=None):
        """``self[key]`` or ``default``."""
        try:
            return self[key]
        except KeyError:
            return default

    def as_dict(self) -> dict:
        """The flat record: the fields (but the histories) and the extra entries."""
        return {**{n: getattr(self, n) for n in self._names()}, **self.extra}


@dataclass(repr=False, eq=False)
class Reconstruction:
    """Result of :func:`recon.reconstruct` for every model kind.

    Attributes
    ----------
    image : ndarray, float32
        The sensor field of view of the estimate on the model grid (Eq. 3.3): (rows,
        cols) or (rows, cols, C) for one PSF or a 2D grid; (n_z, rows, cols) for a
        volume (a stack, or a grid per depth), planes in depth order. Measurement
        units (counts per unit of the normalised PSF); non-negative for the
        iterative methods. :meth:`upright` turns it to the scene's orientation.
    estimate : ndarray, float32
        The whole object domain (the padded grid, twice the sensor, Sec. 3.1), same
        units and layout.
    results : list of SolveResult
        One per solve (per colour channel in 2D), in the scaled problem.
    operator : LinearOperator
        The forward model (of the first channel in 2D).
    info : ReconInfo
        The typed record.
    depths_mm : list of float or None
        Depth of every plane (a volume), mm.
    background : ndarray, float32, (rows, cols) or None
        Eq. 6.2's background estimate (a PSF grid with ``background="estimate"``).
    choice : recon.spatial.ModelChoice or None
        The spatially varying model chosen (a PSF grid).
    """

    image: np.ndarray
    estimate: np.ndarray
    results: list[SolveResult]
    operator: object
    info: ReconInfo
    depths_mm: list[float] | None = None
    background: np.ndarray | None = None
    choice: object | None = None
    record: Callable[[Reconstruction, float | None], dict] | None = field(default=None)

    @property
    def kind(self) -> str:
        """The model kind, ``info.kind``."""
        return self.info.kind

    @property
    def volume(self) -> np.ndarray:
        """The volume (n_z, rows, cols) of a 3D reconstruction (``image``).

        Raises
        ------
        AttributeError
            A 2D reconstruction has no volume.
        """
        if self.image.ndim != 3 or self.depths_mm is None:
            raise AttributeError("a 2D reconstruction has no volume; use .image")
        return self.image

    @property
    def result(self) -> SolveResult:
        """The first (for a volume or a grid, the only) solve's result."""
        return self.results[0]

    def upright(self) -> np.ndarray:
        """The image turned from the model grid to the scene's orientation (a view).

        Both lateral axes flipped (:func:`recon.io.scene_view`): the scene as a person
        in front of the camera sees it; the planes of a volume stay in depth order.

        Returns
        -------
        ndarray
            A view of ``image``, same shape and dtype.
        """
        axes = (1, 2) if self.depths_mm is not None else (0, 1)
        return np.flip(self.image, axis=axes)

    def metrics(self, floor_s: float | None = None) -> dict:
        """The metrics record the command line writes (``--metrics-json``).

        Parameters
        ----------
        floor_s : float, optional
            The FFT floor of one iteration, seconds (the 2D FFT pair, or the floors
            of :func:`recon.volume.fft_floor_seconds` for a volume or a grid's
            ``K`` convolutions); measured now if not given.

        Returns
        -------
        dict
            JSON-ready: method, iterations, weights, the automatic record, shapes,
            timings and their ratio to the floor, histories and solver parameters
            (keys of docs/reconstruction.md).
        """
        if self.record is None:
            raise ValueError("this Reconstruction was built without its metrics record")
        return self.record(self, floor_s)

    def __repr__(self) -> str:
        info = self.info
        used = (f"{info.iterations_used}/{info.iterations}" if info.iterations > 1
                else str(info.iterations))
        return (f"Reconstruction(kind={info.kind!r}, image={self.image.dtype} "
                f"{tuple(self.image.shape)}, method={info.method!r}, iterations={used}, "
                f"seconds={info.seconds_total:.3g})")
