"""The noise model of the measured values, chosen from a fit's residuals, and the standard error it supports.

Each candidate says how the standard deviation σ_n of a measured value y_n about the model value f_n varies, up
to a scale s that maximum likelihood fixes in closed form (per channel). With d_n = f_n − y_n over the n valid
values of a channel, σ_n² = s² g_n, the Gaussian log-likelihood maximised over s is

    ŝ² = (1/n) Σ d_n²/g_n,    ℓ = −(n/2) (ln(2π ŝ²) + 1) − ½ Σ ln g_n,

summed over channels (each channel has its own s). Every candidate has one scale per channel, so differences of
AIC are −2 Δℓ. The candidates (`CANDIDATES`; f̃ = max(f, `brdffit.metrics.MODEL_FLOOR`)):

| name | σ_n | arises from |
|---|---|---|
| ``absolute`` | s | additive noise of one size (read noise, quantisation) |
| ``relative`` | s f̃_n | multiplicative noise (gain, calibration, speckle): a constant fraction of the signal |
| ``signal`` | s √f̃_n (σ² ∝ f) | photon (shot) noise: the variance grows with the signal |
| ``cosine`` | s / (cosθi √w) | what the ``cosine`` loss assumes: its fit is the maximum-likelihood one under this noise |
| ``sigma`` | s σ_n (σ_n stored with the data) | what ``loss="sigma"`` assumes, s = 1 if the stated σ are right |

``cosine`` and ``sigma`` are candidates only for their own loss, which keeps its candidate unless another beats it
by more than ΔAIC 2 (`TIE_AIC`). The candidate is chosen for all channels together, and a channel departs from
that choice to its own best candidate where its own values favour it by more than ΔAIC `BAND_AIC` (a spectral
measurement whose short wavelengths carry detector noise of one size and whose long ones carry relative noise);
where most channels depart to one candidate, that candidate becomes the common choice (a joint choice can be a
compromise that no channel makes). The sums come from the model values of the
answer's own pass (`brdffit.metrics.metric_sums`, over up to 4,096 samples of each chunk of 65,536); the
``sigma`` candidate's are χ² and Σ ln σ over all values, compared per value.

The loss's weighting implies one of the candidates (`LOSS_NOISE`): the Laplace covariance assumes the loss's
residuals have one variance in each channel, i.e. that the noise is the loss's own. When every channel chooses that
candidate, the Laplace standard error (with one noise variance per channel) is the default; where a channel chooses
another, its residuals' variance follows that candidate, and the default is the noise-model covariance, which
weights each residual by the variance its channel's candidate gives it (`brdffit.fitting.uncertainty`;
docs/fitting.md). The sandwich (White 1980), consistent under any variance pattern but short where a few samples
carry most of the leverage, is kept beside it (``stderr_robust``). A ``log`` loss implies none of the candidates:
its default is the noise-model covariance, its residuals linearised at the data. A robust rewrite's default is
the sandwich (its residuals are not the data's noise).

A model σ² = a² + b² f² (a floor plus relative noise) has no closed-form scale and is not a candidate: profiling
its ratio a/b would need a grid of sums over every value.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..metrics import NOISE_ROWS

__all__ = ["NoiseModel", "CANDIDATES", "LOSS_NOISE", "compare", "of_fit", "merge", "NOISE_FORMULAS"]

CANDIDATES = ("absolute", "relative", "signal", "cosine", "sigma")

NOISE_FORMULAS = {
    "absolute": "σ = s",
    "relative": "σ = s·f",
    "signal": "σ² = s²·f",
    "cosine": "σ = s/(cosθi·√w)",
    "sigma": "σ = s·σ_data",
}

# The candidate under which each loss's fit is the maximum-likelihood one (its residuals then have one variance).
LOSS_NOISE = {"absolute": "absolute", "relative": "relative", "cosine": "cosine", "sigma": "sigma", "log": None}

# A loss="sigma" fit's Laplace covariance takes s = 1: it is the default only if the residuals put ŝ within this
# factor of 1 (else the stated σ are wrong by more than 2x and only the sandwich is consistent).
SIGMA_SCALE_RANGE = (0.5, 2.0)

_ROW = {name: 8 + i for i, name in enumerate(NOISE_ROWS)}

# A fit whose relative RMS error is below this in every channel is exact (noise-free data): nothing to compare.
EXACT_RELATIVE_RMS = 1e-9

# ΔAIC within which the loss's own candidate is kept (Burnham & Anderson 2002, 2.6: ΔAIC ≤ 2 is substantial
# support); 10 for ``sigma``, whose log-likelihood comes from all values and the others' from the sampled ones, so
# that a constant stated σ (the same model as ``absolute``) differs by their sampling alone.
TIE_AIC = (2.0, 10.0)
# ΔAIC, within one channel's values, by which that channel's best candidate must beat the common choice for the
# channel to depart from it. The candidates are not nested, and in one channel of ~1,500 values of one noise
# model another candidate can lead by chance: in 448 channel fits of relative noise (tests/test_band_noise.py)
# another led in 30, by at most 10.2. A 31-band spectrum makes 31 such tests a fit, so twice Burnham & Anderson
# (2002)'s "essentially no support" (10). The evidence of a band of another model grows with the range of the
# values its samples cover: absolute against relative noise of 1% led by 177-292 in 1,500 half-diff samples
# around the specular peak, by 14-38 in a gonio-grid of as many that rarely meets it (where 20 misses some bands).
BAND_AIC = 20.0


@dataclasses.dataclass(frozen=True)
class NoiseModel:
    """The noise models' comparison of one fit.

    Attributes:
        name: the chosen candidate (largest log-likelihood), or ``"exact"`` when the residuals are at rounding
            level (`EXACT_RELATIVE_RMS`).
        loss_model: the candidate the fit's loss implies (None for ``log`` or a robust rewrite).
        covariance: ``"laplace"``, ``"noise-model"`` or ``"sandwich"``: the one `FitResult.stderr` holds.
        loglik: candidate -> maximised log-likelihood, scaled to all ``n`` values.
        scale: candidate -> ŝ per channel.
        n: the number of (sample, channel) values of the fit.
        compared: the number of values the sums were taken over (all of them up to 8,191 samples).
        forms: the candidate of each channel (``name`` in every channel but those that depart from it,
            `BAND_AIC`); empty where not recorded (read as ``name`` in every channel).
    """

    name: str
    loss_model: str | None
    covariance: str
    loglik: dict
    scale: dict
    n: int
    compared: int
    forms: tuple = ()

    def channel_forms(self, channels: int) -> tuple:
        """The candidate of each of ``channels`` channels."""
        return tuple(self.forms) if len(self.forms) == channels else (self.name,) * channels

    def aic_gap(self) -> dict:
        """candidate -> its AIC minus the best one's (0 for the chosen)."""
        best = max(self.loglik.values(), default=0.0)
        return {k: 2.0 * (best - v) for k, v in self.loglik.items()}

    def describe(self, loss: str, channels: list | None = None) -> list[str]:
        """Lines for a summary: the chosen model with its scale and the others' AIC gaps, the channels that depart
        from it (named by ``channels``), and which standard error the fit reports and why."""
        if self.name == "exact":
            return ["noise: none: the residuals are at rounding level (noise-free data), nothing to compare; stderr "
                    "Laplace"]
        if self.name not in NOISE_FORMULAS:  # independent channels that chose differently (`merge`)
            return [f"noise per channel {self.name}; stderr per channel {self.covariance} (Laplace where the "
                    f"channel's noise is the {loss} loss's own, else the sandwich)"]
        forms = self.channel_forms(len(self.scale[self.name]))
        scale = _scales([v for v, form in zip(self.scale[self.name], forms) if form == self.name])
        bands = _departures(forms, self.name, self.scale, channels)
        # ΔAIC of each other candidate in all channels against this one in all channels (with departing channels
        # a candidate can be ahead in total: it is then signed).
        own = self.loglik[self.name]
        gaps = ", ".join(f"{k} {2.0 * (own - v):+.3g}" for k, v in sorted(self.loglik.items(), key=lambda kv: -kv[1])
                         if k != self.name)
        where = "" if self.compared >= self.n else f" on {self.compared} of {self.n} values"
        lines = [f"noise {self.name} ({NOISE_FORMULAS[self.name]}, s = {scale}) by likelihood{where}; "
                 f"ΔAIC{' over all channels' if bands else ''} {gaps}"]
        if bands:
            lines.append(f"noise per channel: {bands} (each by more than ΔAIC {BAND_AIC:g} in its own values), "
                         f"{self.name} in the others")
        if self.covariance == "laplace":
            lines.append(f"stderr Laplace, one noise variance per channel: the {loss} loss's weighting matches this "
                         "noise (sandwich in stderr_robust)")
            return lines
        implied = (f"the {loss} loss weights the residuals for {self.loss_model} noise "
                   f"({NOISE_FORMULAS[self.loss_model]})" if self.loss_model
                   else f"the robust rewrite of the {loss} loss implies none of these" if LOSS_NOISE.get(loss)
                   else f"the {loss} loss implies none of these")
        if self.covariance == "noise-model":
            lines.append(f"stderr noise-model: {implied}, so each residual is weighted by the variance its channel's "
                         "noise gives it (Laplace in stderr_laplace, sandwich in stderr_robust)"
                         + _advice(self.name, loss))
            return lines
        if self.name == "sigma":
            implied = f"the stated σ are off by a factor {np.max(self.scale['sigma']):.3g}"
        lines.append(f"stderr sandwich (White 1980, HC1): {implied}, so the Laplace in stderr_laplace is not "
                     "consistent" + _advice(self.name, loss))
        return lines

    def to_dict(self) -> dict:
        """JSON-ready (non-finite numbers become None)."""
        clean = lambda x: x if math.isfinite(x) else None  # noqa: E731
        return {"name": self.name, "loss_model": self.loss_model, "covariance": self.covariance,
                "loglik": {k: clean(float(v)) for k, v in self.loglik.items()},
                "scale": {k: [clean(float(x)) for x in v] for k, v in self.scale.items()},
                "n": int(self.n), "compared": int(self.compared), "forms": list(self.forms)}

    @classmethod
    def from_dict(cls, d: dict) -> "NoiseModel":
        """The inverse of `to_dict`."""
        nan = lambda x: float("nan") if x is None else float(x)  # noqa: E731
        return cls(name=d["name"], loss_model=d.get("loss_model"), covariance=d["covariance"],
                   loglik={k: nan(v) for k, v in d["loglik"].items()},
                   scale={k: [nan(x) for x in v] for k, v in d["scale"].items()}, n=int(d["n"]),
                   compared=int(d.get("compared", d["n"])), forms=tuple(d.get("forms", ())))


def _scales(values: list) -> str:
    """Scales as a list, or as their range where there are more than 8 (a spectrum)."""
    if len(values) > 8:
        return f"{min(values):.3g}–{max(values):.3g} over {len(values)} channels"
    return ", ".join(f"{v:.3g}" for v in values)


def _departures(forms, name: str, scale: dict, channels: list | None) -> str:
    """The runs of consecutive channels whose candidate is not ``name``, with their scales, as "absolute
    (s = ...) in channel 0–channel 9, ..."."""
    runs = []
    for c, form in enumerate(forms):
        if form == name:
            continue
        if runs and runs[-1][0] == form and runs[-1][2] == c - 1:
            runs[-1][2] = c
        else:
            runs.append([form, c, c])
    label = lambda c: str(channels[c]) if channels is not None and c < len(channels) else f"channel {c}"  # noqa: E731
    return ", ".join(f"{form} ({NOISE_FORMULAS[form]}, s = {_scales(scale[form][a:b + 1])}) in {label(a)}"
                     + (f"–{label(b)}" if b > a else "") for form, a, b in runs)


def _advice(name: str, loss: str) -> str:
    matching = {"absolute": "absolute", "relative": "relative"}.get(name)
    if matching and matching != loss:
        return f"; loss='{matching}' would weight the data for this noise (smaller errors)"
    if name == "signal":
        return "; measured σ per sample and loss='sigma' would weight the data for it"
    return ""


def _loglik(n, rss, log_g_half):
    """ℓ of one candidate per channel: n values, Σ d²/g and ½ Σ ln g."""
    variance = np.maximum(rss / np.maximum(n, 1), 1e-300)
    return np.where(n > 0, -0.5 * n * (np.log(2 * np.pi * variance) + 1.0) - log_g_half, 0.0), np.sqrt(variance)


def compare(sums, loss: str, robust=None, *, n_total: int, chi2=None, log_sigma=None) -> NoiseModel:
    """Compare the candidates on a fit's residuals and choose the default standard error.

    Arguments:
        sums: `brdffit.metrics.metric_sums` ``(15, C)`` at the answer.
        loss: the fit's loss name; robust: its robust rewrite, if any.
        n_total: the fit's valid values (the log-likelihoods are scaled to them).
        chi2, log_sigma: for ``loss="sigma"``: per channel Σ d²/σ² and Σ ln σ over all valid values, with the
            count per channel as ``sums``' metric row 1.

    Returns:
        The `NoiseModel`.
    """
    sums = np.asarray(sums, dtype=float)
    row = lambda name: sums[_ROW[name]]  # noqa: E731
    n = row("n")
    loss_model = None if robust else LOSS_NOISE.get(loss)
    parts = {
        "absolute": (row("d2"), np.zeros_like(n)),
        "relative": (row("d2_over_f2"), row("log_f")),
        "signal": (row("d2_over_f"), 0.5 * row("log_f")),
    }
    if loss == "cosine":
        parts["cosine"] = (row("weighted_d2"), -row("log_weight"))
    compared = float(np.sum(n))
    factor = n_total / compared if compared > 0 else 1.0
    scale, per_channel = {}, {}
    for name, (rss, log_g_half) in parts.items():
        ll, s = _loglik(n, rss, log_g_half)
        per_channel[name], scale[name] = ll * factor, [float(x) for x in s]
    if loss == "sigma" and chi2 is not None and log_sigma is not None:
        counts = sums[1]
        ll, s = _loglik(counts, np.asarray(chi2, float), np.asarray(log_sigma, float))
        per_channel["sigma"], scale["sigma"] = ll * n_total / max(float(np.sum(counts)), 1.0), [float(x) for x in s]
    loglik = {name: float(np.sum(ll)) for name, ll in per_channel.items()}
    # Residuals at rounding level (noise-free data): relative RMS error below 1e-9 in every channel.
    relative_rms = np.sqrt(sums[2] / np.maximum(sums[3], 1.0))
    exact = not np.any(row("d2") > 0) or bool(np.all(relative_rms < EXACT_RELATIVE_RMS))
    if exact:
        return NoiseModel("exact", loss_model, "laplace", loglik, scale, int(n_total), int(compared))
    name = max(loglik, key=lambda k: loglik[k] if math.isfinite(loglik[k]) else -math.inf)
    # The residuals keep the loss's own noise model unless another beats it by more than the tolerance (a tie, as
    # between sigma and absolute for a constant stated σ, goes to the loss).
    if loss_model in loglik and 2.0 * (loglik[name] - loglik[loss_model]) <= TIE_AIC[loss_model == "sigma"]:
        name = loss_model
    forms = tuple(_channel_form(per_channel, name, c) for c in range(len(n)))
    # The common choice is the one most channels keep: a joint choice can be a compromise that no channel makes
    # (three channels of relative noise and one of absolute noise favour, summed, the signal model between them).
    common = max(dict.fromkeys(forms), key=lambda k: (forms.count(k), k == name))
    if common != name:
        name = common
        forms = tuple(_channel_form(per_channel, name, c) for c in range(len(n)))
    laplace = all(form == loss_model for form in forms)
    if laplace and name == "sigma":
        lo, hi = SIGMA_SCALE_RANGE
        laplace = all(lo <= x <= hi for x in scale["sigma"] if math.isfinite(x))
    kind = "laplace" if laplace else ("sandwich" if robust or name == "sigma" else "noise-model")
    return NoiseModel(name, loss_model, kind, loglik, scale, int(n_total), int(compared), forms)


def _channel_form(per_channel: dict, name: str, c: int) -> str:
    """Channel ``c``'s candidate: ``name``, unless its own best beats ``name`` by more than `BAND_AIC` in it."""
    finite = {k: float(v[c]) for k, v in per_channel.items() if math.isfinite(float(v[c]))}
    if not finite or name not in finite:
        return name
    best = max(finite, key=finite.get)
    return best if 2.0 * (finite[best] - finite[name]) > BAND_AIC else name


def of_fit(problem, sums, data, channel_cost, n_valid: int) -> NoiseModel:
    """`compare` for a fit: its `Problem`, the metric sums at its answer, its one-material `FitData`, the
    per-channel cost and the valid count (for ``loss="sigma"`` without a robust rewrite the cost is χ², and
    Σ ln σ is summed from the data's σ)."""
    chi2 = log_sigma = None
    if problem.loss == "sigma" and not problem.robust:
        mask = np.asarray(data.mask)
        chi2 = np.asarray(channel_cost, dtype=float)
        log_sigma = np.sum(np.where(mask, np.log(np.asarray(data.sigma, dtype=float)), 0.0), axis=0)
    return compare(sums, problem.loss, problem.robust, n_total=n_valid, chi2=chi2, log_sigma=log_sigma)


def merge(models: list) -> NoiseModel | None:
    """The noise model of an independent-channel fit from its channels' (`brdffit.fit` with
    ``channel_mode="independent"`` fits each channel alone, and each channel's stderr follows its own choice):
    log-likelihoods added, scales concatenated; the name is the channels' if they agree, else theirs joined by
    "/", and likewise the covariance kind."""
    models = [m for m in models if m is not None]
    if not models:
        return None
    names = [m.name for m in models]
    kinds = [m.covariance for m in models]
    common = set.intersection(*(set(m.loglik) for m in models))
    join = lambda xs: xs[0] if len(set(xs)) == 1 else "/".join(xs)  # noqa: E731
    return NoiseModel(name=join(names), loss_model=models[0].loss_model, covariance=join(kinds),
                      loglik={k: float(sum(m.loglik[k] for m in models)) for k in common},
                      scale={k: [x for m in models for x in m.scale[k]] for k in common},
                      n=sum(m.n for m in models), compared=sum(m.compared for m in models),
                      forms=tuple(form for m in models for form in (m.forms or (m.name,))))
