"""The losses of a fit, one registry: each declares its residual, its weighting, its formula and its doc once.

A loss maps model values f_m and data f_d (shape ``(N, C)``) to residuals r whose sum of squares is minimised.
Samples with missing data (NaN) are masked to a zero residual before the solver sees them. The CLI's ``--loss``
choices and the table in docs/fitting.md are generated from `LOSSES` (and checked by a test).

A loss whose residual is w · (f_m − f_d) with a weight w that does not depend on the model is *linear*: for it,
the amplitudes that enter the BRDF linearly are solved exactly by weighted linear least squares
(`brdffit.fitting.separable`). For a nonlinear loss (``log``) and for the robust reweightings the same solve,
with w the residual's derivative at the data, gives the start of a joint solve.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

from .._lazy import module

# NumPy and JAX are loaded when a residual is first computed, not when the registry is read (the CLI's help
# lists it, and answers within half a second).
np = module("numpy")
jnp = module("jax.numpy")

__all__ = ["Loss", "LOSSES", "ROBUST", "get_loss", "loss_table", "residuals", "robust_residuals", "relative_epsilon",
           "loss_epsilon", "residual_scale"]


@dataclasses.dataclass(frozen=True)
class Loss:
    """The declaration of a loss.

    Attributes:
        name: the registry name (``fit(loss=...)``, ``--loss``).
        weight: ``(f_d, cos_i, sqrt_weight, sigma, eps) -> w`` of shape ``(N, C)``: the residual's derivative
            ∂r/∂f_m (at f_m = f_d for a nonlinear loss).
        linear: True when r = w · (f_m − f_d) exactly.
        formula: the residual in symbols (docs, CLI help).
        use: when to use it (docs).
        nonlinear_residual: for a loss that is not linear, ``(f_m, f_d, cos_i, sqrt_weight) -> r``.
        needs_sigma: True when the measurements must carry σ.
    """

    name: str
    weight: Callable
    linear: bool
    formula: str
    use: str
    nonlinear_residual: Callable | None = None
    needs_sigma: bool = False

    def residuals(self, f_model, f_data, cos_i, sqrt_weight, sigma, eps):
        """The residuals ``(N, C)`` (no mask applied)."""
        if self.linear:
            return self.weight(f_data, cos_i, sqrt_weight, sigma, eps) * (f_model - f_data)
        return self.nonlinear_residual(f_model, f_data, cos_i, sqrt_weight)


# The weights are written in arithmetic that keeps NumPy arrays in NumPy (the noise sums of an answer form them
# on the host, `brdffit.fitting.normal_equations.noise_grams_of`, where a jax.numpy call would compile a program
# of its own) and traces as before inside a compiled pass; the data's missing values are 0, never NaN.
def _cosine_weight(f_data, cos_i, sqrt_weight, sigma, eps):
    return (cos_i * sqrt_weight)[:, None] + 0.0 * f_data


def _log_weight(f_data, cos_i, sqrt_weight, sigma, eps):
    c = cos_i[:, None]
    return c * sqrt_weight[:, None] / (1.0 + f_data * c)


def _log_residual(f_model, f_data, cos_i, sqrt_weight):
    xp = np if isinstance(f_model, np.ndarray) else jnp  # NumPy on the host (a selection's held-out errors)
    c = cos_i[:, None]
    return (xp.log1p(f_model * c) - xp.log1p(f_data * c)) * sqrt_weight[:, None]


_REGISTRY = (
    Loss("cosine", _cosine_weight, True, "(f_m − f_d) · cosθi · √w",
         "the image matters: this is Ngan et al. (2005)'s cosine-weighted L2, the error in reflected radiance "
         "under uniform lighting"),
    Loss("log", _log_weight, False, "(ln(1 + f_m cosθi) − ln(1 + f_d cosθi)) · √w",
         "high dynamic range (a sharp peak over a dim diffuse): Löw et al. (2012)'s E2 compresses the peak",
         nonlinear_residual=_log_residual),
    Loss("relative", lambda f_data, cos_i, sqrt_weight, sigma, eps: 1.0 / (f_data + eps), True,
         "(f_m − f_d) / (f_d + ε), ε = 10⁻³ × the channel's mean absolute f_d",
         "relative (multiplicative) noise without known σ"),
    Loss("absolute", lambda f_data, cos_i, sqrt_weight, sigma, eps: 0.0 * f_data + 1.0, True, "f_m − f_d",
         "additive noise of one σ everywhere"),
    Loss("sigma", lambda f_data, cos_i, sqrt_weight, sigma, eps: 1.0 / sigma, True, "(f_m − f_d) / σ",
         "the data carry σ: this is the maximum-likelihood fit and gives calibrated errors", needs_sigma=True),
)
LOSSES: dict[str, Loss] = {loss.name: loss for loss in _REGISTRY}
ROBUST = (None, "huber", "cauchy")


def loss_table() -> str:
    """The Markdown table of the losses in docs/fitting.md (a test checks that the docs hold it)."""
    rows = ["| `loss` | residual | linear in f | use it when |", "|---|---|---|---|"]
    for loss in LOSSES.values():
        name = f"`{loss.name}`" + (" (default)" if loss.name == "cosine" else "")
        rows.append(f"| {name} | {loss.formula} | {'yes' if loss.linear else 'no'} | {loss.use} |")
    return "\n".join(rows)


def get_loss(name: str) -> Loss:
    """The `Loss` registered under ``name``; a ValueError lists the choices."""
    try:
        return LOSSES[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown loss {name!r}; choose one of {', '.join(LOSSES)}") from None


def relative_epsilon(values):
    """The ε of the relative loss per channel: 1e-3 times the mean absolute value of the channel's valid data.

    Arguments:
        values: data ``(N, C)`` with NaN for missing samples.

    Returns:
        Array ``(C,)``, strictly positive.
    """
    with np.errstate(invalid="ignore"):
        scale = np.nanmean(np.abs(values), axis=0) if np.isfinite(values).any() else np.ones(np.shape(values)[1])
    return np.maximum(1e-3 * np.nan_to_num(scale, nan=1.0), 1e-12)


def loss_epsilon(loss: str, values):
    """The ε that the residuals read for ``loss``: `relative_epsilon` for the relative loss, the only one that
    reads it; ones for the others, which spares them a pass over the data.

    Arguments:
        loss: a name in `LOSSES`.
        values: data ``(N, C)`` with NaN for missing samples.

    Returns:
        Array ``(C,)``.
    """
    return relative_epsilon(values) if loss == "relative" else np.ones(np.shape(values)[1])


def residuals(loss: str, f_model, f_data, cos_i, sqrt_weight, sigma, eps):
    """Residuals of one loss (`Loss.residuals` of ``LOSSES[loss]``).

    Arguments:
        loss: a name in `LOSSES`.
        f_model, f_data: ``(N, C)``.
        cos_i: ``(N,)`` cosθi of each sample.
        sqrt_weight: ``(N,)`` square roots of the quadrature weights.
        sigma: ``(N, C)`` standard deviations (ones where unknown).
        eps: ``(C,)`` the relative loss's ε.

    Returns:
        ``(N, C)`` residuals.
    """
    return get_loss(loss).residuals(f_model, f_data, cos_i, sqrt_weight, sigma, eps)


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


def residual_scale(loss: str, data) -> np.ndarray:
    """|∂r/∂f_model| at f_model = f_data for each (sample, channel), 0 for missing samples.

    It linearises a loss at the data: an error δ in f becomes a residual of about ``residual_scale · δ``. The
    posterior uses it to carry a σ given in 1/sr into the loss's residual units.

    Arguments:
        loss: a name in `LOSSES`.
        data: `brdffit.fitting.problem.FitData`.

    Returns:
        NumPy array ``(N, C)``.
    """
    w = get_loss(loss).weight(data.values, data.cos_i, data.sqrt_weight, data.sigma, data.eps)
    return np.where(np.asarray(data.mask), np.abs(np.asarray(w)), 0.0)
