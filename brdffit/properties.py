"""Physical properties of a model: directional albedo, reciprocity, isotropy and energy conservation.

Definitions (docs/conventions.md, docs/properties.md):

- directional albedo a(ωi) = ∫_{H+} f_r(ωi, ωo) cosθo dωo, the fraction of light arriving from ωi that is
  reflected into the upper hemisphere;
- reciprocity (Helmholtz): f_r(ωi, ωo) = f_r(ωo, ωi);
- isotropy: f_r is unchanged when both azimuths are rotated by the same angle;
- energy conservation: a(ωi) <= 1 for every ωi (and every channel).

The albedo quadrature works in half-vector space, where every specular lobe of the library peaks at the normal
(Walter et al. 2007 use the same change of variables to sample microfacet models):

    ωo = 2 (ωi·h) h − ωi,   dωo = 4 (ωi·h) dωh,
    a(ωi) = ∫ f_r(ωi, ωo(h)) cosθo 4 (ωi·h) sinθh dθh dφh.

With ωi at (θi, φi) and h at (θh, φi + φ), cosθo = 2 (ωi·h) cosθh − cosθi works out to R cos(2θh − ψ) with
ψ(φ) = atan2(sinθi cosφ, cosθi), so for each relative azimuth φ the reflected direction is above the horizon
exactly for θh < θmax(φ) = π/4 + ψ(φ)/2 (and ωi·h > 0 holds there too). The horizon is therefore the end of each
θh interval, and a lobe that jumps or has an infinite slope there (Ward, Dür, shadowing "none") costs no accuracy.

- θh: Gauss-Legendre in t ∈ [0, 1] with θh = θmax(φ) t², which puts many nodes near the normal where the
  specular lobes peak (a lobe of width 0.02 rad about the normal gets ~30 nodes at the default resolution).
- φ: two half circles [0, π] and [π, 2π] (relative to φi), each Gauss-Legendre in u ∈ [−1, 1] through the sinh
  map φ = π/2 + σ sinh(A u), σ = cotθi, A = asinh(π/(2σ)). Near grazing incidence θmax(φ) drops from about π/4
  to about 0 within |φ − π/2| ~ cotθi; the map clusters nodes there with that scale (and is close to uniform at
  normal incidence, where σ is large).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax.numpy as jnp
import numpy as np

from .arrays import to_device, traced
from .programs import Program
from .geometry import spherical_to_vector
from .models import Model, evaluate_dirs

__all__ = [
    "directional_albedo",
    "max_albedo",
    "reciprocity_error",
    "isotropy_error",
    "is_energy_conserving",
    "check",
    "PropertyReport",
    "DEFAULT_RESOLUTION",
    "ANISOTROPIC_AZIMUTH_RESOLUTION",
    "ENERGY_THETA_I",
    "ANISOTROPIC_PHI_I",
    "RECIPROCITY_TOL",
    "ISOTROPY_TOL",
    "direction_pairs",
    "scan_albedo",
    "judged_at_the_view",
    "PLAUSIBILITY_THETA_I",
]

# Gauss-Legendre nodes in θh per half-vector azimuth, and azimuth nodes per half circle.
DEFAULT_RESOLUTION = 128
# Azimuth nodes per half circle for an anisotropic model (when the resolution is left to its default): an
# elliptical lobe of widths αx << αy is a thin sliver in azimuth, about 10·αy/αx nodes are needed.
ANISOTROPIC_AZIMUTH_RESOLUTION = 512

# The θi grid on which energy conservation is judged: 0 to 89.5 degrees in steps of 0.5 degree.
ENERGY_THETA_I = np.deg2rad(np.arange(0.0, 89.75, 0.5))
# The φi grid added for anisotropic models: 0 to 90 degrees in steps of 22.5 degrees.
ANISOTROPIC_PHI_I = np.deg2rad(np.arange(0.0, 90.1, 22.5))

# Number of (θi × node × channel) values evaluated in one jitted call: a call holds a few dozen arrays of this size,
# about 16 MB each, so the memory stays well under 1 GB whatever the resolution and channel count.
_CHUNK_VALUES = 2**21

# Bounds on σ = cotθi in the azimuth map: σ -> ∞ at normal incidence (the map is then uniform to 1e-7).
_SIGMA_MIN, _SIGMA_MAX = 1e-9, 1e6


@Program  # kept on disk like the fit's programs: a warm report loads it without tracing
def _albedo_chunk(model: Model, theta_i, phi_i, t, wt, u, wu, centre):
    """Albedo contribution of some azimuth nodes for a chunk of incidence directions.

    theta_i, phi_i have shape (B,); t, wt the θh rule on [0, 1], shape (T,); u, wu, centre the azimuth nodes on
    [−1, 1] with the centre (π/2 or 3π/2) of their half circle, shape (S,). Returns (B, C).
    """
    wi, wo, weight = _albedo_nodes(theta_i, phi_i, t, wt, u, wu, centre)
    f = evaluate_dirs(model, jnp.broadcast_to(wi, wo.shape), wo)  # (B, S, T, C)
    albedo = jnp.einsum("bst,bstc->bc", weight, f)
    # No light arrives from at or below the horizon: the albedo is zero there (f_r needs cosθi > 0).
    return jnp.where((jnp.cos(theta_i) > 1e-12)[:, None], albedo, 0.0)


def _albedo_nodes(theta_i, phi_i, t, wt, u, wu, centre, xp=jnp):
    """The quadrature of `_albedo_chunk` (arguments the same; ``xp`` the array module): ``(wi (B, 1, 1, 3), wo
    (B, S, T, 3), weight (B, S, T))`` with a(ωi) = Σ weight · f_r(ωi, wo)."""
    ti = theta_i[:, None, None]  # (B, 1, 1): chunk × azimuth node × θh node
    cos_i, sin_i = xp.cos(ti), xp.sin(ti)
    sigma = xp.clip(cos_i / xp.maximum(sin_i, _SIGMA_MIN), _SIGMA_MIN, _SIGMA_MAX)
    a = xp.arcsinh(0.5 * math.pi / sigma)

    # Azimuth of h relative to φi, φ = centre + σ sinh(A u), with weights dφ/du · w_u: (B, S, 1).
    uu = u[None, :, None]
    phi = centre[None, :, None] + sigma * xp.sinh(a * uu)
    w_phi = wu[None, :, None] * sigma * a * xp.cosh(a * uu)

    # θh in [0, θmax(φ)] through θh = θmax t², weights dθh/dt · w_t.
    psi = xp.arctan2(sin_i * xp.cos(phi), cos_i)
    theta_max = 0.25 * math.pi + 0.5 * psi  # (B, S, 1)
    tt = t[None, None, :]
    theta_h = theta_max * tt * tt  # (B, S, T)
    w_theta = wt[None, None, :] * 2.0 * theta_max * tt

    h = spherical_to_vector(theta_h, phi + phi_i[:, None, None], xp=xp)  # (B, S, T, 3)
    wi = spherical_to_vector(theta_i, phi_i, xp=xp)[:, None, None, :]  # (B, 1, 1, 3)
    i_dot_h = xp.sum(wi * h, axis=-1)
    wo = 2.0 * i_dot_h[..., None] * h - wi  # the reflection of ωi about h
    cos_o = wo[..., 2]

    # dωo = 4 (ωi·h) sinθh dθh dφ, times the cosine cosθo of the albedo integrand.
    weight = w_phi * w_theta * xp.sin(theta_h) * 4.0 * xp.maximum(i_dot_h, 0.0) * xp.maximum(cos_o, 0.0)
    return wi, wo, weight


def _gauss_legendre(n: int, lower: float, upper: float):
    x, w = np.polynomial.legendre.leggauss(n)
    half = 0.5 * (upper - lower)
    return lower + half * (x + 1.0), half * w


def _anisotropic(model: Model) -> bool:
    # Measured rather than declared: an anisotropic lobe at equal widths is isotropic. Traced parameters cannot be
    # measured; the finer azimuth rule is then the safe choice.
    return traced(model) or isotropy_error(model, n=3000) > ISOTROPY_TOL


def _resolution_pair(resolution) -> tuple[int, int]:
    # ``resolution`` is n or (n_theta, n_phi): θh nodes per azimuth and azimuth nodes per half circle.
    pair = tuple(resolution) if isinstance(resolution, (tuple, list)) else (resolution, resolution)
    ok = len(pair) == 2 and all(
        not isinstance(r, bool) and isinstance(r, (int, np.integer)) and r >= 8 for r in pair)
    if not ok:
        raise ValueError(f"resolution must be an integer >= 8 or a pair of them (θh nodes, azimuth nodes per half "
                         f"circle), got {resolution!r}")
    return int(pair[0]), int(pair[1])


def directional_albedo(model: Model, theta_i, phi_i=0.0, *, resolution: int | tuple[int, int] | None = None):
    r"""Directional albedo a(ωi) = ∫_{H+} f_r(ωi, ωo) cosθo dωo, by deterministic quadrature in half-vector space.

    The integral is taken with ωi at polar angle ``theta_i`` and azimuth ``phi_i``. For an isotropic model the
    albedo does not depend on φi and the default ``phi_i = 0`` is all there is; for an anisotropic lobe
    (``ward-aniso``, ``ashikhmin-shirley-aniso``, ``lafortune(anisotropic=True)``) pass the azimuth(s) of
    interest. The quadrature is described in the module docstring and in docs/properties.md; at the default
    resolution it is accurate to better than 1e-3 (absolute) for every lobe of the library with its default and
    typical parameters, including peaks as narrow as Beckmann/GGX/Ward widths of 0.02 and Phong exponents of 1000,
    for θi up to 89.5°.

    Arguments:
        model: the `Model`.
        theta_i: polar angle(s) of the direction to the light, radians, scalar or 1-d, in [0, π/2]. The albedo is
            0 for θi = π/2 (no light above the horizon).
        phi_i: azimuth(s) of the direction to the light, radians, broadcastable with ``theta_i``.
        resolution: n, the Gauss-Legendre nodes in θh per azimuth and the azimuth nodes per half circle (the
            integrand is evaluated at 2 n² half vectors per θi), or a pair (n_theta, n_phi) to set them apart.
            Doubling it estimates the quadrature error. Default (None): `DEFAULT_RESOLUTION` in both, with
            `ANISOTROPIC_AZIMUTH_RESOLUTION` azimuth nodes instead when the model is anisotropic (its
            `isotropy_error` on 3000 pairs exceeds `ISOTROPY_TOL`, or its parameters are being traced by JAX):
            that keeps Ward lobes with αy/αx up to ~50 within 1e-4 (docs/properties.md).

    Returns:
        The albedo, shape ``broadcast(theta_i, phi_i).shape + (channels,)``: ``(N, channels)`` for 1-d input and
        ``(channels,)`` for scalars.

    Raises:
        ValueError: if a θi is outside [0, π/2] or not finite, or the resolution is not an integer >= 8 (or a
        pair of them).
    """
    theta_i, phi_i = np.broadcast_arrays(np.asarray(theta_i, dtype=float), np.asarray(phi_i, dtype=float))
    shape = theta_i.shape
    if len(shape) > 1:
        raise ValueError(f"theta_i and phi_i must be scalars or 1-d, got shape {shape}")
    theta_flat, phi_flat = theta_i.reshape(-1), phi_i.reshape(-1)
    if not (np.all(np.isfinite(theta_flat)) and np.all(np.isfinite(phi_flat))):
        raise ValueError("theta_i and phi_i must be finite")
    if np.any((theta_flat < 0.0) | (theta_flat > 0.5 * math.pi + 1e-12)):
        raise ValueError(f"theta_i must lie in [0, π/2] radians, got values in [{theta_flat.min()}, "
                         f"{theta_flat.max()}]; did you pass degrees?")
    if resolution is None:
        resolution = (DEFAULT_RESOLUTION, ANISOTROPIC_AZIMUTH_RESOLUTION if _anisotropic(model) else DEFAULT_RESOLUTION)
    n_theta, n_phi = _resolution_pair(resolution)
    t, wt = (to_device(x) for x in _gauss_legendre(n_theta, 0.0, 1.0))
    u_half, wu_half = _gauss_legendre(n_phi, -1.0, 1.0)
    # The azimuth nodes of both half circles, split into slabs of `slab` nodes (zero-weight padding), and the θi
    # into chunks of `chunk`, so that one call evaluates at most about _CHUNK_VALUES values.
    per_azimuth = n_theta * max(model.channels, 4)
    slab = int(min(2 * n_phi, max(1, _CHUNK_VALUES // per_azimuth)))
    chunk = max(1, _CHUNK_VALUES // (slab * per_azimuth))
    n_slabs = -(-2 * n_phi // slab)
    u = np.zeros(n_slabs * slab)
    wu = np.zeros(n_slabs * slab)
    centre = np.zeros(n_slabs * slab)
    u[:2 * n_phi] = np.concatenate([u_half, u_half])
    wu[:2 * n_phi] = np.concatenate([wu_half, wu_half])
    centre[:2 * n_phi] = np.repeat([0.5 * math.pi, 1.5 * math.pi], n_phi)
    count = theta_flat.size
    padded = -(-count // chunk) * chunk
    theta_pad = np.zeros(padded)
    phi_pad = np.zeros(padded)
    theta_pad[:count], phi_pad[:count] = theta_flat, phi_flat
    # The chunks' sums on the host unless the model is traced (eager device additions compiled a program each).
    xp, pieces = (jnp if traced(model) else np), []
    for start in range(0, padded, chunk):
        theta_chunk, phi_chunk = to_device(theta_pad[start:start + chunk]), to_device(phi_pad[start:start + chunk])
        total = 0.0
        for k in range(0, n_slabs * slab, slab):
            nodes = (to_device(x[k:k + slab]) for x in (u, wu, centre))
            total = total + xp.asarray(_albedo_chunk(model, theta_chunk, phi_chunk, t, wt, *nodes))
        pieces.append(total)
    albedo = xp.concatenate(pieces, axis=0)[:count]
    return albedo.reshape(shape + (model.channels,))


# ----------------------------------------------------------------------------------------------------------------
# Energy conservation


def max_albedo(model: Model, *, theta_i=None, phi_i=None, resolution=None):
    """The largest directional albedo of each channel over a grid of incidence directions, and where it occurs.

    Arguments:
        model: the `Model`.
        theta_i: the polar angles to scan (radians, 1-d); default `ENERGY_THETA_I` (0 to 89.5° in 0.5° steps).
        phi_i: the azimuths to scan (radians, 1-d). Default: 0 for an isotropic model, and `ANISOTROPIC_PHI_I`
            (0 to 90° in 22.5° steps) for an anisotropic one. Every anisotropic lobe of the library is symmetric
            about the planes through the normal and the tangent or the bitangent, so its albedo takes all its
            values for φi in [0, π/2].
        resolution: passed to `directional_albedo` (default: chosen there, finer in azimuth for anisotropic
            models).

    Returns:
        ``(albedo, theta, phi)``: NumPy arrays of shape ``(channels,)`` with, per channel, the largest albedo and
        the θi and φi (radians) at which it occurs.
    """
    theta_grid = ENERGY_THETA_I if theta_i is None else np.atleast_1d(np.asarray(theta_i, dtype=float))
    if phi_i is None or resolution is None:
        anisotropic = _anisotropic(model)
        if phi_i is None:
            phi_i = ANISOTROPIC_PHI_I if anisotropic else np.zeros(1)
        if resolution is None:
            resolution = (DEFAULT_RESOLUTION, ANISOTROPIC_AZIMUTH_RESOLUTION if anisotropic else DEFAULT_RESOLUTION)
    phi_grid = np.atleast_1d(np.asarray(phi_i, dtype=float))
    theta_all = np.repeat(theta_grid, phi_grid.size)
    phi_all = np.tile(phi_grid, theta_grid.size)
    albedo = np.asarray(directional_albedo(model, theta_all, phi_all, resolution=resolution))  # (N, C)
    where = np.argmax(albedo, axis=0)
    channels = np.arange(albedo.shape[1])
    return albedo[where, channels], theta_all[where], phi_all[where]


def is_energy_conserving(model: Model, tol: float = 1e-3, *, theta_i=None, phi_i=None,
                         resolution=None) -> bool:
    """Whether the directional albedo stays at or below 1 + ``tol`` for every channel on a grid of θi.

    A passive surface cannot reflect more than it receives: a(ωi) <= 1 for every ωi. The check is made on the
    grid of `max_albedo` (by default θi from 0 to 89.5° in 0.5° steps; several azimuths for anisotropic models).
    Some lobes diverge only as θi -> 90° (Ward's albedo grows like 1/√cosθi); pass a denser ``theta_i`` to probe
    closer to grazing.

    Arguments:
        model: the `Model`.
        tol: allowance above 1, at least the quadrature accuracy (1e-3 at the default resolution).
        theta_i, phi_i, resolution: see `max_albedo`.

    Returns:
        True if every channel's maximum albedo is <= 1 + tol.
    """
    albedo, _, _ = max_albedo(model, theta_i=theta_i, phi_i=phi_i, resolution=resolution)
    return bool(np.all(albedo <= 1.0 + tol))


# ----------------------------------------------------------------------------------------------------------------
# Reciprocity and isotropy

# Errors at or below these are round-off: the model is called reciprocal / isotropic in a `PropertyReport`.
RECIPROCITY_TOL = 1e-8
ISOTROPY_TOL = 1e-8

# Differences are taken relative to max(|f|, floor) with floor this fraction of the channel's largest |f| in the
# sample: far in a lobe's tail only absolute round-off is left (the toon lobes' logistic step, computed as
# (1 + tanh(u/2))/2, has an absolute error of ~1e-17 where its value is ~1e-13), and that must not read as a
# relative error of O(1e-4). Any real asymmetry shows up at values above the floor.
_RELATIVE_FLOOR = 1e-6

DEFAULT_PAIRS = 30_000

# Smallest cosθ of the random directions (θ <= 89.94°).
_MIN_COS = 1e-3


def _uniform_hemisphere(rng, n):
    # Uniform in solid angle over the hemisphere less a band of _MIN_COS at the horizon: cosθ uniform.
    cos_t = rng.uniform(_MIN_COS, 1.0, n)
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    sin_t = np.sqrt(1.0 - cos_t * cos_t)
    return np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=-1)


def _perturb(rng, w, min_angle=1e-3, max_angle=1.0):
    # Tilt each w by an angle log-uniform in [min_angle, max_angle] towards a random perpendicular direction.
    helper = np.where(np.abs(w[:, 2:3]) < 0.9, np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]))
    e1 = np.cross(w, helper)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(w, e1)
    angle = np.exp(rng.uniform(np.log(min_angle), np.log(max_angle), len(w)))[:, None]
    beta = rng.uniform(0.0, 2.0 * np.pi, len(w))[:, None]
    return np.cos(angle) * w + np.sin(angle) * (np.cos(beta) * e1 + np.sin(beta) * e2)


def direction_pairs(n: int = DEFAULT_PAIRS, seed: int = 0):
    """Seeded random pairs of directions above the horizon, for the reciprocity and isotropy checks.

    A third of the pairs are independent and uniform over the hemisphere; a third put ωo near the mirror
    direction of ωi and a third near ωi itself (tilted by an angle log-uniform in [1e-3, 1] rad), so that sharp
    specular and retro-reflective lobes are probed where they are not zero. Every direction has cosθ >= 1e-3
    (θ <= 89.94°): closer to the horizon, round-off alone makes quantities such as ωi·h and ωo·h (equal in exact
    arithmetic) differ by more than 1e-10 relative. A tilted ωo that falls below that band is reflected back
    above it.

    Arguments:
        n: number of pairs.
        seed: seed of NumPy's default generator.

    Returns:
        ``(wi, wo)``, two arrays of shape ``(n, 3)`` of unit vectors with z >= 1e-3.
    """
    if n < 3:
        raise ValueError(f"need at least 3 direction pairs, got {n}")
    rng = np.random.default_rng(seed)
    k = n // 3
    wi = _uniform_hemisphere(rng, n)
    wo = np.concatenate([
        _uniform_hemisphere(rng, n - 2 * k),
        _perturb(rng, wi[n - 2 * k:n - k] * np.array([-1.0, -1.0, 1.0])),
        _perturb(rng, wi[n - k:]),
    ])
    # Reflect below-horizon directions back up, keep z >= _MIN_COS and renormalise.
    xy = wo[:, :2]
    z = np.maximum(np.abs(wo[:, 2]), _MIN_COS)
    xy = xy * (np.sqrt(1.0 - z * z) / np.maximum(np.linalg.norm(xy, axis=-1), 1e-300))[:, None]
    return wi, np.concatenate([xy, z[:, None]], axis=-1)


def _relative_difference(a, b) -> float:
    # max |a − b| / max(|a|, |b|, floor), the floor _RELATIVE_FLOOR times the channel's largest |f| in the sample.
    a, b = np.asarray(a), np.asarray(b)
    abs_a, abs_b = np.abs(a), np.abs(b)
    scale = np.maximum(np.max(abs_a, axis=0), np.max(abs_b, axis=0))  # (channels,)
    floor = np.maximum(_RELATIVE_FLOOR * scale, np.finfo(float).tiny)
    return float(np.max(np.abs(a - b) / np.maximum(np.maximum(abs_a, abs_b), floor)))


def reciprocity_error(model: Model, n: int = DEFAULT_PAIRS, seed: int = 0) -> float:
    r"""Largest relative violation of Helmholtz reciprocity f_r(ωi, ωo) = f_r(ωo, ωi).

    Computes max |f_r(ωi, ωo) − f_r(ωo, ωi)| / max(|f_r(ωi, ωo)|, |f_r(ωo, ωi)|, floor) over the pairs of
    `direction_pairs` and all channels; the floor is 1e-6 times the channel's largest |f_r| in the sample. A reciprocal
    model gives round-off (~1e-15); a non-reciprocal one (``toon-diffuse``) gives O(1).

    Arguments:
        model: the `Model`.
        n: number of direction pairs.
        seed: seed of the pairs.

    Returns:
        The largest relative difference (a float >= 0).
    """
    wi, wo = (jnp.asarray(w) for w in direction_pairs(n, seed))
    return _relative_difference(evaluate_dirs(model, wi, wo), evaluate_dirs(model, wo, wi))


def _rotate_z(w, angle):
    # Rotation about the normal by ``angle`` (one angle per row of w).
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * w[:, 0] - s * w[:, 1], s * w[:, 0] + c * w[:, 1], w[:, 2]], axis=-1)


def isotropy_error(model: Model, n: int = DEFAULT_PAIRS, seed: int = 0) -> float:
    r"""Largest relative change of f_r when both azimuths are rotated by the same angle.

    Computes max |f_r(Rωi, Rωo) − f_r(ωi, ωo)| / max(|f_r(Rωi, Rωo)|, |f_r(ωi, ωo)|, floor), R a rotation about
    the normal by an angle drawn uniformly from [0, 2π) for each pair of `direction_pairs`; the floor is as in
    `reciprocity_error`. An isotropic model gives round-off; an anisotropic one O(1) where its lobes are.

    Arguments:
        model: the `Model`.
        n: number of direction pairs.
        seed: seed of the pairs and of the rotation angles.

    Returns:
        The largest relative change (a float >= 0).
    """
    wi, wo = direction_pairs(n, seed)
    angle = np.random.default_rng([seed, 1]).uniform(0.0, 2.0 * np.pi, len(wi))
    f = evaluate_dirs(model, to_device(wi), to_device(wo))
    f_rot = evaluate_dirs(model, to_device(_rotate_z(wi, angle)), to_device(_rotate_z(wo, angle)))
    return _relative_difference(f, f_rot)


# ----------------------------------------------------------------------------------------------------------------
# The report


@dataclasses.dataclass(frozen=True)
class PropertyReport:
    """The physical properties of one model, as `check` measures them.

    Attributes:
        spec: the model's spec string.
        channels: number of channels.
        reciprocity_error: `reciprocity_error` of the model.
        isotropy_error: `isotropy_error` of the model.
        max_albedo: the largest directional albedo over channels and the θi grid.
        theta_i_max: the θi (radians) where it occurs.
        phi_i_max: the φi (radians) where it occurs (0 unless the model is anisotropic).
        channel_max_albedo: the largest albedo of each channel.
        tol: the energy-conservation allowance used.
        declared_reciprocal: whether every lobe declares itself reciprocal (`Model.reciprocal`).
    """

    spec: str
    channels: int
    reciprocity_error: float
    isotropy_error: float
    max_albedo: float
    theta_i_max: float
    phi_i_max: float
    channel_max_albedo: tuple[float, ...]
    tol: float
    declared_reciprocal: bool

    @property
    def reciprocal(self) -> bool:
        """True if the reciprocity error is round-off (<= `RECIPROCITY_TOL`)."""
        return self.reciprocity_error <= RECIPROCITY_TOL

    @property
    def isotropic(self) -> bool:
        """True if the isotropy error is round-off (<= `ISOTROPY_TOL`)."""
        return self.isotropy_error <= ISOTROPY_TOL

    @property
    def energy_conserving(self) -> bool:
        """True if the largest albedo is <= 1 + tol."""
        return self.max_albedo <= 1.0 + self.tol

    def __str__(self) -> str:
        def verdict(ok, yes, no):
            return yes if ok else no

        declared = "" if self.reciprocal == self.declared_reciprocal else (
            "  (declared reciprocal)" if self.declared_reciprocal else "  (declared not reciprocal)")
        where = f"θi = {math.degrees(self.theta_i_max):.1f}°"
        if not self.isotropic and self.theta_i_max > 0.0:  # at normal incidence every φi is the same direction
            where += f", φi = {math.degrees(self.phi_i_max):.1f}°"
        albedos = ", ".join(f"{a:.4f}" for a in self.channel_max_albedo)
        return "\n".join([
            f"{self.spec} ({self.channels} channel{'s' if self.channels != 1 else ''})",
            f"  reciprocity error  {self.reciprocity_error:9.2e}  "
            f"{verdict(self.reciprocal, 'reciprocal', 'NOT reciprocal')}{declared}",
            f"  isotropy error     {self.isotropy_error:9.2e}  {verdict(self.isotropic, 'isotropic', 'anisotropic')}",
            f"  max albedo         {self.max_albedo:9.4f}  at {where}: "
            f"{verdict(self.energy_conserving, 'energy conserving', 'NOT energy conserving')} "
            f"(limit 1 + {self.tol:g}; per channel {albedos})",
        ])


def check(model: Model, *, tol: float = 1e-3, n: int = DEFAULT_PAIRS, seed: int = 0, theta_i=None,
          resolution=None) -> PropertyReport:
    """Measure reciprocity, isotropy and energy conservation of a model.

    Arguments:
        model: the `Model`.
        tol: energy-conservation allowance (see `is_energy_conserving`).
        n, seed: direction pairs of `reciprocity_error` and `isotropy_error`.
        theta_i: θi grid of `max_albedo` (default `ENERGY_THETA_I`).
        resolution: albedo quadrature resolution.

    Returns:
        A `PropertyReport`; ``print(report)`` gives a readable summary.
    """
    recip = reciprocity_error(model, n=n, seed=seed)
    iso = isotropy_error(model, n=n, seed=seed)
    anisotropic = iso > ISOTROPY_TOL
    if resolution is None:
        resolution = (DEFAULT_RESOLUTION, ANISOTROPIC_AZIMUTH_RESOLUTION if anisotropic else DEFAULT_RESOLUTION)
    phi_grid = ANISOTROPIC_PHI_I if anisotropic else np.zeros(1)
    albedo, theta, phi = max_albedo(model, theta_i=theta_i, phi_i=phi_grid, resolution=resolution)
    best = int(np.argmax(albedo))
    return PropertyReport(
        spec=model.spec,
        channels=model.channels,
        reciprocity_error=recip,
        isotropy_error=iso,
        max_albedo=float(albedo[best]),
        theta_i_max=float(theta[best]),
        phi_i_max=float(phi[best]),
        channel_max_albedo=tuple(float(a) for a in albedo),
        tol=float(tol),
        declared_reciprocal=bool(model.reciprocal),
    )


# ----------------------------------------------------------------------------------------------------------------
# The albedo scan of the plausibility checks (`brdffit.plausibility`)

# The incidence directions of `scan_albedo`: θi 0 to 85° in 5° steps, then 87.5° and 89°, each at φi = 0 and 90°
# (an anisotropic lobe of the library is symmetric about those planes and takes its extremes near them).
PLAUSIBILITY_THETA_I = np.deg2rad(np.r_[np.arange(0.0, 86.0, 5.0), 87.5, 89.0])
PLAUSIBILITY_PHI_I = np.deg2rad([0.0, 90.0])
# 2 n² half vectors per direction: within 3e-4 of the albedo at 128 for every lobe tried, Cook-Torrance m = 0.02
# (the sharpest) included.
PLAUSIBILITY_RESOLUTION = 64


def judged_at_the_view(model: Model) -> bool:
    """Whether the energy of ``model`` is judged by its albedo at each view (`scan_albedo` with ``view``) rather
    than at each incidence: so for a model that is not reciprocal (a renderer's layered material, MaterialX's
    OpenPBR Surface or Cycles' Principled BSDF, weights the layer beneath by the layer's albedo at the view, which
    keeps the albedo at each view, the one a renderer tracing from the camera multiplies by, within 1, while grazing
    light can come back brighter). The plausibility check (`brdffit.plausibility`) and the report's albedo curve
    (`brdffit.report.figures.albedo_curve`) both follow it."""
    return not model.reciprocal


def scan_albedo(model: Model, theta_i=PLAUSIBILITY_THETA_I, phi_i=PLAUSIBILITY_PHI_I,
                resolution: int = PLAUSIBILITY_RESOLUTION, view: bool = False) -> np.ndarray:
    """The directional albedo on a grid of incidence directions, quickly: ``(len(theta_i), len(phi_i), C)``.

    The quadrature of `directional_albedo`, with its nodes computed on the host in NumPy (compiled, they would add
    a compilation to a first fit's summary) and the model evaluated by `brdffit.evaluate_dirs` (compiled once per
    model structure: a far smaller program than the whole quadrature compiled per model). Summaries and reports use
    it (`brdffit.plausibility.plausibility`).

    With ``view``, the grid's directions are the viewer's and the integral runs over the light's:
    ∫ f_r(ωi, ωo) cosθi dωi at each ωo (`judged_at_the_view`); for a reciprocal model the two are the same.
    """
    theta_i, phi_i = (np.asarray(x, dtype=float).reshape(-1) for x in (theta_i, phi_i))
    fixed, wo, weight, horizon = _scan_rule(theta_i.tobytes(), phi_i.tobytes(), int(resolution))
    f = np.asarray(evaluate_dirs(model, wo, fixed) if view else evaluate_dirs(model, fixed, wo))
    albedo = np.einsum("bst,bstc->bc", weight, f)
    albedo[horizon] = 0.0
    return albedo.reshape(theta_i.size, phi_i.size, model.channels)


@functools.lru_cache(maxsize=4)
def _scan_rule(theta_i: bytes, phi_i: bytes, resolution: int) -> tuple:
    """The quadrature of `scan_albedo` for its grid of incidences (the float64 bytes of its θi and φi), which no model
    changes: computed once a process (a selection checks several candidates, then the summary and the report the
    chosen one; the nodes took more time than the model's evaluation at them).

    Returns:
        ``(wi, wo, weight, horizon)``, read-only: the fixed direction broadcast to every node and the integrated one
        ``(B, S, T, 3)``, the weights ``(B, S, T)`` and the incidences at or below the horizon ``(B,)``.
    """
    theta, phi = (x.reshape(-1) for x in np.meshgrid(np.frombuffer(theta_i), np.frombuffer(phi_i), indexing="ij"))
    t, wt = _gauss_legendre(resolution, 0.0, 1.0)
    u_half, wu_half = _gauss_legendre(resolution, -1.0, 1.0)
    u, wu = np.concatenate([u_half, u_half]), np.concatenate([wu_half, wu_half])
    centre = np.repeat([0.5 * math.pi, 1.5 * math.pi], resolution)
    wi, wo, weight = _albedo_nodes(theta, phi, t, wt, u, wu, centre, xp=np)
    rule = (np.ascontiguousarray(np.broadcast_to(wi, wo.shape)), wo, weight, np.cos(theta) <= 1e-12)
    for a in rule:
        a.flags.writeable = False
    return rule
