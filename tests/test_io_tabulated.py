"""What a fit of a tabulated file is given (brdffit.io.tabulated): direction pairs uniform in solid angle or drawn
about the specular direction with importance weights, whose (weighted) mean is the integral over directions
(checked against product Gauss quadrature), a known model recovered from a MERL table and from an RGL-EPFL table
made from it, the nodes' fit of an RGL-EPFL table of a material that no candidate represents against the best fit
over directions, and on the real RGL-EPFL files a fit to the pairs that predicts unseen directions better than a fit
to the file's grid nodes. The materials and held-out pairs are the independent references' (tests/reference_brdfs.py,
scripts/reference_fit.py)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

import brdffit
from brdffit import io as bio
from brdffit.io import tabulated

import reference_brdfs as ref

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
from reference_fit import uniform_pairs  # noqa: E402  (the independent reference's held-out pairs)

DATA = ROOT.parent / "shared" / "data"
MAX = math.radians(80.0)


def _cosine_error(f, data, theta_i):
    c = np.cos(theta_i)[:, None]
    return float(np.linalg.norm((f - data) * c) / np.linalg.norm(data * c))


@pytest.mark.parametrize("isotropic", [False, True])
def test_pairs_are_uniform_in_solid_angle(isotropic):
    theta_i, phi_i, theta_o, phi_o = tabulated.direction_pairs(50_000, 3, max_theta_i=math.radians(60),
                                                               max_theta_o=MAX, isotropic=isotropic)
    assert theta_i.max() <= math.radians(60) + 1e-12 and theta_o.max() <= MAX + 1e-12
    # E[cos θ] over a cone uniform in solid angle is (1 + cos θmax)/2, E[cos² θ] = (1 + c + c²)/3; a low-discrepancy
    # sequence meets both far closer than the 1/√n of random draws (2e-3 here).
    for theta, top in ((theta_i, math.radians(60)), (theta_o, MAX)):
        c = math.cos(top)
        assert np.cos(theta).mean() == pytest.approx((1 + c) / 2, abs=2e-4)
        assert (np.cos(theta) ** 2).mean() == pytest.approx((1 + c + c * c) / 3, abs=2e-4)
    assert np.all(phi_i == 0) if isotropic else abs(np.mean(np.cos(phi_i))) < 1e-3
    assert abs(np.mean(np.cos(phi_o))) < 1e-3 and abs(np.mean(np.sin(phi_o))) < 1e-3
    # another seed, other points; the same seed, the same points
    again = tabulated.direction_pairs(50_000, 3, max_theta_i=math.radians(60), max_theta_o=MAX, isotropic=isotropic)
    np.testing.assert_array_equal(again[2], theta_o)
    assert not np.array_equal(tabulated.direction_pairs(1000, 4)[2], theta_o[:1000])


def test_mean_over_pairs_is_the_integral_by_quadrature():
    """The cosine loss's sum over the pairs, divided by their number and times the two cones' solid angles, is
    ∫∫ ((f − g) cos θi)² dωo dωi: checked against a product Gauss-Legendre rule in (cos θi, cos θo, φo) with the
    isotropic pair's φi integrated out (2π)."""
    f = brdffit.models.get("lambert+ggx", rho_d=0.3, ks=0.5, alpha=0.35, f0=0.04)
    g = brdffit.models.get("lambert+ggx", rho_d=0.25, ks=0.3, alpha=0.5, f0=0.04)

    def integrand(theta_i, phi_i, theta_o, phi_o):
        d = np.asarray(brdffit.evaluate(f, theta_i, phi_i, theta_o, phi_o)) - np.asarray(
            brdffit.evaluate(g, theta_i, phi_i, theta_o, phi_o))
        return (d[:, 0] * np.cos(theta_i)) ** 2

    cone = 2 * math.pi * (1 - math.cos(MAX))
    pairs = tabulated.direction_pairs(8192, 0, max_theta_i=MAX, max_theta_o=MAX, isotropic=True)
    estimate = integrand(*pairs).mean() * cone * cone
    *angles, weights = tabulated.importance_pairs(8192, 0, max_theta_i=MAX, max_theta_o=MAX, isotropic=True)
    weighted = np.sum(integrand(*angles) * weights) / 8192 * cone * cone  # the pairs dropped count 0
    x, w = np.polynomial.legendre.leggauss(48)
    c = 1 - (x + 1) / 2 * (1 - math.cos(MAX))  # cos θ over [cos θmax, 1]
    wc = w * (1 - math.cos(MAX)) / 2
    xp, wp = np.polynomial.legendre.leggauss(96)
    phi = xp * math.pi
    ci, co, po = np.meshgrid(c, c, phi, indexing="ij")
    weight = np.einsum("i,j,k->ijk", wc, wc, wp * math.pi)
    values = integrand(np.arccos(ci).ravel(), np.zeros(ci.size), np.arccos(co).ravel(), po.ravel())
    exact = 2 * math.pi * float(np.sum(values * weight.ravel()))
    assert estimate == pytest.approx(exact, rel=0.01)
    assert weighted == pytest.approx(exact, rel=0.01)


def test_importance_pairs_cut_the_variance_of_a_peak():
    """A near-mirror peak (width ~1.8° about the specular direction): the weighted estimate of its mean over
    uniform pairs is unbiased (against 2 million uniform pairs) and its spread over seeds at least 20x smaller
    than the uniform pairs' own."""
    def peak(theta_i, phi_i, theta_o, phi_o):
        wi = np.stack([np.sin(theta_i) * np.cos(phi_i), np.sin(theta_i) * np.sin(phi_i), np.cos(theta_i)], 1)
        wo = np.stack([np.sin(theta_o) * np.cos(phi_o), np.sin(theta_o) * np.sin(phi_o), np.cos(theta_o)], 1)
        return np.exp(-(1 - np.sum(wi * np.array([-1, -1, 1]) * wo, axis=1)) / 5e-4)

    exact = peak(*tabulated.direction_pairs(2_000_000, 7, max_theta_i=MAX, max_theta_o=MAX, isotropic=True)).mean()
    weighted, uniform = [], []
    for seed in range(8):
        *angles, weights = tabulated.importance_pairs(8192, seed, max_theta_i=MAX, max_theta_o=MAX, isotropic=True)
        assert weights.max() <= 1 / (1 - tabulated.PEAK_FRACTION) + 1e-9 and weights.min() > 0
        weighted.append(np.sum(peak(*angles) * weights) / 8192)
        uniform.append(peak(*tabulated.direction_pairs(8192, 100 + seed, max_theta_i=MAX, max_theta_o=MAX,
                                                       isotropic=True)).mean())
    assert np.mean(weighted) == pytest.approx(exact, rel=0.02)
    assert np.std(weighted) * 20 < np.std(uniform)


def test_merl_table_of_a_known_model_is_recovered(tmp_path):
    """A MERL file written from lambert+ggx, read with the default sampling and fitted: the parameters come back
    within the table's own quantisation (nearest cell: θh cells ~0.5° wide near the peak)."""
    truth = brdffit.models.get("lambert+ggx", rho_d=(0.3, 0.2, 0.1), ks=0.6, alpha=0.2, f0=0.04)
    path = tmp_path / "ggx.binary"
    bio.write_merl(truth, path)
    m = bio.load(path)
    assert m.n <= tabulated.DEFAULT_PAIRS and m.meta["sampling"]["kind"] == "directions"
    assert np.sum(m.weights) / tabulated.DEFAULT_PAIRS == pytest.approx(1, abs=0.02)  # the mean of 1 over pairs
    result = brdffit.fit(m, "lambert+ggx", fixed={"f0": 0.04})
    assert result.converged
    params = result.model.params
    assert float(params["alpha"]) == pytest.approx(0.2, rel=0.03)
    np.testing.assert_allclose(np.asarray(params["rho_d"]), [0.3, 0.2, 0.1], rtol=0.03)
    held = uniform_pairs(20_000, np.random.default_rng(11))
    data = np.asarray(brdffit.evaluate(truth, *held))
    assert _cosine_error(np.asarray(brdffit.evaluate(result.model, *held)), data, held[0]) < 0.03


# ------------------------------------------------------------------- an RGL-EPFL table made from a known material
# The incidences of the shared RGL-EPFL files (paper_white: 0° to 90° in 8 steps).
_RGL_THETA_I = np.radians([0.0, 27.7, 39.9, 49.9, 59.3, 68.6, 78.5, 90.0])


def _ggx_d(cos_m, alpha):
    """GGX's D (`reference_brdfs.microfacet_D`, Walter et al. 2007 eq. 33) of normals with these cosines; 0 below
    the horizon."""
    with np.errstate(all="ignore"):
        return np.where(cos_m > 0, ref.microfacet_D("ggx", np.arccos(np.clip(cos_m, -1.0, 1.0)), alpha), 0.0)


def _material(rho, lobes):
    """f_r(ωi, ωo) (N, 3) of Lambert ρ/π plus GGX lobes ks D G₁(ωi) G₁(ωo) F / (4 cosθi cosθo) with Schlick's F
    (Walter et al. 2007 eq. 20), each lobe ``(ks, alpha, f0)``: `reference_brdfs`' NumPy re-derivations, apart from
    brdffit's models."""
    def f(wi, wo):
        angles = (*tabulated.vector_angles(np.atleast_2d(wi)), *tabulated.vector_angles(np.atleast_2d(wo)))
        value = ref.lambert(*angles, [rho] * 3)
        for ks, alpha, f0 in lobes:
            value = value + ref.cook_torrance(*angles, [ks] * 3, alpha, distribution="ggx", shadowing="smith",
                                              fresnel="schlick", f0=f0)
        return value
    return f


def _rgl_table(f, warp, samples=32, unit=128):
    """An `RglTable` of the material ``f`` as the RGL-EPFL files hold one (brdffit.io.rgl's module doc): ``ndf``
    D(m) and ``sigma`` σ(ωi) = ∫ D(m) max(0, ωi·m) dωm of a mixture of GGX distributions and the cosine one
    (D = 1/π, σ = (1 + cosθ)/2), ``warp`` its ``(weight, alpha)`` terms (alpha None: the cosine one; GGX's
    σ = cosθ (1 + Λ(θ)) = (cosθ + √(cos²θ + α² sin²θ))/2, Heitz 2014 eq. 72 and 86), ``vndf`` the visible normals'
    density (ωi·m) D(m) · dωm/du on the unit square (dωm/du = 2π² u₁ sinθm), and ``rgb`` the value f_r cosθo /
    (D / 4σ) at each node of the sample square, so that the file's lookup equals ``f`` at its nodes."""
    def d(cos_m):
        return sum(w * (_ggx_d(cos_m, a) if a else np.where(cos_m > 0, 1 / math.pi, 0.0)) for w, a in warp)

    def sigma(theta):
        c, s = np.cos(theta), np.sin(theta)
        return sum(w * ((c + np.sqrt(c * c + a * a * s * s)) / 2 if a else (1 + c) / 2) for w, a in warp)

    u1, u2 = np.meshgrid(np.linspace(0, 1, unit), np.linspace(0, 1, unit))  # rows along u₂, columns along u₁
    theta_m = math.pi / 2 * u1 * u1
    m = tabulated.unit_vectors(theta_m, 2 * math.pi * u2 - math.pi)
    vndf = np.stack([np.maximum(m @ tabulated.unit_vectors(t, 0.0), 0) * d(np.cos(theta_m)) * 2 * math.pi ** 2
                     * u1 * np.sin(theta_m) for t in _RGL_THETA_I])[None]
    fields = dict(theta_i=_RGL_THETA_I, phi_i=np.zeros(1), ndf=d(np.cos(theta_m)), sigma=sigma(theta_m), vndf=vndf,
                  jacobian=True)
    count = len(_RGL_THETA_I)
    ones = bio.RglTable(rgb=np.ones((1, count, 3, samples, samples)), **fields)
    s2, s1 = (a.reshape(-1) for a in np.meshgrid(np.linspace(0, 1, samples), np.linspace(0, 1, samples),
                                                 indexing="ij"))
    rgb = np.zeros((1, count, 3, samples, samples))
    for t, theta in enumerate(_RGL_THETA_I):
        nodes = ones._nodes(t, theta, 0.0, s1, s2, np.ones_like(s1))  # the value of rgb = 1 at each node
        wi = np.broadcast_to(tabulated.unit_vectors(theta, 0.0), nodes["wo"].shape)
        with np.errstate(all="ignore"):
            good = (nodes["wo"][:, 2] > 0) & np.isfinite(nodes["values"][:, 0]) & (nodes["values"][:, 0] > 0)
            rgb[0, t] = np.where(good[:, None], f(wi, nodes["wo"]) / nodes["values"], 0.0).T.reshape(3, samples,
                                                                                                    samples)
    return bio.RglTable(rgb=rgb, **fields)


def _weighted_error(measurements, pairs, data) -> float:
    """The cosine error of a lambert+ggx fit to ``measurements`` over importance-weighted ``pairs``
    (`tabulated.importance_pairs`: the weighted sums estimate the integrals over directions) against ``data``."""
    model = brdffit.fit(measurements, "lambert+ggx").model
    *angles, weights = pairs
    c = (np.cos(angles[0]) * np.sqrt(weights))[:, None]
    return float(np.linalg.norm((np.asarray(brdffit.evaluate(model, *angles)) - data) * c)
                 / np.linalg.norm(data * c))


def test_rgl_table_of_a_known_model_is_recovered():
    """A table made from lambert+ggx: its nodes hold the model's values, so the nodes' fit recovers the model
    exactly; the default fits the table's interpolation between them, which differs from the model by a few
    percent (mostly at grazing θo, where 32 x 32 nodes are sparse), and recovers it within that."""
    rho, ks, alpha, f0 = 0.3, 0.5, 0.15, 0.04
    table = _rgl_table(_material(rho, [(ks, alpha, f0)]), [(0.5, alpha), (0.5, None)])
    nodes = table.grid_measurements()
    truth = _material(rho, [(ks, alpha, f0)])(tabulated.unit_vectors(nodes.theta_i, nodes.phi_i),
                                              tabulated.unit_vectors(nodes.theta_o, nodes.phi_o))
    np.testing.assert_allclose(nodes.values, truth, rtol=1e-9, atol=1e-12)
    exact = brdffit.fit(nodes, "lambert+ggx").model.params
    assert float(exact["alpha"]) == pytest.approx(alpha, rel=1e-5)
    default = brdffit.fit(table.to_measurements(), "lambert+ggx").model.params
    assert float(default["alpha"]) == pytest.approx(alpha, rel=0.03)
    np.testing.assert_allclose(np.asarray(default["rho_d"]), rho, rtol=0.02)
    np.testing.assert_allclose(np.asarray(default["ks"]), ks, rtol=0.05)


def test_rgl_table_node_fit_is_biased_over_directions_and_the_default_is_not():
    """A table made from a two-lobe material (GGX α = 0.3 and 0.06) fitted with one lobe. The best fit over
    directions to what the file says there (its lookup, what a renderer reads) is found by brute force: a fit to
    100,000 weighted pairs drawn about that material's own two roughnesses. Judged on 200,000 other such pairs
    (another seed), the default (16,384 pairs drawn about fixed roughnesses, 0.2 and 0.04) comes within 5% of that
    optimum's error; the fit to the grid nodes, whose density follows the warp and the eight tabulated incidences,
    is more than 20% worse."""
    table = _rgl_table(_material(0.4, [(0.3, 0.3, 0.04), (0.2, 0.06, 0.04)]), [(0.5, 0.06), (0.5, 0.3)])

    def pairs(n, seed):
        return tabulated.importance_pairs(n, seed, isotropic=True, peaks=(0.3, 0.06))

    train, held = pairs(100_000, 1), pairs(200_000, 2)
    data = table.lookup(*held[:4])
    optimum = _weighted_error(brdffit.Measurements(*train[:4], table.lookup(*train[:4]), weights=train[4]), held,
                              data)
    default = _weighted_error(table.to_measurements(), held, data)
    nodes = _weighted_error(table.grid_measurements(), held, data)
    assert default < 1.05 * optimum, (default, optimum)
    assert nodes > 1.2 * optimum, (nodes, optimum)


def test_options_are_checked():
    with pytest.raises(ValueError, match="sampling must be one of"):
        tabulated.check_sampling("nodes", 10, 1.0)
    with pytest.raises(ValueError, match="pairs must be a positive"):
        tabulated.check_sampling("directions", 0, 1.0)
    with pytest.raises(ValueError, match="max_theta"):
        tabulated.check_sampling("directions", 10, 2.0)


@pytest.fixture(scope="module")
def paper_white():
    path = DATA / "rgl-epfl" / "paper_white_rgb.bsdf"
    if not path.is_file():
        pytest.skip(f"real RGL-EPFL file not found at {path} (../shared/data)")
    return path


def test_rgl_directions_are_the_lookup_within_max_theta(paper_white):
    table = bio.read_rgl(paper_white)
    m = bio.load(paper_white, pairs=2000, seed=5)
    np.testing.assert_allclose(m.values, table.lookup(m.theta_i, m.phi_i, m.theta_o, m.phi_o), rtol=1e-12)
    assert m.theta_i.max() <= MAX + 1e-12 and m.theta_o.max() <= MAX + 1e-12
    assert m.meta["sampling"]["max_theta_i_deg"] == pytest.approx(80.0)
    narrow = bio.load(paper_white, pairs=500, max_theta=math.radians(40))
    assert narrow.theta_i.max() <= math.radians(40) + 1e-12 and narrow.theta_o.max() <= math.radians(40) + 1e-12


@pytest.mark.parametrize("name", ["paper_white", "satin_rosaline"])
def test_rgl_fit_to_directions_predicts_unseen_directions_better_than_nodes(name):
    """The same model fitted to the file's grid nodes and to the default direction pairs, both judged on 50,000
    other pairs uniform in solid angle against the file's own interpolation: the nodes' fit is worse (their
    density follows the warp and the tabulated incidences, not the directions)."""
    path = DATA / "rgl-epfl" / f"{name}_rgb.bsdf"
    if not path.is_file():
        pytest.skip(f"real RGL-EPFL file not found at {path} (../shared/data)")
    table = bio.read_rgl(path)
    held = uniform_pairs(50_000, np.random.default_rng(202))
    data = table.lookup(*held)
    errors = {}
    for sampling in ("grid", "directions"):
        result = brdffit.fit(bio.load(path, sampling=sampling), "lambert+ggx")
        errors[sampling] = _cosine_error(np.asarray(brdffit.evaluate(result.model, *held)), data, held[0])
    assert errors["directions"] < errors["grid"], errors
