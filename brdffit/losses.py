"""Residual definitions of the fitting losses and the robust reweightings (docs/fitting.md has the formulas).

A loss maps model values f_m and data f_d (shape ``(N, C)``) to residuals r whose sum of squares is minimised.
Samples with missing data (NaN) are masked to a zero residual before the solver sees them.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

__all__ = ["LOSSES", "ROBUST", "residuals", "robust_residuals", "relative_epsilon", "loss_epsilon", "residual_scale"]

LOSSES = ("cosine", "log", "relative", "absolute", "sigma")
ROBUST = (None, "huber", "cauchy")


def relative_epsilon(values):
    """The ε of the relative loss per channel: 1e-3 times the mean absolute value of the channel's valid data.

    Arguments:
        values: data ``(N, C)`` with NaN for missing samples.

    Returns:
        Array ``(C,)``, strictly positive.
    """
    scale = np.nanmean(np.abs(values), axis=0)
    return np.maximum(1e-3 * np.nan_to_num(scale, nan=1.0), 1e-12)


def loss_epsilon(loss: str, values):
    """The ε that `residuals` reads for ``loss``: `relative_epsilon` for the relative loss, the only one that
    reads it; ones for the others, which spares them a pass over the data (0.06 s on a MERL-size table).

    Arguments:
        loss: one of `LOSSES`.
        values: data ``(N, C)`` with NaN for missing samples.

    Returns:
        Array ``(C,)``.
    """
    return relative_epsilon(values) if loss == "relative" else np.ones(np.shape(values)[1])


def residuals(loss: str, f_model, f_data, cos_i, sqrt_weight, sigma, eps):
    """Residuals of one loss.

    - ``cosine``: (f_m − f_d) cosθi √w, Ngan et al. (2005)'s cosine-weighted L2 with the sample's solid-angle
      weight w;
    - ``log``: (ln(1 + f_m cosθi) − ln(1 + f_d cosθi)) √w, Löw et al. (2012)'s E2 metric;
    - ``relative``: (f_m − f_d)/(f_d + ε), ε from `relative_epsilon`;
    - ``absolute``: f_m − f_d;
    - ``sigma``: (f_m − f_d)/σ with the measurements' per-sample σ.

    Arguments:
        loss: one of `LOSSES`.
        f_model, f_data: ``(N, C)``.
        cos_i: ``(N,)`` cosθi of each sample.
        sqrt_weight: ``(N,)`` square roots of the quadrature weights.
        sigma: ``(N, C)`` standard deviations (ones where unknown).
        eps: ``(C,)`` the relative loss's ε.

    Returns:
        ``(N, C)`` residuals.
    """
    c = cos_i[:, None]
    w = sqrt_weight[:, None]
    if loss == "cosine":
        return (f_model - f_data) * c * w
    if loss == "log":
        return (jnp.log1p(f_model * c) - jnp.log1p(f_data * c)) * w
    if loss == "relative":
        return (f_model - f_data) / (f_data + eps)
    if loss == "absolute":
        return f_model - f_data
    if loss == "sigma":
        return (f_model - f_data) / sigma
    raise ValueError(f"unknown loss {loss!r}; choose one of {', '.join(LOSSES)}")


def robust_residuals(kind: str | None, r, scale: float):
    """Rewrite residuals so that their sum of squares is the robust loss Σ 2 s² ρ(r/s).

    - ``huber``: ρ(z) = z²/2 for |z| <= 1, |z| − 1/2 otherwise (Huber 1964); residual sign(r) s √(2|z| − 1)
      outside the core.
    - ``cauchy``: ρ(z) = ln(1 + z²)/2; residual r √(ln(1 + z²)/z²), which tends to r as z -> 0.

    Arguments:
        kind: None (plain least squares), ``"huber"`` or ``"cauchy"``.
        r: residuals.
        scale: s, the residual size beyond which samples count as outliers (in the loss's units).

    Returns:
        Residuals of the same shape.
    """
    if kind is None:
        return r
    z = r / scale
    z2 = z * z
    if kind == "huber":
        outer = jnp.abs(z) > 1.0
        tail = jnp.sign(r) * scale * jnp.sqrt(jnp.where(outer, 2.0 * jnp.abs(z) - 1.0, 1.0))
        return jnp.where(outer, tail, r)
    if kind == "cauchy":
        small = z2 < 1e-8
        factor = jnp.sqrt(jnp.log1p(jnp.where(small, 1.0, z2)) / jnp.where(small, 1.0, z2))
        return r * jnp.where(small, 1.0 - 0.25 * z2, factor)
    raise ValueError(f"unknown robust loss {kind!r}; choose None, 'huber' or 'cauchy'")


def residual_scale(loss: str, data) -> jnp.ndarray:
    """|∂r/∂f_model| at f_model = f_data for each (sample, channel), 0 for missing samples.

    It linearises a loss at the data: an error δ in f becomes a residual of about ``residual_scale · δ``. The
    initial guess uses it to weight its linear amplitude solve, and the posterior to carry a σ given in 1/sr
    into the loss's residual units.

    Arguments:
        loss: one of `LOSSES`.
        data: `brdffit.problem.FitData`.

    Returns:
        NumPy array ``(N, C)``.
    """
    values = np.asarray(data.values)
    cos_i = np.asarray(data.cos_i)[:, None]
    sqrt_w = np.asarray(data.sqrt_weight)[:, None]
    if loss == "cosine":
        w = np.broadcast_to(cos_i * sqrt_w, values.shape)
    elif loss == "log":
        w = cos_i * sqrt_w / (1.0 + values * cos_i)
    elif loss == "relative":
        w = 1.0 / (values + np.asarray(data.eps))
    elif loss == "sigma":
        w = 1.0 / np.asarray(data.sigma)
    else:
        w = np.ones_like(values)
    return np.where(np.asarray(data.mask), w, 0.0)
