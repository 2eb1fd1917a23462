"""Benchmark of issue 8: speed against accuracy of brdffit's solvers and of a scipy baseline, charted.

Data: synthetic measurements (`brdffit.synth.generate`, half-diff pattern by default, 1% relative noise) of a
truth with realistic, non-default RGB parameters for each model. Every model is fitted to data made by its own
truth (the Lafortune rows by a Lafortune truth with as many lobes), from one fixed start per model that every
solver shares (``init="model"``); Cook-Torrance's and GGX's f0 are held at the true 0.04, as in bench_fit.py.
Accuracy is scored on a separate held-out set: uniform directions, another seed and no noise, so that the error
is the fitted model's distance from the truth rather than the noise floor.

Configurations of the full grid (``--quick`` runs a handful at 1e3-1e4 samples, for a smoke run):
- cross: every model x every solver (brdffit's lm, gauss-newton, dogleg, bfgs and the scipy baseline), 1e4 samples;
- size: lambert+cook-torrance with lm and scipy from 1e3 to 1,458,000 samples (the MERL table size), and
  lambert+ggx with the same up to 1e5;
- multistart: multistart=8 (9 starts in one vmapped solve) against 0, with lm and dogleg, for four models;
- float32: brdffit's lm and the scipy baseline in float32 against float64, every model.

Measured per configuration:
- time to result, warm: a first fit on data of the same shape (another seed) compiles, the next fits are timed.
  For brdffit ``time`` is the whole `brdffit.fit` call (start, solve, covariance, metrics), ``solve`` the solve
  alone (``result.run_time``) and ``compile`` the first fit's ``result.compile_time`` (a load from the persistent
  compilation cache when an earlier run left the program there). For scipy ``compile`` is the first call of the
  jitted model evaluation and ``time`` and ``solve`` are the `least_squares` call;
- accuracy: the Ngan and Löw errors on the held-out set (`brdffit.metrics.fit_metrics`, mean over the channels)
  and the largest relative error of the free colour and of the free shape parameters against the truth.
  The held-out errors of different models come from different truths: compare solvers within a model, and
  read the chart's Pareto front over all rows as "what is fastest for a given error on these truths".

The scipy baseline is scipy.optimize.least_squares (trf, 2-point Jacobian, x_scale="jac", tolerances 1e-12 as in
bench_fit.py) on the residuals of brdffit's cosine loss, (f_model - f_data) cos(theta_i) sqrt(w), with f_model
from brdffit's own model evaluation (`brdffit.models.evaluate`, jitted) handed to scipy as a NumPy array, bounds
from the model's ParamSpecs and the start the brdffit solvers get.

Precision: importing brdffit turns on jax_enable_x64 and `fit` has no dtype option. The float32 rows run the
whole `brdffit.fit` inside ``jax.enable_x64(False)``, so that data, model, solver and covariance are float32,
and the scipy baseline with the model evaluated the same way and the residuals in float32 (scipy then takes its
finite-difference step for float32); the fitted parameters are scored in float64 like every other row. A
second table gives the error of a float32 evaluation of each truth against float64 on the held-out directions.

Timing on a shared machine: other processes on the CPUs slow JAX's short solves of many small operations far
more than their share of the CPU; on the shared 2-core benchmark machine the same warm fit of 1e3 samples took
0.03 s in one process and 1 s in the next. Each time is therefore the fastest of up to `MAX_REPEATS` runs (run
again while the runs total under `MIN_TIMED_SECONDS`), and the header records the load average at the start and
the share of the CPUs that other processes used during the run.

Usage: python scripts/bench_speed_accuracy.py [--quick] [--out DIR] [--pattern half-diff|uniform]
Writes DIR/results.json (machine header and all rows), DIR/table.md (the tables printed to stdout) and
DIR/pareto.png (warm time against held-out Ngan error, Pareto front drawn); DIR is scripts/out/speed_accuracy/
unless given. The full grid is sized for about 25 minutes on a 2-core CPU, --quick for under 3.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import platform
import sys
import time
import warnings
from pathlib import Path

import jax
import numpy as np
import optimistix
import scipy
from scipy.optimize import least_squares

import brdffit
from brdffit import models, synth
from brdffit.compilation_cache import enable_compilation_cache
from brdffit.metrics import fit_metrics
from brdffit.params import at_bound

NOISE = "relative:0.01"
TRAIN_SEED, WARMUP_SEED, HELDOUT_SEED = 1, 2, 3
HELDOUT_SAMPLES = {"full": 100_000, "quick": 20_000}
MERL_SIZE = 1_458_000  # 90 x 90 x 180 cells of a MERL table
BRDFFIT_SOLVERS = ("lm", "gauss-newton", "dogleg", "bfgs")
BASELINE = "scipy"
RHO_D = [0.30, 0.20, 0.10]
MIN_TIMED_SECONDS, MAX_REPEATS = 1.0, 3

# Evaluation of a model at spherical angles, compiled once per model structure and dtype; the scipy baseline
# and the float32 evaluation check call it.
evaluate_jit = jax.jit(models.evaluate)


@dataclasses.dataclass(frozen=True)
class ModelCase:
    """A model of the grid.

    Attributes:
        spec: the model spec string.
        truth: parameter values of the truth that makes the data (unset ones take their defaults).
        start: parameter values every solver starts from.
        fixed: parameters held at their true value by every solver (on top of those the model declares fixed).
    """

    spec: str
    truth: dict
    start: dict
    fixed: tuple[str, ...] = ()

    def truth_model(self) -> models.Model:
        """The truth as a `brdffit.Model`."""
        return models.get(self.spec, **self.truth)

    def start_model(self) -> models.Model:
        """The start as a `brdffit.Model`, with the held parameters at their true values."""
        return models.get(self.spec, **{name: self.truth[name] for name in self.fixed}, **self.start)

    def free_names(self) -> list[str]:
        """The fitted parameters, in model order."""
        return [s.name for s in self.start_model().param_specs if not s.fixed and s.name not in self.fixed]


CASES = {case.spec: case for case in (
    ModelCase("lambert", dict(rho_d=RHO_D), dict(rho_d=0.5)),
    ModelCase("lambert+blinn-phong", dict(rho_d=RHO_D, ks=[0.6, 0.5, 0.4], n=60.0),
              dict(rho_d=0.5, ks=0.2, n=20.0)),
    ModelCase("lambert+ward", dict(rho_d=RHO_D, ks=[0.5, 0.4, 0.3], alpha=0.25),
              dict(rho_d=0.5, ks=0.2, alpha=0.4)),
    ModelCase("lambert+cook-torrance", dict(rho_d=RHO_D, ks=[0.8, 0.7, 0.6], m=0.15, f0=0.04),
              dict(rho_d=0.5, ks=0.2, m=0.4), fixed=("f0",)),
    ModelCase("lambert+ggx", dict(rho_d=RHO_D, ks=[0.8, 0.7, 0.6], alpha=0.2, f0=0.04),
              dict(rho_d=0.5, ks=0.2, alpha=0.4), fixed=("f0",)),
    ModelCase("lambert+ashikhmin-shirley", dict(rho_d=RHO_D, rs=[0.10, 0.08, 0.06], n=150.0),
              dict(rho_d=0.5, rs=0.05, n=50.0)),
    # Lafortune lobes start apart: from equal lobes every solver keeps them equal (their Jacobian columns match).
    # The truths keep |cxy| below cz = 1: the lobe's normalisation max(cxy², cz²) has a kink at |cxy| = 1 where
    # lm, dogleg and scipy alike stall and still report convergence.
    ModelCase("lambert+lafortune", dict(rho_d=RHO_D, ks_1=[0.5, 0.4, 0.3], cxy_1=-0.95, n_1=40.0),
              dict(rho_d=0.5, ks_1=0.2, cxy_1=-0.8, n_1=15.0)),
    ModelCase("lambert+lafortune(lobes=2)",
              dict(rho_d=RHO_D, ks_1=[0.3, 0.25, 0.2], cxy_1=-0.7, n_1=6.0, ks_2=[0.5, 0.4, 0.3], cxy_2=-0.95,
                   n_2=60.0),
              dict(rho_d=0.5, ks_1=0.2, cxy_1=-0.6, n_1=3.0, ks_2=0.2, cxy_2=-0.8, n_2=30.0)),
    ModelCase("lambert+lafortune(lobes=3)",
              dict(rho_d=RHO_D, ks_1=[0.2, 0.15, 0.1], cxy_1=-0.6, n_1=3.0, ks_2=[0.3, 0.25, 0.2], cxy_2=-0.85,
                   n_2=15.0, ks_3=[0.4, 0.35, 0.3], cxy_3=-0.95, n_3=100.0),
              dict(rho_d=0.5, ks_1=0.2, cxy_1=-0.5, n_1=2.0, ks_2=0.2, cxy_2=-0.7, n_2=10.0, ks_3=0.2,
                   cxy_3=-0.8, n_3=50.0)),
)}


@dataclasses.dataclass(frozen=True)
class Config:
    """One configuration: model spec, solver (a brdffit solver name or "scipy"), training samples, extra
    starts of the multistart, and the precision of the fit."""

    spec: str
    solver: str
    n: int
    multistart: int = 0
    dtype: str = "float64"


def merge_groups(groups: dict[str, list[Config]]) -> dict[Config, list[str]]:
    """Configuration -> the groups that list it, each configuration once, in the order of first listing."""
    grid: dict[Config, list[str]] = {}
    for group, configs in groups.items():
        for config in configs:
            grid.setdefault(config, []).append(group)
    return grid


def full_grid() -> dict[Config, list[str]]:
    """The full grid (module docstring), about 25 minutes on a 2-core CPU."""
    ct_sizes = (1_000, 3_000, 10_000, 30_000, 100_000, 300_000, MERL_SIZE)
    ggx_sizes = (1_000, 3_000, 10_000, 30_000, 100_000)
    multistart_specs = ("lambert+ward", "lambert+cook-torrance", "lambert+ggx", "lambert+lafortune(lobes=2)")
    return merge_groups({
        "cross": [Config(spec, solver, 10_000) for spec in CASES for solver in BRDFFIT_SOLVERS + (BASELINE,)],
        "size": [Config("lambert+cook-torrance", solver, n) for solver in ("lm", BASELINE) for n in ct_sizes]
                + [Config("lambert+ggx", solver, n) for solver in ("lm", BASELINE) for n in ggx_sizes],
        "multistart": [Config(spec, solver, 10_000, starts) for spec in multistart_specs
                       for solver in ("lm", "dogleg") for starts in (0, 8)],
        "float32": [Config(spec, solver, 10_000, dtype=dtype) for spec in CASES for solver in ("lm", BASELINE)
                    for dtype in ("float64", "float32")],
    })


def quick_grid() -> dict[Config, list[str]]:
    """A handful of configurations at 1e3-1e4 samples that touch every code path of the full grid."""
    ct, lafortune = "lambert+cook-torrance", "lambert+lafortune(lobes=2)"
    return merge_groups({
        "cross": [Config(ct, solver, 1_000) for solver in BRDFFIT_SOLVERS + (BASELINE,)]
                 + [Config(lafortune, solver, 1_000) for solver in ("lm", BASELINE)],
        "size": [Config(ct, solver, n) for solver in ("lm", BASELINE) for n in (1_000, 10_000)],
        "multistart": [Config(ct, "lm", 1_000, starts) for starts in (0, 8)],
        "float32": [Config(ct, solver, 1_000, dtype=dtype) for solver in ("lm", BASELINE)
                    for dtype in ("float64", "float32")],
    })


@contextlib.contextmanager
def float32_jax():
    """JAX with 64-bit types off, so that brdffit's model code traces in float32; its explicit requests for
    float64 are then truncated to float32, and the warnings that say so are silenced."""
    with jax.enable_x64(False), warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Explicitly requested dtype")
        yield


def as_float32(model: models.Model) -> models.Model:
    """The model with its parameter values cast to float32 NumPy arrays."""
    return jax.tree_util.tree_map(lambda value: np.asarray(value, dtype=np.float32), model)


def evaluate_numpy(model: models.Model, angles, dtype) -> np.ndarray:
    """brdffit's evaluation of ``model`` at ``(theta_i, phi_i, theta_o, phi_o)`` as a NumPy array of ``dtype``."""
    if dtype == np.float32:
        with float32_jax():
            return np.asarray(evaluate_jit(as_float32(model), *angles))
    return np.asarray(evaluate_jit(model, *angles))


def canonical(model: models.Model) -> models.Model:
    """The model with each lobe's parameters in canonical order (Lafortune lobes sorted by exponent), the
    order in which `brdffit.fit` reports its results."""
    params = dict(model.params)
    for lobe, names in zip(model.lobes, model.names_by_lobe):
        ordered = lobe.canonical({spec.name: params[name] for spec, name in zip(lobe.param_specs(), names)})
        params.update({name: ordered[spec.name] for spec, name in zip(lobe.param_specs(), names)})
    return model.replace(**params)


class CosineResiduals:
    """The residuals of brdffit's cosine loss, (f_model - f_data) cos(theta_i) sqrt(w), as a NumPy function of
    the flattened free parameters, in float32 or float64; missing values give zero residuals.

    Arguments:
        start: the model whose non-free parameters stay fixed (and whose free ones are ``x0``).
        free: names of the free parameters, in model order.
        data: the `brdffit.Measurements`.
        dtype: ``np.float32`` or ``np.float64``.
    """

    def __init__(self, start: models.Model, free: list[str], data, dtype):
        self.start, self.free, self.dtype = start, free, np.dtype(dtype)
        self.angles = tuple(np.asarray(a, dtype=self.dtype) for a in (data.theta_i, data.phi_i, data.theta_o,
                                                                        data.phi_o))
        self.valid = np.isfinite(data.values)
        self.values = np.where(self.valid, data.values, 0.0).astype(self.dtype)
        weights = np.ones(data.n) if data.weights is None else data.weights
        self.scale = (np.cos(data.theta_i) * np.sqrt(weights))[:, None].astype(self.dtype)
        self.sizes = [np.size(start.params[name]) for name in free]

    @property
    def x0(self) -> np.ndarray:
        """The free parameters of the start, flattened."""
        return np.concatenate([np.ravel(self.start.params[name]) for name in self.free]).astype(float)

    def bounds(self) -> tuple[list[float], list[float]]:
        """Lower and upper bounds of the flattened free parameters, from the model's ParamSpecs."""
        specs = self.start.param_specs
        lower = [specs[name].lower for name, size in zip(self.free, self.sizes) for _ in range(size)]
        upper = [specs[name].upper for name, size in zip(self.free, self.sizes) for _ in range(size)]
        return lower, upper

    def model(self, x) -> models.Model:
        """The model with the free parameters ``x``."""
        values, offset = {}, 0
        for name, size in zip(self.free, self.sizes):
            values[name] = x[offset] if np.ndim(self.start.params[name]) == 0 else x[offset:offset + size]
            offset += size
        return self.start.replace(**values)

    def __call__(self, x) -> np.ndarray:
        f_model = evaluate_numpy(self.model(x), self.angles, self.dtype)
        return np.where(self.valid, (f_model - self.values) * self.scale, 0.0).astype(self.dtype).ravel()


def fastest_run(run):
    """Call ``run()`` until the calls total `MIN_TIMED_SECONDS` or there are `MAX_REPEATS` of them.

    Returns:
        ``(fastest wall time, result of the fastest call, number of calls)``.
    """
    runs = []
    while not runs or (sum(t for t, _ in runs) < MIN_TIMED_SECONDS and len(runs) < MAX_REPEATS):
        t0 = time.perf_counter()
        result = run()
        runs.append((time.perf_counter() - t0, result))
    elapsed, result = min(runs, key=lambda timed: timed[0])
    return elapsed, result, len(runs)


def run_brdffit(config: Config, case: ModelCase, data, warmup_data) -> tuple[dict, models.Model]:
    """A warm `brdffit.fit`: a first fit on ``warmup_data`` compiles, the fits on ``data`` are timed; a float32
    configuration runs under `float32_jax`. The fitted model comes back in float64 for scoring."""
    start = case.start_model()
    options = dict(init="model", fixed=list(case.fixed), solver=config.solver, multistart=config.multistart)
    with float32_jax() if config.dtype == "float32" else contextlib.nullcontext():
        first = brdffit.fit(warmup_data, start, **options)
        elapsed, result, repeats = fastest_run(lambda: brdffit.fit(data, start, **options))
    fitted = jax.tree_util.tree_map(lambda value: np.asarray(value, dtype=np.float64), result.model)
    return dict(compile_s=first.compile_time, time_s=elapsed, solve_s=result.run_time, repeats=repeats,
                steps=result.steps, status=result.status, cost=result.cost, strategy=result.strategy), fitted


def baseline_status(solution, fitted: models.Model, free: list[str]) -> str:
    """A `least_squares` outcome in brdffit's status words."""
    if not np.all(np.isfinite(solution.fun)):
        return "nonfinite"
    if solution.status == 0:
        return "max-steps"
    if solution.status < 0:
        return f"failed ({solution.message})"
    specs = fitted.param_specs
    hit = any(np.any(at_bound(fitted.params[name], specs[name])) for name in free)
    return "converged-at-bound" if hit else "converged"


def run_baseline(config: Config, case: ModelCase, data) -> tuple[dict, models.Model]:
    """scipy.optimize.least_squares on the cosine residuals, timed after the model evaluation has compiled."""
    free = case.free_names()
    residuals = CosineResiduals(case.start_model(), free, data, np.dtype(config.dtype))
    t0 = time.perf_counter()
    residuals(residuals.x0)
    compile_time = time.perf_counter() - t0
    elapsed, solution, repeats = fastest_run(lambda: least_squares(
        residuals, residuals.x0, bounds=residuals.bounds(), method="trf", jac="2-point", x_scale="jac", ftol=1e-12,
        xtol=1e-12, gtol=1e-12))
    fitted = canonical(residuals.model(solution.x))
    residuals64 = CosineResiduals(fitted, free, data, np.float64)  # the cost in float64, as brdffit reports it
    cost = float(np.sum(residuals64(residuals64.x0) ** 2))
    return dict(compile_s=compile_time, time_s=elapsed, solve_s=elapsed, repeats=repeats, steps=int(solution.njev),
                status=baseline_status(solution, fitted, free), cost=cost,
                strategy=f"trf, {solution.nfev} residual + {solution.njev} Jacobian evaluations"), fitted


def parameter_errors(fitted: models.Model, truth: models.Model, free: list[str]) -> tuple[float, float]:
    """Largest relative error |fitted - true| / |true| over the free colour parameters and over the free shape
    parameters (NaN where there are none)."""
    colour, shape = [], []
    for spec in truth.param_specs:
        if spec.name in free:
            true = np.asarray(truth.params[spec.name])
            error = float(np.max(np.abs(np.asarray(fitted.params[spec.name]) - true) / np.abs(true)))
            (colour if spec.colour else shape).append(error)
    return max(colour, default=math.nan), max(shape, default=math.nan)


def score(fitted: models.Model, case: ModelCase, heldout) -> dict:
    """Held-out Ngan and Löw errors (mean over the channels) and parameter errors against the truth."""
    errors = fit_metrics(fitted, heldout)
    colour, shape = parameter_errors(fitted, case.truth_model(), case.free_names())
    return dict(ngan=float(np.mean(errors["ngan"])), low=float(np.mean(errors["low"])), param_err_colour=colour,
                param_err_shape=shape)


def float32_evaluation_error(case: ModelCase, heldout) -> dict:
    """How far a float32 evaluation of the truth lies from float64 on the held-out directions: the largest
    relative difference and the Ngan and Löw errors of the float32 values against the float64 model."""
    truth = case.truth_model()
    angles = (heldout.theta_i, heldout.phi_i, heldout.theta_o, heldout.phi_o)
    exact = evaluate_numpy(truth, angles, np.float64)
    single = evaluate_numpy(truth, tuple(np.asarray(a, np.float32) for a in angles), np.float32).astype(float)
    positive = exact > 0
    errors = fit_metrics(truth, heldout.replace(values=single, sigma=None))
    return dict(model=case.spec, max_rel=float(np.max(np.abs(single - exact)[positive] / exact[positive])),
                ngan=float(np.mean(errors["ngan"])), low=float(np.mean(errors["low"])))


class DataSets:
    """The synthetic data of one model and size: training set, warm-up set (same shape, another seed), and the
    model's held-out set; generated on first use, kept for the configurations that share them."""

    def __init__(self, case: ModelCase, n: int, pattern: str, heldout):
        self.case, self.n, self.pattern, self.heldout = case, n, pattern, heldout
        self._sets: dict[int, object] = {}

    def _generate(self, seed: int):
        if seed not in self._sets:
            self._sets[seed] = synth.generate(self.case.truth_model(), pattern=self.pattern, n=self.n, noise=NOISE,
                                              seed=seed)
        return self._sets[seed]

    @property
    def train(self):
        """The training set (seed `TRAIN_SEED`)."""
        return self._generate(TRAIN_SEED)

    @property
    def warmup(self):
        """The set of the compiling first fit: the training set's shape, seed `WARMUP_SEED`."""
        return self._generate(WARMUP_SEED)


def run_config(config: Config, data: DataSets) -> dict:
    """Fit and score one configuration; a fit that raises gives a row whose status is the error."""
    case = CASES[config.spec]
    row = dataclasses.asdict(config)
    try:
        if config.solver == BASELINE:
            measured, fitted = run_baseline(config, case, data.train)
        else:
            measured, fitted = run_brdffit(config, case, data.train, data.warmup)
        row.update(measured)
        row.update(score(fitted, case, data.heldout))
        row["params"] = {name: np.asarray(value).tolist() for name, value in fitted.params.items()}
    except Exception as error:  # noqa: BLE001 - a failing solver is a result of the benchmark, not its end
        row.update(status=f"raised {type(error).__name__}: {error}"[:200])
    return row


def cpu_seconds() -> tuple[float, float] | None:
    """Seconds the CPUs have been busy since boot (all processes, from /proc/stat) and seconds this process has
    used; None where /proc/stat cannot be read."""
    try:
        ticks = [int(field) for field in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:9]]
    except (OSError, ValueError):
        return None
    busy = sum(ticks) - ticks[3] - ticks[4]  # all but idle and iowait
    own = os.times()
    return busy / os.sysconf("SC_CLK_TCK"), own.user + own.system


def other_cpu_share(before, after, wall: float) -> float | None:
    """The share of all CPUs that other processes used between two `cpu_seconds` readings ``wall`` s apart."""
    if before is None or after is None:
        return None
    others = (after[0] - before[0]) - (after[1] - before[1])
    return max(others, 0.0) / (wall * os.cpu_count())


def cpu_name() -> str:
    """The CPU model from /proc/cpuinfo, else what `platform` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_info(args, heldout_samples: int) -> dict:
    """Machine, date, versions and the benchmark's settings."""
    import matplotlib

    return dict(
        date=time.strftime("%Y-%m-%d %H:%M"), machine=f"{cpu_name()}, {os.cpu_count()} cores",
        load_average_at_start=os.getloadavg()[0],
        python=platform.python_version(), brdffit=brdffit.__version__, jax=jax.__version__,
        optimistix=optimistix.__version__, numpy=np.__version__, scipy=scipy.__version__,
        matplotlib=matplotlib.__version__, backend=jax.default_backend(), grid="quick" if args.quick else "full",
        pattern=args.pattern, noise=NOISE,
        heldout=f"{heldout_samples} uniform samples, no noise, seed {HELDOUT_SEED}",
        precision="float32 rows run brdffit.fit (and the scipy baseline's model) under jax.enable_x64(False)",
    )


def format_number(value, kind: str) -> str:
    """A table cell: ``time`` with 3 significant digits, ``error`` in scientific notation, ``int`` as is."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if kind == "time":
        return f"{value:.3g}"
    if kind == "error":
        return f"{value:.2e}"
    return str(value)


def markdown_tables(rows: list[dict], float32_errors: list[dict], info: dict) -> str:
    """The header, the table of all configurations and the float32 evaluation table, in Markdown."""
    share = info["other_cpu_share"]
    lines = [f"Speed against accuracy, {info['date']}, {info['machine']}, Python {info['python']}, brdffit "
             f"{info['brdffit']}, JAX {info['jax']} ({info['backend']}), optimistix {info['optimistix']}, NumPy "
             f"{info['numpy']}, SciPy {info['scipy']}. Load average at start {info['load_average_at_start']:.1f}; "
             f"other processes used {'an unknown share' if share is None else f'{share:.0%}'} of the CPUs during "
             f"the run ({info['run_time_s']:.0f} s).",
             f"Training data: {info['pattern']} pattern, noise {info['noise']}, seed {TRAIN_SEED}; held-out: "
             f"{info['heldout']}. {info['precision']}. Times in seconds, warm, the fastest of `runs` runs; errors "
             "are means over RGB; steps are solver steps (scipy: Jacobian evaluations).", "",
             "| group | model | solver | samples | starts | dtype | compile | time | solve | runs | steps | status | "
             "held-out Ngan | held-out Löw | max rel. err. colour | max rel. err. shape |",
             "|---|---|---|---:|---:|---|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|"]
    for row in rows:
        cells = [", ".join(row["groups"]), row["spec"], row["solver"], str(row["n"]), str(1 + row["multistart"]),
                 row["dtype"], format_number(row.get("compile_s"), "time"), format_number(row.get("time_s"), "time"),
                 format_number(row.get("solve_s"), "time"), format_number(row.get("repeats"), "int"),
                 format_number(row.get("steps"), "int"), row["status"],
                 format_number(row.get("ngan"), "error"), format_number(row.get("low"), "error"),
                 format_number(row.get("param_err_colour"), "error"),
                 format_number(row.get("param_err_shape"), "error")]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "Float32 evaluation of each truth against float64 on the held-out directions (brdffit's model code "
              "traced with jax_enable_x64 off):", "",
              "| model | max rel. difference | Ngan | Löw |", "|---|---:|---:|---:|"]
    for entry in float32_errors:
        lines.append(f"| {entry['model']} | {entry['max_rel']:.2e} | {entry['ngan']:.2e} | {entry['low']:.2e} |")
    return "\n".join(lines)


FRONT_LABEL_N = 10_000  # the cross grid's sample count, left out of the front's labels


def pareto_front(points: list[tuple[float, float]], tolerance: float = 1e-3) -> list[int]:
    """Indices of the non-dominated (time, error) points, by increasing time: no other point is at least as
    fast and at least as accurate. Errors within ``tolerance`` (relative) of each other count as equal, so that
    two solvers that reach the same optimum do not both make the front through rounding."""
    front, best_error = [], math.inf
    for i in sorted(range(len(points)), key=lambda i: points[i]):
        if points[i][1] < best_error * (1 - tolerance):
            front.append(i)
            best_error = points[i][1]
    return front


def series(row: dict) -> str:
    """The colour series of a row: its solver, with the float32 rows apart."""
    return f"{row['solver']} (float32)" if row["dtype"] == "float32" else row["solver"]


def plot_pareto(rows: list[dict], info: dict, path: Path) -> None:
    """Warm time (log) against held-out Ngan error (log): colour = solver, marker = model, marker size grows
    with the sample count, black edge = multistart; each model's Pareto front is joined by a line and its points
    are labelled with the solver (and the sample count when it is not the cross grid's)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    colours = {"lm": "tab:blue", "gauss-newton": "tab:orange", "dogleg": "tab:green", "bfgs": "tab:red",
               BASELINE: "tab:gray", f"{BASELINE} (float32)": "tab:purple", "lm (float32)": "tab:cyan"}
    markers = dict(zip(CASES, "os^vDPX*h"))
    shown = [row for row in rows if all(isinstance(row.get(key), float) and math.isfinite(row[key]) and row[key] > 0
                                        for key in ("time_s", "ngan"))]
    fig, ax = plt.subplots(figsize=(12, 7))
    for row in shown:
        ax.scatter(row["time_s"], row["ngan"], color=colours[series(row)], marker=markers[row["spec"]],
                   s=40 + 30 * math.log10(row["n"] / 1e3), edgecolors="black" if row["multistart"] else "none",
                   linewidths=1.2, alpha=0.85, zorder=3)
    # One front per model: errors of different models come from different truths, so a single front over all
    # rows would only say that Lambert data are fitted best.
    for spec in markers:
        rows_of_model = [row for row in shown if row["spec"] == spec]
        front = [rows_of_model[i] for i in pareto_front([(row["time_s"], row["ngan"]) for row in rows_of_model])]
        if not front:
            continue
        ax.plot([row["time_s"] for row in front], [row["ngan"] for row in front], "-", color="black", lw=0.8,
                alpha=0.6, zorder=2)
        for row in front:
            ax.annotate(f"{series(row)}" + (f", n={row['n']:.0e}" if row["n"] != FRONT_LABEL_N else "")
                        + (f", {1 + row['multistart']} starts" if row["multistart"] else ""),
                        (row["time_s"], row["ngan"]), textcoords="offset points", xytext=(5, 3), fontsize=6.5,
                        rotation=15)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.margins(x=0.15)  # room for the labels of the front
    ax.set_xlabel("time to result, warm fit (s)")
    ax.set_ylabel("held-out Ngan error (1/sr, mean over RGB)")
    ax.set_title(f"brdffit speed against accuracy ({info['grid']} grid) - {info['machine']}, {info['date']}")
    ax.grid(True, which="both", alpha=0.3)
    solver_handles = [Line2D([], [], ls="", marker="o", color=colour, label=name) for name, colour in colours.items()
                      if any(series(row) == name for row in shown)]
    model_handles = [Line2D([], [], ls="", marker=marker, color="dimgray", label=spec)
                     for spec, marker in markers.items() if any(row["spec"] == spec for row in shown)]
    notes = [Line2D([], [], ls="-", color="black", label="Pareto front (per model)"),
             Line2D([], [], ls="", marker="o", mfc="white", mec="black", label="black edge: multistart"),
             Line2D([], [], ls="", marker="", label="size: more samples")]
    first = ax.legend(handles=solver_handles + notes, title="solver", loc="upper left", bbox_to_anchor=(1.01, 1.0),
                      fontsize=8)
    ax.add_artist(first)
    ax.legend(handles=model_handles, title="model", loc="lower left", bbox_to_anchor=(1.01, 0.0), fontsize=8)
    fig.savefig(path, dpi=150, bbox_inches="tight")
    plt.close(fig)


def json_ready(value):
    """``value`` with non-finite floats replaced by None, so that the JSON is standard."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: json_ready(item) for key, item in value.items()}
    if isinstance(value, list):
        return [json_ready(item) for item in value]
    return value


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a handful of configurations at 1e3-1e4 samples")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "out" / "speed_accuracy",
                        help="output folder (default: scripts/out/speed_accuracy/)")
    parser.add_argument("--pattern", choices=("half-diff", "uniform"), default="half-diff",
                        help="sampling pattern of the training data")
    parser.add_argument("--replot", type=Path, metavar="RESULTS_JSON",
                        help="only redraw pareto.png (into --out) from an earlier run's results.json")
    args = parser.parse_args()
    if args.replot:
        saved = json.loads(args.replot.read_text())
        args.out.mkdir(parents=True, exist_ok=True)
        plot_pareto(saved["rows"], saved["info"], args.out / "pareto.png")
        print(f"wrote {args.out / 'pareto.png'}")
        return
    enable_compilation_cache()
    wall_start, cpu_start = time.perf_counter(), cpu_seconds()
    grid = quick_grid() if args.quick else full_grid()
    heldout_samples = HELDOUT_SAMPLES["quick" if args.quick else "full"]
    info = machine_info(args, heldout_samples)
    heldout = {spec: synth.generate(CASES[spec].truth_model(), pattern="uniform", n=heldout_samples,
                                    seed=HELDOUT_SEED) for spec in dict.fromkeys(config.spec for config in grid)}

    # Run the configurations that share a data set one after the other; list them in the grid's order.
    rows: dict[Config, dict] = {}
    data = None
    for done, config in enumerate(sorted(grid, key=lambda c: (list(CASES).index(c.spec), c.n)), start=1):
        if data is None or (config.spec, config.n) != (data.case.spec, data.n):
            data = DataSets(CASES[config.spec], config.n, args.pattern, heldout[config.spec])
        row = rows[config] = dict(groups=grid[config], **run_config(config, data))
        print(f"[{done}/{len(grid)}] {config.spec}, {config.solver}, n={config.n}, starts={1 + config.multistart}, "
              f"{config.dtype}: {format_number(row.get('time_s'), 'time')} s, {row['status']}, Ngan "
              f"{format_number(row.get('ngan'), 'error')}", file=sys.stderr, flush=True)
    ordered = [rows[config] for config in grid]
    float32_errors = [float32_evaluation_error(CASES[spec], heldout[spec]) for spec in heldout]
    info["run_time_s"] = time.perf_counter() - wall_start
    info["other_cpu_share"] = other_cpu_share(cpu_start, cpu_seconds(), info["run_time_s"])

    args.out.mkdir(parents=True, exist_ok=True)
    tables = markdown_tables(ordered, float32_errors, info)
    print(tables)
    (args.out / "table.md").write_text(tables + "\n")
    (args.out / "results.json").write_text(json.dumps(json_ready(dict(info=info, rows=ordered,
                                                                      float32_evaluation=float32_errors)),
                                                      indent=2) + "\n")
    plot_pareto(ordered, info, args.out / "pareto.png")
    print(f"\nwrote {args.out / 'results.json'}, {args.out / 'table.md'}, {args.out / 'pareto.png'} "
          f"({info['run_time_s']:.0f} s)")


if __name__ == "__main__":
    main()
