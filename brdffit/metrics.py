"""Goodness-of-fit metrics of a model against measurements, per channel (docs/fitting.md has the formulas)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .geometry import LocalPair
from .models.model import Model, evaluate_pair

__all__ = ["fit_metrics", "metric_sums", "metrics_from_sums", "METRICS"]

METRICS = ("rmse_abs", "rmse_rel", "ngan", "low")


_CHUNK = 65_536


def metric_sums(f_model, values, valid, cos_i, weights, xp=jnp):
    """Numerators and denominators of the metrics over some samples: ``(8, C)`` (`metrics_from_sums` finishes
    them). The fits take the same sums from the model values of their last pass, in one program per data shape
    that every model shares (`brdffit.fitting.normal_equations.accumulate`).

    Arguments:
        f_model: model values ``(N, C)``.
        values: data ``(N, C)`` (any value where not ``valid``).
        valid: ``(N, C)`` True where the data count.
        cos_i: ``(N,)`` cosθi.
        weights: ``(N,)`` quadrature weights.
        xp: `jax.numpy` (traced) or ``numpy``.

    Returns:
        ``(8, C)``: for each metric of `METRICS` its numerator, then its denominator.
    """
    f_data = xp.where(valid, values, 0.0)
    c = cos_i[:, None]
    w = xp.where(valid, weights[:, None], 0.0)
    diff = xp.where(valid, f_model - f_data, 0.0)
    positive = valid & (f_data > 0)
    relative = xp.where(positive, diff / xp.where(positive, f_data, 1.0), 0.0)
    low = xp.where(valid, xp.log1p(xp.maximum(f_model * c, -0.999)) - xp.log1p(f_data * c), 0.0)
    terms = (diff * diff, valid, relative * relative, positive, w * (diff * c) ** 2, w, w * low * low, w)
    return xp.stack([xp.sum(t, axis=0, dtype=diff.dtype) for t in terms])


def metrics_from_sums(sums) -> dict:
    """The metrics from `metric_sums` (added over chunks): name -> NumPy array ``(C,)``."""
    sums = np.asarray(sums, dtype=float)
    return dict(zip(METRICS, np.sqrt(sums[0::2] / np.maximum(sums[1::2], 1e-300))))


def _metric_sums(model: Model, pair: LocalPair, values, cos_i, weights):
    return metric_sums(evaluate_pair(model, pair), values, jnp.isfinite(values), cos_i, weights)


@jax.jit
def _metrics(model: Model, pair: LocalPair, values, cos_i, weights):
    # Chunks of _CHUNK samples in one compiled loop: on the CPU this ran twice as fast as the same sums over a
    # MERL-size table at once (the working set stays in cache). Padding repeats the last sample with a NaN value,
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
    if pair is None:
        pair = LocalPair.from_dirs(jnp.asarray(measurements.wi()), jnp.asarray(measurements.wo()))
    extra = pair.wi.shape[0] - measurements.n
    weights = np.ones(measurements.n) if measurements.weights is None else measurements.weights
    values, cos_i = np.asarray(measurements.values, dtype=float), np.cos(np.asarray(measurements.theta_i, float))
    if extra:
        values = np.concatenate([values, np.full((extra, values.shape[1]), np.nan)])
        cos_i = np.concatenate([cos_i, np.ones(extra)])
        weights = np.concatenate([np.asarray(weights, dtype=float), np.ones(extra)])
    return metrics_from_sums(_metrics(model, pair, jnp.asarray(values), jnp.asarray(cos_i),
                                      jnp.asarray(weights, dtype=float)))
