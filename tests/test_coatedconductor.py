"""pbrt-v4's ``coatedconductor`` under a smooth interface (`brdffit.models.coatedconductor`): the lobe against a
NumPy transcription of pbrt-v4's random walk (tests/pbrt_layered_walk.py, which does not import brdffit), its
quadrature and tables against finer ones, its albedo, and a fit that recovers a synthetic material."""

import jax.numpy as jnp
import numpy as np
import pytest

import brdffit
from brdffit.geometry import LocalPair
from brdffit.models import coatedconductor as cc

from pbrt_layered_walk import coated_conductor_f, reflectance_index


def _direction(theta, phi):
    return np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


def _lobe(pairs_wi, pairs_wo, reflectance, alpha, eta):
    """The lobe evaluated eagerly (module constants read at call time, unlike a compiled program)."""
    params = {"reflectance": jnp.asarray(reflectance, dtype=float), "conductor_roughness": jnp.asarray(alpha),
              "interface_eta": jnp.asarray(eta)}
    return np.asarray(cc.CoatedConductor()(params, LocalPair.from_dirs(jnp.asarray(pairs_wi), jnp.asarray(pairs_wo))))


@pytest.mark.parametrize("reflectance, alpha, eta", [([0.95, 0.7, 0.4], 0.3, 1.5), ([0.9, 0.5, 0.2], 0.1, 1.5),
                                                     ([0.8, 0.6, 0.99], 0.7, 1.8)])
def test_lobe_is_the_expectation_of_pbrts_walk(reflectance, alpha, eta):
    # Six pairs: near the mirror direction (where the conductor's own highlight, seen through the coat, is), off
    # it, across, forward and near grazing. The walk's mean of 200,000 walks has a standard error of 0.02-0.5 %; the
    # lobe agrees within four of them plus 0.3 % (its rules: test_rules_converge).
    pairs = [(20, 20, 180), (40, 30, 150), (60, 60, 180), (30, 60, 90), (70, 20, 0), (80, 75, 170)]
    eta_c, k_c = reflectance_index(reflectance)
    for ti, to, dphi in pairs:
        wi, wo = _direction(np.radians(ti), 0.0), _direction(np.radians(to), np.radians(dphi))
        mean, se = coated_conductor_f(wo, wi, eta_c, k_c, alpha, eta, walks=200_000, seed=ti + to)
        got = _lobe(wi[None], wo[None], reflectance, alpha, eta)[0]
        assert np.all(np.abs(got - mean) <= 4.0 * se + 3e-3 * mean), (ti, to, dphi, got, mean, se)


@pytest.mark.parametrize("alpha, eta", [(0.05, 1.5), (0.3, 1.5), (1.0, 1.3)])
def test_rules_converge(alpha, eta, monkeypatch):
    # Every rule three times finer (the cosines', the azimuths', the end directions' and the table's): the lobe
    # moves by at most 1 % at any of 2,000 random pairs, 0.05 % in the cosine-weighted norm (its worst case is the
    # sharpest conductor, α = 0.05, whose bounces' sharp azimuthal profile the 64 harmonics resolve least well).
    rng = np.random.default_rng(4)
    ti, to, po = np.arccos(rng.random(2000)), np.arccos(rng.random(2000)), rng.uniform(0, 2 * np.pi, 2000)
    wi, wo = _direction(ti, 0.0 * ti).T, _direction(to, po).T
    reflectance = [0.9, 0.7, 0.4]
    coarse = _lobe(wi, wo, reflectance, alpha, eta)
    for name, value in dict(COSINE_NODES=48, AZIMUTH_NODES=192, END_NODES=97, TABLE_AZIMUTHS=193).items():
        monkeypatch.setattr(cc, name, value)
    fine = _lobe(wi, wo, reflectance, alpha, eta)
    assert np.max(np.abs(coarse - fine) / fine) < 1e-2
    weight = np.cos(ti)[:, None]
    assert np.linalg.norm((coarse - fine) * weight) / np.linalg.norm(fine * weight) < 5e-4


def test_albedo_stays_below_one_and_grows_with_the_metals_reflectance():
    # The directional albedo ∫ f cosθi dωi by a product rule (Gauss-Legendre in cosθi, 128 azimuths): at most 1
    # and ordered by r; for the brightest metal pbrt takes (r = 0.9999) under a nearly smooth conductor, seen from
    # the normal, the coat's two transmissions (0.96 each) and the slab's transmittance are most of what is lost.
    # A rough conductor returns less: its single scattering loses energy, and what it sends beyond the critical
    # angle is trapped for the walk's five visits (0.22 at α = 0.8, the walk's value too).
    x, w = np.polynomial.legendre.leggauss(64)
    mu, wmu = (x + 1) / 2, w / 2
    phi = (np.arange(128) + 0.5) * 2 * np.pi / 128
    m, p = np.meshgrid(mu, phi, indexing="ij")
    wi = np.stack([np.sqrt(1 - m**2) * np.cos(p), np.sqrt(1 - m**2) * np.sin(p), m], -1).reshape(-1, 3)
    weight = (wmu[:, None] * m * (2 * np.pi / 128)).ravel()
    for theta_o in np.radians([0.0, 45.0, 80.0]):
        wo = np.broadcast_to(_direction(theta_o, np.pi), wi.shape)
        smooth, rough = (weight @ _lobe(wi, wo, [0.9999, 0.9, 0.5], alpha, 1.5) for alpha in (0.05, 0.8))
        for albedo in (smooth, rough):
            assert np.all(albedo <= 1.0) and albedo[0] > albedo[1] > albedo[2] > 0.0, (theta_o, albedo)
        assert np.all(rough < smooth)
        if theta_o == 0.0:
            assert smooth[0] > 0.9


def test_a_fit_recovers_a_coated_metal():
    truth = brdffit.models.get("coatedconductor", reflectance=[0.9, 0.7, 0.4], conductor_roughness=0.25,
                               interface_eta=1.6)
    data = brdffit.synth.generate(truth, n=3000, noise="relative:0.01", seed=2)
    result = brdffit.fit(data, "coatedconductor")
    assert result.converged
    np.testing.assert_allclose(result.params["reflectance"], [0.9, 0.7, 0.4], rtol=0.01)
    assert float(result.params["conductor_roughness"]) == pytest.approx(0.25, rel=0.02)
    assert float(result.params["interface_eta"]) == pytest.approx(1.6, rel=0.02)
