"""Synthetic measurements: patterns, noise statistics, determinism, and the shipped data sets."""

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

import brdffit
from brdffit import geometry, synth
from brdffit.models import get

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "data" / "synthetic"
PATTERNS = tuple(synth.PATTERNS)


@pytest.fixture(scope="module")
def plastic():
    return get("lambert+cook-torrance", rho_d=(0.5, 0.3, 0.2), ks=1.0, m=0.2, f0=0.04)


@pytest.fixture(scope="module")
def lambert():
    """A constant BRDF, so that noise statistics are read off directly."""
    return get("lambert", rho_d=(0.6, 0.5, 0.4))


def _script():
    spec = importlib.util.spec_from_file_location("make_synthetic", ROOT / "scripts" / "make_synthetic.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["make_synthetic"] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def _truth(model, m):
    return np.asarray(brdffit.evaluate(model, m.theta_i, m.phi_i, m.theta_o, m.phi_o))


def _same(a, b, rtol=0.0):
    """Equal field for field; ``rtol`` for the values and σ, which come out of XLA (another CPU may round the
    last bit differently) while angles, weights and the noise draws are NumPy's and must match exactly."""
    for name in ("theta_i", "phi_i", "theta_o", "phi_o", "values", "sigma", "weights"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is None:
            continue
        if name in ("values", "sigma") and rtol:
            np.testing.assert_allclose(x, y, rtol=rtol, atol=0, err_msg=name)
        else:
            np.testing.assert_array_equal(x, y, err_msg=name)
    assert a.meta == b.meta


# ------------------------------------------------------------------------------------------------- patterns
@pytest.mark.parametrize("pattern", PATTERNS)
def test_same_seed_gives_same_data_and_other_seed_differs(plastic, pattern):
    a = synth.generate(plastic, pattern, n=300, noise="relative:0.01", seed=7)
    b = synth.generate(plastic, pattern, n=300, noise="relative:0.01", seed=7)
    c = synth.generate(plastic, pattern, n=300, noise="relative:0.01", seed=8)
    _same(a, b)
    assert not np.array_equal(a.values, c.values)


@pytest.mark.parametrize("pattern", PATTERNS)
def test_pattern_gives_n_samples_in_range_with_truth_in_meta(plastic, pattern):
    m = synth.generate(plastic, pattern, n=400, seed=1)
    assert m.n == 400 and m.n_channels == 3 and m.channels == ("R", "G", "B")
    for theta in (m.theta_i, m.theta_o):
        assert np.all((theta >= 0) & (theta < math.pi / 2))
    for phi in (m.phi_i, m.phi_o):
        assert np.all((phi >= 0) & (phi < 2 * math.pi))
    assert m.weights.shape == (400,) and np.all(m.weights > 0)
    assert m.sigma is None and m.valid.all()
    np.testing.assert_allclose(m.values, _truth(plastic, m), rtol=1e-12)  # noise-free values are the model
    assert m.meta["pattern"] == pattern and m.meta["noise"] == "none" and m.meta["seed"] == 1
    truth = synth.truth_model(m)
    assert truth.spec == plastic.spec
    for name, value in plastic.params.items():
        np.testing.assert_array_equal(truth.params[name], value)


@pytest.mark.parametrize("pattern", PATTERNS)
def test_max_theta_is_respected(plastic, pattern):
    limit = math.radians(50)
    m = synth.generate(plastic, pattern, n=300, seed=2, max_theta=limit)
    assert m.n == 300
    assert m.theta_i.max() <= limit + 1e-12 and m.theta_o.max() <= limit + 1e-12
    assert m.meta["max_theta"] == limit


def test_uniform_is_uniform_in_solid_angle(lambert):
    m = synth.generate(lambert, "uniform", n=20000, seed=3)
    assert m.weights.tolist() == [1.0] * m.n
    # cosθ is uniform on [0, 1] for both directions: mean 1/2, variance 1/12.
    for theta in (m.theta_i, m.theta_o):
        assert abs(np.cos(theta).mean() - 0.5) < 0.01
        assert abs(np.cos(theta).var() - 1 / 12) < 0.003


def test_in_plane_has_phi_o_equal_phi_i_plus_pi(plastic):
    for phi_i in (0.0, 1.0, None):
        m = synth.generate(plastic, "in-plane", n=200, seed=4, phi_i=phi_i)
        gap = np.mod(m.phi_o - m.phi_i - math.pi, 2 * math.pi)
        assert np.all(np.minimum(gap, 2 * math.pi - gap) < 1e-12)
        if phi_i is not None:
            np.testing.assert_allclose(m.phi_i, phi_i)
    assert np.unique(m.phi_i).size == 200  # phi_i=None: a plane per sample


def test_gonio_grid_layout_and_weights(lambert):
    theta_i = np.radians([0, 20, 40, 60])
    m = synth.generate(lambert, "gonio-grid", seed=0, theta_i=theta_i, phi_i=(0.0, math.pi / 2), n_theta_o=9,
                       n_phi_o=24)
    assert m.n == 4 * 2 * 9 * 24
    np.testing.assert_allclose(np.unique(m.theta_i), theta_i)
    assert np.unique(m.theta_o).size == 9 and np.unique(np.round(m.phi_o, 12)).size == 24
    # The weights are the cell measures in dωi dωo (scaled to mean 1): together the two full hemispheres.
    np.testing.assert_allclose(m.weights.mean(), 1.0)
    np.testing.assert_allclose(m.weights.sum() * m.meta["weight_unit_sr2"], (2 * math.pi) ** 2, rtol=1e-12)
    # θo cells have the sinθ measure: weight ∝ cos(lower edge) − cos(upper edge) at fixed θi.
    row = (m.theta_i == theta_i[2]) & (m.phi_i == 0.0) & (m.phi_o == 0.0)
    edges = np.linspace(0, math.pi / 2, 10)
    expected = np.cos(edges[:-1]) - np.cos(edges[1:])
    np.testing.assert_allclose(m.weights[row] / m.weights[row][0], expected / expected[0], rtol=1e-12)
    # The forward in-plane direction φo = φi + π is on the grid (n_phi_o even).
    assert np.any(np.isclose(m.phi_o[m.phi_i == 0.0], math.pi))
    # With n, a seeded subsample of grid points.
    sub = synth.generate(lambert, "gonio-grid", n=500, seed=0)
    assert sub.n == 500 and sub.meta["pattern_options"]["grid_size"] >= 500


def test_merl_cell_centres_map_back_to_their_indices(plastic):
    m = synth.generate(plastic, "merl", n=2000, seed=5)
    theta_h, phi_h, theta_d, phi_d = (np.asarray(a) for a in geometry.to_half_diff(m.theta_i, m.phi_i, m.theta_o,
                                                                                  m.phi_o))
    assert np.all(np.minimum(phi_h, 2 * math.pi - phi_h) < 1e-6)  # φh = 0
    i = np.floor(np.sqrt(theta_h / (math.pi / 2)) * 90).astype(int)
    j = np.floor(theta_d / (math.pi / 2) * 90).astype(int)
    k = np.floor(np.mod(phi_d, math.pi) / math.pi * 180).astype(int)
    np.testing.assert_allclose(theta_h, ((i + 0.5) / 90) ** 2 * math.pi / 2, atol=1e-9)
    np.testing.assert_allclose(theta_d, (j + 0.5) / 90 * math.pi / 2, atol=1e-9)
    np.testing.assert_allclose(phi_d, (k + 0.5) / 180 * math.pi, atol=1e-9)
    assert len(set(zip(i, j, k))) == m.n  # distinct cells


def test_merl_cell_measures_cover_both_hemispheres():
    index, angles, measure = synth.merl_cell_centres()
    assert index.shape == (measure.size, 3)
    assert 1_000_000 < measure.size < 90 * 90 * 180
    # Rusinkiewicz measure 4 cosθd dωh dωd: the cells above the horizon fill (2π)², up to the horizon cells.
    assert measure.sum() == pytest.approx((2 * math.pi) ** 2, rel=1e-3)


def test_half_diff_is_dense_near_the_specular_direction(lambert):
    half = synth.generate(lambert, "half-diff", n=5000, seed=6)
    uniform = synth.generate(lambert, "uniform", n=5000, seed=6)

    def near_specular(m):
        theta_h = np.asarray(geometry.to_half_diff(m.theta_i, m.phi_i, m.theta_o, m.phi_o)[0])
        return np.mean(theta_h < math.radians(10))

    assert near_specular(half) > 3 * near_specular(uniform)


def test_model_given_as_spec_and_channel_names():
    m = synth.generate("lambert", n=50, channels=("550nm",))
    assert m.n_channels == 1 and m.channels == ("550nm",)
    np.testing.assert_allclose(m.values, 0.5 / math.pi)


def test_bad_arguments_are_refused(plastic):
    with pytest.raises(ValueError, match="unknown pattern"):
        synth.generate(plastic, "spiral")
    with pytest.raises(ValueError, match="no option"):
        synth.generate(plastic, "uniform", n_theta_o=3)
    with pytest.raises(ValueError, match="max_theta"):
        synth.generate(plastic, max_theta=2.0)
    with pytest.raises(ValueError, match="exceeds"):
        synth.generate(plastic, "gonio-grid", n=10_000, n_theta_o=2, n_phi_o=4)


# ---------------------------------------------------------------------------------------------------- noise
def test_gaussian_noise_statistics(lambert):
    sigma = 0.004
    m = synth.generate(lambert, n=20000, noise=synth.Gaussian(sigma), seed=10)
    residual = m.values - _truth(lambert, m)
    assert np.all(np.abs(residual.mean(axis=0)) < 4 * sigma / math.sqrt(m.n))
    np.testing.assert_allclose(residual.std(axis=0), sigma, rtol=0.03)
    np.testing.assert_array_equal(m.sigma, sigma)
    assert m.meta["noise"] == "gaussian:0.004"


def test_per_channel_gaussian_noise(lambert):
    sigma = (0.001, 0.002, 0.004)
    m = synth.generate(lambert, n=20000, noise="gaussian:0.001,0.002,0.004", seed=11)
    np.testing.assert_allclose((m.values - _truth(lambert, m)).std(axis=0), sigma, rtol=0.03)
    np.testing.assert_array_equal(m.sigma, np.broadcast_to(sigma, m.values.shape))


def test_relative_noise_statistics(plastic):
    r = 0.01
    m = synth.generate(plastic, n=20000, noise="relative:0.01", seed=12)
    f = _truth(plastic, m)
    ratio = m.values / f - 1
    np.testing.assert_allclose(ratio.std(axis=0), r, rtol=0.03)
    assert np.all(np.abs(ratio.mean(axis=0)) < 4 * r / math.sqrt(m.n))
    np.testing.assert_allclose(m.sigma, r * f, rtol=1e-12)


def test_signal_dependent_noise_statistics(plastic):
    a, b = 0.002, 0.05
    m = synth.generate(plastic, n=20000, noise=synth.SignalDependent(a, b), seed=13)
    f = _truth(plastic, m)
    np.testing.assert_allclose(m.sigma, a + b * f, rtol=1e-12)
    z = (m.values - f) / m.sigma
    np.testing.assert_allclose(z.std(axis=0), 1.0, rtol=0.03)
    assert np.all(np.abs(z.mean(axis=0)) < 4 / math.sqrt(m.n))


def test_outliers_fraction_rows_and_sigma(plastic):
    m = synth.generate(plastic, n=5000, noise="relative:0.01+outliers:0.03,20", seed=14)
    rows = np.asarray(m.meta["outliers"])
    assert rows.size == round(0.03 * 5000)
    f = _truth(plastic, m)
    np.testing.assert_allclose(m.sigma, 0.01 * f, rtol=1e-12)  # the σ of the underlying noise
    ratio = m.values / f
    assert np.all(np.abs(ratio[rows] / 20 - 1) < 0.06)
    clean = np.setdiff1d(np.arange(m.n), rows)
    assert np.all(np.abs(ratio[clean] - 1) < 0.06)
    # Outliers alone: no σ.
    bare = synth.generate(plastic, n=1000, noise=synth.Outliers(0.1, scale=0.5), seed=14)
    assert bare.sigma is None and len(bare.meta["outliers"]) == 100


def test_changing_the_noise_keeps_the_directions(plastic):
    a = synth.generate(plastic, "half-diff", n=300, noise=None, seed=15)
    b = synth.generate(plastic, "half-diff", n=300, noise="gaussian:0.01", seed=15)
    for name in ("theta_i", "phi_i", "theta_o", "phi_o"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_negative_noisy_values_are_missing_or_clipped(lambert):
    sigma = 0.2  # larger than f = 0.19 .. 0.13, so many draws fall below zero
    missing = synth.generate(lambert, n=2000, noise=synth.Gaussian(sigma), seed=16)
    clipped = synth.generate(lambert, n=2000, noise=synth.Gaussian(sigma), seed=16, negative="clip")
    holes = ~missing.valid
    assert holes.sum() == missing.meta["negatives"] > 0
    assert np.all(clipped.values[holes] == 0.0)
    np.testing.assert_array_equal(clipped.values[~holes], missing.values[~holes])


@pytest.mark.parametrize("text", ["gaussian:0.01", "gaussian:0.01,0.02,0.03", "relative:0.05",
                                  "signal-dependent:0.001,0.02", "outliers:0.01,10.0",
                                  "relative:0.01+outliers:0.02,5.0"])
def test_noise_spec_round_trip(text):
    noise = synth.parse_noise(text)
    assert noise.spec == text
    assert synth.parse_noise(noise.spec) == noise


@pytest.mark.parametrize("text", ["poisson:1", "relative", "relative:x", "relative:0.1,0.2", "gaussian:-1",
                                  "relative:0.1+gaussian:0.1", "outliers:2", "signal-dependent:0,0"])
def test_bad_noise_specs_are_refused(text):
    with pytest.raises(ValueError):
        synth.parse_noise(text)


def test_noise_none_and_truth_model_errors(plastic):
    assert synth.parse_noise(None) is None and synth.parse_noise("none") is None
    plain = brdffit.measurements.Measurements(0.1, 0.0, 0.2, 3.0, [[0.1, 0.1, 0.1]])
    with pytest.raises(ValueError, match="ground truth"):
        synth.truth_model(plain)


# --------------------------------------------------------------------------------------------- shipped data
@pytest.fixture(scope="module")
def script():
    return _script()


def test_shipped_files_are_small_and_carry_their_truth(script):
    from brdffit.io import load

    files = {m.filename for m in script.MATERIALS}
    assert files == {p.name for p in SHIPPED.glob("*.h5")}
    assert "plastic.h5" in files
    assert sum((SHIPPED / f).stat().st_size for f in files) < 2 * 1024 * 1024
    for material in script.MATERIALS:
        m = load(SHIPPED / material.filename)
        truth = synth.truth_model(m)
        assert truth.spec == material.model().spec
        assert m.meta["seed"] == material.seed and m.meta["pattern"] == material.pattern
        assert m.valid.all() and m.sigma is not None


def test_shipped_file_is_reproduced_value_for_value(script, tmp_path):
    from brdffit.io import load

    material = next(m for m in script.MATERIALS if m.name == "toon")
    assert script.main([str(tmp_path), "--only", material.name]) == 0
    fresh = load(tmp_path / material.filename)
    shipped = load(SHIPPED / material.filename)
    _same(fresh, shipped, rtol=1e-13)


def test_shipped_readme_matches_the_script_and_the_files(script):
    from brdffit.io import load

    shipped = {m.name: load(SHIPPED / m.filename) for m in script.MATERIALS}
    text = (SHIPPED / "README.md").read_text(encoding="utf-8")
    assert text == script.readme(script.MATERIALS, shipped)
