"""The result of a fit: parameters, uncertainties, the noise model, metrics, information criteria, status and
plausibility."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np

from ..models.model import Model, evaluate
from ..models.registry import model_from_dict, model_to_dict
from .noise import NoiseModel
from .outcome import STATUSES, Status

__all__ = ["FitResult", "Status", "STATUSES"]

# Above this many channels (a spectrum) the summary gives the colour parameters one row per channel.
SPECTRAL_CHANNELS = 8


def _json_value(value):
    value = np.asarray(value)
    if value.ndim == 0:
        v = float(value)
        return v if math.isfinite(v) else None
    return [x if math.isfinite(x) else None for x in value.astype(float).tolist()]


@dataclasses.dataclass
class FitResult:
    """What `brdffit.fit` returns.

    Attributes:
        model: the fitted `Model` (None in ``channel_mode="independent"``, where `models` holds one per channel).
        params: name -> fitted value (as ``model.params``; independent mode stacks shape parameters per channel).
        stderr: name -> standard error in physical units (0 for fixed parameters): the one the residuals' noise
            model supports (`noise_model`): `stderr_laplace` when the noise is the one the loss weights for in
            every channel, else the noise-model standard error, whose covariance weights each residual by the
            variance its channel's noise model gives it (`stderr_robust` after a robust rewrite; docs/fitting.md).
        stderr_laplace: name -> Laplace (Gauss-Newton) standard error, s² (JᵀJ)⁻¹ with one noise variance s² per
            channel (`brdffit.fitting.uncertainty`).
        stderr_robust: name -> sandwich (White 1980, HC1) standard error, valid also when the residual variance
            differs between samples (e.g. relative noise fitted with the cosine loss).
        covariance: covariance matrix of the free scalar parameters (the kind `stderr` comes from), rows labelled
            by `labels`.
        correlation: the matching correlation matrix.
        labels: labels of the covariance rows (``name`` or ``name[i]`` per channel).
        metrics: name -> per-channel array: ``rmse_loss``, ``rmse_abs``, ``rmse_rel``, ``ngan``, ``low``.
        n_samples: valid (sample, channel) values that entered the fit.
        n_params: number of free scalar parameters.
        dof: n_samples − n_params.
        cost: the minimised sum of squared residuals.
        aic, bic: information criteria (docs/fitting.md).
        status: a `Status` (a name of `STATUSES` is read as one).
        bounds_hit: labels of parameters that ended on a bound.
        warnings: human-readable warnings (non-identifiable parameter pairs, ...).
        steps: solver steps of the kept start.
        compile_time, run_time: seconds spent compiling the solve and running it (all starts).
        init_time: seconds spent on the initial guess.
        loss, solver, channel_mode, fixed: how the fit was configured.
        starts: one record per start: initial parameters, final cost, status, steps.
        noise_variance: the residual variance used to scale the covariance (1 for ``loss="sigma"``).
        strategy: ``"full"``, or the coarse subsample solve followed by the full-data refinement.
        models: one model per channel in independent mode, else ``[model]``.
        noise_model: the `brdffit.fitting.noise.NoiseModel` chosen from the residuals (None in results written
            before noise models were compared, and in independent mode).
        theta_i_max: the data's largest θi (radians), where the energy check of `plausibility` ends its
            "measured" range (None: unknown).
    """

    model: Model | None
    params: dict
    stderr: dict
    stderr_robust: dict
    covariance: np.ndarray
    correlation: np.ndarray
    labels: list
    metrics: dict
    n_samples: int
    n_params: int
    dof: int
    cost: float
    aic: float
    bic: float
    status: Status
    bounds_hit: list
    warnings: list
    steps: int
    compile_time: float
    run_time: float
    init_time: float
    loss: str
    solver: str
    channel_mode: str
    fixed: list
    starts: list
    noise_variance: float
    strategy: str = "full"
    models: list = dataclasses.field(default_factory=list)
    stderr_laplace: dict = dataclasses.field(default_factory=dict)
    noise_model: NoiseModel | None = None
    theta_i_max: float | None = None
    _plausibility: object = dataclasses.field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self):
        self.status = Status(self.status)
        if not self.stderr_laplace:  # results built without it (older files, hand-made ones) reported Laplace
            self.stderr_laplace = dict(self.stderr)

    @property
    def stderr_kind(self) -> str:
        """``"laplace"``, ``"noise-model"`` or ``"sandwich"``: what `stderr` holds."""
        return self.noise_model.covariance if self.noise_model is not None else "laplace"

    def plausibility(self):
        """The `brdffit.plausibility.Plausibility` of the fitted model(s): energy conservation, ks·F, parameters
        at bounds, each with what to do (computed on first use, then kept)."""
        if self._plausibility is None:
            from ..plausibility import plausibility

            self._plausibility = plausibility(self.models, bounds_hit=self.bounds_hit, stderr=self.stderr,
                                              theta_max=self.theta_i_max)
        return self._plausibility

    @property
    def converged(self) -> bool:
        """True for ``converged`` and ``converged-at-bound``."""
        return self.status.converged

    @property
    def spec(self) -> str:
        """The spec string of the fitted model."""
        return self.models[0].spec

    def predict(self, theta_i, phi_i, theta_o, phi_o):
        """Evaluate the fitted model(s) at spherical angles; shape ``(N, channels)``."""
        if self.model is not None:
            return np.asarray(evaluate(self.model, theta_i, phi_i, theta_o, phi_o))
        return np.concatenate([np.asarray(evaluate(m, theta_i, phi_i, theta_o, phi_o)) for m in self.models],
                              axis=-1)

    def summary(self, plausibility: bool = True) -> str:
        """A readable table of parameters (value ± stderr, the other standard error, bounds, fixed), the noise
        model, metrics, status, warnings and (unless ``plausibility=False``) the plausibility checks."""
        specs = self.models[0].param_specs
        kind = self.stderr_kind
        other_name, other = ("laplace", self.stderr_laplace) if kind == "sandwich" else ("sandwich",
                                                                                          self.stderr_robust)
        lines = [f"model {self.spec}  loss {self.loss}  solver {self.solver}  channel mode {self.channel_mode}",
                 f"status {self.status}  steps {self.steps}  compile {self.compile_time:.2f} s  "
                 f"run {self.run_time:.2f} s  init {self.init_time:.2f} s",
                 f"{'parameter':<14}{'value':>14}{'± ' + kind:>14}{'(' + other_name + ')':>14}   bounds"]
        others = self._flat_entries(other)[2]
        spectral = self.models[0].channels > SPECTRAL_CHANNELS and self.channel_mode != "independent"
        for label, value, err, alt in zip(*self._flat_entries(), others):
            name = label.split("[")[0]
            spec = specs[name]
            if spectral and spec.colour:
                continue  # in the per-channel block below
            note = " fixed" if name in self.fixed else (" AT BOUND" if label in self.bounds_hit else "")
            lines.append(f"{label:<14}{value:>14.6g}{err:>14.3g}{alt:>14.3g}   [{spec.lower:g}, {spec.upper:g}] "
                         f"{spec.unit}{note}")
        if spectral:
            lines.extend(self._spectral_block(specs, kind))
        lines.append(f"{self._samples_words()}  free parameters {self.n_params}  dof {self.dof}  "
                     f"AIC {self.aic:.6g}  BIC {self.bic:.6g}")
        if self.noise_model is not None:
            lines.extend(self.noise_model.describe(self.loss))
            lines.extend(self._stderr_spread())
        elif self.channel_mode == "independent":
            lines.append("noise: chosen channel by channel, not recorded in this merged result (stderr holds each "
                         "channel's choice)")
        else:
            lines.append("noise: not recorded (a result written before noise models were compared); "
                         "stderr Laplace")
        for name, values in self.metrics.items():
            lines.append(f"{name:<10}" + "  ".join(f"{v:.4g}" for v in np.atleast_1d(values)))
        lines.extend(f"warning: {w}" for w in self.warnings)
        if plausibility:
            lines.extend(self.plausibility().lines())
        return "\n".join(lines)

    def _spectral_block(self, specs, kind: str) -> list[str]:
        """The colour parameters of a fit with many channels (a spectrum): one row per channel, one column per
        parameter, value ± stderr (`_flat_entries`), a parameter at a bound in that channel marked *."""
        entries = {label: (value, err) for label, value, err in zip(*self._flat_entries())}
        names = [n for n in self.params if specs[n].colour]
        channels = np.size(self.params[names[0]])
        head = "; ".join(f"{n} [{specs[n].lower:g}, {specs[n].upper:g}] {specs[n].unit}"
                         + (" fixed" if n in self.fixed else "") for n in names)
        lines = [f"per channel ({channels} channels; value ± {kind}; * at a bound): {head}",
                 f"{'channel':>8}" + "".join(f"{n:>24}" for n in names)]
        for c in range(channels):
            cells = []
            for label in (f"{n}[{c}]" for n in names):
                value, err = entries[label]
                cells.append(f"{value:>12.6g} ± {err:<8.3g}{'*' if label in self.bounds_hit else ' '}")
            lines.append(f"{c:>8}" + "".join(f"{cell:>24}" for cell in cells))
        return lines

    def _samples_words(self) -> str:
        """The data's size in words: samples × channels where every sample has all channels, else the values."""
        channels = self.models[0].channels * len(self.models)
        if channels > 1 and self.n_samples % channels == 0:
            return f"samples {self.n_samples // channels:,} × {channels} channels"
        return f"values {self.n_samples:,}" + (f" in {channels} channels" if channels > 1 else "")

    def _stderr_spread(self) -> list[str]:
        """A noise line where the Laplace and sandwich standard errors differ by more than 2x: the residuals do
        not have one variance, which the noise model above accounts for (stderr follows it)."""
        ratios = []
        for name, laplace in self.stderr_laplace.items():
            with np.errstate(invalid="ignore", divide="ignore"):
                r = np.asarray(self.stderr_robust.get(name, np.nan), dtype=float) / np.asarray(laplace, dtype=float)
            ratios.extend(np.abs(np.log(r[np.isfinite(r) & (r > 0)])).reshape(-1).tolist())
        if not ratios or max(ratios) <= np.log(2.0):
            return []
        return [f"        Laplace and sandwich stderr differ by up to {np.exp(max(ratios)):.3g}x: the residuals' "
                "variance varies between samples (the stderr column follows the noise model above)"]

    def _flat_entries(self, stderr: dict | None = None):
        labels, values, errors = [], [], []
        stderr = self.stderr if stderr is None else stderr
        for name, value in self.params.items():
            value = np.asarray(value, dtype=float)
            err = np.broadcast_to(np.asarray(stderr.get(name, np.nan), dtype=float), value.shape)
            if value.ndim == 0:
                labels.append(name), values.append(float(value)), errors.append(float(err))
            else:
                for i, (v, e) in enumerate(zip(value, err)):
                    labels.append(f"{name}[{i}]"), values.append(float(v)), errors.append(float(e))
        return labels, values, errors

    def __str__(self) -> str:
        return self.summary()

    def to_dict(self) -> dict:
        """A JSON-ready dict of the result (NaN and inf become None)."""
        return {
            "model": self.spec,
            "models": [model_to_dict(m) for m in self.models],
            "params": {k: _json_value(v) for k, v in self.params.items()},
            "stderr": {k: _json_value(v) for k, v in self.stderr.items()},
            "stderr_robust": {k: _json_value(v) for k, v in self.stderr_robust.items()},
            "stderr_laplace": {k: _json_value(v) for k, v in self.stderr_laplace.items()},
            "stderr_kind": self.stderr_kind,
            "noise_model": None if self.noise_model is None else self.noise_model.to_dict(),
            "theta_i_max": self.theta_i_max,
            "labels": list(self.labels),
            "covariance": [_json_value(row) for row in np.atleast_2d(self.covariance)] if self.labels else [],
            "correlation": [_json_value(row) for row in np.atleast_2d(self.correlation)] if self.labels else [],
            "metrics": {k: _json_value(v) for k, v in self.metrics.items()},
            "n_samples": self.n_samples,
            "n_params": self.n_params,
            "dof": self.dof,
            "cost": _json_value(self.cost),
            "aic": _json_value(self.aic),
            "bic": _json_value(self.bic),
            "noise_variance": _json_value(self.noise_variance),
            "strategy": self.strategy,
            "status": self.status,
            "bounds_hit": list(self.bounds_hit),
            "warnings": list(self.warnings),
            "steps": self.steps,
            "compile_time": self.compile_time,
            "run_time": self.run_time,
            "init_time": self.init_time,
            "loss": self.loss,
            "solver": self.solver,
            "channel_mode": self.channel_mode,
            "fixed": list(self.fixed),
            "starts": self.starts,
        }

    def save(self, path, name: str | None = None) -> str:
        """Write the result under ``/fits/<name>`` of an HDF5 file (created if absent; other groups are kept).

        The group holds the JSON of `to_dict` as attribute ``result`` and the covariance as a dataset. The file
        is written to a temporary copy and renamed into place.

        Arguments:
            path: HDF5 file path.
            name: group name; defaults to the model spec.

        Returns:
            The group path written, e.g. ``"/fits/lambert+ggx"``.
        """
        from ..io.hdf5 import update_hdf5

        group = f"fits/{(name or self.spec).replace('/', '_')}"
        payload = json.dumps(self.to_dict())

        def write(g):
            g.attrs["result"] = payload
            g.create_dataset("covariance", data=np.atleast_2d(np.asarray(self.covariance, dtype=float)))

        update_hdf5(path, group, write)
        return "/" + group

    @classmethod
    def from_dict(cls, d: dict) -> "FitResult":
        """Rebuild a result from `to_dict` output (None values come back as NaN)."""
        models = [model_from_dict(m) for m in d["models"]]
        as_array = lambda v: np.asarray(np.nan if v is None else v, dtype=float)  # noqa: E731
        fix = lambda v: np.array([np.nan if x is None else x for x in v], dtype=float) if isinstance(v, list) \
            else as_array(v)  # noqa: E731
        labels = list(d["labels"])
        cov = np.array([[np.nan if x is None else x for x in row] for row in d["covariance"]], dtype=float)
        cor = np.array([[np.nan if x is None else x for x in row] for row in d["correlation"]], dtype=float)
        return cls(
            model=models[0] if d["channel_mode"] != "independent" else None,
            params={k: fix(v) for k, v in d["params"].items()},
            stderr={k: fix(v) for k, v in d["stderr"].items()},
            stderr_robust={k: fix(v) for k, v in d["stderr_robust"].items()},
            covariance=cov.reshape(len(labels), len(labels)),
            correlation=cor.reshape(len(labels), len(labels)),
            labels=labels,
            metrics={k: fix(v) for k, v in d["metrics"].items()},
            n_samples=d["n_samples"], n_params=d["n_params"], dof=d["dof"], cost=float(fix(d["cost"])),
            aic=float(fix(d["aic"])), bic=float(fix(d["bic"])), status=d["status"],
            bounds_hit=list(d["bounds_hit"]), warnings=list(d["warnings"]), steps=d["steps"],
            compile_time=d["compile_time"], run_time=d["run_time"], init_time=d["init_time"], loss=d["loss"],
            solver=d["solver"], channel_mode=d["channel_mode"], fixed=list(d["fixed"]), starts=d["starts"],
            noise_variance=float(fix(d["noise_variance"])), strategy=d.get("strategy", "full"), models=models,
            # Files written before the noise models were compared hold the Laplace standard error as "stderr".
            stderr_laplace={k: fix(v) for k, v in d.get("stderr_laplace", d["stderr"]).items()},
            noise_model=NoiseModel.from_dict(d["noise_model"]) if d.get("noise_model") else None,
            theta_i_max=d.get("theta_i_max"),
        )

    @classmethod
    def load(cls, path, name: str | None = None) -> "FitResult":
        """Read a result written by `save`; with no ``name``, the only (or first) fit in the file.

        Raises:
            brdffit.io.FormatError: the file has no such fit.
        """
        from ..io import FormatError
        from ..io.hdf5 import open_hdf5

        with open_hdf5(path) as f:  # regular files only, the metadata inspected in bounded time (docs/formats.md)
            fits = f.get("fits")
            if fits is None or len(fits) == 0:
                raise FormatError(path, "no /fits group; write one with FitResult.save or `brdffit fit`")
            key = name if name is not None else sorted(fits)[0]
            if key not in fits:
                raise FormatError(path, f"no fit named {key!r}; fits in the file: {', '.join(sorted(fits))}")
            return cls.from_dict(json.loads(fits[key].attrs["result"]))
