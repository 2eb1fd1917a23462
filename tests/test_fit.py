"""Behaviour of the fitting engine: constraints, missing data, failure reporting, uncertainty, batching, I/O."""

import json
import warnings

import jax
import numpy as np
import optimistix as optx
import pytest

from brdffit import FitError, FitResult, Measurements, fit, fit_many, io, models, synth
from brdffit.fitting.losses import loss_epsilon, relative_epsilon, residuals, robust_residuals
from brdffit.fitting.problem import make_fit_data
from brdffit.fitting.marquardt import Marquardt
from brdffit.fitting.solvers import COARSE_OFFSET, coarse_solver

PLASTIC = dict(rho_d=[0.5, 0.35, 0.2], ks=[0.9, 0.8, 0.7], m=0.15, f0=0.04)


@pytest.fixture(scope="module")
def plastic():
    truth = models.get("lambert+cook-torrance", **PLASTIC)
    return truth, synth.generate(truth, pattern="half-diff", n=3000, noise="relative:0.01", seed=5)


def test_fixed_parameters_stay_fixed(plastic):
    truth, data = plastic
    result = fit(data, "lambert+cook-torrance", fixed={"f0": 0.1, "m": 0.3})
    assert float(result.params["f0"]) == 0.1
    assert float(result.params["m"]) == 0.3
    assert result.stderr["m"] == 0.0 and result.n_params == 6
    assert "f0" in result.fixed and "m" in result.fixed


def test_declared_fixed_parameter_is_fixed_unless_freed():
    truth = models.get("toon-specular", ks=[0.9, 0.8, 0.7], threshold=0.9, width=0.05)
    data = synth.generate(truth, pattern="half-diff", n=3000, noise="relative:0.01", seed=2)
    held = fit(data, "toon-specular", loss="sigma")
    assert float(held.params["width"]) == 0.02  # the declared default, held
    freed = fit(data, "toon-specular", loss="sigma", free=["width"], init=truth)
    assert float(freed.params["width"]) == pytest.approx(0.05, rel=0.05)


def test_bounded_parameters_stay_inside_bounds(plastic):
    truth, data = plastic
    # Data from a brighter diffuse than rho_d's upper bound of 1 allows: the fit must stop at the bound.
    bright = data.replace(values=data.values * 4.0, sigma=data.sigma * 4.0)
    result = fit(bright, "lambert", loss="sigma")
    assert np.all(np.asarray(result.params["rho_d"]) <= 1.0)
    assert result.status == "converged-at-bound"
    assert any(label.startswith("rho_d") for label in result.bounds_hit)


def test_missing_samples_are_ignored(plastic):
    truth, data = plastic
    values = np.array(data.values)
    rng = np.random.default_rng(0)
    holes = rng.random(values.shape) < 0.2
    poisoned = values.copy()
    poisoned[holes] = np.nan
    full = fit(data, "lambert+cook-torrance", fixed=["f0"], loss="sigma")
    gappy = fit(data.replace(values=poisoned), "lambert+cook-torrance", fixed=["f0"], loss="sigma")
    assert gappy.n_samples == int((~holes).sum())
    assert gappy.converged
    np.testing.assert_allclose(gappy.params["ks"], full.params["ks"], rtol=0.01)
    assert float(gappy.params["m"]) == pytest.approx(float(full.params["m"]), rel=0.01)


def test_unexplainable_data_report_status_and_finite_metrics(plastic):
    truth, data = plastic
    # A sharp specular material fitted with a plain Lambert model: nothing can explain the peak.
    result = fit(data, "lambert")
    assert result.status in ("converged", "converged-at-bound", "max-steps")
    assert all(np.all(np.isfinite(v)) for v in result.metrics.values())
    # A step limit that is too small is reported, not raised ...
    short = fit(data, "lambert+cook-torrance", init="model", max_steps=2)
    assert short.status == "max-steps" and not short.converged
    # ... unless the caller asks for strictness.
    with pytest.raises(FitError) as info:
        fit(data, "lambert+cook-torrance", init="model", max_steps=2, strict=True)
    assert info.value.result.status == "max-steps"


def test_covariance_matches_spread_of_repeated_fits():
    # Gaussian noise of known σ with loss="sigma": over independent noise draws on one sampling design, the
    # Laplace errors should match the scatter of the estimates within 30% (issue 4). The design is held fixed
    # because the errors depend on it (half-diff designs of different seeds hit the peak differently).
    truth = models.get("lambert+ward", rho_d=[0.4, 0.3, 0.2], ks=[0.5, 0.4, 0.3], alpha=0.2)
    clean = synth.generate(truth, pattern="half-diff", n=1500, seed=0)
    rng = np.random.default_rng(1)
    estimates, errors = [], []
    for _ in range(40):
        values = clean.values + 0.01 * rng.standard_normal(clean.values.shape)
        result = fit(clean.replace(values=values, sigma=np.full_like(values, 0.01)), "lambert+ward", loss="sigma")
        estimates.append([float(result.params["alpha"]), float(result.params["ks"][0]),
                          float(result.params["rho_d"][2])])
        errors.append([float(result.stderr["alpha"]), float(result.stderr["ks"][0]),
                       float(result.stderr["rho_d"][2])])
    spread = np.std(estimates, axis=0, ddof=1)
    predicted = np.mean(errors, axis=0)
    np.testing.assert_allclose(predicted, spread, rtol=0.3)


def test_noise_variance_estimated_from_residuals_without_sigma():
    truth = models.get("lambert", rho_d=[0.4, 0.3, 0.2])
    data = synth.generate(truth, pattern="uniform", n=2000, noise="gaussian:0.02", seed=0)
    result = fit(data, "lambert", loss="absolute")
    assert result.noise_variance == pytest.approx(0.02 ** 2, rel=0.1)
    # σ of the mean of 2000 samples of σ = 0.02 on f = ρ/π: stderr(ρ) = π 0.02 / √2000.
    np.testing.assert_allclose(result.stderr["rho_d"], np.pi * 0.02 / np.sqrt(2000), rtol=0.05)


@pytest.mark.slow
def test_fit_many_matches_fits_one_by_one():
    truth = models.get("lambert+blinn-phong", rho_d=[0.3, 0.2, 0.1], ks=[0.5, 0.5, 0.5], n=50.0)
    sets = [synth.generate(truth.replace(n=30.0 + 20 * k), pattern="half-diff", n=1000, noise="relative:0.01",
                           seed=k) for k in range(3)]
    together = fit_many(sets, "lambert+blinn-phong", loss="sigma")
    for data, batched in zip(sets, together):
        alone = fit(data, "lambert+blinn-phong", loss="sigma")
        for name in alone.params:
            np.testing.assert_allclose(batched.params[name], alone.params[name], rtol=1e-8, atol=1e-12)
        assert batched.status == alone.status


@pytest.mark.slow
def test_fit_many_of_large_data_solves_the_coarse_stage_together_and_matches_fits_one_by_one():
    # 60,000 samples × 3 channels is beyond COARSE_RESIDUALS: each material is solved on a 10,000-sample subsample
    # (three materials × four starts: a compact batch, whose answers carry no sandwich middle) and refined on all
    # of its samples. Such a batch raised TypeError before (NormalEquations.at_point indexed the absent meat).
    sets = [synth.generate(models.get("lambert+ggx", alpha=0.1 + 0.05 * k), n=60_000, noise="relative:0.01", seed=k)
            for k in range(3)]
    together = fit_many(sets, "lambert+ggx")
    for k, (data, batched) in enumerate(zip(sets, together)):
        alone = fit(data, "lambert+ggx")
        assert batched.strategy == alone.strategy == "coarse (10000 samples) + refine"
        assert batched.status == alone.status == "converged"
        assert batched.cost == pytest.approx(alone.cost, rel=1e-8)
        for name in alone.params:
            np.testing.assert_allclose(batched.params[name], alone.params[name], rtol=1e-5, atol=1e-10)
        assert float(batched.params["alpha"]) == pytest.approx(0.1 + 0.05 * k, rel=0.01)  # the truth


def test_fit_many_batch_sizes_are_bucketed_and_padding_leaves_each_answer_unchanged():
    # fit_many pads a batch with copies of its last data set up to batch_bucket of its size (a database's batches
    # come in sizes that differ by one, and each size compiled anew): at most a quarter more work, few sizes per
    # octave, and a material's answer the same whatever the batch around it.
    from brdffit.fitting.api import batch_bucket

    buckets = [batch_bucket(n) for n in range(1, 2049)]
    assert all(n <= b <= max(n, 1.25 * (n - 1)) for n, b in zip(range(1, 2049), buckets))
    assert len(set(buckets)) == 8 + 4 * 8  # 1..8, then four sizes in each octave up to 2048
    sets = [synth.generate(models.get("lambert+ggx", alpha=0.1 + 0.03 * k), n=300, noise="relative:0.01", seed=k)
            for k in range(10)]
    nine, ten = fit_many(sets[:9], "lambert+ggx"), fit_many(sets, "lambert+ggx")
    assert len(nine) == 9 and batch_bucket(9) == 10
    for a, b in zip(nine, ten):
        assert a.cost == b.cost
        for name in a.params:
            np.testing.assert_array_equal(a.params[name], b.params[name])


def test_fit_many_rejects_unequal_shapes():
    a = synth.generate("lambert", n=100, seed=0)
    b = synth.generate("lambert", n=120, seed=0)
    with pytest.raises(ValueError, match="equally shaped"):
        fit_many([a, b], "lambert")


def test_second_fit_of_same_shapes_does_not_recompile(plastic):
    truth, data = plastic
    fit(data, "lambert+cook-torrance", fixed=["f0"])
    again = fit(data.replace(values=data.values * 1.01), "lambert+cook-torrance", fixed=["f0"])
    assert again.compile_time == 0.0


def test_multistart_records_every_start_and_keeps_the_best(plastic):
    truth, data = plastic
    result = fit(data, "lambert+cook-torrance", fixed=["f0"], multistart=4, loss="sigma")
    # init="auto" polishes the search's best separated candidates (brdffit.fitting.search); multistart adds 4.
    searched = fit(data, "lambert+cook-torrance", fixed=["f0"], loss="sigma")
    assert len(result.starts) == len(searched.starts) + 4
    costs = [s["cost"] for s in result.starts]
    assert result.cost == pytest.approx(min(costs), rel=1e-12)


@pytest.mark.parametrize("solver", ["lm", "optx-lm", "gauss-newton", "dogleg", "indirect-lm", "bfgs",
                                    optx.LevenbergMarquardt(rtol=1e-8, atol=1e-10)])
@pytest.mark.slow
def test_every_solver_reaches_the_same_optimum(plastic, solver):
    truth, data = plastic
    reference = fit(data, "lambert+cook-torrance", fixed=["f0"], loss="sigma")
    result = fit(data, "lambert+cook-torrance", fixed=["f0"], loss="sigma", solver=solver, max_steps=1000)
    assert result.converged, result.summary()
    assert result.cost == pytest.approx(reference.cost, rel=1e-6)


def test_robust_loss_resists_outliers():
    truth = models.get("lambert+ward", rho_d=[0.4, 0.3, 0.2], ks=[0.5, 0.4, 0.3], alpha=0.15)
    data = synth.generate(truth, pattern="half-diff", n=3000, noise="relative:0.01+outliers:0.05,10", seed=4)
    plain = fit(data, "lambert+ward", loss="relative")
    robust = fit(data, "lambert+ward", loss="relative", robust="cauchy")
    err_plain = abs(float(plain.params["alpha"]) / 0.15 - 1)
    err_robust = abs(float(robust.params["alpha"]) / 0.15 - 1)
    assert err_robust < 0.02 and err_robust < err_plain / 3


def test_independent_channel_mode_fits_shape_per_channel():
    base = synth.generate(models.get("lambert+ward", rho_d=[0.3, 0.3, 0.3], ks=[0.5, 0.5, 0.5], alpha=0.1),
                          pattern="half-diff", n=1500, noise="relative:0.01", seed=0)
    other = synth.generate(models.get("lambert+ward", rho_d=[0.3, 0.3, 0.3], ks=[0.5, 0.5, 0.5], alpha=0.3),
                           pattern="half-diff", n=1500, noise="relative:0.01", seed=0)
    # Channel 0 from a smooth material, channels 1 and 2 from a rough one (same directions: same seed).
    values = np.concatenate([base.values[:, :1], other.values[:, 1:]], axis=1)
    sigma = np.concatenate([base.sigma[:, :1], other.sigma[:, 1:]], axis=1)
    data = base.replace(values=values, sigma=sigma)
    result = fit(data, "lambert+ward", loss="sigma", channel_mode="independent")
    assert result.model is None and len(result.models) == 3
    np.testing.assert_allclose(result.params["alpha"], [0.1, 0.3, 0.3], rtol=0.02)
    assert result.predict(data.theta_i, data.phi_i, data.theta_o, data.phi_o).shape == data.values.shape
    # The merged result carries the channels' noise models (each σ-weighted fit to data of that σ: the loss's own
    # noise, whose stderr is the Laplace one) and their Laplace stderr.
    assert result.noise_model is not None and result.noise_model.name == "sigma", result.noise_model
    np.testing.assert_array_equal(result.stderr_laplace["alpha"], result.stderr["alpha"])
    assert np.shape(result.stderr_laplace["alpha"]) == (3,) and np.all(result.stderr_laplace["alpha"] > 0)
    assert result.theta_i_max == pytest.approx(float(np.max(data.theta_i)))


def test_result_serialises_to_json_and_hdf5(plastic, tmp_path):
    truth, data = plastic
    result = fit(data, "lambert+cook-torrance", fixed=["f0"])
    text = json.dumps(result.to_dict())
    back = json.loads(text)
    assert back["status"] == result.status and back["model"] == result.spec
    assert back["params"]["m"] == pytest.approx(float(result.params["m"]))
    path = tmp_path / "result.h5"
    group = result.save(path)
    assert group == "/fits/lambert+cook-torrance"
    loaded = FitResult.load(path)
    for name in result.params:
        np.testing.assert_allclose(loaded.params[name], result.params[name], rtol=1e-15)
        np.testing.assert_allclose(loaded.stderr[name], result.stderr[name], rtol=1e-15)
    np.testing.assert_allclose(loaded.covariance, result.covariance, rtol=1e-15)
    assert "model lambert+cook-torrance" in result.summary()


def test_undetermined_and_correlated_parameters_are_flagged():
    truth = models.get("lambert+cook-torrance", **PLASTIC)
    data = synth.generate(truth, pattern="half-diff", n=2000, noise="relative:0.01", seed=5)
    # Two Lambert lobes: only rho_d + rho_d_2 is determined, so JᵀJ is singular.
    twins = fit(data, "lambert+lambert")
    assert any("not determined" in w for w in twins.warnings), twins.warnings
    assert np.all(np.isinf(twins.stderr["rho_d"]))
    # Near normal incidence the Fresnel term is f0 everywhere, so ks and f0 only act as their product.
    near_normal = data.select_angles(max_theta_i=np.radians(10), max_theta_o=np.radians(10))
    product = fit(near_normal, "lambert+cook-torrance", init=truth)
    assert any("ks" in w and "f0" in w and ("correlated" in w or "not determined" in w)
               for w in product.warnings), product.warnings


def test_bad_arguments_give_clear_errors(plastic):
    truth, data = plastic
    with pytest.raises(ValueError, match="unknown loss"):
        fit(data, "lambert", loss="l1")
    with pytest.raises(ValueError, match="unknown solver"):
        fit(data, "lambert", solver="newton-raphson")
    with pytest.raises(ValueError, match="channel_mode"):
        fit(data, "lambert", channel_mode="mixed")
    with pytest.raises(ValueError, match="lobe_search must be True or False, got 'yes'"):
        fit(data, "lambert", lobe_search="yes")
    with pytest.raises(KeyError, match="no parameter"):
        fit(data, "lambert", fixed={"alpha": 0.1})
    with pytest.raises(ValueError, match="sigma"):
        fit(data.replace(sigma=None), "lambert", loss="sigma")


def test_loss_definitions_by_hand():
    fm = np.array([[2.0], [1.0]])
    fd = np.array([[1.0], [1.0]])
    cos_i = np.array([0.5, 1.0])
    sqrt_w = np.array([2.0, 1.0])
    sigma = np.array([[0.5], [1.0]])
    eps = np.array([0.0])
    np.testing.assert_allclose(residuals("cosine", fm, fd, cos_i, sqrt_w, sigma, eps), [[1.0], [0.0]])
    np.testing.assert_allclose(residuals("log", fm, fd, cos_i, sqrt_w, sigma, eps),
                               [[2 * (np.log(2.0) - np.log(1.5))], [0.0]])
    np.testing.assert_allclose(residuals("relative", fm, fd, cos_i, sqrt_w, sigma, eps), [[1.0], [0.0]])
    np.testing.assert_allclose(residuals("sigma", fm, fd, cos_i, sqrt_w, sigma, eps), [[2.0], [0.0]])
    r = np.array([0.5, 3.0, -3.0])
    # Huber: squares sum to 2 s² ρ(r/s) with ρ = z²/2 inside, |z| − 1/2 outside (s = 1).
    np.testing.assert_allclose(np.asarray(robust_residuals("huber", r, 1.0)) ** 2, [0.25, 5.0, 5.0])
    np.testing.assert_allclose(np.asarray(robust_residuals("cauchy", r, 1.0)) ** 2, np.log1p(r ** 2))


def test_measurements_without_sigma_fit_with_cosine_loss():
    truth = models.get("lambert", rho_d=[0.2, 0.4, 0.6])
    clean = synth.generate(truth, pattern="uniform", n=500, seed=0)
    data = Measurements(clean.theta_i, clean.phi_i, clean.theta_o, clean.phi_o, clean.values)
    result = fit(data, "lambert")
    np.testing.assert_allclose(result.params["rho_d"], [0.2, 0.4, 0.6], rtol=1e-6)


def test_only_the_relative_loss_reads_epsilon():
    values = np.array([[1.0, np.nan], [3.0, 4.0]])
    np.testing.assert_allclose(loss_epsilon("relative", values), relative_epsilon(values))
    np.testing.assert_allclose(relative_epsilon(values), [2e-3, 4e-3])  # 1e-3 × mean |valid value| per channel
    for loss in ("cosine", "log", "absolute", "sigma"):
        np.testing.assert_array_equal(loss_epsilon(loss, values), [1.0, 1.0])


def test_fit_data_holds_the_per_sample_arrays_written_out_in_numpy():
    rng = np.random.default_rng(4)
    n = 40
    theta_i, theta_o = rng.uniform(0, 1.5, n), rng.uniform(0, 1.5, n)
    phi_i, phi_o = rng.uniform(0, 6.28, n), rng.uniform(0, 6.28, n)
    values = rng.uniform(0.1, 1.0, (n, 3))
    values[3, 1] = np.nan
    sigma = rng.uniform(0.01, 0.1, (n, 3))
    sigma[3, 1] = np.nan  # no sigma where the value is missing
    weights = rng.uniform(0.5, 2.0, n)
    data = Measurements(theta_i, phi_i, theta_o, phi_o, values, sigma=sigma, weights=weights)
    got = make_fit_data(data, {"m": 0.2}, np.full(3, 1e-3), 0.5)
    mask = np.isfinite(values)
    np.testing.assert_array_equal(got.mask, mask)
    np.testing.assert_array_equal(got.values, np.where(mask, values, 0.0))
    np.testing.assert_allclose(got.cos_i, np.cos(theta_i), rtol=1e-15)
    np.testing.assert_allclose(got.sqrt_weight, np.sqrt(weights), rtol=1e-15)
    np.testing.assert_array_equal(got.sigma, np.where(mask, sigma, 1.0))
    wi = np.stack([np.sin(theta_i) * np.cos(phi_i), np.sin(theta_i) * np.sin(phi_i), np.cos(theta_i)], -1)
    wo = np.stack([np.sin(theta_o) * np.cos(phi_o), np.sin(theta_o) * np.sin(phi_o), np.cos(theta_o)], -1)
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=-1, keepdims=True)
    np.testing.assert_allclose(got.pair.wi, wi, atol=1e-15)
    np.testing.assert_allclose(got.pair.h, h, atol=1e-15)
    np.testing.assert_allclose(got.pair.cos_d, np.sum(wi * h, -1), rtol=1e-14)
    assert float(got.fixed["m"]) == 0.2 and float(got.robust_scale) == 0.5
    plain = make_fit_data(Measurements(theta_i, phi_i, theta_o, phi_o, values), {}, np.ones(3))
    np.testing.assert_array_equal(plain.sigma, np.ones((n, 3)))  # no sigma, no weights: ones
    np.testing.assert_array_equal(plain.sqrt_weight, np.ones(n))


def test_coarse_stage_of_optimistix_lm_solves_normal_equations_in_float64_only():
    import lineax as lx

    solver = coarse_solver("optx-lm", 1e-5, 1e-8)
    assert isinstance(solver, optx.LevenbergMarquardt) and isinstance(solver.descent.linear_solver, lx.Normal)
    assert (solver.rtol, solver.atol) == (1e-5, 1e-8)
    with jax.enable_x64(False):
        single = coarse_solver("optx-lm", 1e-5, 1e-8)
    assert isinstance(single.descent.linear_solver, lx.QR)  # float32 cannot afford the squared condition number
    assert isinstance(coarse_solver("dogleg", 1e-5, 1e-8), optx.Dogleg)
    # The engine's own: no linear solver, and the coarse relative offset.
    assert coarse_solver("lm", 1e-5, 1e-8) == Marquardt(rtol=1e-5, atol=1e-8, offset=COARSE_OFFSET)


@pytest.mark.parametrize("spec", ["lambert+cook-torrance", "lambert+ward", "lambert+lafortune(lobes=2)",
                                  "lambert+blinn-phong"])
def test_the_coarse_stage_ends_within_its_stated_cost_of_the_optimum(spec):
    """`COARSE_OFFSET` = 3e-2 leaves a Gauss-Newton step of about 3e-2 √p standard errors: the cost within ~1e-3 p
    of its minimum in χ² units (the offset squared times p; cost over cost/dof). Measured on these misspecified
    fits: at most 3.8e-4 p (two Lafortune lobes)."""
    truth = models.get("lambert+ggx", rho_d=[0.3, 0.2, 0.1], ks=[0.6, 0.5, 0.4], alpha=0.25, f0=0.05)
    data = synth.generate(truth, pattern="uniform", n=800, noise="relative:0.01", seed=21)
    tight = fit(data, spec)
    coarse = fit(data, spec, solver=coarse_solver("lm", 1e-5, 1e-8))
    assert tight.converged and coarse.converged
    excess = (coarse.cost - tight.cost) / (tight.cost / tight.dof)
    assert -1e-6 <= excess <= 1e-3 * tight.n_params, excess


@pytest.mark.slow
def test_coarse_to_fine_gives_the_full_data_answer():
    # Above COARSE_SAMPLES samples a fit may solve on a subsample and refine on all data (brdffit.fitting.marquardt); the
    # optimum, its cost and its covariance must be those of the plain full-data solve.
    truth = models.get("lambert+ward", rho_d=[0.4, 0.3, 0.2], ks=[0.5, 0.4, 0.3], alpha=0.2)
    data = synth.generate(truth, pattern="half-diff", n=120_000, noise="relative:0.01", seed=9)
    full = fit(data, "lambert+ward", coarse=False)
    staged = fit(data, "lambert+ward", coarse=True)
    assert full.strategy == "full" and staged.strategy.startswith("coarse")
    assert staged.converged
    assert staged.cost == pytest.approx(full.cost, rel=1e-9)
    for name in full.params:
        np.testing.assert_allclose(staged.params[name], full.params[name], rtol=1e-6)
        np.testing.assert_allclose(staged.stderr[name], full.stderr[name], rtol=1e-3)
        np.testing.assert_allclose(staged.stderr_robust[name], full.stderr_robust[name], rtol=1e-3)
    # The refinement's last pass supplies the per-channel loss RMSE; the other metrics come from their own pass.
    for metric in full.metrics:
        np.testing.assert_allclose(staged.metrics[metric], full.metrics[metric], rtol=1e-6)


def test_loading_a_missing_fit_names_the_file(tmp_path):
    from brdffit.io import FormatError

    data = synth.generate("lambert", n=50, seed=0)
    path = tmp_path / "only-data.h5"
    io.save(data, path)
    with pytest.raises(FormatError, match="only-data.h5.*no /fits group"):
        FitResult.load(path)
    fit(data, "lambert").save(path)
    with pytest.raises(FormatError, match="no fit named 'ggx'"):
        FitResult.load(path, "ggx")


@pytest.mark.parametrize("solver", ["gauss-newton", "bfgs"])
def test_fragile_solvers_reach_the_optimum_from_a_far_start(solver):
    # Found by scripts/stability.py on the joint solve: from a far start, undamped Gauss-Newton ended ~1e4x the
    # optimal cost and BFGS saturated rho_d's bound transform at 0. With the amplitudes projected out
    # (brdffit.fitting.separable) both solve a one-parameter problem in m and reach the optimum.
    truth = models.get("lambert+cook-torrance", rho_d=[0.3, 0.2, 0.1], ks=[0.8, 0.7, 0.6], m=0.15, f0=0.04)
    data = synth.generate(truth, pattern="half-diff", n=2000, noise="relative:0.01", seed=0)
    far = dict(rho_d=[0.9] * 3, ks=[0.001] * 3, m=0.9)
    fragile = fit(data, "lambert+cook-torrance", solver=solver, init=far, fixed={"f0": 0.04})
    good = fit(data, "lambert+cook-torrance", init=far, fixed={"f0": 0.04})
    assert good.converged and fragile.converged
    assert fragile.cost == pytest.approx(good.cost, rel=1e-8)


def test_a_solver_that_stops_far_from_the_minimum_is_not_reported_converged():
    # A solver whose own termination test passes far from the optimum (here BFGS with tolerances of 0.5: it
    # stops after its first steps) must be reported stalled by the Gauss-Newton decrease test
    # (brdffit.fitting.status), not converged.
    truth = models.get("lambert+cook-torrance", rho_d=[0.3, 0.2, 0.1], ks=[0.8, 0.7, 0.6], m=0.15, f0=0.04)
    data = synth.generate(truth, pattern="half-diff", n=2000, noise="relative:0.01", seed=0)
    far = dict(rho_d=[0.9] * 3, ks=[0.001] * 3, m=0.9)
    careless = optx.BFGS(rtol=0.5, atol=0.5)
    stalled = fit(data, "lambert+cook-torrance", solver=careless, init=far, fixed={"f0": 0.04})
    good = fit(data, "lambert+cook-torrance", init=far, fixed={"f0": 0.04})
    assert good.converged and stalled.cost > good.cost * (1 + 1e-3)
    assert stalled.status == "stalled" and not stalled.converged
    assert any("not a minimum" in w for w in stalled.warnings)


def test_an_active_bound_is_still_converged_at_bound(plastic):
    # rho_d pressed against its upper bound by data brighter than it allows: the descent direction points out of
    # the box, so the bound is active (KKT) and the fit has converged there.
    truth, data = plastic
    bright = data.replace(values=data.values * 4.0, sigma=data.sigma * 4.0)
    result = fit(bright, "lambert", loss="sigma")
    assert result.status == "converged-at-bound"


def test_auto_init_reaches_the_optimum_of_a_near_mirror():
    # scripts/stability.py, near-mirror seed 3: the joint LM solve from the automatic start saturated rho_d's
    # bound transform in two channels (rho_d -> 0, "stalled") and needed a restart. With the amplitudes solved
    # exactly and the roughness searched over its bounds, the automatic fit reaches the optimum that a start at
    # the truth finds, directly.
    truth = models.get("lambert+cook-torrance", rho_d=[0.3, 0.2, 0.1], ks=[0.8, 0.7, 0.6], m=0.02, f0=0.04)
    data = synth.generate(truth, pattern="half-diff", n=2000, noise="relative:0.01", seed=3)
    oracle = fit(data, "lambert+cook-torrance", init=truth, fixed={"f0": 0.04})
    result = fit(data, "lambert+cook-torrance", fixed={"f0": 0.04})
    assert result.converged and not result.bounds_hit
    assert result.cost == pytest.approx(oracle.cost, rel=1e-6)
    assert not any("held" in w for w in result.warnings)
    # The same optimum as the oracle (which itself sits ~1 standard error, 0.06, off the true rho_d here: with
    # m = 0.02 the diffuse level is seen through few samples).
    for name in ("rho_d", "ks", "m"):
        np.testing.assert_allclose(result.params[name], oracle.params[name], rtol=1e-4)


def test_a_fit_inside_jax_float32_mode_runs_in_float32_and_finds_the_same_optimum(plastic):
    # docs/conventions.md: `with jax.enable_x64(False)` runs a whole fit in float32.
    truth, data = plastic
    double = fit(data, "lambert+cook-torrance", fixed={"f0": 0.04}, init=truth)
    with jax.enable_x64(False), warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Explicitly requested dtype")
        single = fit(data, "lambert+cook-torrance", fixed={"f0": 0.04}, init=truth)
    assert np.asarray(single.params["m"]).dtype == np.float32
    assert single.converged
    for name in ("rho_d", "ks", "m"):  # float32 carries ~7 digits; the noise-limited stderr is ~1e-3 relative
        np.testing.assert_allclose(single.params[name], double.params[name], rtol=1e-4)


def test_tolerances_are_raised_to_what_float32_can_meet_and_unchanged_in_float64():
    from brdffit.fitting.solvers import working_tolerances

    assert working_tolerances(1e-8, 1e-12) == (1e-8, 1e-12)
    with jax.enable_x64(False):
        rtol, atol = working_tolerances(1e-8, 1e-12)
    eps32 = float(np.finfo(np.float32).eps)
    assert rtol == pytest.approx(100 * eps32) and atol == pytest.approx(eps32)


def test_dead_lobe_warning_only_for_amplitudes_at_zero():
    """The "went to 0" warning names an amplitude that sits at 0 in every channel, not one on its upper bound:
    Lambert data with albedo π·1.5 (beyond ρd's bound of 1) end with ρd at 1, a GGX lobe beside Lambert data of
    albedo 0.4 ends with ks at 0."""
    bright = synth.generate(models.get("lambert", rho_d=[0.5, 0.5, 0.5]), n=600, noise=None, seed=3)
    bright = bright.replace(values=bright.values * 3.0)
    result = fit(bright, "lambert")
    np.testing.assert_allclose(result.params["rho_d"], 1.0)
    assert "rho_d[0]" in result.bounds_hit
    assert not any("went to 0" in w for w in result.warnings), result.warnings
    dull = synth.generate(models.get("lambert", rho_d=[0.4, 0.4, 0.4]), n=600, noise=None, seed=4)
    result = fit(dull, "lambert+ggx")
    np.testing.assert_array_equal(result.params["ks"], 0.0)
    assert any(w.startswith("ks went to 0 in every channel") for w in result.warnings), result.warnings


def test_summary_of_a_spectrum_gives_one_row_per_channel():
    """Above SPECTRAL_CHANNELS channels the colour parameters are a per-channel block (one row a band, one column a
    parameter), so a 31-band fit prints 31 rows, not 62; shape parameters stay in the main table."""
    from brdffit.fitting.result import SPECTRAL_CHANNELS

    channels = SPECTRAL_CHANNELS + 4
    rho = np.linspace(0.2, 0.7, channels)
    truth = models.get("lambert+blinn-phong", channels=channels, rho_d=rho, ks=np.full(channels, 0.3), n=40.0)
    data = synth.generate(truth, pattern="half-diff", n=600, noise="relative:0.01", seed=2)
    result = fit(data, "lambert+blinn-phong")
    lines = result.summary().splitlines()
    block = next(i for i, line in enumerate(lines) if line.startswith(f"per channel ({channels} channels"))
    assert lines[block + 1].split() == ["channel", "rho_d", "ks"]
    rows = lines[block + 2: block + 2 + channels]
    for c, row in enumerate(rows):
        cells = row.split()
        assert int(cells[0]) == c
        assert float(cells[1]) == pytest.approx(float(result.params["rho_d"][c]), rel=1e-5)
        assert float(cells[4]) == pytest.approx(float(result.params["ks"][c]), rel=1e-5)
    assert not any(line.startswith("rho_d[") for line in lines)
    assert any(line.startswith("n ") for line in lines[:block])
    three = fit(synth.generate(models.get("lambert", rho_d=[0.2, 0.3, 0.4]), n=200, seed=1), "lambert").summary()
    assert "rho_d[2]" in three and "per channel" not in three


def test_a_list_of_starts_ending_in_auto_is_scored_beside_the_search():
    # init as a list scores those settings instead of the search's grid; ending in "auto", before it (how
    # brdffit.select starts a material with a layer from the fit without it). The near-mirror's optimum
    # (m = 0.02) is far from the given setting (m = 0.9): the grid is what reaches it.
    truth = models.get("lambert+cook-torrance", rho_d=[0.3, 0.2, 0.1], ks=[0.8, 0.7, 0.6], m=0.02, f0=0.04)
    data = synth.generate(truth, pattern="half-diff", n=2000, noise="relative:0.01", seed=3)
    searched = fit(data, "lambert+cook-torrance", fixed={"f0": 0.04})
    given = fit(data, "lambert+cook-torrance", fixed={"f0": 0.04}, init=[{"m": 0.9}])
    both = fit(data, "lambert+cook-torrance", fixed={"f0": 0.04}, init=[{"m": 0.9}, "auto"])
    default_m = models.get("lambert+cook-torrance").params["m"]
    started = {round(float(np.mean(s["init"]["m"])), 9) for s in given.starts}
    assert started <= {0.9, round(float(default_m), 9)}  # the given setting and the model's own value only
    assert len({round(float(np.mean(s["init"]["m"])), 9) for s in both.starts} - started) > 0
    assert both.cost == pytest.approx(searched.cost, rel=1e-9)
    with pytest.raises(ValueError, match="optionally ending in 'auto'"):
        fit(data, "lambert+cook-torrance", init=[0.5, "auto"])
