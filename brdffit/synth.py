"""Synthetic measurements: sampling patterns and instrument noise for any model (docs/synthesis.md).

`generate` evaluates a model at the directions of a sampling pattern, adds noise, and returns `Measurements`
whose ``meta`` holds the ground truth, so a fit can be checked against it (`truth_model`).

Patterns (``pattern=``):

- ``uniform``: ωi and ωo independent and uniform in solid angle on the hemisphere (cap of ``max_theta``).
- ``gonio-grid``: a list of incidence angles times a regular θo/φo grid, as a gonio-reflectometer scans.
- ``in-plane``: θi and θo uniform in angle, φo = φi + π (the forward half of the plane of incidence).
- ``merl``: the cell centres of the MERL table (Matusik et al. 2003) in Rusinkiewicz half/difference angles.
- ``half-diff``: uniform in the Rusinkiewicz angles (θh, φh, θd, φd), hence dense around the specular direction.

Noise (``noise=``): ``None``, a `Noise` object (`Gaussian`, `Relative`, `SignalDependent`, `Outliers`) or its
spec string (``"relative:0.01"``, ``"gaussian:0.002"``, ``"signal-dependent:0.001,0.01"``,
``"relative:0.01+outliers:0.01,10"``); `parse_noise` turns a string into the object and ``noise.spec`` back.

Every random draw comes from ``numpy.random.Generator`` streams derived from ``seed``: the same call gives the
same numbers. The sample directions and the noise use separate streams, so changing the noise of a call keeps
its directions.
"""

from __future__ import annotations

import abc
import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from . import geometry
from .arrays import jitted, padded_columns
from .measurements import Measurements
from .models import Model, evaluate, get, model_from_dict, model_to_dict

__all__ = [
    "generate",
    "truth_model",
    "PATTERNS",
    "Noise",
    "Gaussian",
    "Relative",
    "SignalDependent",
    "Outliers",
    "parse_noise",
    "SIGMA_FLOOR",
    "DEFAULT_N",
    "merl_cell_centres",
]

# Number of samples of the scattered patterns (uniform, in-plane, half-diff) when ``n`` is not given.
DEFAULT_N = 1000

# Smallest standard deviation (1/sr) the noise models use: Measurements needs σ > 0, and a relative σ = r·f is 0
# where the model is 0. Far below any BRDF value that matters (diffuse white is 1/π ≈ 0.32 1/sr).
SIGMA_FLOOR = 1e-9

_HALF_PI = 0.5 * math.pi
_TWO_PI = 2.0 * math.pi

# MERL table resolution (Matusik et al. 2003): θh, θd, φd bins.
_MERL_BINS = (90, 90, 180)


# ---------------------------------------------------------------------------------------------------------------
# Noise models
# ---------------------------------------------------------------------------------------------------------------


def _format(x) -> str:
    """A float written so that ``float(text)`` gives it back exactly."""
    return repr(float(x))


class Noise(abc.ABC):
    """Abstract noise model: turns true values ``f`` ``(N, C)`` into measured values and their σ.

    Concrete models are frozen dataclasses that provide ``spec`` (the string `parse_noise` reads back) and
    ``apply``.
    """

    @property
    @abc.abstractmethod
    def spec(self) -> str:
        """The canonical spec string, e.g. ``"relative:0.01"``; ``parse_noise(noise.spec) == noise``."""

    @abc.abstractmethod
    def apply(self, f: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray | None, dict]:
        """Draw noisy values.

        Arguments:
            f: true values, ``(N, C)`` float64.
            rng: the generator to draw from.

        Returns:
            ``(values, sigma, info)``: noisy values ``(N, C)``; the σ used ``(N, C)`` (None if the model has no
            σ); a JSON-ready dict of what else was drawn (e.g. the outlier rows).
        """


class _Additive(Noise):
    """Noise y = f + σ(f) ε with ε standard normal and σ floored at `SIGMA_FLOOR`."""

    @abc.abstractmethod
    def std(self, f: np.ndarray) -> np.ndarray:
        """σ for true values ``f`` before the floor, broadcastable to ``f``."""

    def apply(self, f, rng):
        sigma = np.maximum(np.broadcast_to(self.std(f), f.shape), SIGMA_FLOOR).astype(float)
        eps = rng.standard_normal(f.shape)
        return f + sigma * eps, sigma, {}


@dataclasses.dataclass(frozen=True)
class Gaussian(_Additive):
    """Additive Gaussian noise of fixed standard deviation: y = f + σ ε.

    Arguments:
        sigma: σ in 1/sr, a scalar or a tuple with one value per channel.
    """

    sigma: float | tuple[float, ...]

    def __post_init__(self):
        values = np.atleast_1d(np.asarray(self.sigma, dtype=float))
        if values.ndim != 1 or values.size == 0 or not np.all(np.isfinite(values)) or np.any(values <= 0):
            raise ValueError(f"Gaussian noise needs a positive σ (scalar or one per channel), got {self.sigma!r}")
        value = float(values[0]) if np.ndim(self.sigma) == 0 else tuple(float(v) for v in values)
        object.__setattr__(self, "sigma", value)

    @property
    def spec(self) -> str:
        values = self.sigma if isinstance(self.sigma, tuple) else (self.sigma,)
        return "gaussian:" + ",".join(_format(v) for v in values)

    def std(self, f):
        value = np.asarray(self.sigma, dtype=float)
        if value.ndim == 1 and value.shape[0] != f.shape[-1]:
            raise ValueError(f"Gaussian noise has {value.shape[0]} per-channel σ but the model has "
                             f"{f.shape[-1]} channels")
        return value


@dataclasses.dataclass(frozen=True)
class Relative(_Additive):
    """Multiplicative noise: y = f (1 + r ε), i.e. σ = r·f.

    Arguments:
        r: relative standard deviation (0.01 for 1 %).
    """

    r: float

    def __post_init__(self):
        if not (math.isfinite(self.r) and self.r > 0):
            raise ValueError(f"Relative noise needs r > 0, got {self.r!r}")
        object.__setattr__(self, "r", float(self.r))

    @property
    def spec(self) -> str:
        return f"relative:{_format(self.r)}"

    def std(self, f):
        return self.r * np.abs(f)


@dataclasses.dataclass(frozen=True)
class SignalDependent(_Additive):
    """Signal-dependent (photon-like) noise: y = f + (a + b·f) ε, a read-noise floor plus a part that grows
    with the signal.

    Arguments:
        a: absolute part of σ in 1/sr (>= 0).
        b: relative part of σ (>= 0); a + b > 0.
    """

    a: float
    b: float

    def __post_init__(self):
        a, b = self.a, self.b
        if not (math.isfinite(a) and math.isfinite(b) and a >= 0 and b >= 0 and a + b > 0):
            raise ValueError(f"SignalDependent noise needs a >= 0, b >= 0 and a + b > 0, got a={a!r}, b={b!r}")
        object.__setattr__(self, "a", float(a))
        object.__setattr__(self, "b", float(b))

    @property
    def spec(self) -> str:
        return f"signal-dependent:{_format(self.a)},{_format(self.b)}"

    def std(self, f):
        return self.a + self.b * np.abs(f)


@dataclasses.dataclass(frozen=True)
class Outliers(Noise):
    """Gross outliers on top of a base noise: exactly round(fraction·N) samples, chosen at random, are
    multiplied by ``scale`` in every channel (a glitch of the detector or a stray reflection).

    The σ stored is the base noise's σ (None without a base): an outlier is by definition not described by it.
    The rows hit are listed in the info under ``"outliers"`` (and so in ``meta["outliers"]``).

    Arguments:
        fraction: share of samples replaced, in [0, 1].
        scale: factor applied to them (> 0; > 1 for bright outliers, < 1 for drop-outs).
        base: the noise of the other samples (a `Noise`, spec string or None).
    """

    fraction: float
    scale: float = 10.0
    base: Noise | None = None

    def __post_init__(self):
        if not (math.isfinite(self.fraction) and 0.0 <= self.fraction <= 1.0):
            raise ValueError(f"Outliers needs a fraction in [0, 1], got {self.fraction!r}")
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"Outliers needs a scale > 0, got {self.scale!r}")
        base = parse_noise(self.base) if isinstance(self.base, str) else self.base
        if isinstance(base, Outliers):
            raise ValueError("the base noise of Outliers cannot itself be Outliers")
        if base is not None and not isinstance(base, Noise):
            raise TypeError(f"the base of Outliers must be a Noise, a spec string or None, got {base!r}")
        object.__setattr__(self, "fraction", float(self.fraction))
        object.__setattr__(self, "scale", float(self.scale))
        object.__setattr__(self, "base", base)

    @property
    def spec(self) -> str:
        own = f"outliers:{_format(self.fraction)},{_format(self.scale)}"
        return own if self.base is None else f"{self.base.spec}+{own}"

    def apply(self, f, rng):
        if self.base is None:
            values, sigma, info = f.copy(), None, {}
        else:
            values, sigma, info = self.base.apply(f, rng)
        count = int(round(self.fraction * f.shape[0]))
        rows = np.sort(rng.choice(f.shape[0], size=count, replace=False))
        values[rows] *= self.scale
        return values, sigma, {**info, "outliers": rows.tolist()}


_NOISE_NAMES = {
    "gaussian": (Gaussian, "gaussian:SIGMA or gaussian:S_1,...,S_C (one σ per channel)"),
    "relative": (Relative, "relative:R"),
    "signal-dependent": (SignalDependent, "signal-dependent:A,B"),
    "outliers": (Outliers, "outliers:FRACTION or outliers:FRACTION,SCALE"),
}


def parse_noise(noise) -> Noise | None:
    """Turn a noise argument into a `Noise` (or None for no noise).

    Arguments:
        noise: None, ``"none"``, a `Noise`, or a spec string: ``"gaussian:0.002"``, ``"relative:0.01"``,
            ``"signal-dependent:0.001,0.01"``, ``"outliers:0.01,10"``, or a base noise and outliers joined with
            ``+`` (``"relative:0.01+outliers:0.01,10"``).

    Returns:
        The `Noise`, or None.

    Raises:
        ValueError: a malformed string or invalid values.
    """
    if noise is None or isinstance(noise, Noise):
        return noise
    if not isinstance(noise, str):
        raise TypeError(f"noise must be None, a Noise or a spec string, got {noise!r}")
    text = noise.strip().lower()
    if text in ("", "none"):
        return None
    base, outliers = None, None
    for part in text.split("+"):
        name, _, args = part.strip().partition(":")
        name = name.strip()
        if name not in _NOISE_NAMES:
            raise ValueError(f"unknown noise {name!r} in {noise!r}; use one of: "
                             + "; ".join(form for _, form in _NOISE_NAMES.values()))
        try:
            numbers = [float(a) for a in args.split(",")] if args.strip() else []
        except ValueError:
            raise ValueError(f"noise {part.strip()!r} in {noise!r} needs numbers: "
                             f"{_NOISE_NAMES[name][1]}") from None
        expected = {"gaussian": None, "relative": (1,), "signal-dependent": (2,), "outliers": (1, 2)}[name]
        if not numbers or (expected is not None and len(numbers) not in expected):
            raise ValueError(f"noise {part.strip()!r} in {noise!r} has the wrong number of values; write "
                             f"{_NOISE_NAMES[name][1]}")
        if name == "outliers":
            if outliers is not None:
                raise ValueError(f"noise {noise!r} names outliers twice")
            outliers = numbers
        else:
            if base is not None:
                raise ValueError(f"noise {noise!r} has two base noises; combine one base noise with outliers")
            base = Gaussian(numbers[0] if len(numbers) == 1 else tuple(numbers)) if name == "gaussian" else \
                _NOISE_NAMES[name][0](*numbers)
    if outliers is None:
        return base
    return Outliers(*outliers, base=base)


# ---------------------------------------------------------------------------------------------------------------
# Sampling patterns. Each returns the four angle arrays, the weights (None for "ones"), and the resolved options.
# ---------------------------------------------------------------------------------------------------------------


def _check_options(pattern: str, options: dict, allowed: tuple[str, ...]):
    unknown = set(options) - set(allowed)
    if unknown:
        raise ValueError(f"pattern {pattern!r} has no option {sorted(unknown)[0]!r}; its options are "
                         f"{', '.join(allowed) or 'none'}")


def _scattered_n(n, pattern):
    n = DEFAULT_N if n is None else n
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"pattern {pattern!r} needs n, a positive number of samples, got {n!r}")
    return int(n)


def _uniform(rng, n, max_theta, options):
    _check_options("uniform", options, ())
    n = _scattered_n(n, "uniform")
    u = rng.random((4, n))
    cos_min = math.cos(max_theta)
    # Uniform in solid angle on the cap θ <= max_theta: cosθ uniform in [cos max_theta, 1].
    theta_i = np.arccos(1.0 - u[0] * (1.0 - cos_min))
    theta_o = np.arccos(1.0 - u[2] * (1.0 - cos_min))
    return (theta_i, _TWO_PI * u[1], theta_o, _TWO_PI * u[3]), None, {}


def _in_plane(rng, n, max_theta, options):
    _check_options("in-plane", options, ("phi_i",))
    n = _scattered_n(n, "in-plane")
    phi_i = options.get("phi_i", 0.0)
    u = rng.random((3, n))
    theta_i = max_theta * u[0]
    theta_o = max_theta * u[1]
    if phi_i is None:
        phi = _TWO_PI * u[2]
    else:
        phi = np.full(n, float(phi_i) % _TWO_PI)
    return (theta_i, phi, theta_o, np.mod(phi + math.pi, _TWO_PI)), None, {"phi_i": None if phi_i is None
                                                                             else float(phi_i)}


def _half_diff(rng, n, max_theta, options):
    _check_options("half-diff", options, ())
    n = _scattered_n(n, "half-diff")
    kept: list[np.ndarray] = []
    total = 0
    for _ in range(10_000):
        batch = max(2 * (n - total), 1024)
        u = rng.random((4, batch))
        angles = _from_half_diff(_HALF_PI * u[0], _TWO_PI * u[1], _HALF_PI * u[2], _TWO_PI * u[3])
        ok = _within(angles[0], angles[2], max_theta)
        kept.append(np.stack(angles)[:, ok])
        total += int(ok.sum())
        if total >= n:
            break
    else:
        raise ValueError(f"half-diff: max_theta={max_theta!r} leaves too few directions to draw {n} samples")
    angles = np.concatenate(kept, axis=1)[:, :n]
    return tuple(angles), None, {}


def _from_half_diff(theta_h, phi_h, theta_d, phi_d):
    arrays = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (theta_h, phi_h, theta_d, phi_d)))
    return padded_columns(jitted(geometry.from_half_diff), *arrays)


def _within(theta_i, theta_o, max_theta):
    """Both directions strictly above the horizon and not beyond ``max_theta``."""
    return (theta_i < _HALF_PI) & (theta_o < _HALF_PI) & (theta_i <= max_theta) & (theta_o <= max_theta)


def _ring_measure(lo, hi):
    """Solid angle per radian of azimuth of the polar band lo <= θ <= hi: cos lo − cos hi."""
    return np.cos(lo) - np.cos(hi)


def _gonio_grid(rng, n, max_theta, options):
    _check_options("gonio-grid", options, ("theta_i", "phi_i", "n_theta_o", "n_phi_o"))
    default_theta_i = np.radians([0.0, 15.0, 30.0, 45.0, 60.0, 75.0])
    theta_i = np.unique(np.asarray(options.get("theta_i", default_theta_i[default_theta_i <= max_theta]),
                                   dtype=float).ravel())
    phi_i = np.unique(np.mod(np.asarray(options.get("phi_i", (0.0,)), dtype=float).ravel(), _TWO_PI))
    if theta_i.size == 0 or np.any(theta_i < 0) or np.any(theta_i > max_theta) or np.any(theta_i >= _HALF_PI):
        raise ValueError(f"gonio-grid: theta_i must be a non-empty list of angles in [0, min(max_theta, π/2)) "
                         f"(radians), got {np.degrees(theta_i).round(3).tolist()} degrees")
    if phi_i.size == 0:
        raise ValueError("gonio-grid: phi_i must list at least one azimuth")
    n_incident = theta_i.size * phi_i.size
    n_theta_o = options.get("n_theta_o")
    if n_theta_o is None:
        if n is None:
            n_theta_o = 18
        else:
            # Smallest grid (with n_phi_o = 4 n_theta_o, equal steps at the equator) that holds n points.
            n_theta_o = max(1, math.ceil(math.sqrt(n / (4 * n_incident))))
            while n_incident * n_theta_o * options.get("n_phi_o", 4 * n_theta_o) < n:
                n_theta_o += 1
    n_phi_o = int(options.get("n_phi_o", 4 * n_theta_o))
    n_theta_o = int(n_theta_o)
    if n_theta_o < 1 or n_phi_o < 1:
        raise ValueError(f"gonio-grid: n_theta_o and n_phi_o must be positive, got {n_theta_o}, {n_phi_o}")
    # θo at the centres of n_theta_o equal bands of [0, max_theta]; φo from φi in equal steps, so that the
    # forward in-plane direction φi + π is on the grid when n_phi_o is even.
    step_t = max_theta / n_theta_o
    t_edges = step_t * np.arange(n_theta_o + 1)
    theta_o = 0.5 * (t_edges[:-1] + t_edges[1:])
    dphi_o = _TWO_PI / n_phi_o
    out_measure = dphi_o * _ring_measure(t_edges[:-1], t_edges[1:])
    # Each incidence angle stands for the band between the midpoints to its neighbours, within [0, max_theta].
    mids = 0.5 * (theta_i[:-1] + theta_i[1:])
    i_edges = np.concatenate([[0.0], mids, [max_theta]])
    in_measure = (_TWO_PI / phi_i.size) * _ring_measure(i_edges[:-1], i_edges[1:])
    ti, pi, to, po = np.meshgrid(np.arange(theta_i.size), np.arange(phi_i.size), np.arange(n_theta_o),
                                 np.arange(n_phi_o), indexing="ij")
    ti, pi, to, po = (a.ravel() for a in (ti, pi, to, po))
    angles = (theta_i[ti], phi_i[pi], theta_o[to], np.mod(phi_i[pi] + po * dphi_o, _TWO_PI))
    measure = in_measure[ti] * out_measure[to]
    size = measure.size
    if n is not None:
        if n > size:
            raise ValueError(f"gonio-grid: n={n} exceeds the {size} points of the grid ({theta_i.size} θi × "
                             f"{phi_i.size} φi × {n_theta_o} θo × {n_phi_o} φo)")
        keep = np.sort(rng.choice(size, size=n, replace=False))
        angles, measure = tuple(a[keep] for a in angles), measure[keep]
    resolved = {"theta_i": theta_i.tolist(), "phi_i": phi_i.tolist(), "n_theta_o": n_theta_o,
                "n_phi_o": n_phi_o, "grid_size": size}
    return angles, measure, resolved


def _merl_cells(max_theta: float):
    """Indices and measures of the MERL cells whose centre directions lie above the horizon and within max_theta.

    The test needs only the cosines of the centre directions, which with φh = 0 are (`geometry.from_half_diff`
    written out for the z components) cosθi = cosθh cosθd − sinθh sinθd cosφd and
    cosθo = cosθh cosθd + sinθh sinθd cosφd; they are evaluated on the separable grid without building vectors.
    """
    nh, nd, nphi = _MERL_BINS
    theta_h = ((np.arange(nh) + 0.5) / nh) ** 2 * _HALF_PI
    theta_d = (np.arange(nd) + 0.5) / nd * _HALF_PI
    phi_d = (np.arange(nphi) + 0.5) / nphi * math.pi
    both = np.cos(theta_h)[:, None, None] * np.cos(theta_d)[None, :, None]
    across = (np.sin(theta_h)[:, None, None] * np.sin(theta_d)[None, :, None]) * np.cos(phi_d)[None, None, :]
    cos_i, cos_o = both - across, both + across
    floor = max(math.cos(max_theta), 0.0)
    keep = (cos_i > 0) & (cos_o > 0) & (cos_i >= floor) & (cos_o >= floor)
    ii, jj, kk = np.nonzero(keep)
    h_edges = (np.arange(nh + 1) / nh) ** 2 * _HALF_PI
    d_edges = np.arange(nd + 1) / nd * _HALF_PI
    h_measure = _ring_measure(h_edges[:-1], h_edges[1:])                       # ∫ sinθh dθh
    d_measure = 0.5 * (np.sin(d_edges[1:]) ** 2 - np.sin(d_edges[:-1]) ** 2)  # ∫ cosθd sinθd dθd
    dphi = math.pi / nphi
    measure = 4.0 * h_measure[ii] * d_measure[jj] * dphi * _TWO_PI * 2.0
    return ii, jj, kk, measure


def _merl_angles(ii, jj, kk):
    nh, nd, nphi = _MERL_BINS
    theta_h = ((ii + 0.5) / nh) ** 2 * _HALF_PI
    theta_d = (jj + 0.5) / nd * _HALF_PI
    phi_d = (kk + 0.5) / nphi * math.pi
    theta_i, phi_i, theta_o, phi_o = _from_half_diff(theta_h, 0.0, theta_d, phi_d)
    # A centre at the very limit may come back a rounding error beyond it; the cell was kept by its cosines.
    return np.minimum(theta_i, _HALF_PI), phi_i, np.minimum(theta_o, _HALF_PI), phi_o


def merl_cell_centres(max_theta: float | None = None):
    """The MERL table cells whose centre directions lie above the horizon, at their centres.

    Cell (i, j, k) has its centre at θh = ((i + ½)/90)² π/2 (the square-root rule of Matusik et al. 2003),
    θd = (j + ½)/90 · π/2, φd = (k + ½)/180 · π and φh = 0 (MERL tables assume isotropy; φd in [0, π) by
    reciprocity).

    Arguments:
        max_theta: drop cells whose θi or θo exceeds it (radians); None keeps everything above the horizon.

    Returns:
        ``(index, angles, measure)``: ``index`` ``(M, 3)`` int cell indices (i, j, k); ``angles`` the tuple
        ``(theta_i, phi_i, theta_o, phi_o)``; ``measure`` ``(M,)`` the cell's measure in dωi dωo (sr²): the
        Rusinkiewicz Jacobian dωi dωo = 4 cosθd dωh dωd integrated over the cell, times 2π for φh (isotropy) and
        2 for the folded half of φd (reciprocity).
    """
    ii, jj, kk, measure = _merl_cells(_HALF_PI if max_theta is None else float(max_theta))
    return np.stack([ii, jj, kk], axis=1), _merl_angles(ii, jj, kk), measure


def _merl(rng, n, max_theta, options):
    _check_options("merl", options, ())
    ii, jj, kk, measure = _merl_cells(max_theta)
    size = measure.size
    if n is not None:
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= size:
            raise ValueError(f"merl: n must be None (all {size} cells) or between 1 and {size}, got {n!r}")
        keep = np.sort(rng.choice(size, size=int(n), replace=False))
        ii, jj, kk, measure = ii[keep], jj[keep], kk[keep], measure[keep]
    return _merl_angles(ii, jj, kk), measure, {"cells": size}


PATTERNS = {
    "uniform": _uniform,
    "gonio-grid": _gonio_grid,
    "in-plane": _in_plane,
    "merl": _merl,
    "half-diff": _half_diff,
}


# ---------------------------------------------------------------------------------------------------------------
# generate
# ---------------------------------------------------------------------------------------------------------------


def _evaluate(model: Model, angles) -> np.ndarray:
    if angles[0].shape[0] == 0:
        return np.zeros((0, model.channels))
    return padded_columns(lambda *a: evaluate(model, *a), *angles)[0]


def _default_channels(count: int) -> tuple[str, ...]:
    return ("R", "G", "B") if count == 3 else tuple(f"c{c}" for c in range(count))


def generate(model, pattern: str = "uniform", n: int | None = None, noise=None, seed: int = 0,
             max_theta: float | None = None, *, channels: Sequence[str] | None = None, negative: str = "missing",
             **pattern_options) -> Measurements:
    """Synthetic measurements of a model.

    Arguments:
        model: a `brdffit.Model`, or a spec string (built by `brdffit.models.get` with its default parameters
            and ``len(channels)`` or 3 channels).
        pattern: ``"uniform"``, ``"gonio-grid"``, ``"in-plane"``, ``"merl"`` or ``"half-diff"`` (module doc,
            docs/synthesis.md).
        n: number of samples. For the scattered patterns (uniform, in-plane, half-diff) None means
            `DEFAULT_N`. For the grids (gonio-grid, merl) None means the whole grid and a number a seeded
            subsample of that many grid points (gonio-grid then picks a grid that holds at least n points unless
            its resolution is given).
        noise: None, a `Noise` or a spec string (`parse_noise`).
        seed: seed of the numpy random generators; the same arguments give the same measurements.
        max_theta: drop directions (incident or outgoing) beyond this polar angle (radians); the scattered
            patterns draw inside it, so they still return n samples.
        channels: channel names; default R, G, B for 3 channels, c0, c1, ... otherwise.
        negative: what to do with noisy values below 0, which `Measurements` rejects: ``"missing"`` (default)
            stores NaN, the way readers treat an instrument's negative readings; ``"clip"`` stores 0. Either
            biases the kept values where the true value is within a few σ of 0; ``meta["negatives"]`` counts
            them.
        **pattern_options: gonio-grid: ``theta_i`` (incidence angles, radians; default 0°, 15°, ..., 75°
            within max_theta), ``phi_i`` (incidence azimuths, default (0,)), ``n_theta_o``, ``n_phi_o`` (grid of
            the detector; default n_phi_o = 4 n_theta_o). in-plane: ``phi_i`` (azimuth of the plane of
            incidence, default 0; None draws one per sample).

    Returns:
        `Measurements` with ``values`` ``(n, C)``, ``sigma`` (the σ the noise used; None without noise),
        ``weights`` (1 for the scattered patterns; for the grids the cell measure in dωi dωo, scaled to mean 1,
        with ``meta["weight_unit_sr2"]`` the measure of weight 1), and ``meta`` with ``truth``
        (`brdffit.models.model_to_dict`), ``pattern``, ``pattern_options``, ``noise`` (spec string or
        ``"none"``), ``seed``, ``max_theta``, ``negative``, ``negatives`` and, for outliers, ``outliers`` (rows).

    Raises:
        ValueError: unknown pattern, option or noise; impossible n or max_theta.
    """
    if pattern not in PATTERNS:
        raise ValueError(f"unknown pattern {pattern!r}; use one of {', '.join(PATTERNS)}")
    if negative not in ("missing", "clip"):
        raise ValueError(f"negative must be 'missing' or 'clip', got {negative!r}")
    if max_theta is not None and not (0.0 < float(max_theta) <= _HALF_PI):
        raise ValueError(f"max_theta must be in (0, π/2] radians, got {max_theta!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    if not isinstance(model, Model):
        model = get(model, channels=3 if channels is None else len(channels))
    names = _default_channels(model.channels) if channels is None else tuple(str(c) for c in channels)
    if len(names) != model.channels:
        raise ValueError(f"{len(names)} channel names for a model with {model.channels} channels")
    noise_obj = parse_noise(noise)
    limit = _HALF_PI if max_theta is None else float(max_theta)

    pattern_rng, noise_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(2))
    angles, measure, resolved = PATTERNS[pattern](pattern_rng, n, limit, dict(pattern_options))
    angles = tuple(np.ascontiguousarray(a, dtype=float) for a in angles)
    angles = (angles[0], np.mod(angles[1], _TWO_PI), angles[2], np.mod(angles[3], _TWO_PI))
    count = angles[0].shape[0]

    truth = _evaluate(model, angles)
    info: dict = {}
    if noise_obj is None:
        values, sigma = truth.copy(), None
    else:
        values, sigma, info = noise_obj.apply(truth, noise_rng)
    below = values < 0
    values = np.where(below, np.nan if negative == "missing" else 0.0, values)

    if measure is None:
        weights, unit = np.ones(count), None
    else:
        unit = float(np.mean(measure))
        weights = measure / unit
    meta = {
        "synthetic": True,
        "truth": model_to_dict(model),
        "pattern": pattern,
        "pattern_options": resolved,
        "noise": "none" if noise_obj is None else noise_obj.spec,
        "seed": int(seed),
        "n": int(count),
        "max_theta": None if max_theta is None else float(max_theta),
        "negative": negative,
        "negatives": int(below.sum()),
        **info,
    }
    if unit is not None:
        meta["weight_unit_sr2"] = unit
    return Measurements(*angles, values, sigma=sigma, weights=weights, channels=names, meta=meta)


def truth_model(measurements) -> Model:
    """The ground-truth model of synthetic measurements (from ``meta["truth"]``, as `generate` stores it).

    Raises:
        ValueError: if the measurements carry no ground truth.
    """
    meta = getattr(measurements, "meta", None) or {}
    if "truth" not in meta:
        raise ValueError("these measurements carry no ground truth (meta['truth']); only data made by "
                         "brdffit.synth.generate (or files written from them) do")
    return model_from_dict(meta["truth"])
