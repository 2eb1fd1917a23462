"""Full-data refinement after a coarse solve: separable Levenberg-Marquardt steps in normal-equation form.

For large data (a MERL table has 4.4 million residuals) a general least-squares solver pays for the tall
Jacobian at every step. The pipeline therefore solves first on a seeded subsample, which lands within the
subsample's statistical error of the full-data optimum, and then refines on all the data here.

Each pass over the data (`brdffit.fitting.normal_equations.accumulate`, in chunks) gives JᵀJ, Jᵀr and the cost
at the current point, with J in the physical parameters. Since the residuals are affine in the amplitudes, those
sums determine the cost as a function of the amplitudes exactly: each pass first moves the amplitudes to their
bounded optimum for the current outer parameters (the projection of `brdffit.fitting.separable`, here from the
pass's own sums: cost(a') = cost + 2 gᵀΔ + Δᵀ G Δ, Δ = a' − a), then takes a Levenberg-Marquardt step in the
outer parameters' unconstrained variables, (JᵀJ + λ diag(JᵀJ)) δ = −Jᵀr (Marquardt 1963, Eq. 29's scaling)
over the outer parameters and the amplitudes off their bounds (Kaufman's joint step, BIT 15, 1975), accepting it
only if the projected cost decreases. The outer columns are mapped to the unconstrained variables by the chain
rule. It stops when both the step and the amplitude change are below ``rtol·|x| + atol`` (optimistix's Cauchy
test), or reports that it did not converge. A problem without amplitudes to project (a nonlinear loss) takes the
same steps over all its free parameters.

One pass per step: a trial point's pass is also the next step's system.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .normal_equations import NormalEquations, accumulate, chunks
from .problem import FitData, Problem
from .separable import solve_box

__all__ = ["refine"]


def _derivative(problem: Problem, params: dict, names) -> np.ndarray:
    """dp/du of the bound transforms of ``names`` at ``params``, flattened (`Layout.flatten` order)."""
    specs = problem.specs
    parts = []
    for name in names:
        u = jnp.asarray(specs[name].to_unconstrained(params[name]))
        parts.append(np.ravel(np.asarray(jax.jvp(specs[name].from_unconstrained, (u,), (jnp.ones_like(u),))[1])))
    return np.concatenate(parts) if parts else np.zeros(0)


class _Point:
    """A pass's sums with the amplitudes moved to their optimum (see the module doc)."""

    def __init__(self, problem: Problem, params: dict, sums: NormalEquations, amplitude_index: list):
        self.params = dict(params)
        jtj, jtr = sums.jtj, sums.jtr.copy()
        cost, channel_cost = sums.cost, sums.channel_cost.copy()
        specs = problem.specs
        self.delta = np.zeros(jtr.shape)
        for c, index in enumerate(amplitude_index):
            if not index:
                continue
            names = problem.linear
            a = np.array([float(np.asarray(params[n])[c]) for n in names])
            gram, grad = jtj[np.ix_(index, index)], jtr[index]
            best = solve_box(gram, gram @ a - grad, [specs[n].lower for n in names], [specs[n].upper for n in names])
            step = best - a
            change = 2.0 * grad @ step + step @ gram @ step
            cost += change
            channel_cost[c] += change
            self.delta[index] = step
            for k, n in enumerate(names):
                value = np.array(self.params[n], dtype=float)
                value[c] = best[k]
                self.params[n] = value
        self.jtr = jtr + jtj @ self.delta  # Jᵀr moves with r = r₀ + J_a Δ
        self.jtj, self.meat = jtj, sums.meat
        self.cost, self.channel_cost = float(max(cost, 0.0)), np.maximum(channel_cost, 0.0)


def refine(problem: Problem, params: dict, data: FitData, *, rtol: float, atol: float, max_steps: int = 20):
    """Refine physical parameter values ``params`` on all of ``data``.

    Arguments:
        problem: the `Problem` (its `linear` amplitudes are projected, its `outer` parameters stepped).
        params: physical values of every parameter, e.g. the coarse solution.
        data: the full `FitData` (``fixed`` holding the parameters that are not free).
        rtol, atol: step-size termination, as in optimistix.
        max_steps: the most steps.

    Returns:
        ``(params, outcome)`` with outcome keys ``cost``, ``steps``, ``max_steps``, ``nonfinite`` (as the
        optimistix solve's), ``channel_cost`` (the cost of each channel) and ``normal`` (a `NormalEquations` in
        the physical parameters at the returned point, for the covariance).
    """
    pieces = chunks(data)  # one copy, reused by every pass
    layout = problem.layout
    offsets = layout.offsets(problem.free)
    amplitude_index = [[offsets[n].start + c for n in problem.linear] for c in range(problem.channels)]
    outer_index = np.concatenate([np.arange(offsets[n].start, offsets[n].stop) for n in problem.outer]) \
        if problem.outer else np.zeros(0, int)
    specs = problem.specs

    def evaluate(values):
        tree = {k: jnp.asarray(values[k]) for k in problem.free}
        return _Point(problem, values, accumulate(problem, tree, pieces), amplitude_index)

    def unconstrained(values):
        return np.concatenate([np.ravel(np.asarray(specs[n].to_unconstrained(values[n]))) for n in problem.outer]) \
            if problem.outer else np.zeros(0)

    current = evaluate(params)
    damping = 1e-6
    steps, converged = 0, False
    while steps < max_steps and np.isfinite(current.cost):
        steps += 1
        # The step's variables: the outer parameters and the amplitudes off their bounds.
        flat = layout.flatten(current.params, problem.free)
        moving = np.zeros(flat.shape, bool)
        moving[outer_index] = True
        for index in amplitude_index:
            for i, name in zip(index, problem.linear):
                spec = specs[name]
                moving[i] = spec.lower + 1e-12 < flat[i] < spec.upper - 1e-12
        amplitude_small = np.linalg.norm(current.delta) <= rtol * np.linalg.norm(flat) + atol
        if not outer_index.size:  # nothing but amplitudes: project until they stop moving
            converged = bool(amplitude_small)
            if converged:
                break
            current = evaluate(current.params)
            continue
        scale = np.ones(flat.shape)
        scale[outer_index] = _derivative(problem, current.params, problem.outer)  # J_u = J_p dp/du
        jtj = current.jtj * np.outer(scale, scale)
        jtr = current.jtr * scale
        sub = np.ix_(moving, moving)
        diag = np.maximum(np.diag(jtj)[moving], 1e-300)
        try:
            delta = -np.linalg.solve(jtj[sub] + damping * np.diag(diag), jtr[moving])
        except np.linalg.LinAlgError:
            damping *= 10.0
            continue
        step = np.zeros(flat.shape)
        step[moving] = delta
        u = unconstrained(current.params)
        outer_step = step[outer_index]
        if np.linalg.norm(outer_step) <= rtol * np.linalg.norm(u) + atol and amplitude_small:
            converged = True  # the next step is below the tolerance: this point is the answer
            break
        trial = dict(current.params)
        new_u = u + outer_step
        position = 0
        for name in problem.outer:
            size = layout[name].size
            piece = jnp.asarray(new_u[position:position + size])
            trial[name] = np.reshape(np.asarray(specs[name].from_unconstrained(piece)), layout[name].shape)
            position += size
        for name in problem.linear:  # amplitudes off their bounds take their part of the joint step
            value = np.array(trial[name], dtype=float)
            for c in range(problem.channels):
                i = offsets[name].start + c
                value[c] = np.clip(value[c] + step[i], specs[name].lower, specs[name].upper)
            trial[name] = value
        candidate = evaluate(trial)
        if np.isfinite(candidate.cost) and candidate.cost <= current.cost:
            current = candidate
            damping = max(damping / 10.0, 1e-12)
        else:
            damping *= 10.0
    finite = bool(np.isfinite(current.cost))
    normal = NormalEquations(jtj=current.jtj, jtr=current.jtr, cost=current.cost, meat=current.meat,
                             channel_cost=current.channel_cost)
    outcome = {"cost": current.cost, "steps": steps, "max_steps": not converged and finite, "nonfinite": not finite,
               "channel_cost": current.channel_cost, "normal": normal}
    return current.params, outcome
