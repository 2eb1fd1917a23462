"""The pipeline's bound handling: the Gauss-Newton step within the bounds (`status.bounded_step`), the
active-set update of the hold rounds (`api._next_holds`) and the choice among polished starts (`api._best`)."""

import numpy as np
import pytest
from scipy.optimize import minimize

from brdffit import synth, models
from brdffit.fitting import api
from brdffit.fitting.outcome import SolveOutcome
from brdffit.fitting.status import bounded_step


def _problem(spec):
    data = synth.generate(models.get(spec), pattern="half-diff", n=60, seed=3)
    return api._prepare(data, spec, loss="cosine", solver="lm", fixed=None, free=None, robust=None,
                        max_steps=64, rtol=None, atol=None)[0]


def _box_qp_decrease(h, g, low, high):
    """−min over low ≤ Δ ≤ high of 2gᵀΔ + ΔᵀHΔ (the linearised change of Σr²), by L-BFGS-B from several starts."""
    def q(d):
        return 2.0 * g @ d + d @ h @ d, 2.0 * g + 2.0 * h @ d

    best = np.inf
    rng = np.random.default_rng(0)
    for _ in range(8):
        x0 = np.clip(rng.normal(size=g.size), low, high)
        out = minimize(q, x0, jac=True, method="L-BFGS-B", bounds=list(zip(low, high)),
                       options={"ftol": 1e-15, "gtol": 1e-13, "maxiter": 10_000})
        best = min(best, out.fun)
    return -best


@pytest.mark.parametrize("seed", range(4))
def test_bounded_step_solves_the_box_constrained_gauss_newton_problem(seed):
    """The predicted decrease equals an independent bounded quadratic minimisation, and the step stays inside
    the bounds; with a plain step inside the box it is rᵀJ(JᵀJ)⁻¹Jᵀr."""
    problem = _problem("lambert+ward")
    layout = problem.layout
    rng = np.random.default_rng(seed)
    k = layout.size(problem.free)
    a = rng.normal(size=(3 * k, k))
    h, g = a.T @ a, rng.normal(size=k) * 30.0
    params = {"rho_d": np.array([0.2, 0.5, 0.9]), "ks": np.array([0.05, 0.3, 1.0]), "alpha": np.array(0.2)}
    values = layout.flatten(params, problem.free)
    lower = np.concatenate([np.full(layout[n].size, layout[n].spec.lower) for n in problem.free])
    upper = np.concatenate([np.full(layout[n].size, layout[n].spec.upper) for n in problem.free])
    step, decrease = bounded_step(problem, params, h, g)
    reference = _box_qp_decrease(h, g, lower - values, upper - values)
    np.testing.assert_allclose(decrease, reference, rtol=1e-6)
    assert np.all(values + step >= lower - 1e-12) and np.all(values + step <= upper + 1e-12)
    plain = np.linalg.solve(h, g)
    small = g * 1e-6  # a gradient small enough that the plain step stays inside
    np.testing.assert_allclose(bounded_step(problem, params, h, small)[1], small @ np.linalg.solve(h, small),
                               rtol=1e-8)
    assert reference < g @ plain  # these random gradients do push some scalar out of the box


def test_next_hold_round_adds_a_parameter_the_re_solve_took_to_a_bound():
    """Two Lafortune lobes: cxy_1 held on −2 and the re-solve brought cxy_2 to −2 + 1e-5: the next round holds
    both; releasing a held bound whose descent points inwards counts as a change too, and no change ends the
    rounds (an empty dict)."""
    problem = _problem("lambert+lafortune(lobes=2)")
    k = problem.layout.size(problem.free)
    params = {"rho_d": np.full(3, 0.3), "ks_1": np.full(3, 0.2), "cxy_1": np.array(-2.0), "cz_1": np.array(1.0),
              "n_1": np.array(20.0), "ks_2": np.full(3, 0.1), "cxy_2": np.array(-2.0 + 1e-5),
              "cz_2": np.array(1.0), "n_2": np.array(300.0)}
    offsets = problem.layout.offsets(problem.free)
    jtr = np.zeros(k)
    jtr[offsets["cxy_1"]] = 1.0  # descent −Jᵀr < 0: outwards at the lower bound, the hold stays
    nxt = api._next_holds(problem, {"cxy_1": np.array(-2.0)}, params, jtr)
    assert set(nxt) == {"cxy_1", "cxy_2"} and float(nxt["cxy_2"]) == -2.0 and float(nxt["cxy_1"]) == -2.0
    assert api._next_holds(problem, nxt, dict(params, cxy_2=np.array(-2.0)), jtr) == {}
    jtr[offsets["cxy_1"]] = -1.0  # now the descent points into the box: released
    released = api._next_holds(problem, {"cxy_1": np.array(-2.0)}, dict(params, cxy_2=np.array(0.5)), jtr)
    assert np.isnan(released["cxy_1"])


def test_a_converged_start_tied_with_a_lower_max_steps_one_is_kept():
    """Two starts at the same optimum to 3e-9: the converged one is kept; a converged start 1e-3 above a
    max-steps one is not (the lower cost wins)."""
    def outcome(cost, max_steps):
        return SolveOutcome({}, cost, max_steps=max_steps)

    assert api._best([outcome(1202.97355, False), outcome(1202.97354, True)]).max_steps is False
    assert api._best([outcome(1204.0, False), outcome(1202.97354, True)]).max_steps is True
    assert api._best([outcome(np.inf, False), outcome(3.0, True)]).cost == 3.0
