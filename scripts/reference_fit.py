"""An independent reference BRDF fitter: grid search over the shape parameters + bounded linear least squares.

Why it exists: every accuracy claim brdffit makes on real measurements ("the chosen model reproduces paper_white
to 5% on held-out directions") needs a yardstick that does not share the engine's code, so that a bug in the
engine (a model's maths, the variable projection, the global search, the Levenberg-Marquardt polish, the
selection) cannot make the engine and its yardstick agree by accident. This file is that yardstick. It is written
apart from the engine on purpose:

- it uses NumPy and SciPy only, and imports nothing of brdffit's models, fitting, selection or JAX code; it
  imports `brdffit.io` only to read a measured file and look up its tabulated values (the data, not the maths);
- each model is written out again here from its paper (cited at each function), in plain NumPy;
- the fit is the simplest one that is still exact for these models: each model is a Lambert lobe ρd/π plus one
  specular lobe ks·S(ω_i, ω_o; shape) whose amplitudes ρd, ks (one per channel) enter linearly. The shape
  parameters are the lobe's width (GGX α, Cook-Torrance m, Blinn-Phong exponent n, Ward α) and, for GGX and
  Cook-Torrance, the f0 of Schlick's Fresnel factor F = f0 + (1 − f0)(1 − ω_i·h)⁵ (`schlick`; f0 = 1 is the
  Fresnel-free lobe), the term that lets a lobe rise towards grazing as vinyl films and felts do. For each point
  of a fixed grid (the width log-spaced, f0 on `F0_GRID`) the amplitudes are solved per channel by bounded linear
  least squares (`scipy.optimize.lsq_linear`, 0 <= ρd <= 1, ks >= 0) on the cosine-weighted residual; the grid
  point with the lowest cost summed over channels is kept, then refined, on log(width) and f0, within the box of
  its grid neighbours (`scipy.optimize.minimize_scalar` for one shape parameter, L-BFGS-B of
  `scipy.optimize.minimize` for two; amplitudes re-solved at each evaluation). The reference is the model, of the
  four, with the lowest training cost. Blinn-Phong and Ward keep their standard, Fresnel-free definitions.

Conventions (docs/conventions.md): local frame with z the normal; ω_i points to the light, ω_o to the detector;
θ polar, φ azimuth, radians; f_r in 1/sr without the cosine factor, 0 unless both directions lie above the
horizon.

The protocol of the held-out comparison: direction pairs uniform in solid angle with θ <= 80° for both
directions (`uniform_pairs`); a training set of `TRAIN_PAIRS` pairs from ``numpy.random.default_rng(TRAIN_SEED)``
and a test set of `TEST_PAIRS` pairs from ``numpy.random.default_rng(TEST_SEED)`` (`protocol_pairs`); the error
is the cosine-weighted relative RMS error `cosine_error` on the test set. On materials with a sharp peak (glossy
films, satins) that error on 2,000 pairs depends strongly on how many pairs fall near the mirror direction, so it
varies a lot with the test seed; ``--test-pairs`` and ``--test-seed`` change the test set.

Command line::

    python scripts/reference_fit.py FILE.bsdf [FILE.binary ...] [--json OUT.json] [--no-refine]
                                    [--test-pairs N] [--test-seed SEED]

For each RGL-EPFL ``.bsdf`` (`brdffit.io.read_rgl`, lookup with the default ``negative="clip"``) or MERL
``.binary`` (`brdffit.io.read_merl`) file it looks the table up at the protocol's training and test pairs, fits the
reference on the training pairs and prints the chosen model, its shape parameters and the training and test
cosine errors (and those of each of the four models); ``--json`` writes the same numbers (shapes as dicts by
name, e.g. ``{"alpha": 0.08, "f0": 0.06}``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from scipy.optimize import lsq_linear, minimize, minimize_scalar

# The protocol of the held-out comparison (module docstring).
MAX_THETA_DEG = 80.0
TRAIN_PAIRS, TRAIN_SEED = 8_000, 101
TEST_PAIRS, TEST_SEED = 2_000, 202

_TINY = 1e-12  # floor of the cosines that are divided by or raised to a power


# --------------------------------------------------------------------------------------------------------------
# Direction pairs and the error measure
# --------------------------------------------------------------------------------------------------------------

def uniform_pairs(n: int, rng: np.random.Generator, max_theta_deg: float = MAX_THETA_DEG):
    """Direction pairs uniform in solid angle on the cap θ <= max_theta, independently for ω_i and ω_o.

    The draws are made in one call, ``u_i, v_i, u_o, v_o = rng.random((4, n))``, and mapped by
    cos θ = 1 − u (1 − cos θmax) and φ = 2π v − π: the same generator state always gives the same pairs.

    Arguments:
        n: number of pairs.
        rng: a `numpy.random.Generator`.
        max_theta_deg: the largest polar angle of both directions, in degrees (0 < max_theta_deg <= 90).

    Returns:
        ``(theta_i, phi_i, theta_o, phi_o)``, four arrays of shape ``(n,)`` in radians, φ in [−π, π).
    """
    if not 0.0 < max_theta_deg <= 90.0:
        raise ValueError(f"max_theta_deg must lie in (0, 90], got {max_theta_deg}")
    one_minus_cos_max = 1.0 - np.cos(np.radians(max_theta_deg))
    u_i, v_i, u_o, v_o = rng.random((4, int(n)))
    theta_i = np.arccos(1.0 - u_i * one_minus_cos_max)
    theta_o = np.arccos(1.0 - u_o * one_minus_cos_max)
    return theta_i, 2.0 * np.pi * v_i - np.pi, theta_o, 2.0 * np.pi * v_o - np.pi


def protocol_pairs(test_pairs: int = TEST_PAIRS, test_seed: int = TEST_SEED):
    """The protocol's training and test direction pairs (module docstring).

    Arguments:
        test_pairs: number of test pairs (default the protocol's `TEST_PAIRS`).
        test_seed: seed of the test pairs' generator (default the protocol's `TEST_SEED`).

    Returns:
        ``(train, test)``: each a tuple ``(theta_i, phi_i, theta_o, phi_o)`` from `uniform_pairs`, with
        `TRAIN_PAIRS` pairs from ``default_rng(TRAIN_SEED)`` and ``test_pairs`` pairs from
        ``default_rng(test_seed)``.
    """
    train = uniform_pairs(TRAIN_PAIRS, np.random.default_rng(TRAIN_SEED))
    test = uniform_pairs(test_pairs, np.random.default_rng(test_seed))
    return train, test


def cosine_error(f_fit, f_data, theta_i) -> float:
    """The cosine-weighted relative RMS error ‖(f_fit − f_data) cos θi‖ / ‖f_data cos θi‖.

    The norms run over all rows and channels; rows where any channel of ``f_data`` is not finite (a missing
    measurement) are left out. cos θi is taken as max(cos θi, 0).

    Arguments:
        f_fit: the model's f_r, shape ``(N, C)`` (or ``(N,)``).
        f_data: the measured f_r, same shape.
        theta_i: polar angle of ω_i in radians, shape ``(N,)``.

    Returns:
        The relative error (a float; NaN when no row is finite or the data are all zero).
    """
    f_fit = np.asarray(f_fit, dtype=np.float64)
    f_data = np.asarray(f_data, dtype=np.float64)
    if f_data.ndim == 1:
        f_fit, f_data = f_fit[:, None], f_data[:, None]
    if f_fit.shape != f_data.shape:
        raise ValueError(f"f_fit has shape {f_fit.shape}, f_data {f_data.shape}")
    cos_i = np.clip(np.cos(np.asarray(theta_i, dtype=np.float64)), 0.0, None)[:, None]
    rows = np.all(np.isfinite(f_data), axis=1)
    if not rows.any():
        return float("nan")
    denominator = np.linalg.norm(f_data[rows] * cos_i[rows])
    if denominator == 0.0:
        return float("nan")
    return float(np.linalg.norm((f_fit[rows] - f_data[rows]) * cos_i[rows]) / denominator)


# --------------------------------------------------------------------------------------------------------------
# Geometry and the four specular lobes (plain NumPy, written from the papers)
# --------------------------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class _Geometry:
    """Cosines of a batch of direction pairs: cos θi, cos θo (clipped to >= _TINY), n·h, ω·h, and which pairs lie
    above the horizon."""

    cos_i: np.ndarray
    cos_o: np.ndarray
    cos_h: np.ndarray
    cos_d: np.ndarray
    above: np.ndarray


def _geometry(theta_i, phi_i, theta_o, phi_o) -> _Geometry:
    theta_i, phi_i, theta_o, phi_o = np.broadcast_arrays(
        *(np.asarray(a, dtype=np.float64).reshape(-1) for a in (theta_i, phi_i, theta_o, phi_o)))
    wi = np.stack([np.sin(theta_i) * np.cos(phi_i), np.sin(theta_i) * np.sin(phi_i), np.cos(theta_i)], axis=-1)
    wo = np.stack([np.sin(theta_o) * np.cos(phi_o), np.sin(theta_o) * np.sin(phi_o), np.cos(theta_o)], axis=-1)
    above = (wi[:, 2] > 0.0) & (wo[:, 2] > 0.0)
    s = wi + wo
    length = np.maximum(np.linalg.norm(s, axis=1), _TINY)
    cos_h = np.clip(s[:, 2] / length, _TINY, 1.0)  # n·h
    cos_d = np.clip(0.5 * length, _TINY, 1.0)  # ω_i·h = ω_o·h = |ω_i + ω_o| / 2
    return _Geometry(np.clip(wi[:, 2], _TINY, 1.0), np.clip(wo[:, 2], _TINY, 1.0), cos_h, cos_d, above)


def _tan2(cos):
    """tan²θ from cos θ (cos θ already clipped to [_TINY, 1])."""
    return np.maximum(1.0 - cos * cos, 0.0) / (cos * cos)


def ggx_d(cos_h, alpha):
    """GGX / Trowbridge-Reitz normal distribution (Walter et al. 2007, eq. 33):
    D(h) = α² / (π cos⁴θh (α² + tan²θh)²) = α² / (π (cos²θh (α² − 1) + 1)²), normalised so that
    ∫ D(h) cos θh dω_h = 1."""
    a2 = alpha * alpha
    c2 = cos_h * cos_h
    return a2 / (np.pi * (c2 * (a2 - 1.0) + 1.0) ** 2)


def ggx_g1(cos_v, alpha):
    """Smith masking of GGX for one direction v (Walter et al. 2007, eq. 34):
    G1(v) = 2 / (1 + sqrt(1 + α² tan²θv)); the χ⁺(v·h / v·n) factor is 1 for reflection above the horizon."""
    return 2.0 / (1.0 + np.sqrt(1.0 + alpha * alpha * _tan2(cos_v)))


def beckmann_d(cos_h, m):
    """Beckmann distribution as used by Cook & Torrance (1982, eq. for D):
    D(h) = exp(−tan²θh / m²) / (π m² cos⁴θh), normalised so that ∫ D(h) cos θh dω_h = 1."""
    m2 = m * m
    c2 = cos_h * cos_h
    return np.exp(-_tan2(cos_h) / m2) / (np.pi * m2 * c2 * c2)


def schlick(cos_d, f0):
    """Schlick's (1994) approximation of the Fresnel reflectance of a microfacet:
    F = f0 + (1 − f0)(1 − cos θd)⁵, with cos θd = ω_i·h = ω_o·h the cosine between either direction and the half
    vector h, and f0 the reflectance at normal incidence (F(1) = f0, F(0) = 1; f0 = 1 gives F = 1)."""
    c = np.clip(cos_d, 0.0, 1.0)
    return f0 + (1.0 - f0) * (1.0 - c) ** 5


def _ggx_microfacet(g: _Geometry, alpha: float):
    """The Fresnel-free part of Walter et al.'s (2007) microfacet reflection with the GGX D (eq. 33) and its
    separable Smith G = G1(ω_i) G1(ω_o) (eq. 34): D G / (4 cos θi cos θo)."""
    d = ggx_d(g.cos_h, alpha)
    g2 = ggx_g1(g.cos_i, alpha) * ggx_g1(g.cos_o, alpha)
    return d * g2 / (4.0 * g.cos_i * g.cos_o)


def _lobe_ggx(g: _Geometry, alpha: float, f0: float):
    """Walter et al. (2007) microfacet reflection, GGX D and Smith G (`_ggx_microfacet`), with Schlick's Fresnel
    term (`schlick`): S = F(ω_i·h; f0) D G / (4 cos θi cos θo)."""
    return schlick(g.cos_d, f0) * _ggx_microfacet(g, alpha)


def _cook_torrance_microfacet(g: _Geometry, m: float):
    """The Fresnel-free part of Cook & Torrance (1982): Beckmann D with roughness m and the V-cavity geometric
    attenuation G = min(1, 2 (n·h)(n·ω_o) / (ω_o·h), 2 (n·h)(n·ω_i) / (ω_o·h)): D G / (4 cos θi cos θo)."""
    d = beckmann_d(g.cos_h, m)
    g_vc = np.minimum(1.0, np.minimum(2.0 * g.cos_h * g.cos_o / g.cos_d, 2.0 * g.cos_h * g.cos_i / g.cos_d))
    return d * g_vc / (4.0 * g.cos_i * g.cos_o)


def _lobe_cook_torrance(g: _Geometry, m: float, f0: float):
    """Cook & Torrance (1982) with Schlick's Fresnel term in place of the exact one (`schlick`):
    S = F(ω_i·h; f0) D G / (4 cos θi cos θo)."""
    return schlick(g.cos_d, f0) * _cook_torrance_microfacet(g, m)


def _lobe_blinn_phong(g: _Geometry, n: float):
    """Blinn (1977) half-vector lobe (n·h)^n with the energy normalisation (n + 8) / (8π) of Akenine-Möller,
    Haines & Hoffman, Real-Time Rendering (3rd ed., §7.6): S = (n + 8) / (8π) (n·h)^n."""
    return (n + 8.0) / (8.0 * np.pi) * np.exp(n * np.log(g.cos_h))


def _lobe_ward(g: _Geometry, alpha: float):
    """Isotropic Ward (1992, eq. 4 with α_x = α_y = α):
    S = exp(−tan²θh / α²) / (4π α² sqrt(cos θi cos θo))."""
    return np.exp(-_tan2(g.cos_h) / (alpha * alpha)) / (4.0 * np.pi * alpha * alpha * np.sqrt(g.cos_i * g.cos_o))


# The grid of Schlick's f0 (GGX and Cook-Torrance); f0 = 1 is the Fresnel-free lobe.
F0_GRID = np.array([0.0, 0.02, 0.04, 0.08, 0.15, 0.3, 0.5, 0.75, 1.0])


@dataclass(frozen=True, eq=False)
class _Model:
    """A reference model's specular lobe.

    Attributes:
        lobe: ``lobe(g, *shape)`` -> S at the pairs of ``g``.
        shape_names: the names of its shape parameters; the first is the lobe's width (α, m or exponent n).
        grids: one grid per shape parameter. The width's grid is log-spaced and refined on log(width); f0's grid is
            `F0_GRID`, refined on f0 itself.
        microfacet: for the models with a Schlick factor, the Fresnel-free part ``microfacet(g, width)``, so that
            S = schlick(cos θd, f0) · microfacet: the grid evaluates it once per width and multiplies by F per f0.
    """

    lobe: Callable
    shape_names: tuple
    grids: tuple
    microfacet: Callable | None = None


MODELS = {
    "ggx": _Model(_lobe_ggx, ("alpha", "f0"), (np.geomspace(0.005, 1.0, 40), F0_GRID), _ggx_microfacet),
    "cook-torrance": _Model(_lobe_cook_torrance, ("m", "f0"), (np.geomspace(0.005, 1.0, 40), F0_GRID),
                            _cook_torrance_microfacet),
    "blinn-phong": _Model(_lobe_blinn_phong, ("n",), (np.geomspace(1.0, 10_000.0, 40),)),
    "ward": _Model(_lobe_ward, ("alpha",), (np.geomspace(0.005, 1.0, 40),)),
}
SHAPE_NAMES = {name: spec.shape_names for name, spec in MODELS.items()}


def _shape_tuple(model: str, shape) -> tuple:
    """``shape`` as a tuple of floats in the order of ``SHAPE_NAMES[model]``: a sequence in that order, a dict keyed
    by the names, or a bare number for a model with one shape parameter."""
    if model not in MODELS:
        raise ValueError(f"unknown reference model {model!r}; known: {', '.join(MODELS)}")
    names = MODELS[model].shape_names
    if isinstance(shape, dict):
        missing = [name for name in names if name not in shape]
        extra = [key for key in shape if key not in names]
        if missing or extra:
            raise ValueError(f"{model} takes the shape parameters {names}, got {sorted(shape)}")
        values = tuple(float(shape[name]) for name in names)
    elif np.ndim(shape) == 0:
        values = (float(shape),)
    else:
        values = tuple(float(v) for v in np.asarray(shape, dtype=np.float64).reshape(-1))
    if len(values) != len(names):
        raise ValueError(f"{model} takes {len(names)} shape parameter(s) {names}, got {len(values)}: {shape!r}")
    return values


def _masked(g: _Geometry, s: np.ndarray) -> np.ndarray:
    """0 below the horizon and where the float arithmetic is not finite."""
    return np.where(g.above & np.isfinite(s), s, 0.0)


def _specular(model: str, g: _Geometry, shape) -> np.ndarray:
    """S of ``model`` at the pairs of ``g``, 0 below the horizon and where the float arithmetic is not finite."""
    shape = _shape_tuple(model, shape)  # checks the model's name and the number of shape parameters
    return _masked(g, MODELS[model].lobe(g, *shape))


def evaluate(model: str, shape, rho_d, ks, theta_i, phi_i, theta_o, phi_o) -> np.ndarray:
    """f_r = ρd/π + ks S(shape) of one reference model.

    Arguments:
        model: one of `MODELS` (``"ggx"``, ``"cook-torrance"``, ``"blinn-phong"``, ``"ward"``).
        shape: the shape parameters in the order of ``SHAPE_NAMES[model]`` (GGX ``(alpha, f0)``, Cook-Torrance
            ``(m, f0)``, Blinn-Phong ``(n,)``, Ward ``(alpha,)``), or a dict keyed by those names; a bare number
            for Blinn-Phong and Ward.
        rho_d, ks: amplitudes, shape ``(C,)`` (scalars are one channel).
        theta_i, phi_i, theta_o, phi_o: angles in radians, shape ``(N,)`` (broadcastable).

    Returns:
        f_r in 1/sr, shape ``(N, C)``; 0 unless both directions lie above the horizon.
    """
    g = _geometry(theta_i, phi_i, theta_o, phi_o)
    rho_d = np.atleast_1d(np.asarray(rho_d, dtype=np.float64))
    ks = np.atleast_1d(np.asarray(ks, dtype=np.float64))
    s = _specular(model, g, shape)
    diffuse = np.where(g.above, 1.0 / np.pi, 0.0)
    return diffuse[:, None] * rho_d[None, :] + s[:, None] * ks[None, :]


# --------------------------------------------------------------------------------------------------------------
# The fit
# --------------------------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class ReferenceFit:
    """A fitted reference model f_r = ρd/π + ks S(shape).

    Attributes:
        model: the model's name (a key of `MODELS`).
        shape: its shape parameters, a tuple in the order of ``SHAPE_NAMES[model]``: GGX ``(alpha, f0)``,
            Cook-Torrance ``(m, f0)``, Blinn-Phong ``(n,)``, Ward ``(alpha,)``.
        rho_d: diffuse albedo per channel, shape ``(C,)``.
        ks: specular amplitude per channel, shape ``(C,)``.
        train_cost: Σ over rows and channels of (w (f_fit − f_data))², w = cos θi sqrt(weight), on the training
            rows with finite data.
    """

    model: str
    shape: tuple
    rho_d: np.ndarray
    ks: np.ndarray
    train_cost: float

    @property
    def shape_dict(self) -> dict:
        """The shape parameters by name, e.g. ``{"alpha": 0.1, "f0": 0.04}``."""
        return dict(zip(SHAPE_NAMES[self.model], self.shape))

    def predict(self, theta_i, phi_i, theta_o, phi_o) -> np.ndarray:
        """f_r of the fit at direction pairs (radians), shape ``(N, C)``."""
        return evaluate(self.model, self.shape, self.rho_d, self.ks, theta_i, phi_i, theta_o, phi_o)


def _solve_amplitudes(spec_w: np.ndarray, diffuse_w: np.ndarray, targets_w: np.ndarray):
    """Bounded linear least squares per channel for the columns [1/π, S] (already multiplied by the row weights).

    The S column is scaled to unit norm for conditioning (the bound ks >= 0 is unchanged by a positive scale).

    Returns:
        ``(rho_d, ks, cost)`` with ``cost`` = Σ_c ‖A x_c − b_c‖².
    """
    scale = np.linalg.norm(spec_w)
    scale = scale if scale > 0.0 and np.isfinite(scale) else 1.0
    a = np.column_stack([diffuse_w, spec_w / scale])
    lower, upper = np.array([0.0, 0.0]), np.array([1.0, np.inf])
    channels = targets_w.shape[1]
    rho_d, ks, cost = np.empty(channels), np.empty(channels), 0.0
    for c in range(channels):
        result = lsq_linear(a, targets_w[:, c], bounds=(lower, upper), method="bvls")
        rho_d[c], ks[c] = result.x[0], result.x[1] / scale
        cost += 2.0 * result.cost  # lsq_linear's cost is ½‖r‖²
    return rho_d, ks, float(cost)


def _grid_costs(model: str, g: _Geometry, w: np.ndarray, diffuse_w: np.ndarray, targets_w: np.ndarray):
    """The training cost at every point of the model's shape grid, shape ``tuple(len(grid) for grid in grids)``.

    For a model with a Schlick factor the Fresnel-free part is evaluated once per width and multiplied by F per f0.
    """
    spec = MODELS[model]
    costs = np.empty(tuple(len(grid) for grid in spec.grids))
    if spec.microfacet is None:
        for k, shape in enumerate(spec.grids[0]):
            costs[k] = _solve_amplitudes(_specular(model, g, (shape,)) * w, diffuse_w, targets_w)[2]
        return costs
    fresnel = [schlick(g.cos_d, f0) for f0 in spec.grids[1]]
    for k, width in enumerate(spec.grids[0]):
        base_w = _masked(g, spec.microfacet(g, float(width))) * w
        for j, factor in enumerate(fresnel):
            costs[k, j] = _solve_amplitudes(base_w * factor, diffuse_w, targets_w)[2]
    return costs


def _fit_model(model: str, g: _Geometry, w: np.ndarray, targets_w: np.ndarray, refine: bool) -> ReferenceFit:
    spec = MODELS[model]
    diffuse_w = w / np.pi

    def solve(shape):
        return _solve_amplitudes(_specular(model, g, shape) * w, diffuse_w, targets_w)

    costs = _grid_costs(model, g, w, diffuse_w, targets_w)
    index = np.unravel_index(int(np.argmin(costs)), costs.shape)
    best_shape = tuple(float(grid[k]) for grid, k in zip(spec.grids, index))
    rho_d, ks, cost = solve(best_shape)
    if refine:
        # bounds: the best grid point's neighbours, on log(width) and on f0
        bounds = []
        for d, (grid, k) in enumerate(zip(spec.grids, index)):
            low, high = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
            bounds.append((np.log(low), np.log(high)) if d == 0 else (float(low), float(high)))

        def to_shape(x):
            return (float(np.exp(x[0])),) + tuple(float(v) for v in x[1:])

        if len(bounds) == 1:
            result = minimize_scalar(lambda log_s: solve((np.exp(log_s),))[2], bounds=bounds[0], method="bounded",
                                     options={"xatol": 1e-6})
            x = np.atleast_1d(result.x)
        else:
            x0 = np.array([np.log(best_shape[0])] + list(best_shape[1:]))
            result = minimize(lambda x: solve(to_shape(x))[2], x0, method="L-BFGS-B", bounds=bounds,
                              options={"ftol": 1e-12, "gtol": 1e-10, "maxiter": 200})
            x = result.x
        if np.isfinite(result.fun) and result.fun <= cost:
            best_shape = to_shape(x)
            rho_d, ks, cost = solve(best_shape)
    return ReferenceFit(model, best_shape, rho_d, ks, cost)


def _prepare(theta_i, phi_i, theta_o, phi_o, values, weights):
    values = np.asarray(values, dtype=np.float64)
    if values.ndim == 1:
        values = values[:, None]
    theta_i, phi_i, theta_o, phi_o = (np.asarray(a, dtype=np.float64).reshape(-1)
                                      for a in (theta_i, phi_i, theta_o, phi_o))
    n = values.shape[0]
    if any(len(a) != n for a in (theta_i, phi_i, theta_o, phi_o)):
        raise ValueError("theta_i, phi_i, theta_o, phi_o and values must have the same number of rows")
    rows = np.all(np.isfinite(values), axis=1)
    for a in (theta_i, phi_i, theta_o, phi_o):
        rows &= np.isfinite(a)
    if weights is None:
        weights = np.ones(n)
    else:
        weights = np.asarray(weights, dtype=np.float64).reshape(-1)
        if len(weights) != n:
            raise ValueError(f"weights must have one value per row ({n}), got {len(weights)}")
        if np.any(weights[np.isfinite(weights)] < 0):
            raise ValueError("weights must be >= 0")
        rows &= np.isfinite(weights)
    if not rows.any():
        raise ValueError("no row with finite data")
    g = _geometry(theta_i[rows], phi_i[rows], theta_o[rows], phi_o[rows])
    w = np.where(g.above, g.cos_i, 0.0) * np.sqrt(weights[rows])  # cos θi sqrt(weight); 0 below the horizon
    return g, w, values[rows] * w[:, None]


def fit_each(theta_i, phi_i, theta_o, phi_o, values, weights=None, *, models=None,
             refine: bool = True) -> dict[str, ReferenceFit]:
    """Fit every reference model by grid search over its shape and bounded linear least squares.

    Arguments:
        theta_i, phi_i, theta_o, phi_o: angles of the training pairs in radians, shape ``(N,)``.
        values: measured f_r in 1/sr, shape ``(N, C)`` (or ``(N,)``); rows with a non-finite value are left out.
        weights: optional per-row weights, shape ``(N,)``; each row's residual is multiplied by cos θi sqrt(weight).
        models: names to fit (default all of `MODELS`).
        refine: refine the best grid point within the box of its grid neighbours (on log(width) and f0) by a
            bounded minimisation, the amplitudes re-solved at each evaluation.

    Returns:
        ``{name: ReferenceFit}``.
    """
    g, w, targets_w = _prepare(theta_i, phi_i, theta_o, phi_o, values, weights)
    names = list(MODELS) if models is None else list(models)
    unknown = [name for name in names if name not in MODELS]
    if unknown:
        raise ValueError(f"unknown reference models {unknown}; known: {', '.join(MODELS)}")
    return {name: _fit_model(name, g, w, targets_w, refine) for name in names}


def fit_reference(theta_i, phi_i, theta_o, phi_o, values, weights=None, *, models=None,
                  refine: bool = True) -> ReferenceFit:
    """The reference fit: the model of `fit_each` with the lowest training cost.

    Arguments:
        as `fit_each`.

    Returns:
        The best `ReferenceFit`.
    """
    fits = fit_each(theta_i, phi_i, theta_o, phi_o, values, weights, models=models, refine=refine)
    return min(fits.values(), key=lambda fit: fit.train_cost)


# --------------------------------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------------------------------

def read_table(path):
    """Read a measured table with `brdffit.io` (the only part of brdffit used here): an RGL-EPFL ``.bsdf`` or a
    MERL ``.binary``.

    Returns:
        A function ``lookup(theta_i, phi_i, theta_o, phi_o) -> (N, 3)`` f_r in 1/sr.
    """
    from brdffit import io  # data only: no model, fitting or selection code

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".bsdf":
        table = io.read_rgl(path)
        return lambda *angles: table.lookup(*angles, negative="clip")
    if suffix in (".binary", ".merl"):
        return io.read_merl(path).lookup
    raise ValueError(f"{path}: expected an RGL-EPFL .bsdf or a MERL .binary file")


def _format_shape(model: str, shape) -> str:
    return ", ".join(f"{name} = {value:.5g}" for name, value in zip(SHAPE_NAMES[model], _shape_tuple(model, shape)))


def evaluate_file(path, *, refine: bool = True, test_pairs: int = TEST_PAIRS, test_seed: int = TEST_SEED) -> dict:
    """Run the protocol on one measured file: look it up at the training and test pairs, fit, measure.

    Arguments:
        path: an RGL-EPFL ``.bsdf`` or MERL ``.binary`` file.
        refine: refine the best grid shape (`fit_each`).
        test_pairs, test_seed: the test set (`protocol_pairs`; default the protocol's).

    Returns:
        A dict with the file, the chosen model, its shape parameters (a dict by name), ρd, ks, the training and
        test cosine errors, each model's shapes and errors, and the seconds taken (all, and the fit alone).
    """
    start = time.perf_counter()
    lookup = read_table(path)
    train, test = protocol_pairs(test_pairs, test_seed)
    f_train, f_test = lookup(*train), lookup(*test)
    fit_start = time.perf_counter()
    fits = fit_each(*train, f_train, refine=refine)
    fit_seconds = time.perf_counter() - fit_start
    best = min(fits.values(), key=lambda fit: fit.train_cost)
    per_model = {name: {"shape": fit.shape_dict, "rho_d": fit.rho_d.tolist(), "ks": fit.ks.tolist(),
                        "train_error": cosine_error(fit.predict(*train), f_train, train[0]),
                        "test_error": cosine_error(fit.predict(*test), f_test, test[0])}
                 for name, fit in fits.items()}
    return {"file": str(path), "model": best.model, "shape": best.shape_dict,
            "rho_d": best.rho_d.tolist(), "ks": best.ks.tolist(),
            "train_error": per_model[best.model]["train_error"], "test_error": per_model[best.model]["test_error"],
            "models": per_model, "fit_seconds": fit_seconds, "seconds": time.perf_counter() - start}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("files", nargs="+", help="RGL-EPFL .bsdf or MERL .binary files")
    parser.add_argument("--json", metavar="OUT", help="write the numbers to this JSON file")
    parser.add_argument("--no-refine", action="store_true",
                        help="keep the best grid shape (no bounded refinement between its grid neighbours)")
    parser.add_argument("--test-pairs", type=int, default=TEST_PAIRS, metavar="N",
                        help=f"number of test pairs (default the protocol's {TEST_PAIRS})")
    parser.add_argument("--test-seed", type=int, default=TEST_SEED, metavar="SEED",
                        help=f"seed of the test pairs (default the protocol's {TEST_SEED})")
    args = parser.parse_args(argv)
    if args.test_pairs < 1:
        parser.error(f"--test-pairs must be >= 1, got {args.test_pairs}")
    print(f"protocol: {TRAIN_PAIRS} training pairs (seed {TRAIN_SEED}), {args.test_pairs} test pairs "
          f"(seed {args.test_seed}), uniform in solid angle, theta <= {MAX_THETA_DEG:g} deg; "
          f"error = cosine-weighted relative RMS")
    results = []
    for path in args.files:
        r = evaluate_file(path, refine=not args.no_refine, test_pairs=args.test_pairs, test_seed=args.test_seed)
        results.append(r)
        print(f"{Path(path).name}: reference {r['model']} ({_format_shape(r['model'], r['shape'])}), "
              f"train error {r['train_error']:.4f}, test error {r['test_error']:.4f}  "
              f"[{r['seconds']:.1f} s, fit {r['fit_seconds']:.1f} s]")
        print(f"    rho_d = {np.round(r['rho_d'], 4).tolist()}, ks = {np.round(r['ks'], 4).tolist()}")
        for name, m in r["models"].items():
            print(f"    {name:>13}: {_format_shape(name, m['shape']):<28} train {m['train_error']:.4f}  "
                  f"test {m['test_error']:.4f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"protocol": {"train_pairs": TRAIN_PAIRS, "train_seed": TRAIN_SEED,
                                                            "test_pairs": args.test_pairs,
                                                            "test_seed": args.test_seed,
                                                            "max_theta_deg": MAX_THETA_DEG},
                                               "results": results}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
