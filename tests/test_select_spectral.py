"""Selection on a spectrum: the candidates are compared on averages of contiguous bands (`select.SCREEN_BANDS`),
exact for models whose shape the channels share, and the chosen model is then fitted to every band."""

import numpy as np
import pytest

from brdffit import evaluate, fit, models, select, synth
from brdffit.select import SCREEN_BANDS, _channel_averages

BANDS = 31


def _truth(channels=BANDS):
    wavelengths = np.linspace(400, 700, channels)
    rho = 0.2 + 0.5 * np.exp(-((wavelengths - 470) / 60.0) ** 2)
    return models.get("lambert+ggx", channels=channels, rho_d=rho, ks=0.2 + 0.2 * (wavelengths - 400) / 300,
                      alpha=0.15)


def test_band_averages_are_the_same_model_with_averaged_amplitudes():
    """Noise-free data of a 31-band material, averaged in 3 groups, equal the same model's values with each
    group's amplitudes averaged (the averaging commutes with a sum of lobes of one shape), to rounding."""
    truth = _truth()
    data = synth.generate(truth, pattern="gonio-grid", n=400, noise=None, seed=1)
    averaged = _channel_averages(data, {})
    groups = list(averaged.meta["averaged"].values())
    assert averaged.n_channels == SCREEN_BANDS and [len(g) for g in groups] == [11, 10, 10]
    index = np.array_split(np.arange(BANDS), SCREEN_BANDS)
    mean = {name: np.array([np.asarray(truth.params[name])[k].mean() for k in index]) for name in ("rho_d", "ks")}
    expected = models.get("lambert+ggx", channels=SCREEN_BANDS, alpha=0.15, **mean)
    values = np.asarray(evaluate(expected, data.theta_i, data.phi_i, data.theta_o, data.phi_o))
    np.testing.assert_allclose(averaged.values, values, rtol=1e-12)
    # Missing bands are left out of their group's mean; a group with none is missing.
    holes = data.values.copy()
    holes[0, :11] = np.nan
    holes[1, 0] = np.nan
    with_holes = _channel_averages(data.replace(values=holes), {})
    assert np.isnan(with_holes.values[0, 0]) and with_holes.values[0, 1] == averaged.values[0, 1]
    assert with_holes.values[1, 0] == pytest.approx(np.mean(data.values[1, 1:11]), rel=1e-15)
    # Not averaged: three channels or fewer, channels fitted independently, a per-channel fixed value.
    assert _channel_averages(synth.generate(_truth(3), n=50, seed=1), {}) is None
    assert _channel_averages(data, {"channel_mode": "independent"}) is None
    assert _channel_averages(data, {"fixed": {"ks": np.full(BANDS, 0.3)}}) is None


def test_the_chosen_model_is_fitted_to_every_band_and_its_heldout_error_is_over_every_band():
    truth = _truth()
    data = synth.generate(truth, pattern="gonio-grid", n=1500, noise="relative:0.01", seed=3)
    selection = select(data, candidates=["lambert", "lambert+ggx", "lambert+ward"])
    assert selection.chosen == "lambert+ggx" and "3 averages of 10-11 of the 31 channels" in selection.compared_on
    assert all(row["samples"] <= data.n * SCREEN_BANDS for row in selection.table)
    result = selection.result
    assert result.model.channels == BANDS and result.converged
    # The same optimum as a fit of every band from the default search.
    direct = fit(data, "lambert+ggx")
    assert result.cost == pytest.approx(direct.cost, rel=1e-8)
    for name in ("rho_d", "ks", "alpha"):
        np.testing.assert_allclose(result.params[name], direct.params[name], rtol=1e-5)
    # Over every band, the held-out error is the noise's: the truth's own loss on those rows (1% relative noise),
    # within 5%, and not the averages' (whose noise is ~√10 smaller).
    every, scale = selection.channel_heldout
    rng = np.random.default_rng(0)
    held = rng.permutation(np.flatnonzero(np.any(np.isfinite(data.values), axis=1)))[: int(round(0.2 * data.n))]
    noise_free = np.asarray(evaluate(truth, data.theta_i, data.phi_i, data.theta_o, data.phi_o))
    loss = (data.values - noise_free) * (np.cos(data.theta_i) * np.sqrt(data.weights))[:, None]  # cosine loss
    floor = np.sqrt(np.mean(loss[held] ** 2))
    assert every == pytest.approx(floor, rel=0.05)
    averaged_error = {row["spec"]: row["heldout_error"] for row in selection.table}["lambert+ggx"]
    assert averaged_error < 0.5 * every
    assert selection.verdict().startswith(f"verdict: lambert+ggx: error on unseen directions {every:.4g} = "
                                          f"{every / scale:.1%} of the reflected radiance (loss RMS over every")
