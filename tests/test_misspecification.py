"""Misspecification matrix: does `brdffit.fit` reach the global least-squares optimum when the model is wrong?

Seven truths (Lambert plus a Cook-Torrance, Ward, Blinn-Phong, Ashikhmin-Shirley, two-lobe Lafortune, Student-t
(STD) microfacet or anisotropic GGX specular lobe, with plausible RGB values) are sampled on the half-diff pattern with 1 % relative noise and each is fitted
with every standard candidate of model selection (`brdffit.select.DEFAULT_CANDIDATES`) using the default options
(cosine loss, init="auto"). Model selection compares the candidates' costs, so a candidate that stops in a local
minimum can lose to a worse model: only on the diagonal (candidate = truth) does a good cost follow from
recovering the truth, and the other pairs are where a fit has no truth to fall into (every pair of the STD and
anisotropic truths, which are not candidates: their references are checked on their own models).

Each fit is compared with an independent reference, `tests/brute_force.py`, that finds the global optimum by a
dense grid (or Sobol points and nested starts) over the shape parameters with the amplitudes solved exactly, then
polished by scipy.optimize.least_squares; it shares no fitting code with brdffit. A fit passes when it converged
(status not max-steps, stalled or nonfinite), its reported cost is the cost of the model it returns, and that
cost is within 1e-3 relative of the reference's. The reference itself is checked on the diagonal: its optimum
costs no more than the truth and lands near the truth's shape parameters.

The data are built once per truth and the reference once per (truth, candidate) pair (`functools.lru_cache`).
"""

import functools

import numpy as np
import pytest

import brdffit
from brdffit import models, synth
from brdffit.select import DEFAULT_CANDIDATES

import brute_force as bf

pytestmark = pytest.mark.slow

# Truth parameters: a plastic-like diffuse colour under a weaker, less saturated specular lobe.
TRUTHS = {
    # Beckmann width 0.15 and Schlick f0 0.04 (a dielectric, n ~ 1.5), as in test_fit_recovery.
    "lambert+cook-torrance": dict(rho_d=[0.5, 0.35, 0.2], ks=[0.9, 0.8, 0.7], m=0.15, f0=0.04),
    # Ward's (1992) fits of painted and plastic samples have α 0.05-0.2 and specular albedo 0.03-0.2.
    "lambert+ward": dict(rho_d=[0.45, 0.3, 0.15], ks=[0.08, 0.07, 0.06], alpha=0.12),
    "lambert+blinn-phong": dict(rho_d=[0.4, 0.25, 0.1], ks=[0.15, 0.15, 0.15], n=80.0),
    "lambert+ashikhmin-shirley": dict(rho_d=[0.5, 0.35, 0.2], rs=[0.15, 0.1, 0.05], n=150.0),
    # A broad retro-reflective lobe (cxy = +cz) and a forward specular one (cxy = −cz), listed in the canonical
    # order of increasing exponent (Lafortune.canonical).
    "lambert+lafortune(lobes=2)": dict(rho_d=[0.4, 0.3, 0.2], ks_1=[0.1, 0.08, 0.06], cxy_1=1.0, n_1=5.0,
                                       ks_2=[0.25, 0.22, 0.2], cxy_2=-1.0, n_2=30.0),
    # A tail between GGX's (γ = 2) and Beckmann's (γ → ∞), as Ribardière et al. 2017 fit to MERL plastics.
    "lambert+cook-torrance(distribution=std, shadowing=smith)": dict(rho_d=[0.5, 0.35, 0.2], ks=[0.9, 0.8, 0.7],
                                                                     m=0.15, gamma=2.5, f0=0.04),
    # Brushed: three times wider across the tangent than along it.
    "lambert+ggx(anisotropic=true)": dict(rho_d=[0.45, 0.3, 0.15], ks=[0.6, 0.5, 0.4], alpha_x=0.08, alpha_y=0.25,
                                          f0=0.04),
}
CANDIDATES = tuple(DEFAULT_CANDIDATES)
# Samples per data set: enough that every candidate's shape is determined, few enough that the 50 fits and
# their references stay within minutes.
N_SAMPLES = 500
# The engine's cost may exceed the global optimum by this fraction (and by an absolute 1e-15 for an exact fit);
# the reference itself is good to 5e-5 (tests/brute_force.py).
COST_RTOL = 1e-3


@functools.lru_cache(maxsize=None)
def truth_and_data(truth_spec: str):
    """The truth model and its noisy half-diff samples (seeded per truth)."""
    truth = models.get(truth_spec, **TRUTHS[truth_spec])
    seed = 11 + list(TRUTHS).index(truth_spec)
    data = synth.generate(truth, pattern="half-diff", n=N_SAMPLES, noise="relative:0.01", seed=seed)
    return truth, data


@functools.lru_cache(maxsize=None)
def reference(truth_spec: str, candidate: str):
    """The brute-force global optimum ``(cost, params)`` of ``candidate`` on the truth's data."""
    return bf.brute_force_optimum(truth_and_data(truth_spec)[1], candidate)


def _shape_values(params: dict, spec: str) -> dict:
    """Free shape parameters of a fitted or true model, Lafortune sub-lobes as (cxy, n) pairs sorted by n (the
    sum does not depend on the order of its sub-lobes)."""
    declared = models.get(spec).param_specs
    values = {s.name: float(np.asarray(params[s.name])) for s in declared if not s.colour and not s.fixed}
    lobes = sorted((values.pop(f"n_{j}"), values.pop(f"cxy_{j}")) for j in range(1, 4) if f"n_{j}" in values)
    for j, (n, cxy) in enumerate(lobes, start=1):
        values[f"n_{j}"], values[f"cxy_{j}"] = n, cxy
    return values


@pytest.mark.parametrize("truth_spec", TRUTHS)
def test_reference_at_or_below_truth(truth_spec):
    """The reference on the diagonal: a global optimum costs no more than the truth (a feasible point), and with
    1 % noise on 500 samples it lies near the truth's shape parameters (5 % relative, 0.05 absolute for
    parameters whose truth is 0 or ±1 such as f0 and cxy)."""
    truth, data = truth_and_data(truth_spec)
    cost, params = reference(truth_spec, truth_spec)
    assert cost <= bf.cost_of(data, truth), f"reference {cost:.6g} above the truth's {bf.cost_of(data, truth):.6g}"
    found, true = _shape_values(params, truth_spec), _shape_values(truth.params, truth_spec)
    for name, value in true.items():
        np.testing.assert_allclose(found[name], value, rtol=0.05, atol=0.05 if abs(value) <= 1 else 0.0,
                                   err_msg=f"{name} of the reference optimum for {truth_spec}")


# Every (truth, candidate) pair. On the anisotropic-GGX truth the optimum of two and three Lafortune lobes has one
# lobe of exponent 2e5-4e5 on the mirror direction that catches the few samples at the peak; the fit reaches it
# through its second search of each sub-lobe (`brdffit.fit`'s ``lobe_search``, with `Lafortune.sub_lobe_candidates`),
# without which it stopped 0.72 % and 0.57 % above. (The sharp STD truth against two Lafortune lobes: the solver
# puts cxy on its bound −2 itself (`brdffit.fitting.marquardt`'s ε-active set) and the lobe sharpens to n = 5.4e3,
# 9.9 % below the reference's spike of ks 2e6 at n = 3e3.)
PAIRS = [(t, c) for t in TRUTHS for c in CANDIDATES]


@functools.lru_cache(maxsize=None)
def fitted(truth_spec: str, candidate: str):
    """The default fit of ``candidate`` to the truth's data (shared by the tests that look at one pair)."""
    return brdffit.fit(truth_and_data(truth_spec)[1], candidate)


@pytest.mark.parametrize("truth_spec, candidate", PAIRS)
def test_fit_reaches_global_optimum(truth_spec, candidate):
    """A default fit of ``candidate`` to the truth's data converges to the global optimum (within COST_RTOL)."""
    truth, data = truth_and_data(truth_spec)
    brute_cost, brute_params = reference(truth_spec, candidate)
    if candidate == truth_spec:
        # Not the claim under test, but a reference above the truth would make the comparison meaningless.
        assert brute_cost <= bf.cost_of(data, truth)
    result = fitted(truth_spec, candidate)
    summary = result.summary()
    assert result.status not in ("max-steps", "stalled", "nonfinite"), summary
    # The cost a fit reports must be what the model it returns achieves (Σ r² of the cosine loss).
    achieved = bf.cost_of(data, result.model)
    np.testing.assert_allclose(result.cost, achieved, rtol=1e-6, atol=1e-15,
                               err_msg=f"reported cost vs. cost of the returned model\n{summary}")
    assert result.cost <= brute_cost * (1 + COST_RTOL) + 1e-15, (
        f"{candidate} on {truth_spec} data: fit cost {result.cost:.8g} is {result.cost / brute_cost - 1:.3g} "
        f"above the global optimum {brute_cost:.8g} at "
        f"{ {k: np.round(np.asarray(v), 4).tolist() for k, v in brute_params.items()} }\n{summary}")


def test_a_lobe_driven_to_a_step_function_is_held_on_its_exponent_bound():
    """Three Lafortune lobes on Blinn-Phong data: the optimum has one lobe at n -> 0, a step function of its
    half-space (the brute-force reference stops at n = 0.045 and cost 0.314514; with cxy_1 held the cost falls to
    0.314416 at n_1 = 0.0135, measured 2026-12-02). The fit used to stall at n_1 = 0.045 with cost 0.314876. The
    hold policy puts an exponent below its search range on its bound 0 (`brdffit.fitting.api._to_hold`), and the
    gain-ratio damping lets the two near-identical forward lobes converge (`brdffit.fitting.marquardt.GAIN_RATIO`):
    the answer is on the bound, named, and below the reference."""
    result = fitted("lambert+blinn-phong", "lambert+lafortune(lobes=3)")
    assert result.status == "converged-at-bound", result.summary()
    assert "n_1" in result.bounds_hit and float(result.params["n_1"]) == 0.0
    assert result.cost < 0.31446, result.summary()
    assert any("held" in w and "n_1" in w for w in result.warnings), result.warnings


# Pairs at 2,000 samples, where the search screens its candidates on 512 samples and scores the best
# SCREEN_KEEP again (the matrix above, at 500 samples, scores every candidate on every sample): a sharp-lobe misfit
# (Ashikhmin-Shirley data, one Lafortune lobe: a spike of n ~ 4e4 that a coarser grid lost), and three whose
# optima lie near bounds.
SCREENED_PAIRS = [("lambert+ashikhmin-shirley", "lambert+lafortune"),
                  ("lambert+blinn-phong", "lambert+ggx(fresnel=dielectric)"),
                  ("lambert+lafortune(lobes=2)", "lambert+ggx"),
                  ("lambert+ashikhmin-shirley", "lambert+ward")]


@pytest.mark.parametrize("truth_spec, candidate", SCREENED_PAIRS)
def test_the_screened_search_finds_the_optimum_of_the_unscreened_one(truth_spec, candidate, monkeypatch):
    """On 2,000 samples the screened search's fit costs no more than that of a search that scores every candidate
    on all samples (the screen turned off), to the solver's tolerance."""
    from brdffit.fitting import search

    truth = models.get(truth_spec, **TRUTHS[truth_spec])
    data = synth.generate(truth, pattern="half-diff", n=2000, noise="relative:0.01",
                          seed=11 + list(TRUTHS).index(truth_spec))
    screened = brdffit.fit(data, candidate)
    monkeypatch.setattr(search, "SCREEN_ABOVE", 10**9)
    unscreened = brdffit.fit(data, candidate)
    assert screened.cost <= unscreened.cost * (1 + 1e-6), (screened.summary(), unscreened.summary())


def test_a_rounded_projection_cannot_end_a_solve_with_a_cost_it_did_not_reach():
    """Three Lafortune lobes on Ward data (2,000 samples): one start drives a lobe that sees almost no sample to an
    amplitude of 1e53, whose projection predicted a cost of 3.2 that rounding made meaningless (the model there
    costs 1.8e108). The solver took that prediction for the cost, "converged" there as the best start, and the fit
    ended at 1.8e108, stalled (until 2026-12-04). A prediction whose terms are too large for its rounding is now
    evaluated by a pass (`brdffit.fitting.marquardt._TRUSTED_SPREAD`): every start's cost is one it reached, none
    below the answer, and the answer (4.99517) costs what its model costs."""
    truth = models.get("lambert+ward", **TRUTHS["lambert+ward"])
    data = synth.generate(truth, pattern="half-diff", n=2000, noise="relative:0.01",
                          seed=11 + list(TRUTHS).index("lambert+ward"))
    result = brdffit.fit(data, "lambert+lafortune(lobes=3)")
    assert result.status == "converged", result.summary()
    np.testing.assert_allclose(result.cost, bf.cost_of(data, result.model), rtol=1e-6)
    assert result.cost < 5.0, result.summary()
    assert min(start["cost"] for start in result.starts) >= result.cost * (1 - 1e-6), result.starts


def anisotropic_ggx_data(seed: int):
    """Half-diff samples of the anisotropic-GGX truth as `truth_and_data` makes them, with another noise seed."""
    truth = models.get("lambert+ggx(anisotropic=true)", **TRUTHS["lambert+ggx(anisotropic=true)"])
    return synth.generate(truth, pattern="half-diff", n=N_SAMPLES, noise="relative:0.01", seed=seed)


def test_no_step_raises_the_cost_where_the_predicted_cost_cancels():
    """Two Lafortune lobes on anisotropic-GGX data of another seed (500 samples): one start reaches 39.91 by step 12,
    then a trial pushes a lobe to an exponent of 1.7e5 on a sample at its peak, whose pass costs 2.5e29; the
    projection's predicted cost cancelled to below 0 (clipped to 0) against terms of 7.6e29, a spread only 3 times
    that pass's cost, so it was trusted, the trial taken, and the start ended at 61.04: the fit 53 % above the
    optimum the reference finds (39.94; `tests/brute_force.py`). The spread is now measured against the predicted
    cost as well, and a kept trial whose second pass costs more than its current point is rejected: the fit reaches
    39.91, at or below the reference."""
    data = anisotropic_ggx_data(14)
    result = brdffit.fit(data, "lambert+lafortune(lobes=2)")
    assert result.status == "converged", result.summary()
    np.testing.assert_allclose(result.cost, bf.cost_of(data, result.model), rtol=1e-6)
    brute_cost, _ = bf.brute_force_optimum(data, "lambert+lafortune(lobes=2)")
    assert result.cost <= brute_cost * (1 + COST_RTOL), (brute_cost, result.summary())
    assert min(start["cost"] for start in result.starts) >= result.cost * (1 - 1e-6), result.starts


@pytest.mark.parametrize("lobe_search", [True, False])
def test_each_sub_lobe_is_searched_again(lobe_search):
    """Two Lafortune lobes on anisotropic-GGX data of another seed (500 samples): the first search's joint grid over
    both lobes starts none near the optimum's sharp lobe (n = 1.4e4 near the mirror direction), and the polish stops
    at two broad lobes, 6.8 % above the reference (`tests/brute_force.py`). The second search of each sub-lobe with
    the other held (`brdffit.fit`'s ``lobe_search``, on by default) finds it; without it the fit stays above."""
    data = anisotropic_ggx_data(13)
    result = brdffit.fit(data, "lambert+lafortune(lobes=2)", lobe_search=lobe_search)
    brute_cost, _ = bf.brute_force_optimum(data, "lambert+lafortune(lobes=2)")
    if lobe_search:
        assert result.cost <= brute_cost * (1 + COST_RTOL), (brute_cost, result.summary())
        assert any("searched again each with the others held" in w for w in result.warnings), result.warnings
    else:
        assert result.cost > brute_cost * 1.05, (brute_cost, result.summary())


def test_fit_many_searches_each_sub_lobe_as_fit_does():
    """`fit_many` runs the second search of each sub-lobe material by material: on the three anisotropic-GGX data
    sets of the tests above (seeds 13, 17 and 14, where it or the solver's guard decides the answer) each
    material's cost is the one `fit` reaches on it alone."""
    data = [anisotropic_ggx_data(seed) for seed in (13, 17, 14)]
    batch = brdffit.fit_many(data, "lambert+lafortune(lobes=2)")
    for one_data, from_batch in zip(data, batch):
        alone = brdffit.fit(one_data, "lambert+lafortune(lobes=2)")
        np.testing.assert_allclose(from_batch.cost, alone.cost, rtol=1e-9)
        np.testing.assert_allclose(from_batch.cost, bf.cost_of(one_data, from_batch.model), rtol=1e-6)
