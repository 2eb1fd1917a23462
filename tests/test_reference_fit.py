"""Tests of the independent reference fitter `scripts/reference_fit.py` (grid + bounded linear least squares,
NumPy/SciPy only), against which brdffit's accuracy on real measurements is compared."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import integrate

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts"))

import reference_fit as ref  # noqa: E402

PAPER_WHITE = ROOT.parent / "shared" / "data" / "rgl-epfl" / "paper_white_rgb.bsdf"

RHO_D = np.array([0.3, 0.5, 0.2])
KS = np.array([0.2, 0.2, 0.2])
TRUE_SHAPES = {"ggx": (0.15, 0.04), "cook-torrance": (0.2, 0.3), "blinn-phong": (150.0,), "ward": (0.12,)}


def test_uniform_pairs_uniform_in_solid_angle():
    n, max_deg = 200_000, 80.0
    ti, pi_, to, po = ref.uniform_pairs(n, np.random.default_rng(7), max_theta_deg=max_deg)
    cos_max = np.cos(np.radians(max_deg))
    for theta, phi in ((ti, pi_), (to, po)):
        assert theta.shape == phi.shape == (n,)
        assert np.all(theta >= 0) and np.all(theta <= np.radians(max_deg) + 1e-12)
        assert np.all(phi >= -np.pi) and np.all(phi < np.pi)
        c = np.cos(theta)
        # uniform in solid angle on the cap: cos θ uniform on [cos θmax, 1], mean (1 + cos θmax)/2, sd (1 - cos θmax)/√12
        se = (1 - cos_max) / np.sqrt(12 * n)
        assert abs(c.mean() - (1 + cos_max) / 2) < 4 * se
        assert abs(c.std() - (1 - cos_max) / np.sqrt(12)) < 0.01 * (1 - cos_max)
        # the upper half of the cap in cos θ holds half the solid angle
        assert abs(np.mean(c > (1 + cos_max) / 2) - 0.5) < 4 * 0.5 / np.sqrt(n)
        assert abs(phi.mean()) < 4 * (2 * np.pi / np.sqrt(12 * n))
    # ω_i and ω_o are independent
    assert abs(np.corrcoef(np.cos(ti), np.cos(to))[0, 1]) < 4 / np.sqrt(n)


def test_uniform_pairs_draw_order_and_protocol():
    # the documented draw order: u_i, v_i, u_o, v_o = rng.random((4, n)) in one call
    u_i, v_i, u_o, v_o = np.random.default_rng(3).random((4, 5))
    ti, pi_, to, po = ref.uniform_pairs(5, np.random.default_rng(3), max_theta_deg=60.0)
    np.testing.assert_allclose(np.cos(ti), 1 - u_i * 0.5, rtol=1e-12)
    np.testing.assert_allclose(pi_, 2 * np.pi * v_i - np.pi, rtol=1e-12)
    np.testing.assert_allclose(np.cos(to), 1 - u_o * 0.5, rtol=1e-12)
    np.testing.assert_allclose(po, 2 * np.pi * v_o - np.pi, rtol=1e-12)
    assert (ref.TRAIN_PAIRS, ref.TRAIN_SEED, ref.TEST_PAIRS, ref.TEST_SEED) == (8000, 101, 2000, 202)
    train, test = ref.protocol_pairs()
    assert train[0].shape == (8000,) and test[0].shape == (2000,)
    np.testing.assert_array_equal(test[0], ref.uniform_pairs(2000, np.random.default_rng(202))[0])
    train_b, test_b = ref.protocol_pairs(test_pairs=300, test_seed=9)
    np.testing.assert_array_equal(train_b[0], train[0])  # the training set does not move
    np.testing.assert_array_equal(test_b[2], ref.uniform_pairs(300, np.random.default_rng(9))[2])
    again = ref.uniform_pairs(8000, np.random.default_rng(101))
    for a, b in zip(train, again):
        np.testing.assert_array_equal(a, b)


def test_cosine_error():
    theta_i = np.array([0.0, np.pi / 3, 0.2])
    data = np.array([[1.0, 2.0], [4.0, 0.0], [np.nan, 1.0]])  # the third row is missing and left out
    fit = np.array([[1.1, 2.0], [4.0, 1.0], [100.0, 100.0]])
    expected = np.sqrt(0.1 ** 2 + (1.0 * 0.5) ** 2) / np.sqrt(1 + 4 + (4 * 0.5) ** 2)
    assert ref.cosine_error(fit, data, theta_i) == pytest.approx(expected, rel=1e-12)
    assert ref.cosine_error(data, data, theta_i) == 0.0


def test_ggx_and_beckmann_d_are_normalised():
    # ∫ D(h) cos θh dω_h = 2π ∫_0^{π/2} D(θ) cos θ sin θ dθ = 1 (Walter et al. 2007, eq. 4)
    for d in (ref.ggx_d, ref.beckmann_d):
        for alpha in (0.05, 0.3, 1.0):
            value, _ = integrate.quad(lambda t: d(np.cos(t), alpha) * np.cos(t) * np.sin(t), 0, np.pi / 2,
                                      points=[alpha, min(3 * alpha, 1.5)], limit=200, epsabs=1e-12)
            assert 2 * np.pi * value == pytest.approx(1.0, abs=1e-6), (d.__name__, alpha)


def test_ggx_smith_g1_projected_area():
    # Heitz (2014), eq. 2: the visible projected area of the microsurface equals the projected area of the
    # surface, ∫ G1(ω_o) <ω_o·h> D(h) dω_h = cos θo, ties Walter's G1 (eq. 34) to the D (eq. 33).
    alpha, theta_o = 0.4, np.radians(60.0)
    wo = np.array([np.sin(theta_o), 0.0, np.cos(theta_o)])

    def integrand(theta_h, phi_h):
        h = np.array([np.sin(theta_h) * np.cos(phi_h), np.sin(theta_h) * np.sin(phi_h), np.cos(theta_h)])
        return max(wo @ h, 0.0) * ref.ggx_d(np.cos(theta_h), alpha) * np.sin(theta_h)

    value, _ = integrate.dblquad(integrand, 0, 2 * np.pi, 0, np.pi / 2, epsabs=1e-8, epsrel=1e-8)
    g1 = ref.ggx_g1(np.cos(theta_o), alpha)
    assert g1 * value == pytest.approx(np.cos(theta_o), rel=1e-5)


def test_schlick_factor():
    # Schlick (1994): F = f0 + (1 - f0)(1 - cos θd)^5, F(1) = f0 at normal incidence, F(0) = 1 at grazing
    for f0 in (0.0, 0.04, 0.3, 1.0):
        assert ref.schlick(1.0, f0) == pytest.approx(f0, abs=1e-15)
        assert ref.schlick(0.0, f0) == pytest.approx(1.0, abs=1e-15)
        assert ref.schlick(0.5, f0) == pytest.approx(f0 + (1 - f0) / 32, rel=1e-14)
        c = np.linspace(0, 1, 101)
        assert np.all(np.diff(ref.schlick(c, f0)) <= 0)  # falls from 1 at grazing to f0 at normal incidence


def test_microfacet_lobes_carry_the_schlick_factor_of_the_half_angle():
    rng = np.random.default_rng(4)
    ti, pi_, to, po = ref.uniform_pairs(500, rng)
    wi = np.stack([np.sin(ti) * np.cos(pi_), np.sin(ti) * np.sin(pi_), np.cos(ti)], axis=-1)
    wo = np.stack([np.sin(to) * np.cos(po), np.sin(to) * np.sin(po), np.cos(to)], axis=-1)
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=1, keepdims=True)
    cos_d = np.sum(wi * h, axis=1)
    np.testing.assert_allclose(cos_d, np.sum(wo * h, axis=1), rtol=1e-12)  # ω_i·h = ω_o·h
    for model, width in (("ggx", 0.2), ("cook-torrance", 0.3)):
        free = ref.evaluate(model, (width, 1.0), [0.0], [1.0], ti, pi_, to, po)[:, 0]  # f0 = 1: F = 1
        for f0 in (0.0, 0.04, 0.5):
            f = ref.evaluate(model, (width, f0), [0.0], [1.0], ti, pi_, to, po)[:, 0]
            np.testing.assert_allclose(f, (f0 + (1 - f0) * (1 - cos_d) ** 5) * free, rtol=1e-10)
    # the Fresnel-free GGX lobe written out: D G1 G1 / (4 cos θi cos θo) with Walter et al.'s eqs. 33-34
    alpha = 0.2
    cos_h = h[:, 2]
    d = alpha ** 2 / (np.pi * cos_h ** 4 * (alpha ** 2 + (1 - cos_h ** 2) / cos_h ** 2) ** 2)
    g1 = [2 / (1 + np.sqrt(1 + alpha ** 2 * (1 - c ** 2) / c ** 2)) for c in (wi[:, 2], wo[:, 2])]
    free = ref.evaluate("ggx", {"alpha": alpha, "f0": 1.0}, [0.0], [1.0], ti, pi_, to, po)[:, 0]
    np.testing.assert_allclose(free, d * g1[0] * g1[1] / (4 * wi[:, 2] * wo[:, 2]), rtol=1e-10)
    # at normal incidence and exitance h = n, F = f0, D = 1/(π α²), G = 1: S = f0 / (4π α²)
    f = ref.evaluate("ggx", (0.3, 0.04), [0.0], [1.0], [0.0], [0.0], [0.0], [0.0])
    assert f[0, 0] == pytest.approx(0.04 / (4 * np.pi * 0.09), rel=1e-12)


def test_shape_arguments():
    p = ref.uniform_pairs(50, np.random.default_rng(1))
    by_tuple = ref.evaluate("ggx", (0.2, 0.1), [0.5], [1.0], *p)
    np.testing.assert_array_equal(ref.evaluate("ggx", {"f0": 0.1, "alpha": 0.2}, [0.5], [1.0], *p), by_tuple)
    np.testing.assert_array_equal(ref.evaluate("ggx", np.array([0.2, 0.1]), [0.5], [1.0], *p), by_tuple)
    np.testing.assert_array_equal(ref.evaluate("ward", 0.2, [0.5], [1.0], *p),
                                  ref.evaluate("ward", (0.2,), [0.5], [1.0], *p))
    assert ref.SHAPE_NAMES == {"ggx": ("alpha", "f0"), "cook-torrance": ("m", "f0"), "blinn-phong": ("n",),
                               "ward": ("alpha",)}
    for model, shape in (("ggx", 0.2), ("ggx", (0.2, 0.1, 0.3)), ("ward", (0.2, 0.1)), ("ggx", {"alpha": 0.2}),
                         ("cook-torrance", {"alpha": 0.2, "f0": 0.1}), ("phong", 10.0)):
        with pytest.raises(ValueError):
            ref.evaluate(model, shape, [0.5], [1.0], *p)


def test_grid_costs_match_a_direct_solve():
    # the grid's shortcut (the Fresnel-free part once per width, times F per f0) gives the costs of the full lobe
    rng = np.random.default_rng(8)
    train = ref.uniform_pairs(1500, rng)
    values = ref.evaluate("cook-torrance", (0.25, 0.1), RHO_D, KS, *train)
    values *= 1 + 0.05 * rng.standard_normal(values.shape)
    g, w, targets_w = ref._prepare(*train, values, None)
    for model in ("ggx", "cook-torrance", "ward"):
        grids = ref.MODELS[model].grids
        costs = ref._grid_costs(model, g, w, w / np.pi, targets_w)
        assert costs.shape == tuple(len(grid) for grid in grids)
        for index in ((0,) * len(grids), (17,) + (3,) * (len(grids) - 1), (39,) + (len(ref.F0_GRID) - 1,)
                      * (len(grids) - 1)):
            shape = tuple(grid[k] for grid, k in zip(grids, index))
            direct = ref._solve_amplitudes(ref._specular(model, g, shape) * w, w / np.pi, targets_w)[2]
            assert costs[index] == pytest.approx(direct, rel=1e-10, abs=1e-14), (model, index)


def test_blinn_phong_lobe_at_the_mirror_direction():
    # at the mirror direction h = n and S = (n + 8)/(8π) (Akenine-Möller et al.'s normalisation of Blinn 1977)
    theta = np.array([0.1, 0.5, 1.2])
    for n in (1.0, 50.0, 5000.0):
        f = ref.evaluate("blinn-phong", n, [0.0], [1.0], theta, np.zeros(3), theta, np.full(3, np.pi))
        np.testing.assert_allclose(f[:, 0], (n + 8) / (8 * np.pi), rtol=1e-9)
    # and (n·h)^n off the mirror: ω_i = n, ω_o at θo gives θh = θo/2
    f = ref.evaluate("blinn-phong", 20.0, [0.0], [1.0], [0.0], [0.0], [0.4], [0.0])
    assert f[0, 0] == pytest.approx(28 / (8 * np.pi) * np.cos(0.2) ** 20, rel=1e-12)


def test_ward_lobe_closed_form():
    # Ward (1992) eq. 4, isotropic: ω_i = ω_o at θ gives h = ω_i, θh = θ
    alpha, theta = 0.2, 0.3
    f = ref.evaluate("ward", alpha, [0.0], [1.0], [theta], [0.0], [theta], [0.0])
    expected = np.exp(-np.tan(theta) ** 2 / alpha ** 2) / (4 * np.pi * alpha ** 2 * np.cos(theta))
    assert f[0, 0] == pytest.approx(expected, rel=1e-12)


def test_models_are_zero_below_the_horizon_and_finite():
    ti = np.array([0.3, 1.7, 0.3, np.pi / 2, 0.0, 1.5])
    to = np.array([1.8, 0.3, 0.3, 0.2, 0.0, 1.5])
    phi_o = np.array([0.0, 0.0, np.pi, 0.0, 0.0, np.pi])
    for model, spec in ref.MODELS.items():
        corners = np.array(np.meshgrid(*[(grid[0], grid[-1]) for grid in spec.grids])).reshape(len(spec.grids), -1).T
        for shape in corners:
            f = ref.evaluate(model, tuple(shape), [0.5], [1.0], ti, np.zeros(6), to, phi_o)
            assert np.all(np.isfinite(f)), (model, shape)
            assert np.all(f[:2] == 0.0), (model, shape)
            assert np.all(f >= 0.0), (model, shape)


@pytest.mark.parametrize("model", list(TRUE_SHAPES))
def test_recovery_of_each_reference_model(model):
    rng = np.random.default_rng(11)
    train = ref.uniform_pairs(4000, rng)
    values = ref.evaluate(model, TRUE_SHAPES[model], RHO_D, KS, *train)
    fit = ref.fit_reference(*train, values)
    assert fit.model == model
    assert isinstance(fit.shape, tuple) and len(fit.shape) == len(ref.SHAPE_NAMES[model])
    assert fit.shape == pytest.approx(TRUE_SHAPES[model], rel=0.02)
    assert fit.shape_dict == dict(zip(ref.SHAPE_NAMES[model], fit.shape))
    np.testing.assert_allclose(fit.rho_d, RHO_D, rtol=0.01)
    np.testing.assert_allclose(fit.ks, KS, rtol=0.01)
    test = ref.uniform_pairs(2000, rng)
    assert ref.cosine_error(fit.predict(*test), ref.evaluate(model, TRUE_SHAPES[model], RHO_D, KS, *test),
                            test[0]) < 1e-3


@pytest.mark.parametrize("model, shape", [("ggx", (0.23, 0.11)), ("cook-torrance", (0.09, 0.62)),
                                          ("ggx", (0.05, 1.0)), ("cook-torrance", (0.4, 0.0))])
def test_recovery_off_the_grid_and_at_the_f0_bounds(model, shape):
    # widths and f0 between grid points (found by the refinement) and f0 at its bounds 0 and 1
    rng = np.random.default_rng(12)
    train = ref.uniform_pairs(4000, rng)
    values = ref.evaluate(model, shape, RHO_D, KS, *train)
    fit = ref.fit_each(*train, values, models=[model])[model]
    assert fit.shape == pytest.approx(shape, rel=0.02, abs=1e-3)
    np.testing.assert_allclose(fit.rho_d, RHO_D, rtol=0.01)
    np.testing.assert_allclose(fit.ks, KS, rtol=0.01)
    # without the refinement the fit stays on the grid
    coarse = ref.fit_each(*train, values, models=[model], refine=False)[model]
    assert coarse.shape[0] in ref.MODELS[model].grids[0] and coarse.shape[1] in ref.F0_GRID
    assert fit.train_cost <= coarse.train_cost


def test_fit_ignores_missing_rows_and_uses_weights():
    rng = np.random.default_rng(5)
    train = ref.uniform_pairs(3000, rng)
    values = ref.evaluate("ggx", (0.3, 0.15), RHO_D, KS, *train)
    corrupted = values.copy()
    corrupted[:300] = np.nan  # missing rows are left out
    fit = ref.fit_reference(*train, corrupted, models=["ggx"])
    assert fit.shape == pytest.approx((0.3, 0.15), rel=0.02)
    # outliers given zero weight do not move the fit
    corrupted = values.copy()
    corrupted[:300] *= 5.0
    weights = np.ones(3000)
    weights[:300] = 0.0
    fit = ref.fit_reference(*train, corrupted, weights, models=["ggx"])
    assert fit.shape == pytest.approx((0.3, 0.15), rel=0.02)
    np.testing.assert_allclose(fit.rho_d, RHO_D, rtol=0.01)
    # and do when weighted in
    assert ref.fit_reference(*train, corrupted, models=["ggx"]).train_cost > 1.0


def test_amplitude_bounds_hold():
    rng = np.random.default_rng(6)
    train = ref.uniform_pairs(2000, rng)
    values = ref.evaluate("ward", 0.2, [1.6, 0.5, 0.0], [0.1, 0.0, 0.3], *train)  # ρd beyond 1 in channel 0
    fit = ref.fit_each(*train, values)["ward"]
    assert np.all(fit.rho_d >= 0) and np.all(fit.rho_d <= 1.0) and np.all(fit.ks >= 0)
    assert fit.rho_d[0] == pytest.approx(1.0)


def test_reference_is_independent_of_the_engine():
    # importing and fitting with the reference must load neither JAX nor brdffit's models, fitting or selection
    code = ("import sys, numpy as np; sys.path.insert(0, 'scripts'); import reference_fit as r; "
            "p = r.uniform_pairs(500, np.random.default_rng(0)); "
            "r.fit_reference(*p, r.evaluate('ggx', (0.2, 0.1), [0.5], [0.3], *p)); "
            "print(sorted(m for m in sys.modules if m == 'jax' or m.startswith(('jax.', 'brdffit'))))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


@pytest.mark.skipif(not PAPER_WHITE.exists(), reason=f"real RGL-EPFL data not present: {PAPER_WHITE} "
                                                      "(../shared/data beside the project)")
def test_paper_white_held_out_error(tmp_path):
    out = tmp_path / "ref.json"
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "reference_fit.py"), str(PAPER_WHITE),
                           "--json", str(out)], cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "paper_white_rgb.bsdf: reference" in done.stdout
    result = json.loads(out.read_text())["results"][0]
    assert result["model"] in ref.MODELS
    assert np.isfinite(result["test_error"]) and result["test_error"] < 0.2
    assert np.isfinite(result["train_error"]) and result["train_error"] < 0.2
    # the chosen model is the one with the lowest training error of the four
    assert result["train_error"] == min(m["train_error"] for m in result["models"].values())
    # shapes are written by name
    assert list(result["shape"]) == list(ref.SHAPE_NAMES[result["model"]])
    for name, m in result["models"].items():
        assert list(m["shape"]) == list(ref.SHAPE_NAMES[name])
        assert 0.0 <= m["shape"].get("f0", 0.0) <= 1.0
    assert json.loads(out.read_text())["protocol"] == {"train_pairs": 8000, "train_seed": 101, "test_pairs": 2000,
                                                       "test_seed": 202, "max_theta_deg": 80.0}
    # another test set: same training fit, other test pairs
    other = tmp_path / "other.json"
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "reference_fit.py"), str(PAPER_WHITE),
                           "--json", str(other), "--test-pairs", "500", "--test-seed", "7"],
                          cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "500 test pairs (seed 7)" in done.stdout
    again = json.loads(other.read_text())
    assert again["protocol"]["test_pairs"] == 500 and again["protocol"]["test_seed"] == 7
    assert again["results"][0]["train_error"] == result["train_error"]
    assert again["results"][0]["shape"] == result["shape"]
    assert again["results"][0]["test_error"] != result["test_error"] and again["results"][0]["test_error"] < 0.2
