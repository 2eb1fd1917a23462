"""brdffit.geometry: angles <-> vectors, half vector, mirror, Rusinkiewicz angles and the safe helpers.

Expected values are computed here with NumPy from the definitions (docs/conventions.md; Rusinkiewicz, A new change
of variables for efficient BRDF representation, EGWR 1998, Sec. 3), not with brdffit.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdffit  # noqa: F401  (float64)
from brdffit import geometry as geo

RTOL = 1e-12


def _unit(theta, phi):
    theta, phi = np.broadcast_arrays(np.asarray(theta, dtype=float), np.asarray(phi, dtype=float))
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=-1)


def _angle_diff(a, b):
    """Difference of azimuths modulo 2π, in (−π, π]."""
    return np.angle(np.exp(1j * (np.asarray(a) - np.asarray(b))))


# --------------------------------------------------------------------------------------------------------------
# Spherical angles and vectors


def test_spherical_to_vector_known_directions():
    np.testing.assert_allclose(geo.spherical_to_vector(0.0, 1.3), [0, 0, 1], atol=1e-16)
    np.testing.assert_allclose(geo.spherical_to_vector(np.pi / 2, 0.0), [1, 0, 0], atol=1e-16)
    np.testing.assert_allclose(geo.spherical_to_vector(np.pi / 2, np.pi / 2), [0, 1, 0], atol=1e-16)
    np.testing.assert_allclose(geo.spherical_to_vector(np.pi / 3, np.pi / 4),
                               [np.sqrt(3) / 2 / np.sqrt(2), np.sqrt(3) / 2 / np.sqrt(2), 0.5], rtol=RTOL)


def test_spherical_to_vector_broadcasts_and_is_unit(rng):
    theta = rng.uniform(0, np.pi, (4, 1))
    phi = rng.uniform(0, 2 * np.pi, (1, 5))
    w = np.asarray(geo.spherical_to_vector(theta, phi))
    assert w.shape == (4, 5, 3)
    np.testing.assert_allclose(np.linalg.norm(w, axis=-1), 1.0, rtol=1e-14)
    np.testing.assert_allclose(w, _unit(theta, phi), rtol=RTOL, atol=1e-16)


def test_spherical_vector_round_trip(rng):
    theta = rng.uniform(1e-3, np.pi - 1e-3, 200)
    phi = rng.uniform(0, 2 * np.pi, 200)
    t, p = geo.vector_to_spherical(geo.spherical_to_vector(theta, phi))
    np.testing.assert_allclose(t, theta, rtol=1e-10)
    np.testing.assert_allclose(p, phi, rtol=1e-10)
    assert np.all((np.asarray(p) >= 0) & (np.asarray(p) < 2 * np.pi))


def test_vector_round_trip_and_unnormalised_input(rng):
    w = rng.normal(size=(100, 3))
    t, p = geo.vector_to_spherical(w)
    np.testing.assert_allclose(geo.spherical_to_vector(t, p), w / np.linalg.norm(w, axis=-1, keepdims=True),
                               rtol=1e-10, atol=1e-14)
    t, p = geo.vector_to_spherical(np.array([0.0, 0.0, 5.0]))
    assert float(t) == 0.0 and float(p) == 0.0  # φ is 0 along the normal
    t, p = geo.vector_to_spherical(np.array([0.0, -2.0, 0.0]))
    np.testing.assert_allclose([t, p], [np.pi / 2, 3 * np.pi / 2], rtol=RTOL)


# --------------------------------------------------------------------------------------------------------------
# Half vector and mirror


def test_half_vector_bisects(rng):
    wi = _unit(rng.uniform(0, 1.5, 50), rng.uniform(0, 6.28, 50))
    wo = _unit(rng.uniform(0, 1.5, 50), rng.uniform(0, 6.28, 50))
    h = np.asarray(geo.half_vector(wi, wo))
    np.testing.assert_allclose(np.linalg.norm(h, axis=-1), 1.0, rtol=1e-14)
    np.testing.assert_allclose(np.sum(h * wi, -1), np.sum(h * wo, -1), rtol=1e-12)
    # cosθd = ωi·h = √((1 + ωi·ωo)/2): h bisects the angle between ωi and ωo.
    np.testing.assert_allclose(np.sum(h * wi, -1), np.sqrt(0.5 * (1 + np.sum(wi * wo, -1))), rtol=1e-12)
    # h lies in the plane of ωi and ωo.
    np.testing.assert_allclose(np.sum(h * np.cross(wi, wo), -1), 0.0, atol=1e-14)


def test_half_vector_known_cases():
    wi = _unit(0.5, 0.2)
    np.testing.assert_allclose(geo.half_vector(wi, wi), wi, rtol=RTOL)
    # In-plane specular pair: h is the normal.
    np.testing.assert_allclose(geo.half_vector(wi, _unit(0.5, 0.2 + np.pi)), [0, 0, 1], atol=1e-15)
    # Opposite directions: the sum is zero and the helper falls back to the normal instead of NaN.
    h = np.asarray(geo.half_vector(np.array([1.0, 0, 0]), np.array([-1.0, 0, 0])))
    np.testing.assert_array_equal(h, [0, 0, 1])


def test_mirror(rng):
    w = _unit(rng.uniform(0, np.pi / 2, 20), rng.uniform(0, 6.28, 20))
    n = np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(geo.mirror(w), 2 * (w @ n)[:, None] * n - w, rtol=RTOL, atol=1e-16)
    # The mirror direction has the same θ and azimuth φ + π.
    t, p = geo.vector_to_spherical(geo.mirror(_unit(0.7, 0.4)))
    np.testing.assert_allclose([t, _angle_diff(p, 0.4 + np.pi)], [0.7, 0.0], atol=1e-14)
    np.testing.assert_array_equal(geo.mirror(geo.mirror(w)), w)


# --------------------------------------------------------------------------------------------------------------
# Rusinkiewicz half/difference angles


def _half_diff_reference(theta_i, phi_i, theta_o, phi_o):
    """Rusinkiewicz 1998, Sec. 3, from the definition: h = normalize(ωi + ωo), d = ωi in the frame whose pole is
    h, i.e. rotated by −φh about n and then by −θh about the bitangent (written with explicit matrices)."""
    wi, wo = _unit(theta_i, phi_i), _unit(theta_o, phi_o)
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    th = np.arccos(np.clip(h[..., 2], -1, 1))
    ph = np.mod(np.arctan2(h[..., 1], h[..., 0]), 2 * np.pi)
    out = []
    for k in range(wi.shape[0]):
        c, s = np.cos(-ph[k]), np.sin(-ph[k])
        rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        c, s = np.cos(-th[k]), np.sin(-th[k])
        ry = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
        out.append(ry @ rz @ wi[k])
    d = np.array(out)
    td = np.arccos(np.clip(d[:, 2], -1, 1))
    pd = np.mod(np.arctan2(d[:, 1], d[:, 0]), 2 * np.pi)
    return th, ph, td, pd


def _random_pairs(rng, n):
    return (rng.uniform(0.05, 1.5, n), rng.uniform(0, 2 * np.pi, n), rng.uniform(0.05, 1.5, n),
            rng.uniform(0, 2 * np.pi, n))


@pytest.mark.parametrize("xp", [jnp, np], ids=["jax", "numpy"])
def test_to_half_diff_matches_definition(rng, xp):
    angles = _random_pairs(rng, 100)
    got = [np.asarray(a) for a in geo.to_half_diff(*angles, xp=xp)]
    want = _half_diff_reference(*angles)
    np.testing.assert_allclose(got[0], want[0], rtol=1e-10)
    np.testing.assert_allclose(_angle_diff(got[1], want[1]), 0.0, atol=1e-10)
    np.testing.assert_allclose(got[2], want[2], rtol=1e-10)
    np.testing.assert_allclose(_angle_diff(got[3], want[3]), 0.0, atol=1e-10)


def test_to_half_diff_identities(rng):
    """cosθd = ωi·h and cosθh = h·n, computed independently with vectors."""
    ti, pi_, to, po = _random_pairs(rng, 100)
    th, ph, td, pd = geo.to_half_diff(ti, pi_, to, po)
    wi, wo = _unit(ti, pi_), _unit(to, po)
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=-1, keepdims=True)
    np.testing.assert_allclose(np.cos(td), np.sum(wi * h, -1), rtol=1e-10)
    np.testing.assert_allclose(np.cos(th), h[:, 2], rtol=1e-10)
    # Swapping ωi and ωo keeps h; ωo is d mirrored about the pole h, (−dx, −dy, dz): θd' = θd, φd' = φd + π.
    th2, ph2, td2, pd2 = geo.to_half_diff(to, po, ti, pi_)
    np.testing.assert_allclose(th2, th, rtol=1e-10)
    np.testing.assert_allclose(_angle_diff(ph2, ph), 0.0, atol=1e-10)
    np.testing.assert_allclose(td2, td, rtol=1e-10)
    np.testing.assert_allclose(_angle_diff(pd2, np.asarray(pd) + np.pi), 0.0, atol=1e-9)


def test_half_diff_round_trip_from_directions(rng):
    angles = _random_pairs(rng, 200)
    back = geo.from_half_diff(*geo.to_half_diff(*angles))
    np.testing.assert_allclose(back[0], angles[0], rtol=1e-10)
    np.testing.assert_allclose(_angle_diff(back[1], angles[1]), 0.0, atol=1e-10)
    np.testing.assert_allclose(back[2], angles[2], rtol=1e-10)
    np.testing.assert_allclose(_angle_diff(back[3], angles[3]), 0.0, atol=1e-10)


def test_half_diff_round_trip_from_half_diff(rng):
    n = 200
    th, ph = rng.uniform(0.05, 0.7, n), rng.uniform(0, 2 * np.pi, n)
    td, pd = rng.uniform(0.05, 0.8, n), rng.uniform(0, 2 * np.pi, n)
    back = geo.to_half_diff(*geo.from_half_diff(th, ph, td, pd))
    for got, want in zip(back, (th, ph, td, pd)):
        np.testing.assert_allclose(_angle_diff(got, want), 0.0, atol=1e-10)


def test_in_plane_specular_has_theta_h_zero_and_theta_d_theta_i():
    theta = np.radians([5.0, 30.0, 60.0, 85.0])
    phi = np.radians([0.0, 40.0, 200.0, 310.0])
    th, ph, td, pd = geo.to_half_diff(theta, phi, theta, phi + np.pi)
    np.testing.assert_allclose(th, 0.0, atol=1e-7)
    np.testing.assert_allclose(td, theta, rtol=1e-12)
    # With h = n, φh is arbitrary (rounding picks it) but d is ωi turned by −φh about n: φd + φh = φi.
    np.testing.assert_allclose(_angle_diff(np.asarray(pd) + np.asarray(ph), phi), 0.0, atol=1e-12)


def test_normal_incidence_and_retro_reflection_cases():
    # Light and view both along the normal: h = n and d = n.
    th, ph, td, pd = geo.to_half_diff(0.0, 0.0, 0.0, 0.0)
    assert float(th) == 0.0 and float(td) == 0.0
    # Retro-reflection: ωo = ωi gives h = ωi and θd = 0.
    th, ph, td, pd = geo.to_half_diff(0.6, 1.1, 0.6, 1.1)
    np.testing.assert_allclose([th, _angle_diff(ph, 1.1), td], [0.6, 0.0, 0.0], atol=1e-7)
    # In-plane pair at θi = 20°, θo = 60° in the plane φ = 0 / π: h lies in the plane at θh = (60 − 20)/2 = 20°,
    # tilted towards ωo, and θd is half the 80° between the directions.
    th, ph, td, pd = geo.to_half_diff(np.radians(20.0), 0.0, np.radians(60.0), np.pi)
    np.testing.assert_allclose([th, _angle_diff(ph, np.pi), td], [np.radians(20.0), 0.0, np.radians(40.0)],
                               atol=1e-12)


def test_from_half_diff_can_point_below_the_horizon():
    ti, pi_, to, po = geo.from_half_diff(np.radians(60.0), 0.0, np.radians(60.0), np.pi)
    assert float(to) > np.pi / 2 or float(ti) > np.pi / 2


# --------------------------------------------------------------------------------------------------------------
# Safe helpers: finite values and gradients at 0, at normal incidence and at grazing angles


def _finite(x):
    return bool(np.all(np.isfinite(np.asarray(x))))


@pytest.mark.parametrize("x", [0.0, 1e-300, 1e-13, -1e-20, -1.0, 1e-6, 1.0, 4.0])
def test_safe_sqrt(x):
    value = geo.safe_sqrt(x)
    grad = jax.grad(geo.safe_sqrt)(x)
    assert _finite(value) and _finite(grad)
    if x > geo.TINY:
        np.testing.assert_allclose([value, grad], [np.sqrt(x), 0.5 / np.sqrt(x)], rtol=RTOL)
    else:
        assert float(value) == 0.0 and float(grad) == 0.0


@pytest.mark.parametrize("den", [0.0, 1e-300, -1e-20, 2.0, -0.5])
def test_safe_div(den):
    value = geo.safe_div(3.0, den, fallback=7.0)
    g_num, g_den = jax.grad(geo.safe_div, argnums=(0, 1))(3.0, den)
    assert _finite(value) and _finite(g_num) and _finite(g_den)
    if abs(den) > geo.TINY:
        np.testing.assert_allclose([value, g_num, g_den], [3.0 / den, 1.0 / den, -3.0 / den**2], rtol=RTOL)
    else:
        assert float(value) == 7.0 and float(g_num) == 0.0 and float(g_den) == 0.0


@pytest.mark.parametrize("v", [[0.0, 0.0, 0.0], [1e-20, 0.0, 0.0], [3.0, 0.0, 4.0], [0.0, 0.0, 1.0],
                               [1.0, 0.0, 1e-17]])
def test_safe_normalize(v):
    v = jnp.asarray(v)
    value = geo.safe_normalize(v)
    jac = jax.jacobian(geo.safe_normalize)(v)
    assert _finite(value) and _finite(jac)
    norm = float(jnp.linalg.norm(v))
    if norm > geo.TINY:
        np.testing.assert_allclose(value, np.asarray(v) / norm, rtol=RTOL)
        # d(v/|v|)/dv = (I − u uᵀ)/|v|
        u = np.asarray(v) / norm
        np.testing.assert_allclose(jac, (np.eye(3) - np.outer(u, u)) / norm, rtol=1e-10, atol=1e-12)
    else:
        np.testing.assert_array_equal(value, [0.0, 0.0, 1.0])


@pytest.mark.parametrize("x", [0.0, -0.3, 1e-14, 0.5, 1.0])
@pytest.mark.parametrize("n", [0.5, 1.0, 20.0, 500.0])
def test_safe_pow(x, n):
    value = geo.safe_pow(x, n)
    gx, gn = jax.grad(geo.safe_pow, argnums=(0, 1))(x, n)
    assert _finite(value) and _finite(gx) and _finite(gn)
    if x > geo.TINY:
        np.testing.assert_allclose([value, gx, gn], [x**n, n * x ** (n - 1), x**n * np.log(x)], rtol=1e-12)
    else:
        assert float(value) == 0.0 and float(gn) == 0.0


@pytest.mark.parametrize("u", [-1e4, -50.0, -1.0, 0.0, 2.0, 50.0, 1e4])
def test_logistic(u):
    value = geo.logistic(u)
    grad = jax.grad(geo.logistic)(u)
    assert _finite(value) and _finite(grad)
    s = 1.0 / (1.0 + np.exp(-u)) if u > -700 else 0.0
    # The tanh form is accurate to ~1e-16 absolute, not relative: for u < −37 it returns exactly 0 (and so does
    # its derivative), where the true logistic is below 1e-16.
    np.testing.assert_allclose([value, grad], [s, s * (1 - s)], rtol=1e-12, atol=1e-16)


def _pair_quantities(t, dphi):
    wi = geo.spherical_to_vector(t, 0.3)
    wo = geo.spherical_to_vector(t, 0.3 + dphi)
    h = geo.half_vector(wi, wo)
    pair = geo.LocalPair.from_dirs(wi, wo)
    return jnp.stack([h[0], h[2], jnp.sum(wi * h), pair.cos_h, pair.cos_d, pair.cos_i,
                      geo.safe_sqrt(pair.cos_i * pair.cos_o), geo.safe_div(1.0, h[2])])


_pair_quantities_and_jacobian = jax.jit(lambda t, dphi: (_pair_quantities(t, dphi),
                                                         jax.jacobian(_pair_quantities)(t, dphi)))


@pytest.mark.parametrize("dphi", [np.pi, 0.0, 2.0], ids=["specular", "retro", "off-plane"])
@pytest.mark.parametrize("theta_deg", [0.0, 1e-6, 45.0, 89.9, 89.999999, 90.0])
def test_gradients_of_geometry_are_finite_at_normal_and_grazing(theta_deg, dphi):
    """Derivatives of the quantities models use (half vector, cosines of h and d) w.r.t. the angle stay finite at
    θ = 0, where h = n and the azimuths are undefined, and at grazing angles."""
    values, jac = _pair_quantities_and_jacobian(np.radians(theta_deg), dphi)
    assert _finite(values) and _finite(jac)


def test_local_pair_quantities(rng):
    wi = _unit(rng.uniform(0, 1.5, 30), rng.uniform(0, 6.28, 30))
    wo = _unit(rng.uniform(0, 1.5, 30), rng.uniform(0, 6.28, 30))
    pair = geo.LocalPair.from_dirs(wi, wo)
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=-1, keepdims=True)
    np.testing.assert_allclose(pair.cos_i, wi[:, 2], rtol=RTOL)
    np.testing.assert_allclose(pair.cos_o, wo[:, 2], rtol=RTOL)
    np.testing.assert_allclose(pair.cos_h, h[:, 2], rtol=RTOL)
    np.testing.assert_allclose(pair.cos_d, np.sum(wi * h, -1), rtol=RTOL)
    np.testing.assert_allclose(pair.h, h, rtol=RTOL, atol=1e-15)
    # half_vector's arithmetic, component by component: equal up to the order of rounding in |ωi + ωo| (1 ulp).
    np.testing.assert_allclose(pair.h, geo.half_vector(wi, wo), rtol=3e-16, atol=2e-16)
    assert np.all(pair.above)
    opposite = geo.LocalPair.from_dirs(wi, -wi)  # ωi + ωo = 0: h falls back to the normal, as half_vector does
    np.testing.assert_array_equal(opposite.h, np.broadcast_to([0.0, 0.0, 1.0], wi.shape))
    below = geo.LocalPair.from_dirs(np.array([0.0, 0.6, -0.8]), np.array([0.0, 0.0, 1.0]))
    assert not bool(below.above) and float(below.cos_i) > 0  # clamped so lobes may divide by it
