"""brdffit.models.fresnel against closed forms and independent references.

The library's conductor term is pbrt's real-arithmetic form; the reference here uses complex amplitudes
(tests/reference_brdfs.py, Born & Wolf Sec. 14.2) and the dielectric reference uses Fresnel's sine and tangent
laws, so the two sides share no algebra.
"""

from __future__ import annotations

import math

import jax
import numpy as np
import pytest

import brdffit  # noqa: F401  (float64)
from brdffit.models import fresnel as fr

import reference_brdfs as ref

RTOL = 1e-10
ANGLES = np.radians([0.0, 5.0, 20.0, 35.0, 50.0, 65.0, 75.0, 80.0, 85.0, 88.0, 89.5, 89.99])


# --------------------------------------------------------------------------------------------------------------
# Schlick


@pytest.mark.parametrize("f0", [0.0, 0.04, 0.5, 0.95, 1.0])
def test_schlick(f0):
    c = np.cos(ANGLES)
    np.testing.assert_allclose(fr.schlick(c, f0), f0 + (1 - f0) * (1 - c) ** 5, rtol=1e-14, atol=1e-16)
    assert float(fr.schlick(1.0, f0)) == f0
    assert float(fr.schlick(0.0, f0)) == 1.0


def test_schlick_matches_the_exact_dielectric_at_normal_incidence_and_grazing():
    eta = 1.5
    f0 = ((eta - 1) / (eta + 1)) ** 2
    np.testing.assert_allclose(fr.schlick(1.0, f0), fr.dielectric(1.0, 1.0, eta), rtol=1e-14)
    np.testing.assert_allclose(fr.schlick(0.0, f0), fr.dielectric(0.0, 1.0, eta), rtol=1e-14)
    # In between it is an approximation: for glass its error peaks at about 0.036 (absolute) near 85°.
    c = np.cos(ANGLES)
    error = np.abs(np.asarray(fr.schlick(c, f0)) - np.asarray(fr.dielectric(c, 1.0, eta)))
    assert 0.03 < np.max(error) < 0.04


# --------------------------------------------------------------------------------------------------------------
# Dielectric


@pytest.mark.parametrize("eta", [1.0001, 1.333, 1.5, 2.42, 3.9])
def test_dielectric_normal_incidence(eta):
    want = ((eta - 1) / (eta + 1)) ** 2
    np.testing.assert_allclose(fr.dielectric(1.0, 1.0, eta), want, rtol=1e-13)
    # from the dense side the normal-incidence value is the same
    np.testing.assert_allclose(fr.dielectric(1.0, eta, 1.0), want, rtol=1e-13)


@pytest.mark.parametrize("eta_i, eta_t", [(1.0, 1.5), (1.0, 1.333), (1.0, 2.42), (1.5, 1.0), (1.333, 1.5)])
def test_dielectric_brewster_angle(eta_i, eta_t):
    """At θB = arctan(ηt/ηi) the p amplitude vanishes and θi + θt = π/2, so r_s = −sin(θi − θt) = cos(2θB)
    = (ηi² − ηt²)/(ηi² + ηt²) and F = r_s²/2."""
    theta_b = math.atan(eta_t / eta_i)
    r_s = (eta_i**2 - eta_t**2) / (eta_i**2 + eta_t**2)
    np.testing.assert_allclose(fr.dielectric(math.cos(theta_b), eta_i, eta_t), 0.5 * r_s**2, rtol=1e-10)


@pytest.mark.parametrize("eta_i, eta_t", [(1.0, 1.5), (1.0, 1.333), (1.0, 2.42), (1.5, 1.0), (1.333, 1.5),
                                          (2.42, 1.333)])
def test_dielectric_matches_sine_and_tangent_laws(eta_i, eta_t):
    got = fr.dielectric(np.cos(ANGLES), eta_i, eta_t)
    np.testing.assert_allclose(got, ref.fresnel_dielectric(ANGLES, eta_i, eta_t), rtol=RTOL, atol=1e-15)


def test_total_internal_reflection_from_the_dense_side():
    eta_i, eta_t = 1.5, 1.0
    critical = math.asin(eta_t / eta_i)
    above = np.array([critical + 1e-6, math.radians(45.0), math.radians(60.0), math.radians(80.0),
                      math.radians(89.9)])
    np.testing.assert_array_equal(fr.dielectric(np.cos(above), eta_i, eta_t), 1.0)
    below = np.array([0.0, math.radians(20.0), math.radians(40.0), critical - 1e-3])
    got = np.asarray(fr.dielectric(np.cos(below), eta_i, eta_t))
    assert np.all(got < 1.0)
    np.testing.assert_allclose(got, ref.fresnel_dielectric(below, eta_i, eta_t), rtol=RTOL)
    # F rises continuously to 1 at the critical angle
    assert float(fr.dielectric(math.cos(critical - 1e-9), eta_i, eta_t)) > 0.999


@pytest.mark.parametrize("eta", [1.0001, 1.5, 2.42])
def test_dielectric_grazing_goes_to_one(eta):
    """F -> 1 as θ -> 90° for any index (for η near 1 only very close to grazing)."""
    assert float(fr.dielectric(0.0, 1.0, eta)) == pytest.approx(1.0, abs=1e-14)
    values = np.asarray(fr.dielectric(np.cos(np.radians([80.0, 85.0, 89.0, 89.9, 89.99, 90.0 - 1e-7])), 1.0, eta))
    assert np.all(np.diff(values) > 0) and values[-1] > 0.999


def test_vacuum_reflects_nothing():
    np.testing.assert_allclose(fr.dielectric(np.cos(ANGLES[:-1]), 1.0, 1.0), 0.0, atol=1e-15)


# --------------------------------------------------------------------------------------------------------------
# Conductor


@pytest.mark.parametrize("eta, k", [(0.2, 3.0), (0.37, 2.82), (1.1, 0.0), (2.485, 3.433), (1.0, 1e-3), (5.0, 10.0)])
def test_conductor_normal_incidence(eta, k):
    want = ((eta - 1) ** 2 + k**2) / ((eta + 1) ** 2 + k**2)
    # atol: pbrt's form subtracts numbers of order 1 to get R_s, so a reflectance near 0 (η = 1, κ = 1e-3 gives
    # 2.5e-7) is accurate to ~1e-16 absolute, not relative.
    np.testing.assert_allclose(fr.conductor(1.0, eta, k), want, rtol=1e-13, atol=1e-16)


@pytest.mark.parametrize("eta, k", [(0.2, 3.0), (0.37, 2.82), (0.617, 2.63), (1.1, 0.0), (1.5, 0.0),
                                    (2.485, 3.433), (0.05, 0.5), (5.0, 10.0)])
def test_conductor_matches_complex_amplitudes(eta, k):
    got = np.asarray(fr.conductor(np.cos(ANGLES), eta, k))
    want = np.array([ref.fresnel_conductor_scalar(t, eta, k) for t in ANGLES])
    np.testing.assert_allclose(got, want, rtol=RTOL)
    np.testing.assert_allclose(ref.fresnel_conductor(ANGLES, eta, k), want, rtol=1e-13)


def test_conductor_with_zero_extinction_is_a_dielectric():
    for eta in (1.333, 1.5, 2.42):
        np.testing.assert_allclose(fr.conductor(np.cos(ANGLES), eta, 0.0), fr.dielectric(np.cos(ANGLES), 1.0, eta),
                                   rtol=1e-10, atol=1e-15)


@pytest.mark.parametrize("eta, k", [(0.37, 2.82), (2.485, 3.433), (1.5, 0.0)])
def test_conductor_grazing_goes_to_one(eta, k):
    assert float(fr.conductor(0.0, eta, k)) == pytest.approx(1.0, abs=1e-14)
    np.testing.assert_allclose(fr.conductor(np.cos(math.radians(89.99)), eta, k),
                               ref.fresnel_conductor_scalar(math.radians(89.99), eta, k), rtol=RTOL)


def test_conductor_broadcasts_per_channel():
    eta, k = np.array([0.2, 0.6, 1.1]), np.array([3.0, 2.4, 1.8])
    got = np.asarray(fr.conductor(np.cos(ANGLES)[:, None], eta, k))
    assert got.shape == (len(ANGLES), 3)
    want = ref.fresnel_conductor(ANGLES[:, None], eta[None, :], k[None, :])
    np.testing.assert_allclose(got, want, rtol=RTOL)


# --------------------------------------------------------------------------------------------------------------
# Presets


ISSUE_CONDUCTORS = {"gold": (0.370, 2.820), "silver": (0.177, 3.638), "copper": (0.617, 2.63),
                    "steel": (2.485, 3.433)}
ISSUE_DIELECTRICS = {"vacuum": 1.0, "air": 1.00029, "ice": 1.31, "water": 1.333, "fused-quartz": 1.46,
                     "glass": 1.5, "sapphire": 1.77, "diamond": 2.42}


def test_presets_are_the_issue_values():
    assert fr.CONDUCTORS == ISSUE_CONDUCTORS
    assert fr.DIELECTRICS == ISSUE_DIELECTRICS


@pytest.mark.parametrize("name", sorted(fr.CONDUCTORS))
def test_conductor_presets_at_normal_incidence(name):
    eta, k = fr.CONDUCTORS[name]
    want = ((eta - 1) ** 2 + k**2) / ((eta + 1) ** 2 + k**2)
    np.testing.assert_allclose(fr.conductor(1.0, eta, k), want, rtol=1e-13)
    assert 0.5 < want < 1.0  # metals reflect most of the light at normal incidence


@pytest.mark.parametrize("name", sorted(fr.DIELECTRICS))
def test_dielectric_presets_at_normal_incidence(name):
    eta = fr.DIELECTRICS[name]
    want = ((eta - 1) / (eta + 1)) ** 2
    np.testing.assert_allclose(fr.dielectric(1.0, 1.0, eta), want, rtol=1e-13, atol=1e-300)


def test_glass_and_water_reflectance_textbook_values():
    """Known values: glass (1.5) reflects 4 % and water (1.333) about 2 % at normal incidence."""
    assert float(fr.dielectric(1.0, 1.0, fr.DIELECTRICS["glass"])) == pytest.approx(0.04, rel=1e-12)
    assert float(fr.dielectric(1.0, 1.0, fr.DIELECTRICS["water"])) == pytest.approx(0.02037, abs=1e-5)


# --------------------------------------------------------------------------------------------------------------
# Gradients


@pytest.mark.parametrize("cos_theta", [0.0, 1e-4, 0.5, 1.0])
def test_fresnel_gradients_are_finite(cos_theta):
    g_dielectric = jax.grad(fr.dielectric, argnums=(0, 2))(cos_theta, 1.0, 1.5)
    g_tir = jax.grad(fr.dielectric, argnums=(0, 1))(cos_theta, 1.5, 1.0)
    g_conductor = jax.grad(fr.conductor, argnums=(0, 1, 2))(cos_theta, 0.37, 2.82)
    g_schlick = jax.grad(fr.schlick, argnums=(0, 1))(cos_theta, 0.04)
    for g in (g_dielectric, g_tir, g_conductor, g_schlick):
        assert np.all(np.isfinite(np.asarray(g)))


def test_conductor_gradient_matches_finite_differences():
    c, eta, k, h = 0.4, 0.37, 2.82, 1e-6
    grads = jax.grad(fr.conductor, argnums=(0, 1, 2))(c, eta, k)

    def f(c, eta, k):
        return ref.fresnel_conductor_scalar(math.acos(c), eta, k)

    fd = [(f(c + h, eta, k) - f(c - h, eta, k)) / (2 * h),
          (f(c, eta + h, k) - f(c, eta - h, k)) / (2 * h),
          (f(c, eta, k + h) - f(c, eta, k - h)) / (2 * h)]
    np.testing.assert_allclose(grads, fd, rtol=1e-6)


def test_f82_tint_meets_its_defining_values():
    """Hoffman's F82-tinted Schlick term: F(1) = f0, F(0) = 1, at cosθ = 1/7 the tint times Schlick's term, and with
    a white tint (f82 = 1) Schlick's term itself."""
    from brdffit.models.fresnel import f82_tint, schlick

    f0, f82 = np.array([0.9, 0.6, 0.3]), np.array([0.8, 1.0, 0.5])
    np.testing.assert_allclose(f82_tint(1.0, f0, f82), f0, rtol=1e-15)
    np.testing.assert_allclose(f82_tint(0.0, f0, f82), 1.0, rtol=1e-15)
    np.testing.assert_allclose(f82_tint(1.0 / 7.0, f0, f82), f82 * np.asarray(schlick(1.0 / 7.0, f0)), rtol=1e-13)
    c = np.linspace(0.0, 1.0, 11)[:, None]
    np.testing.assert_allclose(f82_tint(c, f0, 1.0), schlick(c, f0), rtol=1e-15)
