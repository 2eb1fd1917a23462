"""Goodness-of-fit metrics of a model against measurements, per channel (docs/fitting.md has the formulas)."""

from __future__ import annotations

import numpy as np

from .models.model import Model, evaluate_dirs

__all__ = ["fit_metrics", "METRICS"]

METRICS = ("rmse_abs", "rmse_rel", "ngan", "low")


def fit_metrics(model: Model, measurements) -> dict:
    """Error metrics of ``model`` on the valid samples of ``measurements``, one value per channel.

    - ``rmse_abs``: √(mean (f_m − f_d)²), in 1/sr;
    - ``rmse_rel``: √(mean ((f_m − f_d)/f_d)²) over samples with f_d > 0;
    - ``ngan``: √(Σ w (f_m − f_d)² cos²θi / Σ w), the cosine-weighted L2 of Ngan et al. (2005), with the
      samples' quadrature weights w (1 when the data have none);
    - ``low``: √(Σ w (ln(1 + f_m cosθi) − ln(1 + f_d cosθi))² / Σ w), Löw et al. (2012)'s E2.

    Arguments:
        model: the model to score.
        measurements: `brdffit.Measurements` with the same number of channels.

    Returns:
        name -> NumPy array ``(C,)``.
    """
    f_model = np.asarray(evaluate_dirs(model, measurements.wi(), measurements.wo()), dtype=float)
    f_data = np.asarray(measurements.values, dtype=float)
    valid = np.isfinite(f_data)
    f_data = np.where(valid, f_data, 0.0)
    cos_i = np.cos(np.asarray(measurements.theta_i))[:, None]
    w = np.ones(len(f_data)) if measurements.weights is None else np.asarray(measurements.weights, dtype=float)
    w = np.where(valid, w[:, None], 0.0)
    diff = f_model - f_data
    positive = valid & (f_data > 0)
    count = np.maximum(valid.sum(axis=0), 1)

    def weighted_rms(x, weights):
        return np.sqrt(np.sum(weights * x * x, axis=0) / np.maximum(np.sum(weights, axis=0), 1e-300))

    return {
        "rmse_abs": np.sqrt(np.sum(np.where(valid, diff * diff, 0.0), axis=0) / count),
        "rmse_rel": weighted_rms(np.where(positive, diff / np.where(positive, f_data, 1.0), 0.0),
                                 positive.astype(float)),
        "ngan": weighted_rms(diff * cos_i, w),
        "low": weighted_rms(np.log1p(np.maximum(f_model * cos_i, -0.999)) - np.log1p(f_data * cos_i), w),
    }
