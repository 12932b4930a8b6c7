"""Time-dependent scenes for the virtual bench, with the truth known per frame.

Two scenes after Fig. 6.5 of the reference (Sec. 6.5, video at 10 fps):

* :class:`BeadFlowScene`: fluorescent beads flowing along a straight channel at a
  stated speed, wrapping round at the channel's end (so the scene repeats with
  period ``channel_length / speed``);
* :class:`NeuronFieldScene`: a sparse field of neurons whose brightness follows
  calcium transients: random spike times (Poisson, per cell), each spike adding
  ``dff_per_spike`` to ΔF/F and decaying with ``tau_s``, on a baseline ``F0``.

A scene is a function of time ``t`` in seconds. :meth:`VideoScene.sources_at`
gives the point sources the virtual bench renders through its lensless model (the
same ray-traced PSFs as the pinhole; a bead or a cell is a point at its centre:
at the default depth an object pixel of the camera is ~30 um, larger than a cell
and comparable to a bead); :meth:`VideoScene.object_image` draws the truth on an
object-plane grid (discs of the stated diameters); ``truth(t)`` gives positions or
traces. A streaming simulated camera samples the scene at the middle of each
exposure (:func:`frame_time_s`).

``time_step_s`` makes a scene piecewise constant in time (scene time
``floor(t / step) * step``): with a periodic scene this bounds the number of
distinct renders, so the virtual bench can render them ahead
(:meth:`instrument.devices.virtual_bench.VirtualBench.prerender`) and stream in real
time with fresh camera noise per frame. The truth always refers to the scene
time, so it matches what was rendered.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass, field

import numpy as np

from recon.errors import ReconInputError

__all__ = ["BeadFlowScene", "BeadTruth", "NeuronFieldScene", "NeuronTruth", "VideoScene",
           "frame_time_s"]


def frame_time_s(frame) -> float:
    """Simulated time a frame of the simulated camera saw its scene at: the middle of
    its exposure (``device_timestamp_s + exposure_s / 2``), s."""
    return float(frame.device_timestamp_s) + 0.5 * float(frame.exposure_s)


def _positive(name: str, value, example: str) -> float:
    ok = isinstance(value, int | float | np.integer | np.floating) and not isinstance(value,
                                                                                      bool)
    if not ok or not math.isfinite(value) or value <= 0:
        raise ReconInputError(f"{name}={value!r} must be a finite number > 0, e.g. {example}")
    return float(value)


def _count(name: str, value, example: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise ReconInputError(f"{name}={value!r} must be an integer >= 1, e.g. {example}")
    return int(value)


def _discs(centres_xy_mm: np.ndarray, radii_mm: np.ndarray, values: np.ndarray,
           shape: tuple[int, int], width_mm: float, supersample: int = 4) -> np.ndarray:
    """Discs on the object grid (rows along +y, columns along +x, centred on the
    axis, square pixels ``width_mm / cols``), each pixel the area fraction covered
    times the disc's value (``supersample^2`` samples per pixel)."""
    rows, cols = shape
    px = width_mm / cols
    ss = supersample
    out = np.zeros((rows * ss, cols * ss))
    sub = px / ss
    ys = (np.arange(rows * ss) + 0.5) * sub - rows * px / 2
    xs = (np.arange(cols * ss) + 0.5) * sub - cols * px / 2
    for (x, y), r, v in zip(centres_xy_mm, radii_mm, values, strict=True):
        r_eff = max(r, sub / 2)  # a disc smaller than a sample still shows
        i0, i1 = np.searchsorted(ys, [y - r_eff, y + r_eff])
        j0, j1 = np.searchsorted(xs, [x - r_eff, x + r_eff])
        if i0 >= i1 or j0 >= j1:
            continue
        yy, xx = ys[i0:i1, None], xs[None, j0:j1]
        out[i0:i1, j0:j1] += v * ((yy - y) ** 2 + (xx - x) ** 2 <= r_eff**2)
    return out.reshape(rows, ss, cols, ss).mean(axis=(1, 3))


@dataclass(frozen=True)
class VideoScene(abc.ABC):
    """Base of the time-dependent scenes (see the module notes); a subclass gives
    :meth:`sources_at` and :meth:`object_image`.

    Attributes
    ----------
    z_mm : float
        Depth of the scene plane in front of the diffuser, mm.
    time_step_s : float or None
        Scene time resolution, s (None: continuous).
    seed : int
        Seeds the random layout (and spike times).
    """

    z_mm: float = 20.0
    time_step_s: float | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        _positive("z_mm", self.z_mm, "20.0")
        if self.time_step_s is not None:
            _positive("time_step_s", self.time_step_s, "0.05")

    @property
    def period_s(self) -> float | None:
        """Time after which the scene repeats exactly, s (None: never)."""
        return None

    def scene_time(self, t_s: float) -> float:
        """The scene time shown at time ``t_s``: wrapped into one period (periodic
        scenes) and rounded down to a multiple of ``time_step_s``."""
        t = float(t_s)
        if not math.isfinite(t):
            raise ReconInputError(f"t_s={t_s!r} must be finite (seconds)")
        if self.period_s is not None:
            t = math.fmod(t, self.period_s)
            t = t + self.period_s if t < 0 else t
        if self.time_step_s is not None:
            t = math.floor(t / self.time_step_s + 1e-9) * self.time_step_s
        return t

    def distinct_times(self) -> np.ndarray | None:
        """Every distinct scene time, s, when there are finitely many (a periodic
        scene with a ``time_step_s``), else None."""
        if self.period_s is None or self.time_step_s is None:
            return None
        n = max(1, math.ceil(self.period_s / self.time_step_s - 1e-9))
        return np.arange(n) * self.time_step_s

    @abc.abstractmethod
    def sources_at(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Point sources the scene shows at ``t_s``: positions ``(N, 3)`` float64
        (x, y, z) mm and powers ``(N,)`` float64 photons/s emitted isotropically."""

    @abc.abstractmethod
    def object_image(self, t_s: float, shape: tuple[int, int], width_mm: float) -> np.ndarray:
        """The scene at ``t_s`` on an object-plane grid.

        Parameters
        ----------
        t_s : float
            Time, s.
        shape : (int, int)
            Grid ``(rows, cols)``; rows along +y, columns along +x, centred on the axis
            (the orientation of :class:`~instrument.devices.virtual_bench.PlanarScene`).
        width_mm : float
            Lateral extent of the columns, mm (square pixels).

        Returns
        -------
        ndarray, float64, ``shape``
            Each pixel the area fraction covered by the objects times their relative
            brightness (beads 1; cells ``F / F0`` of their own baseline).
        """


@dataclass(frozen=True)
class BeadTruth:
    """Bead positions at a scene time.

    Attributes
    ----------
    time_s : float
        Scene time, s.
    positions_mm : ndarray, float64, (N, 3)
        Bead centres (x, y, z), mm.
    along_mm : ndarray, float64, (N,)
        Distance along the channel from its start, in [0, channel_length_mm), mm.
    """

    time_s: float
    positions_mm: np.ndarray
    along_mm: np.ndarray


@dataclass(frozen=True)
class BeadFlowScene(VideoScene):
    """Beads flowing along a straight channel at constant speed (Fig. 6.5a).

    Bead ``i`` sits at ``s_i(t) = (s_i0 + speed t) mod channel_length`` along the
    channel (from its upstream end) and at a fixed offset across it (the bead stays
    inside the channel walls); beads leaving the downstream end re-enter upstream,
    so the scene has period ``channel_length / speed``.

    Attributes
    ----------
    n_beads : int
    bead_diameter_um : float
        Drawn in :meth:`object_image`; the optics render each bead as a point.
    speed_um_per_s : float
        Flow speed along the channel, um/s.
    channel_centre_mm : (float, float)
        Centre of the channel (x, y), mm.
    channel_length_mm, channel_width_mm : float
    direction_deg : float
        Flow direction, degrees from +x towards +y.
    bead_power_photons_per_s : float
        Power each bead emits, photons/s.
    """

    n_beads: int = 6
    bead_diameter_um: float = 60.0
    speed_um_per_s: float = 400.0
    channel_centre_mm: tuple[float, float] = (0.0, 0.0)
    channel_length_mm: float = 1.6
    channel_width_mm: float = 0.3
    direction_deg: float = 0.0
    bead_power_photons_per_s: float = 5e10
    _start: np.ndarray = field(init=False, repr=False, compare=False)
    _across: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        super().__post_init__()
        _count("n_beads", self.n_beads, "6")
        for name, ex in (("bead_diameter_um", "60.0"), ("speed_um_per_s", "400.0"),
                         ("channel_length_mm", "1.6"), ("channel_width_mm", "0.3"),
                         ("bead_power_photons_per_s", "5e10")):
            _positive(name, getattr(self, name), ex)
        radius_mm = self.bead_diameter_um * 5e-4
        if 2 * radius_mm > self.channel_width_mm:
            raise ReconInputError(
                f"beads of {self.bead_diameter_um} um do not fit a channel "
                f"{self.channel_width_mm} mm wide; use smaller beads or a wider channel")
        rng = np.random.default_rng([self.seed, 0xB3AD])
        # evenly spread along the channel with jitter, so beads do not overlap at t = 0
        spacing = self.channel_length_mm / self.n_beads
        start = (np.arange(self.n_beads) + rng.uniform(0.1, 0.9, self.n_beads)) * spacing
        half = self.channel_width_mm / 2 - radius_mm
        object.__setattr__(self, "_start", start)
        object.__setattr__(self, "_across", rng.uniform(-half, half, self.n_beads))

    @property
    def period_s(self) -> float:
        """``channel_length / speed``, s."""
        return self.channel_length_mm / (self.speed_um_per_s * 1e-3)

    def truth(self, t_s: float) -> BeadTruth:
        """Bead positions at scene time ``scene_time(t_s)`` (see :class:`BeadTruth`)."""
        ts = self.scene_time(t_s)
        along = np.mod(self._start + self.speed_um_per_s * 1e-3 * ts, self.channel_length_mm)
        a = math.radians(self.direction_deg)
        u, n = np.array([math.cos(a), math.sin(a)]), np.array([-math.sin(a), math.cos(a)])
        s = along - self.channel_length_mm / 2
        xy = np.asarray(self.channel_centre_mm, float) + s[:, None] * u + self._across[:,
                                                                                     None] * n
        pos = np.column_stack([xy, np.full(self.n_beads, float(self.z_mm))])
        return BeadTruth(time_s=ts, positions_mm=pos, along_mm=along)

    def sources_at(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Bead centres and powers at ``t_s`` (see :meth:`VideoScene.sources_at`)."""
        pos = self.truth(t_s).positions_mm
        return pos, np.full(self.n_beads, float(self.bead_power_photons_per_s))

    def object_image(self, t_s: float, shape: tuple[int, int], width_mm: float) -> np.ndarray:
        """Bead discs at ``t_s`` (see :meth:`VideoScene.object_image`)."""
        pos = self.truth(t_s).positions_mm
        radii = np.full(self.n_beads, self.bead_diameter_um * 5e-4)
        return _discs(pos[:, :2], radii, np.ones(self.n_beads), tuple(shape),
                      _positive("width_mm", width_mm, "2.0"))


@dataclass(frozen=True)
class NeuronTruth:
    """Cell brightness at a scene time.

    Attributes
    ----------
    time_s : float
        Scene time, s.
    f_photons_per_s : ndarray, float64, (N,)
        Each cell's emitted power ``F``, photons/s.
    dff : ndarray, float64, (N,)
        ``ΔF/F = (F - F0) / F0`` of each cell.
    """

    time_s: float
    f_photons_per_s: np.ndarray
    dff: np.ndarray


@dataclass(frozen=True)
class NeuronFieldScene(VideoScene):
    """A sparse field of neurons with calcium transients (Fig. 6.5b).

    Cell ``i`` at a fixed position emits ``F_i(t) = F0_i (1 + dff_i(t))`` with
    ``dff_i(t) = dff_per_spike * sum_k exp(-(t - t_ik) / tau_s)`` over its spikes
    ``t_ik <= t``: spike times are a Poisson process of rate ``spike_rate_hz``
    on ``[0, duration_s)`` (none after), drawn from ``seed``.

    Attributes
    ----------
    n_cells : int
    field_mm : (float, float)
        Width and height of the field the cells lie in (centred on the axis), mm.
    radius_um : (float, float)
        Range of the cell radii, um (drawn uniformly); drawn in :meth:`object_image`,
        the optics render each cell as a point.
    f0_photons_per_s : float
        Baseline power of a cell, photons/s (each cell's ``F0`` is this times a
        factor drawn in [0.5, 1.5]).
    spike_rate_hz, tau_s, dff_per_spike : float
        Mean spike rate, decay time of a transient (s) and ΔF/F added per spike.
    duration_s : float
        Spikes occur in ``[0, duration_s)``.
    """

    n_cells: int = 12
    field_mm: tuple[float, float] = (1.6, 1.2)
    radius_um: tuple[float, float] = (5.0, 8.0)
    f0_photons_per_s: float = 2e10
    spike_rate_hz: float = 0.5
    tau_s: float = 0.6
    dff_per_spike: float = 1.0
    duration_s: float = 60.0
    _xy: np.ndarray = field(init=False, repr=False, compare=False)
    _radii: np.ndarray = field(init=False, repr=False, compare=False)
    _f0: np.ndarray = field(init=False, repr=False, compare=False)
    _spikes: tuple = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        super().__post_init__()
        _count("n_cells", self.n_cells, "12")
        for name, ex in (("f0_photons_per_s", "2e10"), ("spike_rate_hz", "0.5"),
                         ("tau_s", "0.6"), ("dff_per_spike", "1.0"), ("duration_s", "60")):
            _positive(name, getattr(self, name), ex)
        fw, fh = (_positive("field_mm", v, "(1.6, 1.2)") for v in self.field_mm)
        r_lo, r_hi = (_positive("radius_um", v, "(5.0, 8.0)") for v in self.radius_um)
        if r_lo > r_hi:
            raise ReconInputError(f"radius_um={self.radius_um!r}: give (smallest, largest)")
        rng = np.random.default_rng([self.seed, 0xCE11])
        xy = np.column_stack([rng.uniform(-fw / 2, fw / 2, self.n_cells),
                              rng.uniform(-fh / 2, fh / 2, self.n_cells)])
        spikes = []
        for _ in range(self.n_cells):
            n = rng.poisson(self.spike_rate_hz * self.duration_s)
            spikes.append(np.sort(rng.uniform(0.0, self.duration_s, n)))
        object.__setattr__(self, "_xy", xy)
        object.__setattr__(self, "_radii", rng.uniform(r_lo, r_hi, self.n_cells) * 1e-3)
        object.__setattr__(self, "_f0", self.f0_photons_per_s
                           * rng.uniform(0.5, 1.5, self.n_cells))
        object.__setattr__(self, "_spikes", tuple(spikes))

    @property
    def positions_mm(self) -> np.ndarray:
        """Cell centres (x, y, z), mm, ``(N, 3)`` float64."""
        return np.column_stack([self._xy, np.full(self.n_cells, float(self.z_mm))])

    @property
    def radii_mm(self) -> np.ndarray:
        """Cell radii, mm, ``(N,)``."""
        return self._radii.copy()

    @property
    def f0_per_cell(self) -> np.ndarray:
        """Each cell's baseline ``F0``, photons/s, ``(N,)``."""
        return self._f0.copy()

    @property
    def spike_times_s(self) -> tuple[np.ndarray, ...]:
        """Each cell's spike times, s (sorted)."""
        return tuple(s.copy() for s in self._spikes)

    def dff_traces(self, times_s) -> np.ndarray:
        """ΔF/F of every cell at the scene times of ``times_s``: ``(T, N)`` float64."""
        ts = np.array([self.scene_time(t) for t in np.atleast_1d(np.asarray(times_s, float))])
        out = np.zeros((ts.size, self.n_cells))
        for i, spikes in enumerate(self._spikes):
            lag = ts[:, None] - spikes[None, :]
            decay = np.exp(-np.where(lag >= 0, lag, 0.0) / self.tau_s)
            out[:, i] = self.dff_per_spike * np.sum(np.where(lag >= 0, decay, 0.0), axis=1)
        return out

    def truth(self, t_s: float) -> NeuronTruth:
        """``F`` and ΔF/F of every cell at scene time ``scene_time(t_s)``."""
        dff = self.dff_traces([t_s])[0]
        return NeuronTruth(time_s=self.scene_time(t_s), f_photons_per_s=self._f0 * (1 + dff),
                           dff=dff)

    def sources_at(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Cell centres and their ``F`` at ``t_s`` (see :meth:`VideoScene.sources_at`)."""
        return self.positions_mm, self.truth(t_s).f_photons_per_s

    def object_image(self, t_s: float, shape: tuple[int, int], width_mm: float) -> np.ndarray:
        """Cell discs weighted by ``F / F0`` at ``t_s`` (see
        :meth:`VideoScene.object_image`)."""
        dff = self.truth(t_s).dff
        return _discs(self._xy, self._radii, 1.0 + dff, tuple(shape),
                      _positive("width_mm", width_mm, "2.0"))
