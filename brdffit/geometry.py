"""Directions in the local shading frame, the quantities models share, and safe maths.

Convention (docs/conventions.md): z is the surface normal and x the tangent; ωi points to the light and ωo to the
detector, both leaving the surface; θ is the polar angle from z and φ the azimuth from x, in radians.

The "safe" helpers keep values *and* gradients finite where the plain formula divides by zero or takes the root
of zero: at normal incidence (θ = 0, where the half vector equals the normal and every azimuth is undefined) and
at grazing angles (θ -> π/2, where cosines vanish).
"""

from __future__ import annotations

from typing import NamedTuple

from ._lazy import module

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX
jax = module("jax")


__all__ = [
    "LocalPair",
    "spherical_to_vector",
    "vector_to_spherical",
    "half_vector",
    "mirror",
    "to_half_diff",
    "from_half_diff",
    "safe_sqrt",
    "safe_div",
    "safe_normalize",
    "safe_pow",
    "logistic",
    "TINY",
]

# Smallest magnitude the safe helpers let through; far below any physically meaningful cosine.
TINY = 1e-12


def safe_sqrt(x, xp=jnp, tiny: float = TINY):
    """√x for x > ``tiny`` and 0 otherwise; the gradient is finite everywhere (0 where x <= ``tiny``). ``xp``: the
    array module (``jax.numpy``, or ``numpy`` on the host); ``tiny`` = 0 is Mitsuba's ``safe_sqrt``, √max(x, 0)."""
    positive = x > tiny
    return xp.where(positive, xp.sqrt(xp.where(positive, x, 1.0)), 0.0)


def safe_div(num, den, fallback=0.0):
    """num / den where |den| > TINY, else ``fallback``; no NaN leaks into values or gradients."""
    ok = jnp.abs(den) > TINY
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), fallback)


def safe_normalize(v, xp=jnp):
    """v / |v| along the last axis; a zero vector maps to the normal (0, 0, 1) with a finite gradient. ``xp``: the
    array module (``jax.numpy``, or ``numpy`` on the host)."""
    norm2 = xp.sum(v * v, axis=-1, keepdims=True)
    ok = norm2 > TINY * TINY
    unit = v / xp.sqrt(xp.where(ok, norm2, 1.0))
    return xp.where(ok, unit, xp.array([0.0, 0.0, 1.0], dtype=v.dtype))


def safe_pow(x, n):
    """max(0, x)^n with n > 0, written as exp(n ln x) so that d/dn is finite (0) where x <= 0."""
    positive = x > TINY
    return jnp.where(positive, jnp.exp(n * jnp.log(jnp.where(positive, x, 1.0))), 0.0)


def logistic(u):
    """The logistic function 1 / (1 + e^(-u)), accurate in relative terms in both tails (jax.nn.sigmoid)."""
    return jax.nn.sigmoid(u)


def spherical_to_vector(theta, phi, xp=jnp):
    """Unit vector(s) of polar angle θ and azimuth φ.

    Arguments:
        theta: polar angle from the normal (radians), any shape.
        phi: azimuth from the tangent x (radians), broadcastable with ``theta``.
        xp: the array module (``jax.numpy``, or ``numpy`` on the host).

    Returns:
        Array of shape ``broadcast(theta, phi).shape + (3,)``.
    """
    theta, phi = xp.broadcast_arrays(xp.asarray(theta, dtype=float), xp.asarray(phi, dtype=float))
    s = xp.sin(theta)
    return xp.stack([s * xp.cos(phi), s * xp.sin(phi), xp.cos(theta)], axis=-1)


def vector_to_spherical(w, xp=jnp):
    """Polar angle and azimuth of vector(s) ``w`` (last axis of size 3).

    Arguments:
        w: direction(s), not necessarily normalised.
        xp: the array module (``jax.numpy``, or ``numpy`` on the host).

    Returns:
        ``(theta, phi)`` with θ in [0, π] and φ in [0, 2π); φ is 0 along the normal.
    """
    w = safe_normalize(xp.asarray(w, dtype=float), xp)
    theta = xp.arccos(xp.clip(w[..., 2], -1.0, 1.0))
    phi = xp.mod(xp.arctan2(w[..., 1], w[..., 0]), 2 * xp.pi)
    return theta, phi


def half_vector(wi, wo, xp=jnp):
    """The half vector h = normalize(ωi + ωo) (Cook & Torrance 1982); ``xp`` as in `safe_normalize`."""
    return safe_normalize(wi + wo, xp)


def mirror(w):
    """Mirror reflection of ``w`` about the normal: 2 (n·w) n − w = (−wx, −wy, wz)."""
    return w * jnp.array([-1.0, -1.0, 1.0], dtype=w.dtype)


def _rotate_z(v, angle, xp=jnp):
    c, s = xp.cos(angle), xp.sin(angle)
    return xp.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1], v[..., 2]], axis=-1)


def _rotate_y(v, angle, xp=jnp):
    c, s = xp.cos(angle), xp.sin(angle)
    return xp.stack([c * v[..., 0] + s * v[..., 2], v[..., 1], -s * v[..., 0] + c * v[..., 2]], axis=-1)


def to_half_diff(theta_i, phi_i, theta_o, phi_o, xp=jnp):
    """Rusinkiewicz (1998) half/difference angles of a pair of directions.

    The difference vector d is ωi expressed in a frame where the half vector h is the pole:
    d = Rot_y(−θh) Rot_z(−φh) ωi (Rusinkiewicz 1998, Sec. 3).

    Arguments:
        theta_i, phi_i, theta_o, phi_o: spherical angles (radians), broadcastable.
        xp: the array module (``jax.numpy``, or ``numpy`` on the host: no compiled program, for a report's few
            thousand samples).

    Returns:
        ``(theta_h, phi_h, theta_d, phi_d)``, with φ values in [0, 2π).
    """
    wi = spherical_to_vector(theta_i, phi_i, xp)
    wo = spherical_to_vector(theta_o, phi_o, xp)
    h = half_vector(wi, wo, xp)
    theta_h, phi_h = vector_to_spherical(h, xp)
    d = _rotate_y(_rotate_z(wi, -phi_h, xp), -theta_h, xp)
    theta_d, phi_d = vector_to_spherical(d, xp)
    return theta_h, phi_h, theta_d, phi_d


def from_half_diff(theta_h, phi_h, theta_d, phi_d):
    """Inverse of `to_half_diff`: spherical angles of ωi and ωo from half/difference angles.

    Arguments:
        theta_h, phi_h, theta_d, phi_d: Rusinkiewicz angles (radians), broadcastable.

    Returns:
        ``(theta_i, phi_i, theta_o, phi_o)``; a direction below the horizon has θ > π/2.
    """
    d = spherical_to_vector(theta_d, phi_d)
    wi = _rotate_z(_rotate_y(d, theta_h), phi_h)
    h = spherical_to_vector(theta_h, phi_h)
    wo = 2.0 * jnp.sum(wi * h, axis=-1, keepdims=True) * h - wi
    theta_i, phi_i = vector_to_spherical(wi)
    theta_o, phi_o = vector_to_spherical(wo)
    return theta_i, phi_i, theta_o, phi_o


class LocalPair(NamedTuple):
    """Quantities of a direction pair that many lobes need, computed once per evaluation.

    Fields:
        wi, wo: unit directions to the light and the detector, shape ``(..., 3)``.
        cos_i, cos_o: n·ωi and n·ωo, clamped to at least TINY so that lobes may divide by them.
        h: half vector, shape ``(..., 3)``.
        cos_h: n·h.
        cos_d: ωi·h (= ωo·h), the angle the Fresnel term sees; computed as the mean of the two so that it is
            exactly symmetric in ωi and ωo (reciprocity to the last bit).
        above: True where both directions are strictly above the horizon; the model is zero elsewhere.
    """

    wi: jnp.ndarray
    wo: jnp.ndarray
    cos_i: jnp.ndarray
    cos_o: jnp.ndarray
    h: jnp.ndarray
    cos_h: jnp.ndarray
    cos_d: jnp.ndarray
    above: jnp.ndarray

    @classmethod
    def from_dirs(cls, wi, wo, xp=jnp) -> "LocalPair":
        """Build the shared quantities from unit vectors ``wi`` and ``wo`` (broadcastable, last axis 3); ``xp``:
        ``jax.numpy``, or ``numpy`` for a fit's data, prepared on the host (`brdffit.fitting.problem`)."""
        wi, wo = xp.broadcast_arrays(xp.asarray(wi, dtype=float), xp.asarray(wo, dtype=float))
        # Component by component (the same arithmetic as `half_vector`): XLA on the CPU runs reductions over a
        # last axis of length 3 slowly, and this form has none.
        sx, sy, sz = (wi[..., k] + wo[..., k] for k in range(3))
        norm2 = sx * sx + sy * sy + sz * sz
        ok = norm2 > TINY * TINY
        norm = xp.sqrt(xp.where(ok, norm2, 1.0))
        hx, hy, hz = xp.where(ok, sx / norm, 0.0), xp.where(ok, sy / norm, 0.0), xp.where(ok, sz / norm, 1.0)
        return cls(
            wi=wi,
            wo=wo,
            cos_i=xp.maximum(wi[..., 2], TINY),
            cos_o=xp.maximum(wo[..., 2], TINY),
            h=xp.stack([hx, hy, hz], axis=-1),
            cos_h=xp.maximum(hz, TINY),
            cos_d=xp.maximum(0.5 * (sx * hx + sy * hy + sz * hz), TINY),
            above=(wi[..., 2] > 0) & (wo[..., 2] > 0),
        )
