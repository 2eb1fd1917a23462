"""Bounded-variable least squares: min ‖A z + b‖² over low ≤ z ≤ high, by an active-set method in NumPy.

The method is Stark and Parker's BVLS (Computational Statistics 10, 1995), Lawson and Hanson's NNLS (Solving Least
Squares Problems, 1974, ch. 23) extended to two-sided bounds, for the small dense problems of a fit's diagnosis
(`brdffit.fitting.status.bounded_step`: a Gauss-Newton step within the box, tens of unknowns). From a feasible start
it alternates: solve the least-squares problem in the free variables with the others held on their bounds; if that
leaves the box, move towards it until the first variable meets a bound and hold that one; once inside, free the held
variable whose Karush-Kuhn-Tucker multiplier has the wrong sign (the gradient pushes it into the box), until none
has. Each free solve is `numpy.linalg.lstsq` (minimum norm where the free columns are rank deficient). It replaces
SciPy's ``lsq_linear(method="bvls")``, the same algorithm, whose module takes a sizeable share of a warm default
fit's start-up to import.
"""

from __future__ import annotations

import numpy as np

__all__ = ["bounded_least_squares"]


def bounded_least_squares(a: np.ndarray, b: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """argmin ‖a z + b‖² over low ≤ z ≤ high, started from 0 clipped into the box.

    Arguments:
        a: ``(m, n)``; b: ``(m,)``.
        low, high: ``(n,)`` bounds, low ≤ high (equal: the variable is fixed; ±inf: none).

    Returns:
        The optimum ``(n,)``, inside the box.
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    low, high = np.asarray(low, dtype=float), np.asarray(high, dtype=float)
    n = a.shape[1]
    z = np.clip(np.zeros(n), low, high)
    scale = max(float(np.abs(a).max(initial=0.0)) * max(float(np.abs(b).max(initial=0.0)), 1.0), 1e-300)
    tol = 1e-12 * scale  # a multiplier smaller than this is zero
    at_low, at_high = z <= low, z >= high
    fixed = low == high
    for _ in range(10 * n + 10):  # every pass holds or frees a variable; the bound is never reached in practice
        held = at_low | at_high
        free = ~held
        if free.any():
            rest = b + a[:, held] @ z[held]
            target = z.copy()
            target[free] = np.linalg.lstsq(a[:, free], -rest, rcond=None)[0]
        else:
            target = z
        outside = free & ((target < low) | (target > high))
        if outside.any():
            # Move from z towards target until the first free variable meets its bound, and hold it there.
            step = target - z
            with np.errstate(divide="ignore", invalid="ignore"):
                room = np.where(step < 0, (low - z) / step, np.where(step > 0, (high - z) / step, np.inf))
            room = np.where(free, np.clip(room, 0.0, 1.0), np.inf)
            k = int(np.argmin(room))
            z = np.clip(z + room[k] * step, low, high)
            (at_low if step[k] < 0 else at_high)[k] = True
            z[k] = low[k] if step[k] < 0 else high[k]
            continue
        z = target
        # Karush-Kuhn-Tucker: a variable held on its lower bound needs a gradient ≥ 0, on its upper bound ≤ 0.
        gradient = a.T @ (a @ z + b)
        wrong = np.where(at_low & ~fixed, -gradient, 0.0) + np.where(at_high & ~fixed, gradient, 0.0)
        k = int(np.argmax(wrong))
        if wrong[k] <= tol:
            return np.clip(z, low, high)
        at_low[k] = at_high[k] = False
    return np.clip(z, low, high)
