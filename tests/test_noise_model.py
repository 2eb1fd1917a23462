"""The noise model chosen from a fit's residuals, and the standard error it makes the default (brdffit.fitting.noise).

The coverage tests fit many seeded replicates of one synthetic material with `brdffit.fit_many` (one batched
solve; warm, each batch takes seconds) and count how often the reported default 68% interval
(value ± stderr) holds the truth: for R = 150 replicates the binomial standard error of a 68% coverage is 3.8%,
so 55-82% is the nominal value within about ±3.5 of them.
"""

import json
from pathlib import Path

import numpy as np
import pytest

import brdffit
from brdffit import synth
from brdffit.fitting.noise import NoiseModel, compare, merge

ROOT = Path(__file__).resolve().parents[1]
TRUTH = {"rho_d": 0.3, "ks": 0.4, "alpha": 0.15}
REPLICATES = 150
COVERAGE = (0.55, 0.82)


def _replicates(noise, seed, count=REPLICATES):
    truth = brdffit.models.get("lambert+ward", channels=1, **TRUTH)
    # Half-diff samples cover the specular peak (a uniform pattern leaves a few samples with most of the leverage,
    # which no sandwich estimate covers at n = 500); θ ≤ 80°, as a gonio-reflectometer measures.
    return [synth.generate(truth, pattern="half-diff", n=500, noise=noise, seed=seed + i,
                           max_theta=np.deg2rad(80.0), channels=["c0"]) for i in range(count)]


def _coverage(results, attribute="stderr"):
    coverage = {}
    for name, truth in TRUTH.items():
        values = np.array([float(np.ravel(r.params[name])[0]) for r in results])
        errors = np.array([float(np.ravel(getattr(r, attribute)[name])[0]) for r in results])
        coverage[name] = float(np.mean(np.abs(values - truth) <= errors))
    return coverage


@pytest.fixture(scope="module")
def relative_fits():
    return brdffit.fit_many(_replicates("relative:0.03", 3000), "lambert+ward")


@pytest.fixture(scope="module")
def absolute_fits():
    return brdffit.fit_many(_replicates("gaussian:0.01", 4000), "lambert+ward")


def test_relative_noise_is_identified_and_the_default_stderr_covers(relative_fits):
    assert all(r.converged for r in relative_fits)
    assert [r.noise_model.name for r in relative_fits] == ["relative"] * REPLICATES
    # The cosine loss weights for σ ∝ 1/cosθi, not for σ ∝ f: the default is the noise-model covariance.
    assert {r.stderr_kind for r in relative_fits} == {"noise-model"}
    coverage = _coverage(relative_fits)
    assert all(COVERAGE[0] <= c <= COVERAGE[1] for c in coverage.values()), coverage
    # The Laplace standard error, the old default, does not cover alpha (measured: 0.47 of 150 replicates).
    assert _coverage(relative_fits, "stderr_laplace")["alpha"] < COVERAGE[0]


def test_absolute_noise_is_identified_and_the_default_stderr_covers(absolute_fits):
    assert all(r.converged for r in absolute_fits)
    assert [r.noise_model.name for r in absolute_fits] == ["absolute"] * REPLICATES
    assert {r.stderr_kind for r in absolute_fits} == {"noise-model"}  # still not the cosine loss's own noise
    coverage = _coverage(absolute_fits)
    assert all(COVERAGE[0] <= c <= COVERAGE[1] for c in coverage.values()), coverage


def test_the_loss_weighted_for_the_noise_reports_laplace():
    results = brdffit.fit_many(_replicates("gaussian:0.01", 5000), "lambert+ward", loss="absolute")
    assert [r.noise_model.name for r in results] == ["absolute"] * REPLICATES
    assert {r.stderr_kind for r in results} == {"laplace"}
    for r in results:
        for name in TRUTH:
            np.testing.assert_array_equal(r.stderr[name], r.stderr_laplace[name])
    coverage = _coverage(results)
    assert all(COVERAGE[0] <= c <= COVERAGE[1] for c in coverage.values()), coverage


def test_signal_dependent_noise_is_identified(absolute_fits):
    # σ² = k f (photon noise), drawn here: synth's signal-dependent noise is σ = a + b f.
    truth = brdffit.models.get("lambert+ward", channels=1, **TRUTH)
    items = []
    for i, clean in enumerate(_replicates(None, 6000, 40)):
        f = clean.values[:, 0]
        noisy = f + np.sqrt(1e-4 * f) * np.random.default_rng(i).standard_normal(f.shape)
        items.append(clean.replace(values=np.maximum(noisy, 1e-6)[:, None]))
    names = [r.noise_model.name for r in brdffit.fit_many(items, truth.spec)]
    assert names.count("signal") >= 38, names


def test_shipped_plastic_default_stderr_is_consistent_with_the_truth():
    m = brdffit.io.load(ROOT / "data" / "synthetic" / "plastic.h5")
    truth = synth.truth_model(m)
    result = brdffit.fit(m, "lambert+cook-torrance", fixed={"f0": 0.04})
    assert result.noise_model.name == "relative" and result.stderr_kind == "noise-model"
    z_default, z_laplace = [], []
    for name in ("rho_d", "ks", "m"):
        error = np.ravel(result.params[name]) - np.ravel(truth.params[name])
        z_default.extend(np.abs(error) / np.ravel(result.stderr[name]))
        z_laplace.extend(np.abs(error) / np.ravel(result.stderr_laplace[name]))
    assert max(z_default) < 3.0, z_default  # measured: 1.99 (rho_d[0]), 1.71 (ks[0])
    assert max(z_laplace) > 20.0  # the old default put ks[0] 27σ from the truth
    summary = result.summary()
    assert "noise relative" in summary and "stderr noise-model" in summary


def test_noise_model_round_trip_and_old_files(tmp_path, absolute_fits):
    result = absolute_fits[0]
    path = tmp_path / "fit.h5"
    result.save(path)
    loaded = brdffit.FitResult.load(path)
    assert loaded.noise_model == result.noise_model and loaded.stderr_kind == result.stderr_kind
    for name in TRUTH:
        np.testing.assert_array_equal(loaded.stderr_laplace[name], result.stderr_laplace[name])
        np.testing.assert_array_equal(loaded.stderr[name], result.stderr[name])
    # A result written before noise models were compared: no noise_model, no stderr_laplace; its stderr was
    # the Laplace one.
    old = json.loads(json.dumps(result.to_dict()))
    for key in ("noise_model", "stderr_laplace", "stderr_kind", "theta_i_max"):
        del old[key]
    legacy = brdffit.FitResult.from_dict(old)
    assert legacy.noise_model is None and legacy.stderr_kind == "laplace"
    assert legacy.stderr_laplace.keys() == legacy.stderr.keys()
    assert "noise: not recorded" in legacy.summary(plausibility=False)


def test_compare_maximum_likelihood_by_hand():
    rng = np.random.default_rng(1)
    f = rng.uniform(0.1, 3.0, 4000)
    d = 0.02 * f * rng.standard_normal(f.size)
    cos_i = rng.uniform(0.2, 1.0, f.size)
    sums = brdffit.metrics.metric_sums(f[:, None], (f - d)[:, None], np.ones((f.size, 1), bool), cos_i,
                                       np.ones(f.size), xp=np)
    noise = compare(sums, "cosine", n_total=f.size)
    assert noise.name == "relative" and noise.covariance == "noise-model" and noise.forms == ("relative",)
    n = f.size
    for name, g in (("absolute", np.ones(n)), ("relative", f ** 2), ("signal", f), ("cosine", 1 / cos_i ** 2)):
        s2 = np.mean(d ** 2 / g)
        expected = -0.5 * n * (np.log(2 * np.pi * s2) + 1) - 0.5 * np.sum(np.log(g))
        assert noise.loglik[name] == pytest.approx(expected, rel=1e-10), name
        assert noise.scale[name][0] == pytest.approx(np.sqrt(s2), rel=1e-10)
    assert noise.scale["relative"][0] == pytest.approx(0.02, rel=0.05)
    assert NoiseModel.from_dict(json.loads(json.dumps(noise.to_dict()))) == noise


def test_independent_channels_merge_their_noise_models():
    rng = np.random.default_rng(2)
    f = rng.uniform(0.1, 3.0, 3000)
    cos_i = rng.uniform(0.2, 1.0, f.size)
    models = []
    for d in (0.02 * f * rng.standard_normal(f.size), 0.01 * rng.standard_normal(f.size)):
        sums = brdffit.metrics.metric_sums(f[:, None], (f - d)[:, None], np.ones((f.size, 1), bool), cos_i,
                                           np.ones(f.size), xp=np)
        models.append(compare(sums, "absolute", n_total=f.size))
    assert [m.name for m in models] == ["relative", "absolute"]
    assert [m.covariance for m in models] == ["noise-model", "laplace"]
    merged = merge(models)
    assert merged.name == "relative/absolute" and merged.covariance == "noise-model/laplace"
    assert merged.forms == ("relative", "absolute")
    assert merged.loglik["signal"] == pytest.approx(models[0].loglik["signal"] + models[1].loglik["signal"])
    assert len(merged.scale["relative"]) == 2 and "per channel relative/absolute" in merged.describe("absolute")[0]
    assert merge([models[1], models[1]]).name == "absolute" and merge([None]) is None


def test_a_channel_departs_from_the_common_noise_model_only_where_its_values_show_it():
    # Three channels of relative noise and one of absolute noise, compared together for the cosine loss.
    rng = np.random.default_rng(4)
    f = rng.uniform(0.1, 3.0, (4000, 4))
    cos_i = rng.uniform(0.2, 1.0, 4000)
    d = np.concatenate([0.02 * f[:, :3] * rng.standard_normal((4000, 3)), 0.02 * rng.standard_normal((4000, 1))],
                       axis=1)
    sums = brdffit.metrics.metric_sums(f, f - d, np.ones(f.shape, bool), cos_i, np.ones(4000), xp=np)
    noise = compare(sums, "cosine", n_total=f.size)
    assert noise.name == "relative" and noise.forms == ("relative",) * 3 + ("absolute",)
    assert noise.covariance == "noise-model"
    lines = noise.describe("cosine", ["r", "g", "b", "ir"])
    assert lines[1].startswith("noise per channel: absolute (σ = s, s = 0.0198) in ir (each"), lines
    assert "ΔAIC over all channels signal -" in lines[0], lines  # signal leads the sum, and no channel chose it
    # The same absolute channel with the others: each channel's log-likelihoods are its own, so one channel of
    # another noise does not move the common choice, and channels of the common noise never depart.
    same = compare(brdffit.metrics.metric_sums(f[:, :3], (f - d)[:, :3], np.ones((4000, 3), bool), cos_i,
                                               np.ones(4000), xp=np), "cosine", n_total=12000)
    assert same.forms == ("relative",) * 3 and len(same.describe("cosine")) == 2
