"""Standard errors of a fit: the Laplace (Gauss-Newton) covariance and the heteroscedasticity-consistent sandwich;
which of them a result reports by default is decided by the noise model its residuals support
(`brdffit.fitting.noise`).

Both come from the residual Jacobian J in the physical parameters at the optimum, over every free parameter
(the projected amplitudes included: at the optimum the joint Gauss-Newton covariance is that of the separable
problem, Golub & Pereyra 1973, section 5):

- Laplace: s² (JᵀJ)⁻¹ with s² = Σr²/dof (1 for ``loss="sigma"``, whose residuals are already in units of σ);
- sandwich (White 1980, with MacKinnon & White 1985's HC1 factor n/(n − p) for the degrees of freedom the fit
  used): n/(n − p) (JᵀJ)⁻¹ Jᵀ diag(r²) J (JᵀJ)⁻¹, valid when the residuals' variance differs between samples.

Directions of JᵀJ with eigenvalues below 1e-12 of the largest are undetermined by the data: parameters with a
component along them get infinite variance.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .normal_equations import NormalEquations, accumulate, chunks
from .problem import FitData, Problem

__all__ = ["normal_equations_at", "covariances", "Uncertainty"]


def normal_equations_at(problem: Problem, params: dict, data: FitData, width: int = 1) -> NormalEquations:
    """JᵀJ, Jᵀ diag(r²) J, Jᵀr, the costs and the metric sums at physical ``params`` over the free parameters
    (chunked pass).

    Arguments:
        problem, params, data: the `Problem`, physical values of every parameter, one material's `FitData`.
        width: evaluate the point as a batch of this many (equal) points: the width of the solve that found it, so
            that its compiled pass serves here too instead of compiling one for a single point.

    Returns:
        The `NormalEquations` of the point.
    """
    data = data._replace(fixed={k: jnp.asarray(v) for k, v in params.items() if k not in problem.free})
    trees = {k: np.broadcast_to(np.asarray(params[k], dtype=float), (1, width) + np.shape(params[k])).copy()
             for k in problem.free}
    return accumulate(problem, trees, chunks(data), metrics=True).at_point(0, 0)


class Uncertainty:
    """The covariances and what derives from them.

    Attributes:
        covariance, sandwich: the Laplace and sandwich covariances ``(P, P)`` over the free scalars
            (`Layout.flatten` order).
        stderr, stderr_robust: their square-rooted diagonals.
        correlation: the Laplace correlation matrix.
        variance: the noise variance s².
        undetermined: ``(P,)`` True for scalars along a null direction of JᵀJ.
    """

    def __init__(self, normal: NormalEquations | None, cost: float, loss: str, n_valid: int):
        if normal is None or normal.jtj.shape[0] == 0:
            self.covariance = self.sandwich = self.correlation = np.zeros((0, 0))
            self.stderr = self.stderr_robust = np.zeros(0)
            self.variance, self.undetermined = float("nan"), np.zeros(0, bool)
            return
        self.covariance, self.sandwich, self.variance, self.undetermined = covariances(
            normal.jtj, normal.meat, cost, loss, n_valid)
        with np.errstate(invalid="ignore", divide="ignore"):
            self.stderr = np.sqrt(np.diag(self.covariance))
            self.stderr_robust = np.sqrt(np.diag(self.sandwich))
            self.correlation = self.covariance / np.outer(self.stderr, self.stderr)

    def chosen(self, kind: str):
        """``(covariance, correlation, stderr)`` of ``kind``: ``"laplace"`` or ``"sandwich"``."""
        if kind == "laplace":
            return self.covariance, self.correlation, self.stderr
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.sandwich, self.sandwich / np.outer(self.stderr_robust, self.stderr_robust), \
                self.stderr_robust


def covariances(jtj, meat, rss: float, loss: str, n_valid: int):
    """The Laplace and sandwich covariances (see the module doc).

    Arguments:
        jtj: JᵀJ ``(P, P)``; meat: Jᵀ diag(r²) J.
        rss: Σr² at the optimum.
        loss: the fit's loss name.
        n_valid: number of valid residuals.

    Returns:
        ``(laplace, sandwich, variance, undetermined)``.
    """
    p = jtj.shape[0]
    dof = max(n_valid - p, 1)
    variance = 1.0 if loss == "sigma" else rss / dof
    with np.errstate(over="ignore", invalid="ignore"):
        finite = np.all(np.isfinite(jtj))
        eigval, eigvec = np.linalg.eigh(jtj if finite else np.nan_to_num(jtj, posinf=0.0, neginf=0.0, nan=0.0))
    good = eigval > 1e-12 * max(eigval.max(initial=0.0), 1e-300)
    inv = (eigvec[:, good] / eigval[good]) @ eigvec[:, good].T
    cov = variance * inv
    sandwich = (max(n_valid, 1) / dof) * (inv @ np.nan_to_num(meat) @ inv)
    undetermined = np.any(np.abs(eigvec[:, ~good]) > 1e-6, axis=1) if (~good).any() else np.zeros(p, bool)
    if not finite:
        undetermined = np.ones(p, bool)
    for matrix in (cov, sandwich):
        matrix[undetermined, :] = np.inf
        matrix[:, undetermined] = np.inf
    return cov, sandwich, variance, undetermined
