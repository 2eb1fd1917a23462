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

from .problem import FitData, Problem, chunk_data, flatten_free, physical_params, residual_fn

__all__ = ["refine", "CHUNK_SAMPLES"]

CHUNK_SAMPLES = 262_144


@functools.lru_cache(maxsize=32)
def _normal_equations(problem: Problem):
    """Jitted (JᵀJ, Jᵀr, rᵀr, Jᵀ diag(r²) J) of one chunk, J the Jacobian w.r.t. the unconstrained variables."""

    def fn(y: dict, data: FitData):
        flat, unravel = flatten_free(problem, y)

        def r(theta):
            return residual_fn(problem, physical_params(problem, unravel(theta), data.fixed), data).ravel()

        jac = jax.jacfwd(r)(flat)
        res = r(flat)
        scaled = jac * res[:, None]
        return jac.T @ jac, jac.T @ res, jnp.sum(res * res), scaled.T @ scaled

    return jax.jit(fn)


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
    chunk = CHUNK_SAMPLES
    pieces = list(chunk_data(data, chunk))
    normal = _normal_equations(problem)
    cost_fn = _cost(problem)

    def system(y):
        h, g, c, meat = 0.0, 0.0, 0.0, 0.0
        for piece in pieces:
            a, b, s, t = normal(y, piece)
            h, g, c, meat = h + np.asarray(a), g + np.asarray(b), c + float(s), meat + np.asarray(t)
        return h, g, c, meat

    def cost(y):
        return sum(float(cost_fn(y, piece)) for piece in pieces)

    flat, unravel = flatten_free(problem, y)
    flat = np.asarray(flat, dtype=float)
    h, g, c, meat = system(unravel(jnp.asarray(flat)))
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
        trial_cost = cost(unravel(jnp.asarray(trial)))
        small = np.linalg.norm(delta) <= rtol * np.linalg.norm(flat) + atol
        if np.isfinite(trial_cost) and trial_cost <= c:
            flat = trial
            damping = max(damping / 10.0, 1e-12)
            if small:
                c = trial_cost
                converged = True
                break
            h, g, c, meat = system(unravel(jnp.asarray(flat)))
        else:
            if small:
                converged = True
                break
            damping *= 10.0
    outcome = {"cost": np.asarray(c), "steps": np.asarray(steps), "successful": np.asarray(converged),
               "max_steps": np.asarray(not converged and np.isfinite(c)), "nonfinite": np.asarray(not np.isfinite(c)),
               # JᵀJ and Jᵀ diag(r²) J at the last linearisation point (within rtol of the answer when converged),
               # in the unconstrained variables: `fit` turns them into the covariance without another pass.
               "normal_matrices": (h, meat)}
    return unravel(jnp.asarray(flat)), outcome
