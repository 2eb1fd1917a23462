"""Posteriors with emcee: agreement with the Laplace errors, calibration, resuming, robustness, output."""

import json

import h5py
import numpy as np
import pytest

from brdffit import fit, models, synth
from brdffit.posterior import posterior

WARD = dict(rho_d=[0.4, 0.3, 0.2], ks=[0.5, 0.4, 0.3], alpha=0.2)


@pytest.fixture(scope="module")
def ward_fit():
    truth = models.get("lambert+ward", **WARD)
    data = synth.generate(truth, pattern="half-diff", n=600, noise="gaussian:0.01", seed=11)
    return truth, data, fit(data, "lambert+ward", loss="sigma")


def test_posterior_agrees_with_laplace_for_a_well_determined_fit(ward_fit):
    truth, data, result = ward_fit
    post = posterior(result, data, nwalkers=24, nsteps=1500, noise="known", progress=False, seed=1)
    assert post.names == ["rho_d[0]", "rho_d[1]", "rho_d[2]", "ks[0]", "ks[1]", "ks[2]", "alpha"]
    for name in post.names:
        s = post.summary[name]
        # Near-Gaussian likelihood: the posterior median sits at the least-squares value and the posterior std
        # matches the Laplace error within 20%. The median's allowance, a quarter of the width, covers its Monte
        # Carlo error (about 1.25 σ/√ESS with ESS ~ 1000) plus the slight skew of alpha's posterior.
        assert abs(s["median"] - post.fit_values[name]) < 0.25 * post.laplace_stderr[name]
        assert s["std"] == pytest.approx(post.laplace_stderr[name], rel=0.2)
        assert s["q2.5"] < s["q16"] < s["median"] < s["q84"] < s["q97.5"]
    d = post.diagnostics
    assert 0.15 <= d["acceptance_fraction"] <= 0.6
    assert d["r_hat_max"] < 1.05
    assert d["steps"] == 1500 and d["samples"] == post.samples.shape[0]
    assert post.burn >= 2 * d["tau_max"] - 1 and post.thin >= 1


def test_noise_scale_is_estimated_per_channel(ward_fit):
    truth, data, result = ward_fit
    # The fit used loss="sigma" with σ = 0.01, so the residuals have unit scale in every channel.
    post = posterior(result, data, nwalkers=24, nsteps=800, progress=False, seed=2)
    for c in range(3):
        s = post.summary[f"noise_sigma[{c}]"]
        assert s["q2.5"] < 1.0 < s["q97.5"]
        assert s["median"] == pytest.approx(1.0, abs=0.1)


@pytest.mark.slow
def test_intervals_are_calibrated_over_repeated_data_sets():
    # Issue 5's calibration check, small version (scripts/posterior_calibration.py runs the larger study):
    # 68% intervals must cover the truth in 55-80% of cases and 95% intervals in 88-99%.
    # Parameters of one data set are correlated (ks and alpha miss together), so many data sets are needed for a
    # stable coverage estimate: 24 here, 168 intervals. With 300 half-diff samples the peak is hit too rarely for
    # the errors to be Gaussian (even the Laplace intervals then cover 95% of the truth in only 86% of cases);
    # 1000 samples determine the parameters.
    truth = models.get("lambert+ward", **WARD)
    hits68 = hits95 = total = 0
    for seed in range(24):
        data = synth.generate(truth, pattern="half-diff", n=1000, noise="gaussian:0.01", seed=100 + seed)
        result = fit(data, "lambert+ward", loss="sigma")
        post = posterior(result, data, nwalkers=16, nsteps=1000, noise="known", progress=False, seed=seed)
        true_flat = dict(zip(post.names, np.concatenate([np.ravel(truth.params[n]) for n in truth.params])))
        for name in post.names:
            s = post.summary[name]
            hits68 += s["q16"] <= true_flat[name] <= s["q84"]
            hits95 += s["q2.5"] <= true_flat[name] <= s["q97.5"]
            total += 1
    assert 0.55 <= hits68 / total <= 0.80, hits68 / total
    assert 0.88 <= hits95 / total <= 0.99, hits95 / total


def test_interrupted_and_resumed_chain_equals_uninterrupted(ward_fit, tmp_path):
    truth, data, result = ward_fit
    whole = tmp_path / "whole.h5"
    parts = tmp_path / "parts.h5"
    reference = posterior(result, data, nwalkers=24, nsteps=300, store=whole, progress=False, seed=7)
    posterior(result, data, nwalkers=24, nsteps=120, store=parts, progress=False, seed=7)  # "interrupted"
    resumed = posterior(result, data, nwalkers=24, nsteps=300, store=parts, progress=False, seed=7)
    np.testing.assert_array_equal(resumed.chain, reference.chain)
    with h5py.File(parts, "r") as f:
        assert f["posteriors/lambert+ward/chain"].attrs["iteration"] == 300


def test_student_t_likelihood_resists_outliers():
    truth = models.get("lambert+ward", **WARD)
    data = synth.generate(truth, pattern="half-diff", n=600, noise="gaussian:0.01+outliers:0.05,20", seed=3)
    result = fit(data, "lambert+ward", loss="absolute", robust="cauchy")
    gaussian = posterior(result, data, nwalkers=24, nsteps=800, progress=False, seed=0)
    robust = posterior(result, data, nwalkers=24, nsteps=800, likelihood="student-t", progress=False, seed=0)
    # The Gaussian likelihood inflates its noise scale to absorb the outliers; Student-t does not.
    assert robust.summary["noise_sigma[0]"]["median"] < 0.5 * gaussian.summary["noise_sigma[0]"]["median"]
    assert abs(robust.summary["alpha"]["median"] - 0.2) < 3 * robust.summary["alpha"]["std"] + 1e-3


def test_user_prior_pulls_the_posterior(ward_fit):
    truth, data, result = ward_fit
    # A Gaussian prior as wide as the likelihood, centred two widths above the optimum: the product of the two
    # Gaussians is centred one width above it (to the extent that alpha's likelihood is Gaussian).
    width = float(result.stderr_laplace["alpha"])  # the likelihood's width, whatever stderr reports
    centre = float(result.params["alpha"])
    pulled = posterior(result, data, nwalkers=24, nsteps=1500, noise="known", progress=False,
                       prior={"alpha": ("normal", centre + 2 * width, width)}, seed=0)
    assert pulled.summary["alpha"]["median"] == pytest.approx(centre + width, abs=0.3 * width)
    assert pulled.summary["alpha"]["std"] == pytest.approx(width / np.sqrt(2), rel=0.3)
    with pytest.raises(ValueError, match="not a free parameter"):
        posterior(result, data, nsteps=10, prior={"f0": ("normal", 0.0, 1.0)}, progress=False)
    with pytest.raises(ValueError, match="outside a prior's support"):
        posterior(result, data, nsteps=10, prior={"alpha": ("uniform", 0.5, 0.6)}, progress=False)


def test_subsampling_is_reported(ward_fit):
    truth, data, result = ward_fit
    post = posterior(result, data, nwalkers=24, nsteps=200, max_samples=200, progress=False)
    assert post.subsample == (200, 600)
    assert any("subsample of 200 of 600" in w for w in post.warnings)
    assert any("shorter than 50 autocorrelation times" in w for w in post.warnings)


def test_output_dict_save_and_predictive_band(ward_fit, tmp_path):
    truth, data, result = ward_fit
    post = posterior(result, data, nwalkers=24, nsteps=300, progress=False)
    d = json.loads(json.dumps(post.to_dict()))
    assert set(d["params"]["ks[1]"]) == {"mean", "median", "std", "q2.5", "q16", "q84", "q97.5"}
    assert {"acceptance_fraction", "tau", "ess", "r_hat"} <= set(d["diagnostics"])
    path = tmp_path / "run.h5"
    assert post.save(path) == "/posteriors/lambert+ward/result"
    with h5py.File(path, "r") as f:
        assert f["posteriors/lambert+ward/result/samples"].shape == post.samples.shape
    theta = np.radians(np.linspace(0, 80, 9))
    band = post.predictive_band(np.radians(30), 0.0, theta, np.pi, n_draws=50)
    assert band[2.5].shape == (9, 3)
    assert np.all(band[2.5] <= band[50.0]) and np.all(band[50.0] <= band[97.5])
    centre = result.predict(np.radians(30), 0.0, theta, np.pi)
    np.testing.assert_allclose(band[50.0], centre, rtol=0.01)


def test_too_few_walkers_is_a_clear_error(ward_fit):
    truth, data, result = ward_fit
    with pytest.raises(ValueError, match="at least twice the number of sampled dimensions"):
        posterior(result, data, nwalkers=16, nsteps=10, progress=False)


def test_independent_fits_are_rejected(ward_fit):
    truth, data, _ = ward_fit
    independent = fit(data, "lambert+ward", channel_mode="independent")
    with pytest.raises(ValueError, match="shared-shape"):
        posterior(independent, data, nsteps=10, progress=False)
