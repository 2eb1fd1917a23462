"""Full-data refinement after a coarse solve: damped Gauss-Newton steps in normal-equation form.

For large data (a MERL table has 4.4 million residuals) a general least-squares solver pays for the tall
Jacobian at every step. `fit` therefore solves first on a seeded subsample with the chosen solver, which lands
within the subsample's statistical error of the full-data optimum, and then refines on all the data here. Each
step accumulates JᵀJ and Jᵀr over chunks of samples (p × p, p the number of free scalars) and solves the
Levenberg-Marquardt system (JᵀJ + λ diag(JᵀJ)) δ = −Jᵀr (Marquardt 1963, Eq. 29's diagonal scaling) in the
unconstrained variables, accepting a step only if the cost decreases. It stops when the step is below
``rtol·|y| + atol`` (the same test as optimistix's Cauchy termination), or reports that it did not converge.

From a coarse start nearly every step is accepted, so each trial point gets the full pass (JᵀJ, Jᵀr and the cost
together) at once, which the next step then uses: one pass over the data per step instead of a cost pass and then a
Jacobian pass. A rejected step wastes that pass's Jacobian part.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .normal_equations import accumulate, chunks
from .problem import FitData, Problem, flatten_free

__all__ = ["refine"]


def refine(problem: Problem, y: dict, data: FitData, *, rtol: float, atol: float, max_steps: int = 20):
    """Refine unconstrained variables ``y`` on all of ``data``.

    Arguments:
        problem: the `Problem`.
        y: free name -> unconstrained value (no batch axis), e.g. the coarse solution.
        data: the full `FitData`.
        rtol, atol: step-size termination, as in optimistix.
        max_steps: the most normal-equation solves.

    Returns:
        ``(y, outcome)`` with outcome keys ``cost``, ``steps``, ``successful``, ``max_steps``, ``nonfinite``
        (the same as the optimistix solve's), ``channel_cost`` (the cost of each channel) and
        ``normal_matrices`` (JᵀJ, Jᵀ diag(r²) J) in the unconstrained variables at the returned point.
    """
    flat, unravel = flatten_free(problem, y)
    flat = np.asarray(flat, dtype=float)
    pieces = chunks(data)  # one copy, reused by every pass

    def system(point):
        return accumulate(problem, unravel(jnp.asarray(point)), pieces, physical=False)

    current = system(flat)
    damping = 1e-6
    steps, converged = 0, False
    while steps < max_steps and np.isfinite(current.cost):
        steps += 1
        scale = np.maximum(np.diag(current.jtj), 1e-300)
        try:
            delta = -np.linalg.solve(current.jtj + damping * np.diag(scale), current.jtr)
        except np.linalg.LinAlgError:
            damping *= 10.0
            continue
        if np.linalg.norm(delta) <= rtol * np.linalg.norm(flat) + atol:
            # The next step is below the tolerance: this point is the answer, and its matrices are at hand.
            converged = True
            break
        point = flat + delta
        trial = system(point)
        if np.isfinite(trial.cost) and trial.cost <= current.cost:
            flat, current = point, trial
            damping = max(damping / 10.0, 1e-12)
        else:
            damping *= 10.0
    finite = bool(np.isfinite(current.cost))
    outcome = {"cost": np.asarray(current.cost), "steps": np.asarray(steps), "successful": np.asarray(converged),
               "max_steps": np.asarray(not converged and finite), "nonfinite": np.asarray(not finite)}
    if finite:
        # `fit` turns these into the covariance and the per-channel metrics without another pass.
        outcome["channel_cost"] = current.channel_cost
        outcome["normal_matrices"] = (current.jtj, current.meat)
    return unravel(jnp.asarray(flat)), outcome
