"""Diagnosis of a fit: its status, the bounds it ended on, and the warnings a user should read.

A status is a `brdffit.fitting.outcome.Status` (its docstring and docs/fitting.md explain each).
"""

from __future__ import annotations

import itertools

import numpy as np

from ..params import at_bound
from .bvls import bounded_least_squares
from .outcome import STATUSES, Status
from .problem import Problem

__all__ = ["Status", "STATUSES", "STALL_TOLERANCE", "bounds_hit", "bounded_step", "predicted_decrease", "diagnose", "warnings_of",
           "information_criteria"]

# A fit whose final point still leaves a predicted Gauss-Newton decrease above this fraction of the cost is
# "stalled", not converged. Converged fits leave ~1e-12; the stalls the stability study found (docs/stability.md)
# leave more than the cost itself.
STALL_TOLERANCE = 1e-4
_CORRELATION_WARNING = 0.99


def bounds_hit(problem: Problem, params: dict) -> list[str]:
    """Labels of the free scalars that lie on a bound (`brdffit.params.at_bound`)."""
    layout = problem.layout
    hit = []
    for name in problem.free:
        flags = np.atleast_1d(at_bound(params[name], layout[name].spec))
        hit.extend(label for label, flag in zip(layout[name].labels(), flags) if flag)
    return hit


def bounded_step(problem: Problem, params: dict, jtj, jtr) -> tuple[np.ndarray, float]:
    """The Gauss-Newton step from ``params`` that stays inside the bounds, and the decrease of Σr² it predicts.

    The linearised problem min ‖JΔ + r‖² is solved over the box lower − p ≤ Δ ≤ upper − p, in Jacobi-scaled
    coordinates (physical units span many decades) and on the range of JᵀJ (a direction the data do not see
    predicts nothing). A scalar within `brdffit.params.at_bound`'s margin of a bound counts as on it. The plain
    step rᵀJ (JᵀJ)⁺ Jᵀr is the answer when it stays inside; otherwise the box-constrained linear least squares
    (`brdffit.fitting.bvls.bounded_least_squares`) is. Near 0 at a true (constrained) optimum: Karush-Kuhn-Tucker.

    Arguments:
        problem: the `Problem`.
        params: physical values.
        jtj, jtr: JᵀJ and Jᵀr in the physical free parameters at ``params``.

    Returns:
        ``(step, decrease)``: the step over the flattened free scalars (physical units) and the predicted
        decrease (>= 0).
    """
    layout = problem.layout
    values = layout.flatten(params, problem.free)
    lower = np.concatenate([np.full(layout[n].size, layout[n].spec.lower) for n in problem.free])
    upper = np.concatenate([np.full(layout[n].size, layout[n].spec.upper) for n in problem.free])
    near = np.concatenate([np.ravel(at_bound(params[n], layout[n].spec)) for n in problem.free])
    at_lower = near & (np.abs(values - lower) <= np.abs(values - upper))
    at_upper = near & ~at_lower
    g = np.asarray(jtr, dtype=float)
    h = np.asarray(jtj, dtype=float)
    zero = np.zeros_like(values)
    if not g.size or not np.all(np.isfinite(h)) or not np.all(np.isfinite(g)):  # nothing to linearise
        return zero, 0.0
    scale = np.sqrt(np.maximum(np.diag(h), 1e-300))
    eigenvalues, vectors = np.linalg.eigh(h / np.outer(scale, scale))
    seen = eigenvalues > 1e-12 * max(eigenvalues.max(initial=0.0), 1e-300)
    if not seen.any():
        return zero, 0.0
    root, basis = np.sqrt(eigenvalues[seen]), vectors[:, seen]
    projected = basis.T @ (g / scale)  # ‖AΔ' + b‖² = Δ'ᵀHΔ' + 2gᵀΔ' + gᵀH⁺g with A = √Λ Vᵀ, b = Λ^(-1/2) Vᵀ g
    a, b = root[:, None] * basis.T, projected / root
    full = float(b @ b)
    z = -basis @ (projected / eigenvalues[seen])
    low = np.where(at_lower, 0.0, (lower - values) * scale)
    high = np.where(at_upper, 0.0, (upper - values) * scale)
    if np.all((z >= low) & (z <= high)):
        return z / scale, max(full, 0.0)
    z = bounded_least_squares(a, b, low, np.maximum(high, low))
    rest = a @ z + b
    return z / scale, max(full - float(rest @ rest), 0.0)


def predicted_decrease(problem: Problem, params: dict, jtj, jtr) -> float:
    """The decrease of Σr² that a Gauss-Newton step from ``params`` predicts within the bounds (`bounded_step`)."""
    return bounded_step(problem, params, jtj, jtr)[1]


def diagnose(problem: Problem, params: dict, cost: float, max_steps: bool, nonfinite: bool, jtj, jtr):
    """The status of a fit and the decrease a further step predicts.

    Arguments:
        problem: the `Problem`.
        params: the final physical values.
        cost: the final cost.
        max_steps, nonfinite: the solver's flags.
        jtj, jtr: the physical normal matrices at ``params``.

    Returns:
        ``(status, hit, decrease)``: a `Status`, the labels on a bound, the predicted decrease.
    """
    hit = bounds_hit(problem, params)
    decrease = predicted_decrease(problem, params, jtj, jtr) if problem.free else 0.0
    if nonfinite or not np.isfinite(cost):
        return Status.NONFINITE, hit, decrease
    if max_steps:
        return Status.MAX_STEPS, hit, decrease
    if decrease > STALL_TOLERANCE * max(cost, 1e-300):
        return Status.STALLED, hit, decrease
    return (Status.CONVERGED_AT_BOUND if hit else Status.CONVERGED), hit, decrease


def warnings_of(problem: Problem, labels: list, uncertainty, hit: list, status: str, decrease: float,
                cost: float, params: dict) -> list[str]:
    """The human-readable warnings of a fit: undetermined or correlated parameters, bounds,
    dead lobes (``params``: the physical values, to tell a lower bound from an upper one), a stall."""
    warnings = []
    if uncertainty.undetermined.any():
        names = [label for label, u in zip(labels, uncertainty.undetermined) if u]
        warnings.append(f"JᵀJ is singular: {', '.join(names)} not determined by these data (stderr = inf)")
    correlation = uncertainty.correlation
    for a, b in itertools.combinations(range(len(labels)), 2):
        rho = correlation[a, b]
        if np.isfinite(rho) and abs(rho) > _CORRELATION_WARNING:
            warnings.append(f"{labels[a]} and {labels[b]} are correlated (ρ = {rho:+.4f}): not separately "
                            "identifiable from these data")
    if hit:
        warnings.append(f"parameters at a bound: {', '.join(hit)}")
    layout = problem.layout
    for name in problem.free:
        spec = layout[name].spec
        if spec.linear and spec.lower == 0 and np.all(np.asarray(params[name]) == 0.0):
            warnings.append(f"{name} went to 0 in every channel: its lobe contributes nothing, a model without "
                            "it suffices")
    if status == "stalled":
        warnings.append(f"the solver stopped where a Gauss-Newton step still predicts a cost decrease of "
                        f"{decrease:.3g} ({decrease / max(cost, 1e-300):.2g} of the cost): not a minimum "
                        "(try solver='lm', init='auto' or multistart)")
    return warnings


def information_criteria(loss: str, cost: float, n: int, k: int) -> tuple[float, float]:
    """AIC and BIC of a least-squares fit (docs/fitting.md): from χ² with known σ, else from the profile
    Gaussian likelihood n ln(RSS/n)."""
    base = cost if loss == "sigma" else n * np.log(max(cost, 1e-300) / max(n, 1))
    return float(base + 2 * k), float(base + k * np.log(max(n, 1)))
