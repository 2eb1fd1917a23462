"""`brdffit.fitting.bvls.bounded_least_squares` against SciPy's own bounded-variable least squares
(``scipy.optimize.lsq_linear(method="bvls")``, an independent implementation of the same problem) and against the
Karush-Kuhn-Tucker conditions, on random problems: full rank and rank deficient, one- and two-sided bounds, variables
pinned at a bound and unbounded ones, columns whose scales span decades (as the Jacobi-scaled steps of
`brdffit.fitting.status.bounded_step` do)."""

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from brdffit.fitting.bvls import bounded_least_squares


def _problem(rng):
    n = int(rng.integers(1, 25))
    rows = n if rng.random() < 0.5 else int(rng.integers(1, n + 1))  # rank deficient when rows < n
    a = rng.normal(size=(rows, n)) * np.exp(2.0 * rng.normal(size=n))[None, :]
    b = rng.normal(size=rows) * 10.0 ** rng.uniform(-3, 3)
    low, high = -np.exp(rng.normal(size=n)), np.exp(rng.normal(size=n))
    u = rng.random(n)
    low[u < 0.1] = 0.0  # on the lower bound (the start, 0, is there)
    high[(u >= 0.1) & (u < 0.2)] = 0.0  # on the upper bound
    low[(u >= 0.2) & (u < 0.3)] = -np.inf
    return a, b, low, high


@pytest.mark.parametrize("seed", range(4))
def test_the_optimum_is_scipys(seed):
    """The residual norm equals that of SciPy's BVLS to 1e-12 of ‖b‖² (the optimum is unique in A z, not in z where
    A is rank deficient), and the point lies in the box."""
    rng = np.random.default_rng(seed)
    for _ in range(300):
        a, b, low, high = _problem(rng)
        z = bounded_least_squares(a, b, low, high)
        assert np.all(z >= low) and np.all(z <= high)
        want = lsq_linear(a, -b, bounds=(low, high), method="bvls", tol=1e-14).x
        cost, reference = np.sum((a @ z + b) ** 2), np.sum((a @ want + b) ** 2)
        assert cost <= reference + 1e-12 * float(b @ b), (cost, reference)


def test_the_karush_kuhn_tucker_conditions_hold():
    """At the optimum the gradient Aᵀ(Az + b) vanishes on the free variables, is ≥ 0 on those at their lower bound
    and ≤ 0 on those at their upper bound (to rounding)."""
    rng = np.random.default_rng(7)
    for _ in range(300):
        a, b, low, high = _problem(rng)
        z = bounded_least_squares(a, b, low, high)
        g = a.T @ (a @ z + b)
        size = np.abs(a).max() * (np.abs(a @ z).max() + np.abs(b).max()) * a.shape[0]
        tol = 1e-9 * size
        at_low, at_high = z <= low, z >= high
        free = ~at_low & ~at_high
        assert np.all(np.abs(g[free]) <= tol)
        assert np.all(g[at_low & ~at_high] >= -tol)
        assert np.all(g[at_high & ~at_low] <= tol)


def test_an_interior_optimum_is_the_plain_least_squares_solution():
    """Bounds the unconstrained optimum does not reach change nothing: z = −A⁺b."""
    rng = np.random.default_rng(3)
    a, b = rng.normal(size=(12, 5)), rng.normal(size=12)
    free = np.linalg.lstsq(a, -b, rcond=None)[0]
    z = bounded_least_squares(a, b, np.full(5, -1e6), np.full(5, 1e6))
    np.testing.assert_allclose(z, free, rtol=1e-12, atol=1e-12)
