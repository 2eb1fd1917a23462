"""Goodness-of-fit metrics of a model against measurements, per channel (docs/fitting.md has the formulas)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .geometry import LocalPair
from .models.model import Model, evaluate_pair

__all__ = ["fit_metrics", "METRICS"]

METRICS = ("rmse_abs", "rmse_rel", "ngan", "low")


@jax.jit
def _metrics(model: Model, pair: LocalPair, values, cos_i, weights):
    f_model = evaluate_pair(model, pair)
    valid = jnp.isfinite(values)
    f_data = jnp.where(valid, values, 0.0)
    c = cos_i[:, None]
    w = jnp.where(valid, weights[:, None], 0.0)
    diff = f_model - f_data
    positive = valid & (f_data > 0)

    def weighted_rms(x, weights):
        return jnp.sqrt(jnp.sum(weights * x * x, axis=0) / jnp.maximum(jnp.sum(weights, axis=0), 1e-300))

    return {
        "rmse_abs": weighted_rms(diff, valid.astype(diff.dtype)),
        "rmse_rel": weighted_rms(jnp.where(positive, diff / jnp.where(positive, f_data, 1.0), 0.0),
                                 positive.astype(diff.dtype)),
        "ngan": weighted_rms(diff * c, w),
        "low": weighted_rms(jnp.log1p(jnp.maximum(f_model * c, -0.999)) - jnp.log1p(f_data * c), w),
    }


def fit_metrics(model: Model, measurements, pair: LocalPair | None = None) -> dict:
    """Error metrics of ``model`` on the valid samples of ``measurements``, one value per channel.

    - ``rmse_abs``: √(mean (f_m − f_d)²), in 1/sr;
    - ``rmse_rel``: √(mean ((f_m − f_d)/f_d)²) over samples with f_d > 0;
    - ``ngan``: √(Σ w (f_m − f_d)² cos²θi / Σ w), the cosine-weighted L2 of Ngan et al. (2005), with the
      samples' quadrature weights w (1 when the data have none);
    - ``low``: √(Σ w (ln(1 + f_m cosθi) − ln(1 + f_d cosθi))² / Σ w), Löw et al. (2012)'s E2.

    Arguments:
        model: the model to score.
        measurements: `brdffit.Measurements` with the same number of channels.
        pair: the data's precomputed `LocalPair`, if at hand.

    Returns:
        name -> NumPy array ``(C,)``.
    """
    if pair is None:
        pair = LocalPair.from_dirs(jnp.asarray(measurements.wi()), jnp.asarray(measurements.wo()))
    weights = np.ones(measurements.n) if measurements.weights is None else measurements.weights
    out = _metrics(model, pair, jnp.asarray(measurements.values, dtype=float),
                   jnp.cos(jnp.asarray(measurements.theta_i, dtype=float)), jnp.asarray(weights, dtype=float))
    return {k: np.asarray(out[k], dtype=float) for k in METRICS}
