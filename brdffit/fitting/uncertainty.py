"""Standard errors of a fit: the Laplace (Gauss-Newton) covariance and the heteroscedasticity-consistent sandwich;
which of them a result reports by default is decided by the noise model its residuals support
(`brdffit.fitting.noise`).

Both come from the residual Jacobian J in the physical parameters at the optimum, over every free parameter
(the projected amplitudes included: at the optimum the joint Gauss-Newton covariance is that of the separable
problem, Golub & Pereyra 1973, section 5):

- Laplace: s² (JᵀJ)⁻¹ with s² = Σr²/dof (1 for ``loss="sigma"``, whose residuals are already in units of σ), with
  one variance per channel where the channels have their own: (JᵀJ)⁻¹ (Σ_c s_c² J_cᵀJ_c) (JᵀJ)⁻¹, s_c² the
  channel's Σr²/n_c times n/dof (the shared shape parameters are fitted to all channels unweighted, so their
  covariance is this sandwich of the channels' Fisher informations, not the inverse of their weighted sum); with
  equal s_c it is s² (JᵀJ)⁻¹;
- noise-model: n/(n − p) (JᵀJ)⁻¹ (Σ_n v_n J_nᵀJ_n) (JᵀJ)⁻¹ with v_n the variance that the noise model chosen for
  the residual's channel (`brdffit.fitting.noise`, its scale fitted by maximum likelihood to all the channel's
  values) gives the residual,
  carried into the loss's units (`brdffit.fitting.normal_equations.noise_grams_of`): the covariance of a
  least-squares estimate under a known variance function (Carroll & Ruppert 1988, "Transformation and Weighting
  in Regression", section 2.3); it is the Laplace where every channel's noise is the loss's own;
- sandwich (White 1980, with MacKinnon & White 1985's HC1 factor n/(n − p) for the degrees of freedom the fit
  used): n/(n − p) (JᵀJ)⁻¹ Jᵀ diag(r²) J (JᵀJ)⁻¹, valid when the residuals' variance differs between samples in
  any pattern, but short where a few samples carry most of the leverage (each then stands for its own variance).

Directions of JᵀJ with eigenvalues below 1e-12 of the largest are undetermined by the data: parameters with a
component along them get infinite variance.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .normal_equations import NOISE_FORMS, NormalEquations, _expand, accumulate, chunks
from .problem import FitData, Problem

__all__ = ["normal_equations_at", "covariances", "pseudo_inverse", "Uncertainty"]


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
    return accumulate(problem, trees, chunks(data), metrics=True, first=1).at_point(0, 0)


class Uncertainty:
    """The covariances and what derives from them.

    Attributes:
        covariance, sandwich, noise_model: the Laplace, sandwich and noise-model covariances ``(P, P)`` over the
            free scalars (`Layout.flatten` order); the noise-model one is the Laplace where no noise model or
            noise sums were given.
        stderr, stderr_robust: the Laplace and sandwich covariances' square-rooted diagonals.
        correlation: the Laplace correlation matrix.
        variance: the noise variance s² (over all channels).
        undetermined: ``(P,)`` True for scalars along a null direction of JᵀJ.
    """

    def __init__(self, normal: NormalEquations | None, cost: float, loss: str, n_valid: int, *, problem=None,
                 noise=None, channel_counts=None):
        """Arguments:
            normal: the sums at the answer (None: no free parameter); cost: Σr²; loss: the loss's name;
            n_valid: the valid values.
            problem: the `Problem` (with ``noise`` and ``channel_counts``: per-channel variances).
            noise: the `brdffit.fitting.noise.NoiseModel` chosen from the residuals.
            channel_counts: ``(C,)`` valid values of each channel.
        """
        if normal is None or normal.jtj.shape[0] == 0:
            self.covariance = self.sandwich = self.noise_model = self.correlation = np.zeros((0, 0))
            self.stderr = self.stderr_robust = np.zeros(0)
            self.variance, self.undetermined = float("nan"), np.zeros(0, bool)
            return
        inv, self.undetermined = pseudo_inverse(normal.jtj)
        self.covariance, self.sandwich, self.variance = covariances(inv, self.undetermined, normal.meat, cost, loss,
                                                                    n_valid)
        self.noise_model = self.covariance
        if problem is not None and noise is not None and normal.noise_grams is not None and loss != "sigma" \
                and noise.name != "exact" and channel_counts is not None:
            laplace, noise_model = _channel_covariances(problem, normal, noise, cost, n_valid,
                                                        np.asarray(channel_counts, dtype=float), inv,
                                                        self.undetermined)
            self.covariance = laplace
            self.noise_model = laplace if noise.covariance == "laplace" else noise_model
        with np.errstate(invalid="ignore", divide="ignore"):
            self.stderr = np.sqrt(np.diag(self.covariance))
            self.stderr_robust = np.sqrt(np.diag(self.sandwich))
            self.correlation = self.covariance / np.outer(self.stderr, self.stderr)

    def chosen(self, kind: str):
        """``(covariance, correlation, stderr)`` of ``kind``: ``"laplace"``, ``"noise-model"`` or
        ``"sandwich"``."""
        if kind == "laplace":
            return self.covariance, self.correlation, self.stderr
        matrix = self.noise_model if kind == "noise-model" else self.sandwich
        with np.errstate(invalid="ignore", divide="ignore"):
            stderr = np.sqrt(np.diag(matrix))
            return matrix, matrix / np.outer(stderr, stderr), stderr


def _channel_covariances(problem: Problem, normal: NormalEquations, noise, cost: float, n_valid: int,
                         counts: np.ndarray, inv: np.ndarray, undetermined: np.ndarray):
    """The Laplace covariance with one noise variance per channel and the noise-model covariance (module doc),
    each written as s² [(JᵀJ)⁻¹ + (JᵀJ)⁻¹ D (JᵀJ)⁻¹] with s² = Σr²/dof and D = Σ_c ((v_c/v̄) G_c − J_cᵀJ_c),
    G_c the channel's Gram matrix weighted for its noise form, v_c its variance per unit weight and v̄ = Σr²/n:
    D is exactly 0 for one channel whose noise is the loss's own, so that the Laplace is then the plain one to the
    last bit.

    ``inv`` is (JᵀJ)⁻¹ on its determined directions (`pseudo_inverse`).

    Returns:
        ``(laplace, noise_model)`` ``(P, P)``, infinite on the ``undetermined`` scalars.
    """
    dof = max(n_valid - normal.jtj.shape[0], 1)
    sums = np.asarray(normal.noise_grams, dtype=float)  # (F, Q + 1, Q + 1, C)
    grams, rss = sums[:, :-1, :-1], sums[:, -1, -1]  # the weighted Gram matrices; each form's Σ d²/g (F, C)
    channels = grams.shape[-1]
    forms = noise.channel_forms(channels)
    own = grams[NOISE_FORMS.index("loss")]
    with np.errstate(all="ignore"):
        channel_cost = np.asarray(normal.channel_cost, dtype=float)
        mean = cost / max(n_valid, 1)
        laplace_ratio = (channel_cost / np.maximum(counts, 1.0)) / mean if mean > 0 else np.ones(channels)

        def covariance(ratio, weighted):
            middle = _expand(problem, weighted * ratio - own)
            out = (cost / dof) * (inv + inv @ np.nan_to_num(middle) @ inv)
            out[undetermined, :] = np.inf
            out[:, undetermined] = np.inf
            return out

        laplace = covariance(laplace_ratio, own)
        weighted = np.stack([own[..., c] if form == noise.loss_model else grams[NOISE_FORMS.index(form)][..., c]
                             for c, form in enumerate(forms)], axis=-1)
        # A form's scale over every valid value of the channel (the noise model's own, which chose the form, is
        # taken over a subsample of them: `brdffit.metrics.NOISE_SAMPLES`).
        ratio = np.array([laplace_ratio[c] if form == noise.loss_model
                          else rss[NOISE_FORMS.index(form), c] / max(counts[c], 1.0) / mean if mean > 0 else 1.0
                          for c, form in enumerate(forms)])
        return laplace, covariance(ratio, weighted)


def pseudo_inverse(jtj):
    """(JᵀJ)⁻¹ on the directions the data determine, and the scalars along the others (module doc).

    Arguments:
        jtj: JᵀJ ``(P, P)``.

    Returns:
        ``(inverse (P, P), undetermined (P,))``; every scalar is undetermined where JᵀJ is not finite.
    """
    p = jtj.shape[0]
    with np.errstate(over="ignore", invalid="ignore"):
        finite = np.all(np.isfinite(jtj))
        eigval, eigvec = np.linalg.eigh(jtj if finite else np.nan_to_num(jtj, posinf=0.0, neginf=0.0, nan=0.0))
    good = eigval > 1e-12 * max(eigval.max(initial=0.0), 1e-300)
    inv = (eigvec[:, good] / eigval[good]) @ eigvec[:, good].T
    undetermined = np.any(np.abs(eigvec[:, ~good]) > 1e-6, axis=1) if (~good).any() else np.zeros(p, bool)
    return inv, (undetermined if finite else np.ones(p, bool))


def covariances(inv, undetermined, meat, rss: float, loss: str, n_valid: int):
    """The Laplace and sandwich covariances (see the module doc).

    Arguments:
        inv, undetermined: (JᵀJ)⁻¹ on its determined directions and the scalars along the others
            (`pseudo_inverse`).
        meat: Jᵀ diag(r²) J.
        rss: Σr² at the optimum.
        loss: the fit's loss name.
        n_valid: number of valid residuals.

    Returns:
        ``(laplace, sandwich, variance)``: the covariances, infinite on the undetermined scalars, and s².
    """
    dof = max(n_valid - inv.shape[0], 1)
    variance = 1.0 if loss == "sigma" else rss / dof
    cov = variance * inv
    sandwich = (max(n_valid, 1) / dof) * (inv @ np.nan_to_num(meat) @ inv)
    for matrix in (cov, sandwich):
        matrix[undetermined, :] = np.inf
        matrix[:, undetermined] = np.inf
    return cov, sandwich, variance
