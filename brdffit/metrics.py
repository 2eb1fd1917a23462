"""Goodness-of-fit metrics of a model against measurements, per channel (docs/fitting.md has the formulas)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .arrays import to_device
from .geometry import LocalPair
from .models.model import Model, evaluate_pair

__all__ = ["fit_metrics", "fit_sums", "metric_sums", "metrics_from_sums", "METRICS", "NOISE_ROWS"]

METRICS = ("rmse_abs", "rmse_rel", "ngan", "low")


_CHUNK = 65_536


# Rows of `metric_sums` after the metrics' numerators and denominators: the sums from which the noise models of
# `brdffit.fitting.noise` get their maximum-likelihood scales and log-likelihoods (no second pass over the data).
NOISE_ROWS = ("n", "d2", "log_f", "d2_over_f", "d2_over_f2", "log_weight", "weighted_d2")
_METRIC_ROWS = 2 * len(METRICS)

# Model values below this (1/sr) count as this in the noise sums: σ ∝ f or σ² ∝ f would be 0 there.
MODEL_FLOOR = 1e-8
# Samples with cosθi below this (θi > 81.4°) are left out of the noise sums. The cosine loss hardly weighs them,
# so their residuals hold the fit's own error where the specular lobes grow fastest (Ward's peak at grazing
# incidence reached 600 1/sr, fitted 35σ off): absolute noise was taken for signal-dependent in 14 of 150 fits of
# a synthetic Ward material, 0 of 150 without them.
NOISE_MIN_COS = 0.15
# The noise sums are taken over every k-th sample of a call with k = max(1, N // NOISE_SAMPLES): they need a log
# and two divisions per value, which over every sample of a MERL-size fit add a sizeable share to the CPU time of
# the metric sums; over 4,096 samples of each chunk of 65,536 they add little, and 94,000 samples still tell the
# noise models apart by thousands of log-likelihood units.
NOISE_SAMPLES = 4096


def metric_sums(f_model, values, valid, cos_i, weights, xp=jnp):
    """Numerators and denominators of the metrics over some samples, and the noise models' sums: ``(15, C)``
    (`metrics_from_sums` finishes the metrics, `brdffit.fitting.noise.compare` the noise models). The fits take
    the same sums from the model values of their last pass, in one program per data shape that every model
    shares (`brdffit.fitting.normal_equations.accumulate`).

    Arguments:
        f_model: model values ``(..., N, C)`` (leading axes: independent sets of samples, summed apart).
        values: data ``(..., N, C)`` (any value where not ``valid``).
        valid: ``(..., N, C)`` True where the data count.
        cos_i: ``(..., N)`` cosθi.
        weights: ``(..., N)`` quadrature weights.
        xp: `jax.numpy` (traced) or ``numpy``.

    Returns:
        ``(..., 15, C)``: for each metric of `METRICS` its numerator, then its denominator; then the rows of
        `NOISE_ROWS`, over the valid samples with cosθi ≥ `NOISE_MIN_COS` among every k-th (`NOISE_SAMPLES`),
        with d = f_m − f_d, f̃ = max(f_m, `MODEL_FLOOR`) and ω = cosθi √w (the cosine loss's weight): their count,
        Σ d², Σ ln f̃, Σ d²/f̃, Σ d²/f̃², Σ ln ω and Σ ω² d².
    """
    f_data = xp.where(valid, values, 0.0)
    c = cos_i[..., None]
    w = xp.where(valid, weights[..., None], 0.0)
    diff = xp.where(valid, f_model - f_data, 0.0)
    positive = valid & (f_data > 0)
    relative = xp.where(positive, diff / xp.where(positive, f_data, 1.0), 0.0)
    low = xp.where(valid, xp.log1p(xp.maximum(f_model * c, -0.999)) - xp.log1p(f_data * c), 0.0)
    terms = [diff * diff, valid, relative * relative, positive, w * (diff * c) ** 2, w, w * low * low, w]
    step = max(1, f_model.shape[-2] // NOISE_SAMPLES)
    sub_valid = valid[..., ::step, :] & (cos_i[..., ::step] >= NOISE_MIN_COS)[..., None]
    sub_diff = xp.where(sub_valid, diff[..., ::step, :], 0.0)
    floored = xp.where(sub_valid, xp.maximum(f_model[..., ::step, :], MODEL_FLOOR), 1.0)
    d2 = sub_diff * sub_diff
    d2_over_f = d2 / floored
    omega2 = (xp.maximum(cos_i[..., ::step], NOISE_MIN_COS) ** 2 * weights[..., ::step])[..., None]
    log_weight = xp.where(sub_valid, 0.5 * xp.log(xp.maximum(omega2, 1e-300)), 0.0)
    terms += [sub_valid, d2, xp.log(floored), d2_over_f, d2_over_f / floored, log_weight,
              xp.where(sub_valid, omega2, 0.0) * d2]
    if xp is np:  # a product with ones: NumPy's sum over the sample axis loops over the channels innermost (20x)
        return np.stack([np.ones(t.shape[-2]) @ t.astype(diff.dtype, copy=False) for t in terms], axis=-2)
    return xp.stack([xp.sum(t, axis=-2, dtype=diff.dtype) for t in terms], axis=-2)


def metrics_from_sums(sums) -> dict:
    """The metrics from `metric_sums` (added over chunks): name -> NumPy array ``(C,)``."""
    sums = np.asarray(sums, dtype=float)[:_METRIC_ROWS]
    return dict(zip(METRICS, np.sqrt(sums[0::2] / np.maximum(sums[1::2], 1e-300))))


def _metric_sums(model: Model, pair: LocalPair, values, cos_i, weights):
    return metric_sums(evaluate_pair(model, pair), values, jnp.isfinite(values), cos_i, weights)


@jax.jit
def _metrics(model: Model, pair: LocalPair, values, cos_i, weights):
    # Chunks of _CHUNK samples in one compiled loop: on the CPU this runs faster than the same sums over a
    # MERL-size table at once, since the working set stays in cache. Padding repeats the last sample with a NaN value,
    # which no sum counts.
    n = values.shape[0]
    chunks = max(-(-n // _CHUNK), 1)
    size = -(-n // chunks)
    pad = chunks * size - n

    def blocks(a, fill=None):
        if pad:
            tail = jnp.repeat(a[-1:], pad, axis=0) if fill is None else jnp.full((pad,) + a.shape[1:], fill, a.dtype)
            a = jnp.concatenate([a, tail])
        return a.reshape((chunks, size) + a.shape[1:])

    batched = (jax.tree_util.tree_map(blocks, pair), blocks(values, jnp.nan), blocks(cos_i), blocks(weights))
    return jnp.sum(jax.lax.map(lambda xs: _metric_sums(model, *xs), batched), axis=0)


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
        pair: the data's precomputed `LocalPair`, if at hand; it may hold more rows than the measurements (a fit's
            padded data, `brdffit.fitting.problem.bucket`), which count as missing.

    Returns:
        name -> NumPy array ``(C,)``.
    """
    return metrics_from_sums(fit_sums(model, measurements, pair))


def fit_sums(model: Model, measurements, pair: LocalPair | None = None) -> np.ndarray:
    """The `metric_sums` ``(15, C)`` of ``model`` on the valid samples of ``measurements`` (arguments as
    `fit_metrics`): the metrics and the noise models' sums in one evaluation of the model."""
    if pair is None:
        pair = LocalPair.from_dirs(to_device(measurements.wi()), to_device(measurements.wo()))
    extra = pair.wi.shape[0] - measurements.n
    weights = np.ones(measurements.n) if measurements.weights is None else measurements.weights
    values, cos_i = np.asarray(measurements.values, dtype=float), np.cos(np.asarray(measurements.theta_i, float))
    if extra:
        values = np.concatenate([values, np.full((extra, values.shape[1]), np.nan)])
        cos_i = np.concatenate([cos_i, np.ones(extra)])
        weights = np.concatenate([np.asarray(weights, dtype=float), np.ones(extra)])
    return np.asarray(_metrics(model, pair, to_device(values), to_device(cos_i), to_device(weights, dtype=float)))
