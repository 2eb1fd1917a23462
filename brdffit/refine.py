"""Full-data refinement after a coarse solve: damped Gauss-Newton steps in normal-equation form.

For large data (a MERL table has 4.4 million residuals) a general least-squares solver pays for the tall
Jacobian at every step. `fit` therefore solves first on a seeded subsample with the chosen solver, which lands
within the subsample's statistical error of the full-data optimum, and then refines on all the data here. Each
step accumulates JᵀJ and Jᵀr over chunks of samples (p × p, p the number of free scalars) and solves the
Levenberg-Marquardt system (JᵀJ + λ diag(JᵀJ)) δ = −Jᵀr (Marquardt 1963, Eq. 29's diagonal scaling) in the
unconstrained variables, accepting a step only if the cost decreases. It stops when the step is below
``rtol·|y| + atol`` (the same test as optimistix's Cauchy termination), or reports that it did not converge.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .normal_equations import accumulate, chunks
from .problem import FitData, Problem, flatten_free, physical_params, residual_fn

__all__ = ["refine"]


@functools.lru_cache(maxsize=32)
def _cost(problem: Problem):
    def fn(y: dict, data: FitData):
        r = residual_fn(problem, physical_params(problem, y, data.fixed), data)
        return jnp.sum(r * r)

    return jax.jit(fn)


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
        (the same as the optimistix solve's) and ``normal_matrices`` (JᵀJ, Jᵀ diag(r²) J) in the unconstrained
        variables.
    """
    pieces = chunks(data)
    cost_fn = _cost(problem)

    def system(flat):
        return accumulate(problem, unravel(jnp.asarray(flat)), pieces, physical=False)

    def cost(flat):
        return sum(float(cost_fn(unravel(jnp.asarray(flat)), piece)) for piece in pieces)

    flat, unravel = flatten_free(problem, y)
    flat = np.asarray(flat, dtype=float)
    h, g, c, meat = system(flat)
    damping = 1e-6
    steps, converged = 0, False
    while steps < max_steps and np.isfinite(c):
        steps += 1
        scale = np.maximum(np.diag(h), 1e-300)
        try:
            delta = -np.linalg.solve(h + damping * np.diag(scale), g)
        except np.linalg.LinAlgError:
            damping *= 10.0
            continue
        trial = flat + delta
        trial_cost = cost(trial)
        small = np.linalg.norm(delta) <= rtol * np.linalg.norm(flat) + atol
        if np.isfinite(trial_cost) and trial_cost <= c:
            flat = trial
            damping = max(damping / 10.0, 1e-12)
            if small:
                c = trial_cost
                converged = True
                break
            h, g, c, meat = system(flat)
        else:
            if small:
                converged = True
                break
            damping *= 10.0
    outcome = {"cost": np.asarray(c), "steps": np.asarray(steps), "successful": np.asarray(converged),
               "max_steps": np.asarray(not converged and np.isfinite(c)), "nonfinite": np.asarray(not np.isfinite(c))}
    if np.isfinite(c):
        # JᵀJ and Jᵀ diag(r²) J in the unconstrained variables at the last linearisation point (within rtol of
        # the answer when converged): `fit` turns them into the covariance without another pass.
        outcome["normal_matrices"] = (h, meat)
    return unravel(jnp.asarray(flat)), outcome
