"""Stability study of issue 8: where do the fitting methods fail?

Each scenario is a synthetic data set that makes fitting hard in one way, drawn afresh for every seed with a
fixed size (2000 samples, 3 channels) so that the compiled solves are reused across seeds and scenarios. The base
material is Lambert + Cook-Torrance (Beckmann, V-cavity, Schlick) with rho_d = (0.30, 0.20, 0.10),
ks = (0.80, 0.70, 0.60), m = 0.15, f0 = 0.04 held fixed at the truth, 1% relative noise and the default cosine
loss, unless a scenario says otherwise:

 1. far-start: half-diff sampling; the solvers start far from the truth (m = 0.9, ks = 0.001, rho_d = 0.9).
 2. near-mirror: m = 0.02, half-diff sampling (dense around the mirror direction, so the peak is caught).
 3. very-rough: m = 0.8, uniform sampling.
 4. grazing-only: uniform sampling kept where θi and θo both exceed 65°.
 5. normal-only: uniform sampling with θi and θo below 25°.
 6. missing-peak: uniform sampling without the samples whose half-vector lies within 15° of the normal.
 7. high-noise: 20% relative noise, half-diff sampling.
 8. outliers: 5% of the samples multiplied by 10 (`brdffit.synth.Outliers`), half-diff sampling; every fit uses
    loss="sigma" with robust=("cauchy", 3) (a fixed scale of 3 σ, so that all minimise the same function). With
    plain least squares the optimum itself is biased (amplitudes about 1.5x the truth), which tests the loss,
    not the solvers.
 9. ks-f0-correlated: f0 = 0.3 free as well, so ks and f0 trade off; uniform sampling.
10. dynamic-range: specular peak about 1e4 times the diffuse level (rho_d about 0.0015, ks = 1, m = 0.03),
    half-diff sampling, loss="sigma". With the cosine loss the peak's noise swamps the diffuse level: rho_d is
    not determined and even the fit started at the truth runs into its bound at 0.

Configurations: the solvers lm, gauss-newton, dogleg and bfgs started from a fixed generic start (the model's
default values rho_d = 0.5, ks = 0.2, m = 0.2, f0 = 0.04; the far start in scenario 1), and "default",
`brdffit.fit(data, spec)` with its data-driven initial guess (init="auto") and its safeguards, which is what a
user gets. Every configuration gets the scenario's fixed parameters and loss.

Reference: on every case an "oracle" fit (lm) starts at the truth. A case determines the parameters when the
oracle converges with finite standard errors and recovers the truth: every free parameter within
max(2% of the true value, 4 standard errors of the oracle) of it, taking the larger of the Laplace and the
sandwich standard error (relative noise fitted with the cosine loss is heteroscedastic, which the Laplace error
ignores, and the sandwich error runs low when a few peak samples carry most of the residual); a true value on a
bound is also matched by a fitted value on a bound. A configuration succeeds on a determined case when its cost
is at most the oracle's (within 1e-6 relative plus 1e-12 absolute) and its parameters agree with the truth at
the same tolerance. Otherwise the failure mode is the first that applies of: "exception: <type>" (the engine
raised: a finding by itself), "nonfinite" (status nonfinite or a NaN cost), "stuck at bound" (parameters on a
bound where the oracle has none), "max steps", "wrong basin" (finite, higher cost) and "off truth" (the oracle's
cost with other parameters: a flat direction). Cases the oracle does not determine are counted apart and
excluded from the success rates.

Usage: python scripts/stability.py [--seeds 10] [--quick] [--out scripts/out/stability]
  (--quick: 2 seeds and 3 scenarios, for a smoke run)
Prints a Markdown table and writes it, with stability.json, success_rate.png and failure_modes.png, to --out.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import math
import platform
import sys
import time
from collections.abc import Callable
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402
import numpy as np  # noqa: E402

import brdffit  # noqa: E402
from brdffit import models, synth  # noqa: E402
from brdffit.compilation_cache import enable_compilation_cache  # noqa: E402
from brdffit.params import at_bound  # noqa: E402

SPEC = "lambert+cook-torrance"
N_SAMPLES = 2000
NOISE = "relative:0.01"
BASE_TRUTH = dict(rho_d=[0.30, 0.20, 0.10], ks=[0.80, 0.70, 0.60], m=0.15, f0=0.04)
FAR_START = dict(rho_d=[0.9, 0.9, 0.9], ks=[0.001, 0.001, 0.001], m=0.9, f0=0.04)
SOLVER_CONFIGS = ("lm", "gauss-newton", "dogleg", "bfgs")
DEFAULT_CONFIG = "default"
CONFIGS = SOLVER_CONFIGS + (DEFAULT_CONFIG,)
QUICK_SCENARIOS = ("far-start", "near-mirror", "ks-f0-correlated")
QUICK_SEEDS = 2
# The outlier scenario's loss: noise-normalised residuals with a Cauchy loss of fixed scale (3 σ), so that every
# configuration minimises the same function (a scale estimated from each start would differ between them).
ROBUST_SIGMA = dict(loss="sigma", robust=("cauchy", 3.0))

# Agreement with the truth (per free parameter) and with the oracle's cost.
PARAM_RTOL = 0.02
PARAM_STDERR = 4.0
COST_RTOL, COST_ATOL = 1e-6, 1e-12

SUCCESS = "success"
NOT_DETERMINED = "not determined"
FAILURE_MODES = ("nonfinite", "stuck at bound", "max steps", "wrong basin", "off truth")


# ---------------------------------------------------------------------------------------------------------------
# Scenarios
# ---------------------------------------------------------------------------------------------------------------


def _generated(pattern: str, noise: str = NOISE, **options) -> Callable:
    """A sampler drawing `N_SAMPLES` samples of a synth pattern: (truth model, seed) -> Measurements."""

    def sample(truth, seed):
        return synth.generate(truth, pattern=pattern, n=N_SAMPLES, noise=noise, seed=seed, **options)

    return sample


def _uniform_where(keep: Callable, oversample: int) -> Callable:
    """A sampler drawing ``oversample`` x `N_SAMPLES` uniform samples and keeping the first `N_SAMPLES` for which
    ``keep(measurements)`` is True (so every seed gives the same shape)."""

    def sample(truth, seed):
        data = synth.generate(truth, pattern="uniform", n=oversample * N_SAMPLES, noise=NOISE, seed=seed)
        rows = np.flatnonzero(keep(data))[:N_SAMPLES]
        if rows.size < N_SAMPLES:
            raise RuntimeError(f"only {rows.size} of {oversample * N_SAMPLES} uniform samples pass the filter; "
                               "raise the oversampling")
        return data.take(rows)

    return sample


def _grazing(data) -> np.ndarray:
    """True where θi and θo both exceed 65°."""
    return (data.theta_i > np.radians(65)) & (data.theta_o > np.radians(65))


def _off_peak(data) -> np.ndarray:
    """True where the half-vector is more than 15° from the normal."""
    h = data.wi() + data.wo()
    cos_h = h[:, 2] / np.linalg.norm(h, axis=1)
    return cos_h < np.cos(np.radians(15))


@dataclasses.dataclass(frozen=True)
class Scenario:
    """One way of making a fit hard.

    Attributes:
        name: short label (table row).
        description: one line for the table's legend.
        sample: (truth model, seed) -> Measurements of `N_SAMPLES` samples.
        truth: the true parameters (the base material unless changed).
        fixed: parameters held at their true value in every fit.
        start: the start of the per-solver configurations (None: the model's default values).
        fit_options: further `brdffit.fit` arguments (loss, robust) that every fit of the scenario gets.
    """

    name: str
    description: str
    sample: Callable
    truth: dict = dataclasses.field(default_factory=lambda: dict(BASE_TRUTH))
    fixed: tuple = ("f0",)
    start: dict | None = None
    fit_options: dict = dataclasses.field(default_factory=dict)


def scenarios() -> list[Scenario]:
    """The ten scenarios of the module docstring, in order."""
    return [
        Scenario("far-start", "solvers start at m = 0.9, ks = 0.001, rho_d = 0.9; half-diff sampling",
                 _generated("half-diff"), start=FAR_START),
        Scenario("near-mirror", "m = 0.02; half-diff sampling", _generated("half-diff"),
                 truth=dict(BASE_TRUTH, m=0.02)),
        Scenario("very-rough", "m = 0.8; uniform sampling", _generated("uniform"), truth=dict(BASE_TRUTH, m=0.8)),
        Scenario("grazing-only", "θi, θo > 65° only", _uniform_where(_grazing, oversample=8)),
        Scenario("normal-only", "θi, θo < 25° only", _generated("uniform", max_theta=np.radians(25))),
        Scenario("missing-peak", "no half-vector within 15° of the normal",
                 _uniform_where(_off_peak, oversample=2)),
        Scenario("high-noise", "20% relative noise; half-diff sampling", _generated("half-diff", "relative:0.2")),
        Scenario("outliers", "5% of samples x10 on 1% noise; half-diff; loss='sigma', robust=('cauchy', 3)",
                 _generated("half-diff", "relative:0.01+outliers:0.05,10"), fit_options=ROBUST_SIGMA),
        Scenario("ks-f0-correlated", "f0 = 0.3 free with ks; uniform sampling", _generated("uniform"),
                 truth=dict(BASE_TRUTH, f0=0.3), fixed=()),
        Scenario("dynamic-range", "peak ≈ 1e4 x diffuse (rho_d ≈ 0.0015, ks = 1, m = 0.03); half-diff; "
                 "loss='sigma'", _generated("half-diff"),
                 truth=dict(rho_d=[0.002, 0.0015, 0.001], ks=[1.0, 1.0, 1.0], m=0.03, f0=0.04),
                 fit_options=dict(loss="sigma")),
    ]


# ---------------------------------------------------------------------------------------------------------------
# Fitting and judging one case
# ---------------------------------------------------------------------------------------------------------------


def free_names(truth, fixed) -> list[str]:
    """The parameters a fit adjusts: those neither declared fixed by the model nor held by the scenario."""
    return [spec.name for spec in truth.param_specs if not spec.fixed and spec.name not in fixed]


def agrees(params: dict, truth, tolerance: dict) -> bool:
    """True when every parameter named in ``tolerance`` is within it of the truth, or on a bound where the truth
    is on one."""
    specs = truth.param_specs
    for name, tol in tolerance.items():
        value, true = np.asarray(params[name], dtype=float), np.asarray(truth.params[name], dtype=float)
        close = np.abs(value - true) <= tol
        both_on_bound = at_bound(true, specs[name]) & at_bound(value, specs[name])
        if not np.all(close | both_on_bound):
            return False
    return True


def determination(oracle, truth, free: list[str]) -> tuple[dict | None, str]:
    """The per-parameter tolerance when the oracle fit determines the parameters, else None, and the reason."""
    if not oracle.converged:
        return None, f"oracle {oracle.status}"
    tolerance = {}
    for name in free:
        # stderr_laplace, not stderr: since the noise model (25136ca) `stderr` holds the kind the residuals support,
        # often the sandwich itself, and the larger of the two kinds is what the tolerance takes.
        stderr = np.maximum(np.asarray(oracle.stderr_laplace[name], dtype=float),
                            np.asarray(oracle.stderr_robust[name], dtype=float))
        if not np.all(np.isfinite(stderr)):
            return None, f"oracle stderr of {name} infinite"
        tolerance[name] = np.maximum(PARAM_RTOL * np.abs(np.asarray(truth.params[name], dtype=float)),
                                     PARAM_STDERR * stderr)
    off = [name for name in free if not agrees(oracle.params, truth, {name: tolerance[name]})]
    if off:
        return None, f"oracle off truth in {', '.join(off)}"
    return tolerance, "determined"


def outcome(result, oracle, truth, tolerance: dict) -> str:
    """`SUCCESS` or the failure mode of a configuration's result on a determined case (module docstring)."""
    if result.status == "nonfinite" or not math.isfinite(result.cost):
        return "nonfinite"
    if result.cost <= oracle.cost * (1.0 + COST_RTOL) + COST_ATOL and agrees(result.params, truth, tolerance):
        return SUCCESS
    if result.bounds_hit and not oracle.bounds_hit:
        return "stuck at bound"
    if result.status == "max-steps":
        return "max steps"
    if result.cost > oracle.cost * (1.0 + COST_RTOL) + COST_ATOL:
        return "wrong basin"
    return "off truth"


def run_config(config: str, scenario: Scenario, data, fixed: dict):
    """Fit one configuration to one data set."""
    if config == DEFAULT_CONFIG:
        return brdffit.fit(data, SPEC, fixed=fixed, **scenario.fit_options)
    return brdffit.fit(data, SPEC, solver=config, init=scenario.start or "model", fixed=fixed,
                       **scenario.fit_options)


def _json_float(value) -> float | None:
    """A float for JSON: None for NaN and infinities, which strict JSON has no spelling for."""
    value = float(value)
    return value if math.isfinite(value) else None


def _params_json(params: dict) -> dict:
    """Parameters as JSON lists and floats."""
    return {name: np.asarray(value, dtype=float).tolist() for name, value in params.items()}


def run_case(scenario: Scenario, seed: int, configs) -> list[dict]:
    """All configurations (and the oracle) on one seed of one scenario: one record per configuration."""
    truth = models.get(SPEC, **scenario.truth)
    fixed = {name: truth.params[name] for name in scenario.fixed}
    data = scenario.sample(truth, seed)
    try:
        oracle = brdffit.fit(data, SPEC, init=truth, fixed=fixed, **scenario.fit_options)
    except Exception as error:  # a finding, as for the configurations; the case is then not determined
        oracle, tolerance, reason = None, None, f"oracle exception: {type(error).__name__}: {error}"
    else:
        tolerance, reason = determination(oracle, truth, free_names(truth, fixed))
    records = []
    for config in configs:
        record = dict(scenario=scenario.name, seed=seed, config=config, determined=tolerance is not None,
                      determination=reason, oracle_cost=None if oracle is None else _json_float(oracle.cost))
        t0 = time.perf_counter()
        try:
            result = run_config(config, scenario, data, fixed)
        except Exception as error:  # the engine should not raise: record it as a finding
            record.update(outcome=f"exception: {type(error).__name__}", error=str(error),
                          time=time.perf_counter() - t0)
            records.append(record)
            continue
        record.update(time=time.perf_counter() - t0, status=result.status, cost=_json_float(result.cost),
                      steps=int(result.steps), bounds_hit=list(result.bounds_hit),
                      params=_params_json(result.params),
                      outcome=NOT_DETERMINED if tolerance is None else outcome(result, oracle, truth, tolerance))
        records.append(record)
    return records


# ---------------------------------------------------------------------------------------------------------------
# Summary, table and figures
# ---------------------------------------------------------------------------------------------------------------


def summarise(records: list[dict], scenario_names, configs) -> dict:
    """(scenario, config) -> counts: determined cases, successes and failure modes on them, undetermined cases."""
    summary = {}
    for name in scenario_names:
        for config in configs:
            rows = [r for r in records if r["scenario"] == name and r["config"] == config]
            determined = [r for r in rows if r["determined"]]
            failures = collections.Counter(r["outcome"] for r in determined if r["outcome"] != SUCCESS)
            summary[name, config] = dict(
                determined=len(determined), not_determined=len(rows) - len(determined),
                success=sum(r["outcome"] == SUCCESS for r in determined), failures=dict(failures.most_common()))
    return summary


def _cell(counts: dict) -> str:
    if counts["determined"] == 0:
        return "n/a"
    text = f"{counts['success'] / counts['determined']:.0%} ({counts['success']}/{counts['determined']})"
    if counts["failures"]:
        mode, count = next(iter(counts["failures"].items()))
        text += f"; {mode} ×{count}"
    return text


def markdown_table(summary: dict, scenario_list: list[Scenario], configs, seeds: int) -> str:
    """Scenario x configuration: success rate on the determined cases, counts, dominant failure mode."""
    lines = ["| scenario | not determined | " + " | ".join(configs) + " |",
             "|---|---|" + "---|" * len(configs)]
    for scenario in scenario_list:
        undetermined = summary[scenario.name, configs[0]]["not_determined"]
        cells = [_cell(summary[scenario.name, config]) for config in configs]
        lines.append(f"| {scenario.name} | {undetermined}/{seeds} | " + " | ".join(cells) + " |")
    lines.append("")
    lines.extend(f"- **{s.name}**: {s.description}" for s in scenario_list)
    return "\n".join(lines)


def undetermined_notes(records: list[dict]) -> list[str]:
    """One line per case the oracle did not determine, with the reason."""
    cases = {(r["scenario"], r["seed"]): r["determination"] for r in records if not r["determined"]}
    return [f"- not determined: {name} seed {seed}: {reason}" for (name, seed), reason in cases.items()]


def engine_exceptions(records: list[dict]) -> list[str]:
    """One line per fit that raised (the oracle's included): the engine should return a status instead."""
    lines = {f"- {r['scenario']} seed {r['seed']} {r['config']}: {r['outcome']}: {r['error']}"
             for r in records if r["outcome"].startswith("exception")}
    lines |= {f"- {r['scenario']} seed {r['seed']} oracle: {r['determination']}"
              for r in records if r["determination"].startswith("oracle exception")}
    return sorted(lines)


def overall_rate(summary: dict, config: str) -> tuple[int, int]:
    """Successes and determined cases of one configuration over all scenarios."""
    pairs = [counts for (_, c), counts in summary.items() if c == config]
    return sum(p["success"] for p in pairs), sum(p["determined"] for p in pairs)


def plot_success(summary: dict, scenario_names, configs, path: Path):
    """Heatmap of the success rate (scenario x configuration), annotated with the counts."""
    rate = np.full((len(scenario_names), len(configs)), np.nan)
    fig, ax = plt.subplots(figsize=(1.6 * len(configs) + 2.5, 0.5 * len(scenario_names) + 1.5))
    for i, name in enumerate(scenario_names):
        for j, config in enumerate(configs):
            counts = summary[name, config]
            if counts["determined"]:
                rate[i, j] = counts["success"] / counts["determined"]
                label = f"{rate[i, j]:.0%}\n{counts['success']}/{counts['determined']}"
            else:
                label = "n/a"
            ax.text(j, i, label, ha="center", va="center", fontsize=8)
    cmap = plt.get_cmap("RdYlGn").copy()
    cmap.set_bad("lightgrey")
    image = ax.imshow(np.ma.masked_invalid(rate), cmap=cmap, vmin=0.0, vmax=1.0, aspect="auto")
    ax.set_xticks(range(len(configs)), configs)
    ax.set_yticks(range(len(scenario_names)), scenario_names)
    ax.set_title("success rate on determined cases")
    fig.colorbar(image, ax=ax, label="success rate")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_failure_modes(records: list[dict], scenario_names, configs, path: Path):
    """One panel per configuration: per scenario, the cases stacked by outcome (success, each failure mode,
    not determined)."""
    failures = list(FAILURE_MODES) + sorted({r["outcome"] for r in records if r["outcome"].startswith("exception")})
    tab10 = plt.get_cmap("tab10").colors
    palette = [c for i, c in enumerate(tab10) if i not in (2, 7)]  # green and grey: success, not determined
    colours = {SUCCESS: "tab:green", **dict(zip(failures, palette)), NOT_DETERMINED: "lightgrey"}
    outcomes = list(colours)
    fig, axes = plt.subplots(1, len(configs), figsize=(2.6 * len(configs) + 1.5, 0.45 * len(scenario_names) + 1.8),
                             sharey=True)
    rows = np.arange(len(scenario_names))
    for ax, config in zip(np.atleast_1d(axes), configs):
        left = np.zeros(len(scenario_names))
        for mode in outcomes:
            counts = np.array([sum(r["outcome"] == mode for r in records
                                   if r["scenario"] == name and r["config"] == config) for name in scenario_names])
            ax.barh(rows, counts, left=left, color=colours[mode], label=mode)
            left += counts
        ax.set_title(config)
        ax.set_xlabel("cases")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    axes[0].set_yticks(rows, scenario_names)
    axes[0].invert_yaxis()
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(len(outcomes), 5), fontsize=8)
    fig.tight_layout(rect=(0, 0.12, 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ---------------------------------------------------------------------------------------------------------------


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10, help="data sets per scenario (default 10)")
    parser.add_argument("--quick", action="store_true",
                        help=f"{QUICK_SEEDS} seeds and the scenarios {', '.join(QUICK_SCENARIOS)} (smoke run)")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "out" / "stability",
                        help="output folder (default scripts/out/stability)")
    args = parser.parse_args()

    enable_compilation_cache()
    scenario_list = scenarios()
    seeds = args.seeds
    if args.quick:
        scenario_list = [s for s in scenario_list if s.name in QUICK_SCENARIOS]
        seeds = QUICK_SEEDS
    names = [s.name for s in scenario_list]

    t0 = time.perf_counter()
    records = []
    for scenario in scenario_list:
        for seed in range(seeds):
            records.extend(run_case(scenario, seed, CONFIGS))
        print(f"{scenario.name}: done after {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    elapsed = time.perf_counter() - t0

    summary = summarise(records, names, CONFIGS)
    table = markdown_table(summary, scenario_list, CONFIGS, seeds)
    success, determined = overall_rate(summary, DEFAULT_CONFIG)
    header = (f"{len(scenario_list)} scenarios x {seeds} seeds x {len(CONFIGS)} configurations, {N_SAMPLES} "
              f"samples each, {elapsed:.0f} s on {platform.machine()} ({time.strftime('%Y-%m-%d')}, brdffit "
              f"{brdffit.__version__})")
    overall = (f"default configuration: {success}/{determined} determined cases succeeded"
               f" ({success / determined:.1%})" if determined else "default configuration: no determined cases")
    notes = "\n".join(undetermined_notes(records))
    raised = engine_exceptions(records)
    exceptions = "engine exceptions: " + ("\n" + "\n".join(raised) if raised else "none")
    report = "\n\n".join(part for part in (header, table, notes, overall, exceptions) if part)
    print(report)

    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "stability_table.md").write_text(report + "\n")
    summary_json = [dict(scenario=name, config=config, **counts) for (name, config), counts in summary.items()]
    (args.out / "stability.json").write_text(json.dumps(
        dict(seeds=seeds, samples=N_SAMPLES, elapsed_s=elapsed, scenarios={s.name: s.description for s in
                                                                            scenario_list},
             configs=list(CONFIGS), summary=summary_json, records=records), indent=1))
    plot_success(summary, names, CONFIGS, args.out / "success_rate.png")
    plot_failure_modes(records, names, CONFIGS, args.out / "failure_modes.png")
    print(f"wrote {args.out}/stability_table.md, stability.json, success_rate.png, failure_modes.png",
          file=sys.stderr)


if __name__ == "__main__":
    main()
