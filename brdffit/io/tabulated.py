r"""Tabulated BRDFs as measurements over directions: what a fit of a MERL or RGL-EPFL table is given.

A tabulated file stores its BRDF on a grid of its own parameterisation (MERL: cells in Rusinkiewicz half/difference
angles; RGL-EPFL: the nodes of a sample square warped by the visible-normal distribution). The grid's nodes are
not spread evenly over directions: RGL-EPFL puts them where the warp puts them, dense in the highlight, and only at
the tabulated incidences; MERL's cells shrink towards the specular peak. A least-squares fit to the nodes minimises
the error at the nodes, not the error a renderer shows, which is an integral over incoming and outgoing directions.

The default sampling (``"directions"``) evaluates the file's own interpolation (its ``lookup``, what a renderer
reads) at quasi-random direction pairs with θi, θo ≤ ``max_theta``: a renderer shows the table at every incidence,
so between and beyond the measured incidences (an RGL-EPFL file measures up to 78.5° and interpolates towards a copy
of that slice at 90°) it is the file's interpolation that a fit should follow. Each direction is drawn as
cos θ = 1 − u (1 − cos θmax), φ = 2π v − π from a randomly shifted low-discrepancy point (`_kronecker`), so that
the plain mean over the samples of any function g(ωi, ωo) is a quasi-Monte Carlo estimate of

.. math::
    \frac{1}{\Omega_i \Omega_o} \int_{\Omega_i} \int_{\Omega_o} g(\omega_i, \omega_o)\, d\omega_o\, d\omega_i ,

with Ω the solid angles of the two cones. The samples carry no weights: the cosine loss's sum of squared
residuals ((f − f_data) cos θi)² over them is then the integral of the squared radiance error the renderer shows,
up to a constant (docs/fitting.md). An isotropic table fixes φi = 0 (every azimuth of ωi sees the same function)
and draws the other three coordinates, a denser stratification for the same number of pairs.

``max_theta`` (80° by default) keeps the outgoing directions away from the horizon, where an RGL-EPFL lookup
divides the tabulated f_r cos θo by cos θo → 0 and a MERL table holds its noisiest cells; the cosine weighting of
the loss does not reach those rows (it weights by θi), so a few of them would dominate a fit.

``"grid"`` keeps the file's own nodes with their quadrature weights (`brdffit.io.rgl.RglTable.grid_measurements`,
`brdffit.io.merl.MerlTable.grid_measurements`): what the file holds, for inspecting it or for a fit that should
see exactly the measured values.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from ..defaults import TABULATED
from ..measurements import Measurements

__all__ = ["SAMPLINGS", "DEFAULT_SAMPLING", "DEFAULT_PAIRS", "DEFAULT_MAX_THETA", "PEAK_ROUGHNESS", "PEAK_FRACTION",
           "direction_pairs", "importance_pairs", "over_directions", "check_sampling"]

SAMPLINGS = ("directions", "grid")
# The defaults are declared in `brdffit.defaults.TABULATED` (the CLI's help reads them there without NumPy).
DEFAULT_SAMPLING = TABULATED.sampling
DEFAULT_PAIRS = TABULATED.pairs
DEFAULT_MAX_THETA = math.radians(TABULATED.max_theta_deg)
# The peak components of `importance_pairs`: GGX half vectors of these roughnesses (a glossy and a near-mirror
# peak), half of the pairs in all. The uniform half keeps every direction sampled (weights at most 2).
PEAK_ROUGHNESS = (0.2, 0.04)
PEAK_FRACTION = 0.5


# ------------------------------------------------------------------ NumPy helpers the tabulated readers share
# (brdffit.geometry holds the same maths in JAX; reading a file loads no JAX.)
def unit_vectors(theta, phi) -> np.ndarray:
    """Unit vectors (N, 3) of polar angles and azimuths; exactly the normal (0, 0, 1) at θ = 0."""
    s = np.sin(theta)
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)], axis=-1)


def vector_angles(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Polar angle (2 asin(|v − z| / 2), accurate near the normal) and azimuth in [−π, π] of unit vectors (N, 3);
    the azimuth is 0 on the normal (the convention at normal incidence)."""
    theta = 2.0 * np.arcsin(np.minimum(0.5 * np.sqrt(v[:, 0] ** 2 + v[:, 1] ** 2 + (v[:, 2] - 1.0) ** 2), 1.0))
    on_axis = (v[:, 0] == 0) & (v[:, 1] == 0)
    return theta, np.where(on_axis, 0.0, np.arctan2(v[:, 1], v[:, 0]))


def grid_patch(coord, nodes: int) -> tuple[np.ndarray, np.ndarray]:
    """The patch index (0 .. nodes−2) and the fraction within it of coordinates in [0, 1] on a regular grid of
    ``nodes`` nodes (clamped to the first and last patch)."""
    scaled = np.clip(coord, 0.0, 1.0) * (nodes - 1)
    index = np.minimum(scaled.astype(np.intp), nodes - 2)
    return index, scaled - index


def _cone_polar(u, max_theta: float) -> np.ndarray:
    """The polar angle of u ∈ [0, 1) mapped uniformly in solid angle onto the cone θ ≤ ``max_theta``:
    cos θ = 1 − u (1 − cos θmax)."""
    return np.arccos(1.0 - u * (1.0 - math.cos(max_theta)))


def check_sampling(sampling: str, pairs: int, max_theta: float) -> None:
    """Refuse a sampling, a number of pairs or a largest polar angle that cannot be used (a `ValueError` naming
    the argument and what was expected)."""
    if sampling not in SAMPLINGS:
        raise ValueError(f"sampling must be one of {', '.join(SAMPLINGS)}, got {sampling!r}")
    if isinstance(pairs, bool) or not isinstance(pairs, (int, np.integer)) or pairs < 1:
        raise ValueError(f"pairs must be a positive whole number of direction pairs, got {pairs!r}")
    if not (isinstance(max_theta, (int, float, np.floating)) and 0 < max_theta <= math.pi / 2):
        raise ValueError(f"max_theta must be an angle in (0, π/2] radians, got {max_theta!r}")


def _kronecker(n: int, dims: int, seed: int) -> np.ndarray:
    """n points of the additive recurrence x_k = frac(s + k·α) in [0, 1)^dims, α = (1/φ_d, 1/φ_d², ...) with φ_d
    the real root of x^(d+1) = x + 1 (Roberts 2018, "The unreasonable effectiveness of quasirandom sequences"): a
    low-discrepancy sequence for any n, shifted by a seeded uniform s (Cranley & Patterson 1976) so that each
    seed gives an unbiased quasi-Monte Carlo estimate. Pure NumPy: no import of scipy.stats on the CLI's path."""
    phi = 2.0
    for _ in range(64):  # Newton-free fixed point of x = (1 + x)^(1/(d+1)), converges from 2
        phi = (1.0 + phi) ** (1.0 / (dims + 1))
    alpha = phi ** -np.arange(1, dims + 1, dtype=np.float64)
    shift = np.random.default_rng(seed).random(dims)
    return np.mod(shift + np.arange(1, n + 1, dtype=np.float64)[:, None] * alpha, 1.0)


def direction_pairs(n: int, seed: int = 0, *, max_theta_i: float = DEFAULT_MAX_THETA,
                    max_theta_o: float = DEFAULT_MAX_THETA, isotropic: bool = False):
    """Quasi-random direction pairs uniform in solid angle within two cones about the normal.

    Arguments:
        n: number of pairs.
        seed: seed of the sequence's random shift.
        max_theta_i, max_theta_o: the cones' half-angles, radians.
        isotropic: fix φi = 0 and draw the other three coordinates.

    Returns:
        (theta_i, phi_i, theta_o, phi_o), each (n,), radians, φ in [−π, π).
    """
    points = _kronecker(n, 3 if isotropic else 4, seed)
    u_i, u_o, v_o = points[:, 0], points[:, 1], points[:, 2]
    theta_i, theta_o = _cone_polar(u_i, max_theta_i), _cone_polar(u_o, max_theta_o)
    phi_o = 2.0 * math.pi * v_o - math.pi
    phi_i = np.zeros(n) if isotropic else 2.0 * math.pi * points[:, 3] - math.pi
    return theta_i, phi_i, theta_o, phi_o


def _ggx_half_density(cos_h, alpha: float) -> np.ndarray:
    """D(h) cos θh of the GGX distribution (Walter et al. 2007, eq. 33): the density of half vectors h per unit
    solid angle that `_peak_pairs` draws."""
    c2 = np.clip(cos_h, 1e-12, 1.0) ** 2
    a2 = alpha * alpha
    return a2 * np.sqrt(c2) / (math.pi * (c2 * (a2 - 1.0) + 1.0) ** 2)


def _peak_pairs(points: np.ndarray, alpha: float, max_theta_i: float, isotropic: bool):
    """Pairs whose ωi is uniform in its cone and whose ωo is the mirror of ωi about a half vector h drawn from
    GGX of roughness ``alpha`` (θh = atan(α √(u/(1−u))), Walter et al. 2007, eq. 35-36): dense about the
    specular direction, where the peaks of glossy materials are. Returns unit vectors ωi, ωo (n, 3)."""
    theta_i = _cone_polar(points[:, 0], max_theta_i)
    phi_i = np.zeros(len(points)) if isotropic else 2.0 * math.pi * points[:, 3] - math.pi
    theta_h = np.arctan(alpha * np.sqrt(points[:, 1] / np.maximum(1.0 - points[:, 1], 1e-300)))
    h = unit_vectors(theta_h, 2.0 * math.pi * points[:, 2] - math.pi)
    wi = unit_vectors(theta_i, phi_i)
    return wi, 2.0 * np.sum(wi * h, axis=1)[:, None] * h - wi


def importance_pairs(n: int, seed: int = 0, *, max_theta_i: float = DEFAULT_MAX_THETA,
                     max_theta_o: float = DEFAULT_MAX_THETA, isotropic: bool = False,
                     peaks: tuple = PEAK_ROUGHNESS, peak_fraction: float = PEAK_FRACTION):
    """Direction pairs and weights whose weighted mean of any g(ωi, ωo) estimates the mean of g over pairs
    uniform in solid angle within the two cones (`direction_pairs`), with far less variance where g has a
    specular peak: a share ``1 − peak_fraction`` of the pairs is uniform, the rest mirror ωi about GGX half
    vectors of each roughness in ``peaks`` (equal shares). Each pair's weight is the uniform density over the
    mixture's density at it, p_u / Σₖ cₖ pₖ (the balance heuristic of multiple importance sampling, Veach &
    Guibas 1995, eq. 9); the density of ωo mirrored about h is D(h) cos θh / (4 ωo·h) (Walter et al. 2007,
    eq. 14). Pairs whose ωo leaves its cone are dropped (the estimate is over the cone, where they count 0).

    Arguments:
        n: number of pairs drawn (a few of the peaks' are dropped).
        seed: seed of the sequences' random shifts.
        max_theta_i, max_theta_o, isotropic: as `direction_pairs`.
        peaks: the GGX roughnesses of the peak components; ``()`` gives `direction_pairs` with weights 1.
        peak_fraction: the share of the pairs drawn about the specular direction.

    Returns:
        (theta_i, phi_i, theta_o, phi_o, weights), radians, weights with mean close to 1.
    """
    counts = [n] if not peaks else [n - (len(peaks) * int(n * peak_fraction / len(peaks)))] + \
        [int(n * peak_fraction / len(peaks))] * len(peaks)
    shares = np.array(counts, dtype=np.float64) / sum(counts)
    theta_i, phi_i, theta_o, phi_o = direction_pairs(counts[0], seed, max_theta_i=max_theta_i,
                                                     max_theta_o=max_theta_o, isotropic=isotropic)
    wi, wo = [unit_vectors(theta_i, phi_i)], [unit_vectors(theta_o, phi_o)]
    for k, alpha in enumerate(peaks):
        a, b = _peak_pairs(_kronecker(counts[k + 1], 3 if isotropic else 4, seed + 1 + k), alpha, max_theta_i,
                           isotropic)
        wi.append(a)
        wo.append(b)
    wi, wo = np.concatenate(wi), np.concatenate(wo)
    inside = wo[:, 2] >= math.cos(max_theta_o)
    wi, wo = wi[inside], wo[inside]
    uniform = 1.0 / (2.0 * math.pi * (1.0 - math.cos(max_theta_o)))
    h = wi + wo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    jacobian = 1.0 / (4.0 * np.maximum(np.sum(wo * h, axis=1), 1e-12))
    mixture = shares[0] * uniform + sum(share * _ggx_half_density(h[:, 2], alpha) * jacobian
                                        for share, alpha in zip(shares[1:], peaks))
    theta_i, phi_i = vector_angles(wi)
    theta_o, phi_o = vector_angles(wo)
    return theta_i, phi_i, theta_o, phi_o, uniform / mixture


def over_directions(lookup: Callable, *, pairs: int, seed: int, max_theta_i: float, max_theta_o: float,
                    isotropic: bool, channels, meta: dict) -> Measurements:
    """A tabulated BRDF's lookup at `importance_pairs`, as `Measurements` weighted by their importance weights.

    Arguments:
        lookup: f_r of the table at (theta_i, phi_i, theta_o, phi_o), shape (n, channels), NaN where missing.
        pairs, seed, max_theta_i, max_theta_o, isotropic: as `importance_pairs`.
        channels: the channels' names.
        meta: the file's metadata; ``"sampling"`` is added (what was drawn, so that a reader can redraw it).

    Returns:
        `Measurements` whose weighted sums estimate integrals over directions (module docstring).
    """
    theta_i, phi_i, theta_o, phi_o, weights = importance_pairs(pairs, seed, max_theta_i=max_theta_i,
                                                               max_theta_o=max_theta_o, isotropic=isotropic)
    values = np.asarray(lookup(theta_i, phi_i, theta_o, phi_o), dtype=np.float64)
    meta = dict(meta)
    meta["sampling"] = {
        "kind": "directions",
        "pairs": int(pairs),
        "seed": int(seed),
        "max_theta_i_deg": round(math.degrees(max_theta_i), 6),
        "max_theta_o_deg": round(math.degrees(max_theta_o), 6),
        "isotropic": bool(isotropic),
        "peaks": {"roughness": list(PEAK_ROUGHNESS), "fraction": PEAK_FRACTION},
        "rule": "the file's own interpolation at shifted Kronecker (R_d) direction pairs, half uniform in solid "
                "angle, half mirrored about GGX half vectors; weights = uniform density / mixture density "
                "(docs/formats.md)",
    }
    return Measurements(theta_i, phi_i, theta_o, phi_o, values, weights=weights, channels=channels, meta=meta)
