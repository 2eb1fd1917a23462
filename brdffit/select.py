"""Model selection: fit candidate models and choose the smallest that is good enough (docs/model-selection.md).

`select(measurements, candidates, criterion)` fits every candidate, scores it by AIC, BIC or cross-validated
held-out error, and chooses the simplest candidate whose score is within a stated margin of the best. Given a
scene (`brdffit.scene.Scene`) and a tolerance, it chooses the cheapest candidate whose error in that scene stays
under the tolerance: a scene that only sees diffuse-dominated directions can then pick a diffuse model even when
the full data need a specular lobe.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import os
import re
import time
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

import numpy as np

from .blas_threads import one_blas_thread
from .defaults import FIT
from .criteria import CRITERIA, DEFAULT_MARGIN, HELDOUT_MARGIN, resolve_criterion
from .fitting.api import COARSE_ATOL, COARSE_RTOL, fit
from .fitting.outcome import Status
from .fitting.result import FitResult
from .fitting.solvers import coarse_solver
from .fitting.losses import get_loss, loss_epsilon
from .fitting.normal_equations import SLOT_ROWS
from .arrays import to_device
from .models.model import EVALUATION_ROWS, evaluate_dirs, evaluation_program
from .models.registry import get as get_model
from .fitting.progressive import new_lobe_candidates
from .fitting.problem import make_fit_data
from .fitting.status import information_criteria
from .progress import Progress

__all__ = ["select", "Selection", "DEFAULT_CANDIDATES", "CRITERIA", "DEFAULT_MARGIN", "HELDOUT_MARGIN",
           "resolve_criterion"]

# The standard candidates (docs/model-selection.md says why each is here): diffuse alone, one specular lobe of
# each family, GGX with a dielectric's Fresnel term (η bounds ks·F where the data cannot separate ks from f0),
# two GGX lobes with one Fresnel term, and Lafortune lobes (forward, off-specular or retro-reflective).
DEFAULT_CANDIDATES = (
    "lambert",
    "oren-nayar",
    "lambert+blinn-phong",
    "lambert+ward",
    "lambert+cook-torrance",
    "lambert+ggx",
    "lambert+ggx(fresnel=dielectric)",
    "lambert+ashikhmin-shirley",
    "lambert+ggx+ggx(share=f0)",
    "lambert+lafortune",
    "lambert+lafortune(lobes=2)",
    "lambert+lafortune(lobes=3)",
)
# Timed evaluations of a candidate's residual program for its ``cost_ns`` (the best is kept: a shared host's load
# only ever adds time).
_COST_REPEATS = 5
# Candidates fitted at a time, each in a thread of its own: a first selection is mostly XLA compiling every
# candidate's programs, one core a compilation, while the GIL is free. Every fit is the same as alone.
SELECT_THREADS = min(4, os.cpu_count() or 1)
# Screening (AIC/BIC): every candidate is fitted to the training rows (a subsample of SCREEN_SAMPLES of them when
# there are twice as many), and only those that can still be chosen are refitted to all the data. A subsample optimum costs the full data about
# k (n/n_s − 1) more in the criterion's units for a well-specified model (the excess χ² of an estimate with n/n_s
# times the full-data covariance); SCREEN_SLACK times k n/n_s bounds it for misspecified ones too
# (docs/model-selection.md, and the measurement there). As many as a slot of the passes (`SLOT_ROWS`): the screen's
# polish of four starts and the refit of one point on four times as many rows run one compiled pass.
SCREEN_SAMPLES = SLOT_ROWS
# A measurement with more channels than this (a spectrum: 31 bands) is compared on this many averages of
# contiguous channels, and only the chosen model is then fitted to every channel. With the shape shared by the
# channels (the default channel mode), an average of channels is the same sum of lobes with those channels'
# amplitudes averaged (within the same bounds), so every candidate's family is the same on the averages; the
# comparison then costs what it costs on RGB data instead of growing with the bands (docs/model-selection.md).
SCREEN_BANDS = 3
# A fit whose directional albedo stays within 1 where the data were measured but exceeds this beyond their largest
# θi is not chosen while another converged candidate does not (``plausible``): a diffuse lobe and a specular one,
# uncoupled and each within 1, could reach 2 towards grazing; more is a lobe the data never constrained.
EXTRAPOLATION_ALBEDO = 2.0
SCREEN_SLACK = 10.0
# What a user can do when no candidate is plausible (the verdict's advice).
IMPLAUSIBLE_ADVICE = ("What to do: check the values' units (f_r in 1/sr without the cosine; a reflectance factor is "
                      "π f_r); for a material a renderer can take as plausible, fit the chosen model with its "
                      "amplitudes bounded by 1 (--model with 'bounded=true' on each specular lobe, e.g. "
                      "'lambert+ggx(bounded=true)'; it predicts the data less well); a material with a lobe none of "
                      "the candidates has (retro-reflection, a sheen) needs a model with that lobe. A renderer "
                      "export of this fit is refused unless forced.")
_LAFORTUNE = re.compile(r"^(?P<base>.*?)\+?lafortune(?:\((?P<options>[^)]*)\))?$")


@dataclasses.dataclass
class Selection:
    """What `select` returns.

    Attributes:
        table: one dict per candidate: ``spec``, ``n_params``, ``train_error``, ``heldout_error``,
            ``heldout_se``, ``aic``, ``bic``, ``score``, ``cost_ns`` (measured evaluation cost per sample,
            nanoseconds), ``status``, ``samples`` (the valid values the reported fit was fitted to: fewer than
            the data's for a candidate that screening ruled out), ``verdict`` (why it was or was not chosen by
            the criterion), and with a scene ``scene_error``.
        chosen: the chosen spec (the scene's choice when a scene was given, the target's with a target, else the
            criterion's).
        criterion: ``"heldout"``, ``"aic"``, ``"bic"`` or ``"cv"``; margin: the margin used; holdout: the fraction
            of the rows held out; heldout_scale: with the cosine loss, the RMS of the data's own cosine-weighted
            values f cosθi √w on the held-out rows (a held-out error over it is the relative error in reflected
            radiance), else None; target: the renderer the choice was made for, or None.
        compared_on: where the candidates were compared on averages of the channels (`SCREEN_BANDS`), what they
            were ("3 averages of 10-11 of the 31 channels"); the table's errors are then those of the averages,
            and ``results[chosen]`` is the chosen model's fit to every channel. None: compared on the channels.
        channel_heldout: with ``compared_on``, the chosen model's held-out error over every channel (fitted to
            the same training rows) and the radiance scale of the held-out rows (as ``heldout_scale``, or None).
        best: the candidate with the best score.
        chosen_by_criterion: the criterion's choice (equals ``chosen`` without a scene).
        chosen_by_scene: the scene's choice, or None.
        results: spec -> the reported `FitResult`: the full-data fit, or for a candidate that screening ruled
            out its fit to the training rows (or their subsample).
        scene_results: spec -> the `FitResult` fitted to what the scene sees (empty without a scene).
        warnings: human-readable warnings.
    """

    table: list
    chosen: str
    criterion: str
    margin: float
    best: str
    chosen_by_criterion: str
    chosen_by_scene: str | None
    results: dict
    warnings: list
    scene_results: dict = dataclasses.field(default_factory=dict)
    holdout: float = 0.2
    heldout_scale: float | None = None
    target: str | None = None
    compared_on: str | None = None
    channel_heldout: tuple | None = None

    @property
    def result(self) -> FitResult:
        """The fit of the chosen model: to the scene when the scene chose it, else to all the data."""
        if self.chosen_by_scene is not None:
            return self.scene_results[self.chosen]
        return self.results[self.chosen]

    def verdict(self) -> str:
        """The answer to "is this good?", in the first lines of a summary and a report: the chosen model, its error
        on the held-out rows (absolute, in the loss's units, and relative to Lambert's), its plausibility, and what
        to do when no candidate was plausible."""
        rows = {row["spec"]: row for row in self.table}
        shown = self.chosen if self.target else self.chosen_by_criterion
        error = rows[shown]["heldout_error"]
        line = f"verdict: {self.chosen}" + (f" for {self.target}" if self.target else "")
        # Compared on channel averages: the error over every channel first, then the comparison's.
        every, scale = self.channel_heldout if self.compared_on else (error, self.heldout_scale)
        line += f": error on unseen directions {every:.4g}"
        if scale:
            line += f" = {every / scale:.1%} of the reflected radiance"
        line += (f" (loss RMS{' over every channel' if self.compared_on else ''} on the {self.holdout:.0%} of rows "
                 "held out from its fit)")
        if self.compared_on:
            line += f"; on the {self.compared_on} the candidates were compared on, {error:.4g}"
        lambert = rows.get("lambert")
        if lambert is not None and shown != "lambert" and lambert["heldout_error"] > 0:
            line += f", {error / lambert['heldout_error']:.2f}x Lambert's {lambert['heldout_error']:.4g}"
        if self.target and self.chosen_by_criterion != shown:
            free = rows[self.chosen_by_criterion]["heldout_error"]
            line += (f"; the renderer's cost: the best model without the target's limits, "
                     f"{self.chosen_by_criterion}, has {free:.4g} ({error / free:.2f}x)" if free > 0 else "")
        why = "; ".join(f"{c.name}: {c.message}" for c in self.result.plausibility().implausible)
        if not why:
            return line + "; plausible"
        return (line + f"; IMPLAUSIBLE ({why}).\nNo plausible candidate predicts these data within the margin of "
                f"the best (the warnings below name the closest plausible one, if any). {IMPLAUSIBLE_ADVICE}")

    @property
    def plausible(self) -> bool:
        """Whether the chosen fit passes every plausibility check (`FitResult.plausibility`)."""
        return self.result.plausibility().ok

    def summary(self) -> str:
        """The table as text, with the choice and the rule that made it."""
        has_scene = any("scene_error" in row for row in self.table)
        head = (f"{'candidate':<32}{'params':>7}{'fit on':>8}{'train':>11}{'held-out':>11}{'AIC':>13}{'BIC':>13}"
                f"{'ns/sample':>10}" + (f"{'scene err':>11}" if has_scene else "") + "  status")
        lines = [head]
        for row in self.table:
            mark = "*" if row["spec"] == self.chosen else " "
            line = (f"{mark}{row['spec']:<31}{row['n_params']:>7}{row['samples']:>8}{row['train_error']:>11.4g}"
                    f"{row['heldout_error']:>11.4g}{row['aic']:>13.6g}{row['bic']:>13.6g}{row['cost_ns']:>10.1f}")
            if has_scene:
                line += f"{row['scene_error']:>11.4g}"
            lines.append(line + f"  {row['status']}")
        rule = {"aic": f"ΔAIC <= {self.margin:g}", "bic": f"ΔBIC <= {self.margin:g}",
                "cv": "CV error within one standard error",
                "heldout": f"held-out error within {self.margin:.0%} of the best, plausible first"}[self.criterion]
        if self.compared_on:
            lines.append(f"compared on {self.compared_on} (the errors above are theirs); {self.chosen} then fitted "
                         "to every channel")
        lines.append(f"best by {self.criterion}: {self.best}; simplest with {rule}: {self.chosen_by_criterion}")
        if self.chosen_by_scene is not None:
            lines.append(f"cheapest within the scene tolerance: {self.chosen_by_scene}")
        if self.target:
            lines.append(f"chosen for {self.target} (its models exact and in its ranges): {self.chosen}")
        lines.extend(f"  {row['spec']}: {row['verdict']}" for row in self.table
                     if row["spec"] not in (self.chosen_by_criterion, self.chosen) and "verdict" in row)
        lines.extend(f"warning: {w}" for w in self.warnings)
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """JSON-ready: the table, the choices and the warnings."""
        def clean(v):
            return None if isinstance(v, float) and not math.isfinite(v) else v

        return {"table": [{k: clean(v) for k, v in row.items()} for row in self.table], "chosen": self.chosen,
                "criterion": self.criterion, "margin": self.margin, "best": self.best,
                "chosen_by_criterion": self.chosen_by_criterion, "chosen_by_scene": self.chosen_by_scene,
                "target": self.target, "compared_on": self.compared_on, "warnings": list(self.warnings)}


def _loss_residuals(result: FitResult, measurements):
    """The fit's loss residuals on every sample ``(N, C)``, NaN where the data are missing: the model evaluated by
    `brdffit.evaluate_dirs` (one compiled program per model structure, the one that the plausibility checks and the
    report run too) and the loss formed on the host (`brdffit.fitting.losses`, in NumPy).

    Arguments:
        result: a fit with a model.
        measurements: the samples to evaluate it at.

    Returns:
        ``(residuals, evaluation)``: ``evaluation`` is what `_cost_ns` times.
    """
    model = result.model
    data = make_fit_data(measurements, {}, loss_epsilon(result.loss, measurements.values), device=False)
    f = evaluate_dirs(model, data.pair.wi, data.pair.wo)
    r = get_loss(result.loss).residuals(f, data.values, data.cos_i, data.sqrt_weight, data.sigma, data.eps)
    return np.where(data.mask, r, np.nan), (model, data.pair.wi, data.pair.wo)


def _cost_ns(evaluation) -> float:
    """The evaluation cost of a `_loss_residuals` ``evaluation`` in nanoseconds per sample: the best of
    `_COST_REPEATS` calls of the compiled program that evaluated it (`brdffit.models.model.evaluation_program`, on
    its samples repeated or cut to one call's `EVALUATION_ROWS`; a selection's ``cost_ns``, measured without
    compiling another program for each candidate). Called while no other candidate is being fitted."""
    model, wi, wo = evaluation
    run = evaluation_program(model)
    block = [to_device(np.resize(a, (EVALUATION_ROWS, 3))) for a in (wi, wo)]
    best = math.inf
    for _ in range(_COST_REPEATS):
        t0 = time.perf_counter()
        np.asarray(run(*block))
        best = min(best, time.perf_counter() - t0)
    return 1e9 * best / EVALUATION_ROWS


def _rms(r: np.ndarray) -> float:
    """RMS over the finite entries."""
    finite = r[np.isfinite(r)]
    return float(np.sqrt(np.sum(finite ** 2) / max(finite.size, 1)))


def _masked(measurements, rows: np.ndarray):
    """The measurements with the given rows marked missing (same shape, so fits reuse their compilation)."""
    values = np.array(measurements.values, dtype=float)
    values[rows] = np.nan
    return measurements.replace(values=values)


def _smaller_lafortune(spec: str):
    """The spec of the same base with one Lafortune lobe fewer and this spec's lobe count ``(smaller, k)``, or
    ``(None, None)`` for a spec that is not a Lafortune sum of two or more lobes (progressive start)."""
    match = _LAFORTUNE.match(spec)
    if not match:
        return None, None
    options = match.group("options") or ""
    lobes = re.search(r"lobes\s*=\s*(\d+)", options)
    k = int(lobes.group(1)) if lobes else 1
    if k < 2:
        return None, None
    rest = re.sub(r"\s*lobes\s*=\s*\d+\s*,?\s*", "", options).strip(", ")
    smaller_options = ", ".join(x for x in ([f"lobes={k - 1}"] if k - 1 > 1 else []) + ([rest] if rest else []))
    lobe = "lafortune" + (f"({smaller_options})" if smaller_options else "")
    base = match.group("base")
    return (f"{base}+{lobe}" if base else lobe), k


def _layer_starts(previous: FitResult, model, values: dict) -> list:
    """`brdffit.fit`'s ``init`` for a one-lobe model from the fit of the form it contains one layer fewer
    (``previous``): that fit's shape with the layer off (``values``: its weight at 0), where the cost is that
    fit's, so the model's fit ends no higher; the same with the layer's parameters at their defaults; then
    ``"auto"``, the search's own candidates, so the global search is not lost."""
    declared = model.param_specs
    kept = {name: np.asarray(value) for name, value in previous.params.items()
            if name in declared.names and not declared[name].linear}
    layer_on = dict(kept, **{s.name: s.default for s in declared if not s.linear and s.name not in kept})
    return [dict(layer_on, **values), layer_on, "auto"]


def _contained(spec: str, earlier) -> tuple[str | None, object]:
    """The earlier candidate that ``spec`` contains and the starts of ``spec`` from its fit: ``(smaller,
    starts)``, ``starts(previous_fit)`` giving `brdffit.fit`'s ``init``; ``(None, None)`` where there is none.

    Two kinds: a Lafortune sum of K lobes contains the same sum of K − 1 (`_smaller_lafortune`; the new-lobe
    starts of `brdffit.fitting.progressive`), and a one-lobe model with a layer option on contains the lobe
    without it (`brdffit.models.lobe.Lobe.nested`; `_layer_starts`)."""
    smaller, k = _smaller_lafortune(spec)
    if smaller is not None:
        anisotropic = "anisotropic=true" in spec.replace(" ", "").lower()
        return smaller, lambda previous: new_lobe_candidates(previous, k, anisotropic)
    try:
        model = get_model(spec)
    except (ValueError, KeyError):  # an unknown spec: its fit says so
        return None, None
    forms = model.lobes[0].nested() if len(model.lobes) == 1 else []
    if not forms:
        return None, None
    canonical = {}
    for other in earlier:
        try:
            canonical[get_model(other).spec] = other
        except (ValueError, KeyError):
            pass
    for form, values in forms:
        if form.token() in canonical:
            return canonical[form.token()], lambda previous, values=values: _layer_starts(previous, model, values)
    return None, None


def _each_candidate(candidates, work, bar, message, when_idle=None):
    """``work(spec, init)`` for every candidate, `SELECT_THREADS` at a time, where ``init`` is ``"auto"`` or, for
    a candidate that contains an earlier one (`_contained`: a Lafortune sum with one lobe more, a renderer's
    material with one layer more), starts from that one's fit; where its cost still ends above that fit's (both
    fit the same rows), the first of those starts, the contained fit's own point, is polished alone and the lower
    kept. ``work`` returns a pair whose first element is the candidate's `FitResult`.

    A chain of such candidates (one lobe, two, three; no coat, a coat) is one task, its members fitted in turn,
    and the longest chains are started first: the chain is the selection's critical path (each member waits for
    the one before), and a member in a pool slot of its own would hold that slot idle while it waits.

    Arguments:
        when_idle: ``when_idle(finished)``, run in the first pool slot that the candidates leave idle (once every
            chain has started and one has ended), with ``finished`` the ``work`` outputs of the candidates done by
            then (spec -> output): work that the caller would do next and can begin on a guess (`select` refits
            the candidate leading so far). Its return value is returned beside the outputs.

    Returns:
        ``(outputs, guess)``: the ``work`` outputs in the order of ``candidates``, and ``when_idle``'s return (None
        without it).
    """
    chains: dict[str, list[str]] = {}  # the chain's first spec -> its specs in order
    head, contained = {}, {}
    for i, spec in enumerate(candidates):
        contained[spec] = _contained(spec, candidates[:i])
        smaller = contained[spec][0]
        head[spec] = head[smaller] if smaller in head else spec
        chains.setdefault(head[spec], []).append(spec)
    finished = {}  # every chain's outputs so far, for `when_idle`

    def run(chain):
        out = {}
        for spec in chain:
            smaller, starts = contained[spec]
            previous = out[smaller][0] if smaller in out and out[smaller][0].model is not None else None
            init = "auto" if previous is None else starts(previous)
            output = work(spec, init)
            if previous is not None and output[0].cost > previous.cost * (1.0 + 1e-9):
                # The search kept other starts than the contained fit's own point: polish that one too, so that a
                # candidate never fits its rows worse than the one it contains.
                again = work(spec, init[:1])
                output = again if again[0].cost < output[0].cost else output
            out[spec] = finished[spec] = output
        return out

    def idle():  # queued after every chain: it starts when a slot has no chain left to start
        wait(futures.values(), return_when=FIRST_COMPLETED)
        return when_idle(dict(finished))

    with ThreadPoolExecutor(max_workers=SELECT_THREADS) as pool:
        futures = {first: pool.submit(run, chain)
                   for first, chain in sorted(chains.items(), key=lambda item: -len(item[1]))}
        guess = pool.submit(idle) if when_idle is not None else None
        out = []
        for i, spec in enumerate(candidates):
            bar.update(i, message(spec))
            out.append(futures[head[spec]].result()[spec])
        return out, (None if guess is None else guess.result())


def _verdict(row: dict, chosen: dict, best: dict, threshold: float, criterion: str, usable: list,
             implausible: dict) -> str:
    """Why a candidate was or was not chosen, in words."""
    name = {"aic": "ΔAIC", "bic": "ΔBIC", "cv": "CV error", "heldout": "held-out error"}[criterion]
    if row is chosen:
        if row["spec"] in implausible:
            return "chosen although IMPLAUSIBLE: no plausible candidate came within the margin of the best"
        return "chosen: the simplest " + ("plausible " if criterion == "heldout" else "") + "candidate within " + (
            "one standard error of the best CV error" if criterion == "cv" else "the margin of the best")
    if row["spec"] in implausible:
        why = implausible[row["spec"]]
        return (f"not eligible: {why}" if criterion == "heldout"
                else f"not eligible: implausible beyond the data ({why})")
    if row not in usable:
        return f"not eligible: its fit ended {row['status']}"
    if row["score"] > threshold:
        gap = {"cv": f"{name} {row['score']:.4g} against {best['score']:.4g}",
               "heldout": f"{name} {row['score']:.4g} against {best['score']:.4g} "
                          f"({row['score'] / best['score'] - 1:+.1%})"}.get(
            criterion, f"{name} {row['score'] - best['score']:+.4g}")
        return f"worse than {best['spec']}: {gap}, beyond the " + ("standard error" if criterion == "cv" else "margin")
    if row["n_params"] > chosen["n_params"]:
        return f"as good, but {row['n_params']} parameters against {chosen['n_params']}"
    label = {"aic": "AIC", "bic": "BIC"}.get(criterion, name)
    return f"as good and as small, but a higher {label} ({row['score']:.6g} against {chosen['score']:.6g})"


def _implausibility(result: FitResult) -> str:
    """Why a fit extrapolates implausibly (`FitResult.plausibility`'s energy check: within 1 where the data are,
    above `EXTRAPOLATION_ALBEDO` beyond their largest θi), in words; empty when it does not."""
    energy = result.plausibility()["energy"]
    if energy.level == "caution" and energy.value > EXTRAPOLATION_ALBEDO:
        return f"energy: {energy.message}"
    return ""


def _radiance_scale(measurements, rows: np.ndarray) -> float:
    """The RMS of the data's cosine-weighted values f cosθi √w on ``rows`` (the cosine loss's residual of a model
    that reflects nothing): a cosine-loss error over it is the relative error in reflected radiance."""
    weights = np.ones(measurements.n) if measurements.weights is None else np.asarray(measurements.weights)
    scaled = (np.asarray(measurements.values)[rows] * (np.cos(np.asarray(measurements.theta_i)[rows])
                                                       * np.sqrt(weights[rows]))[:, None])
    return _rms(scaled)


def _implausible_where_measured(result: FitResult) -> str:
    """Why a fit is IMPLAUSIBLE (`FitResult.plausibility`: an albedo above 1 where the data were measured, or a
    ks·F above 1), in words; empty when no check says so."""
    return "; ".join(f"IMPLAUSIBLE {c.name}: {c.message}" for c in result.plausibility().implausible)


def _score(row: dict, criterion: str) -> float:
    """A row's score under ``criterion``: its held-out error for ``cv`` and ``heldout``, else its AIC or BIC."""
    return row["heldout_error"] if criterion in ("cv", "heldout") else row[criterion]


def _simplicity(row: dict) -> tuple:
    """The order of "simplest": fewest parameters, then the better score. Not the evaluation cost: ``cost_ns`` is a
    timing, and two candidates of a similar cost (GGX with Schlick's or a dielectric's Fresnel) would swap places
    from one run to the next."""
    return row["n_params"], row["score"]


def _simplest(rows: list[dict], eligible) -> dict:
    return min((r for r in rows if eligible(r)), key=_simplicity)


def _threshold(best: dict, criterion: str, margin: float) -> float:
    """The largest score within the criterion's margin of the best row's: ``heldout`` a relative margin on the
    held-out error, ``cv`` one standard error of the best's, ``aic``/``bic`` an additive margin."""
    if criterion == "heldout":
        return best["score"] * (1.0 + margin)
    if criterion == "cv":
        return best["score"] + (best["heldout_se"] if math.isfinite(best["heldout_se"]) else 0.0)
    return best["score"] + margin


@one_blas_thread()
def select(measurements, candidates=DEFAULT_CANDIDATES, criterion: str = "auto", *, loss: str = FIT.loss,
           margin: float | None = None, folds: int = 5, holdout: float = 0.2, scene=None,
           tolerance: float | None = None, scene_metric: str = "relative", reference: str = "data", seed: int = 0,
           screen: bool = True, plausible: bool = True, target: str | None = None, progress: bool = False,
           **fit_options) -> Selection:
    """Fit candidate models and choose the smallest one that is good enough.

    Arguments:
        measurements: `brdffit.Measurements`.
        candidates: spec strings (default `DEFAULT_CANDIDATES`).
        criterion: ``"auto"`` (default: `resolve_criterion`), ``"heldout"`` (the loss RMSE on the held-out rows
            of a fit to the others: prediction of unseen directions), ``"aic"``, ``"bic"`` or ``"cv"``
            (``folds``-fold cross-validated loss RMSE).
        loss: the fits' loss (same for all candidates, so scores compare).
        margin: ΔAIC/ΔBIC within which a simpler model is preferred (default 2), or for ``heldout`` the fraction
            of the best held-out error (default `HELDOUT_MARGIN`); ignored for ``cv``, which uses the
            one-standard-error rule.
        folds: folds of the ``cv`` criterion.
        holdout: fraction of samples held out (seeded): the ``heldout`` criterion's test rows, and each
            candidate's reported held-out error with ``aic``/``bic``.
        scene: a `brdffit.scene.Scene`: with ``tolerance``, choose the cheapest candidate whose error in the
            scene is at most ``tolerance``. Each candidate is judged at its best for the scene: fitted to the
            reference at the scene's directions (radiance-weighted cosine loss, starting from its full-data fit),
            then rendered in the scene and compared with the reference.
        tolerance: the scene tolerance, in the units of ``scene_metric``.
        scene_metric: ``"relative"`` (relative RMS radiance error), ``"max-relative"`` or ``"delta-e"`` (mean
            CIE ΔE*ab; 3 channels) (`brdffit.scene.scene_error`).
        reference: what a candidate's scene radiance is compared with: ``"data"`` (the measurements interpolated
            at the scene's directions, `brdffit.interpolation.interpolate`) or ``"best"`` (the best-scoring candidate).
        seed: seed of the held-out split, folds and fits.
        screen: with ``aic``/``bic``, fit every candidate to the training rows first (at most `SCREEN_SAMPLES` of
            them) and refit to all the data only the candidates that can still be chosen (docs/model-selection.md);
            False fits every candidate to all the data and again with the held-out rows masked.
        plausible: with ``heldout``, prefer plausible fits (`FitResult.plausibility` has no IMPLAUSIBLE check:
            albedo ≤ 1 over the measured incidences, ks·F ≤ 1): an implausible one is chosen only when no
            plausible one is within the margin, with a warning. With the other criteria, leave out fits that
            conserve energy where the data were measured but whose directional
            albedo exceeds `EXTRAPOLATION_ALBEDO` beyond the data's largest θi (`brdffit.plausibility.plausibility`)
            while a converged candidate remains; such a candidate's verdict says so.
        target: a renderer in `brdffit.export.FIT_TARGETS` (``"gltf"``, ``"mitsuba"``): its own models
            (`brdffit.export.Target.renders`, exact in it with every parameter in its ranges) join the
            candidates, and the choice is the best of them by the criterion's score; ``chosen_by_criterion`` stays
            the choice among all candidates, so that the summary shows what the renderer costs. Not with a scene.
        progress: show a progress line on stderr, one update per candidate (and per scene refit).
        **fit_options: passed to every `brdffit.fit` (solver, fixed, max_steps, ...).

    Returns:
        A `Selection`; ``.chosen`` is the chosen spec, ``.table`` the per-candidate rows.
    """
    measurements.check_informative()  # no information, no selection (named in the error)
    criterion = resolve_criterion(criterion, measurements)
    averaged = _channel_averages(measurements, fit_options) if scene is None and target is None else None
    if averaged is not None:
        selection = select(averaged, candidates, criterion, loss=loss, margin=margin, folds=folds,
                           holdout=holdout, seed=seed, screen=screen, plausible=plausible, progress=progress,
                           **fit_options)
        return _fitted_to_every_channel(selection, measurements, averaged, dict(loss=loss, seed=seed,
                                                                                **fit_options), holdout, seed)
    candidates = list(candidates)
    renders = target_models(target, scene)
    candidates += [spec for spec in renders if spec not in candidates]
    if not candidates:
        raise ValueError("select needs at least one candidate")
    if scene is not None and tolerance is None:
        raise ValueError("a scene needs a tolerance (e.g. tolerance=0.05 for a 5% relative radiance error)")
    if reference not in ("data", "best"):
        raise ValueError(f"reference must be 'data' or 'best', got {reference!r}")
    margin = (HELDOUT_MARGIN if criterion == "heldout" else DEFAULT_MARGIN) if margin is None else float(margin)
    rng, valid_rows, order = _shuffled_rows(measurements, seed)
    fold_rows = np.array_split(order, folds) if criterion == "cv" else [_held_out(order, holdout)]
    options = dict(loss=loss, seed=seed, **fit_options)
    train_rows = np.setdiff1d(valid_rows, fold_rows[0])
    screen = (screen and criterion != "cv") or criterion == "heldout"  # heldout: the screening fits are its test
    done: dict[str, FitResult] = {}
    warnings = []
    bar = Progress("select", len(candidates) * (2 if scene is not None else 1), enabled=progress, unit="fits")
    if screen:
        if len(train_rows) >= 2 * SCREEN_SAMPLES:  # a subsample of the training rows, in a smaller compiled shape
            seen = np.sort(rng.choice(train_rows, SCREEN_SAMPLES, replace=False))
            screen_data = measurements.take(seen)
        else:  # all the training rows, the held-out ones masked: the refits reuse the screening's programs
            seen, screen_data = train_rows, _masked(measurements, fold_rows[0])
        # heldout: the choice's refit begins on the first idle pool slot (`_refit_leader`)
        leader = functools.partial(_refit_leader, measurements=measurements, margin=margin, plausible=plausible,
                                   options=options) if criterion == "heldout" else None
        rows, screened, guess = _screened_rows(candidates, measurements, screen_data, seen, fold_rows[0], options,
                                               done, bar, when_idle=leader)
        if criterion != "heldout":
            _refit_contenders(rows, measurements, screened, criterion, margin, options, done, bar)
    else:
        rows, screened, guess = _fitted_rows(candidates, measurements, fold_rows, options, done, bar), None, None
    finite, usable = _scored(rows, criterion, warnings)
    implausible: dict[str, str] = {}
    if criterion == "heldout":
        best, threshold, chosen = _choose_by_heldout(usable, margin, plausible, done, implausible, warnings)
        if guess is not None and guess[0] == chosen["spec"]:
            done[chosen["spec"]] = guess[1]
        else:
            done[chosen["spec"]] = fit(measurements, chosen["spec"], init=done[chosen["spec"]].model, **options)
        chosen.update(_full_fit_fields(done[chosen["spec"]], train_error=False))
    else:
        best, threshold, chosen, usable = _choose_by_criterion(rows, usable, criterion, margin, plausible, done,
                                                               implausible, warnings, screened, measurements,
                                                               options, bar)
    for row in rows:
        row["verdict"] = _verdict(row, chosen, best, threshold, criterion, usable, implausible)
    for_target = None
    if renders:
        for_target = _choose_for_target(finite, renders, criterion, margin, measurements, screened, done, options,
                                        warnings)
        for_target["verdict"] = (f"chosen for {target}: the simplest of its models within the margin of their best "
                                 f"by the {criterion} score")
    by_scene, scene_results = None, {}
    if scene is not None:
        by_scene, scene_results = _choose_by_scene(scene, reference, tolerance, scene_metric, rows, usable, best,
                                                   measurements, done, fit_options, bar, warnings)
    final = by_scene or (for_target or chosen)["spec"]
    bar.close(f"chose {final}")
    return Selection(table=rows, chosen=final, criterion=criterion, margin=margin,
                     best=best["spec"], chosen_by_criterion=chosen["spec"], chosen_by_scene=by_scene,
                     results=done, warnings=warnings, scene_results=scene_results, holdout=holdout,
                     heldout_scale=_radiance_scale(measurements, fold_rows[0]) if loss == "cosine" else None,
                     target=target)


def _channel_averages(measurements, fit_options: dict):
    """The measurements averaged over `SCREEN_BANDS` groups of contiguous channels, where there are more channels
    than that and their shape is shared (the default channel mode, with no per-channel fixed value); else None.

    A group's value is the mean of its finite values (NaN where it has none), its σ that of the mean
    (√Σσ² / count), the weights the rows'. ``meta["averaged"]`` names each average's channels.
    """
    from .measurements import Measurements

    count = measurements.n_channels
    fixed = fit_options.get("fixed") or {}
    if count <= SCREEN_BANDS or fit_options.get("channel_mode", "shared-shape") != "shared-shape" \
            or any(np.size(value) > 1 for value in fixed.values()):
        return None
    groups = np.array_split(np.arange(count), SCREEN_BANDS)
    values = np.asarray(measurements.values, dtype=float)
    finite = np.isfinite(values)
    counts = np.stack([finite[:, g].sum(axis=1) for g in groups], axis=1)
    sums = np.stack([np.where(finite[:, g], values[:, g], 0.0).sum(axis=1) for g in groups], axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = np.where(counts > 0, sums / counts, np.nan)
        sigma = None
        if measurements.sigma is not None:
            s2 = np.asarray(measurements.sigma, dtype=float) ** 2
            sigma = np.stack([np.sqrt(np.where(finite[:, g], s2[:, g], 0.0).sum(axis=1)) for g in groups], axis=1)
            sigma = np.where(counts > 0, sigma / np.maximum(counts, 1), np.nan)
    names = [str(measurements.channels[g[0]]) + (f"–{measurements.channels[g[-1]]}" if len(g) > 1 else "")
             for g in groups]
    meta = {k: v for k, v in (measurements.meta or {}).items() if k != "wavelengths_nm"}
    meta["averaged"] = {name: [str(measurements.channels[k]) for k in g] for name, g in zip(names, groups)}
    return Measurements(measurements.theta_i, measurements.phi_i, measurements.theta_o, measurements.phi_o, means,
                        sigma=sigma, weights=measurements.weights, channels=names, meta=meta)


def _shuffled_rows(measurements, seed: int):
    """The selection's random order of the rows with a value: ``(rng, valid rows, their order)``; the held-out
    rows are the order's first ``holdout`` fraction (and, for ``cv``, its folds)."""
    rng = np.random.default_rng(seed)
    valid_rows = np.flatnonzero(np.any(np.isfinite(measurements.values), axis=1))
    return rng, valid_rows, rng.permutation(valid_rows)


def _held_out(order: np.ndarray, holdout: float) -> np.ndarray:
    """The rows a ``heldout`` (or screened AIC/BIC) selection holds out: the first ``holdout`` fraction of its
    random order (`_shuffled_rows`)."""
    return order[: int(round(holdout * len(order)))]


def _fitted_to_every_channel(selection: Selection, measurements, averaged, options: dict, holdout: float,
                             seed: int) -> Selection:
    """A selection made on channel averages (`_channel_averages`), with its chosen model fitted to every channel of
    ``measurements`` from the shape the averages gave it (the amplitudes solved per channel): first to the rows
    the comparison trained on, for its held-out error over every channel on the rows it held out, then from there
    to all the rows (the same compiled programs: the held-out rows are masked, not removed)."""
    held = _held_out(_shuffled_rows(averaged, seed)[2], holdout)
    chosen = selection.results[selection.chosen]
    specs = chosen.models[0].param_specs
    shape = {name: value for name, value in chosen.params.items() if not specs[name].colour}
    trained = fit(_masked(measurements, held), selection.chosen, init=shape, **options)
    every = _rms(_loss_residuals(trained, measurements)[0][held])
    scale = _radiance_scale(measurements, held) if trained.loss == "cosine" else None
    results = dict(selection.results)
    results[selection.chosen] = fit(measurements, selection.chosen, init=trained.model, **options)
    sizes = sorted({len(g) for g in averaged.meta["averaged"].values()})
    return dataclasses.replace(
        selection, results=results, channel_heldout=(every, scale),
        compared_on=f"{averaged.n_channels} averages of {'-'.join(str(k) for k in sizes)} of the "
                    f"{measurements.n_channels} channels")


def target_models(target: str | None, scene) -> tuple:
    """The models of a fit for ``target`` (`brdffit.export.Target.renders`); empty without a target."""
    if target is None:
        return ()
    from .export.registry import FIT_TARGETS, TARGETS

    if target not in FIT_TARGETS:
        raise ValueError(f"no fit can be made for {target!r}: the targets with models declared exact and in range "
                         f"are {', '.join(FIT_TARGETS)}")
    if scene is not None:
        raise ValueError("a selection for a target takes no scene")
    return TARGETS[target].renders


def _choose_for_target(finite, renders, criterion, margin, measurements, screened, done, options,
                       warnings) -> dict:
    """The row of the target's choice: the simplest of its models within the criterion's margin of their best
    (`_threshold`: its forms nest, a coat or a fuzz of weight 0 being the form without it), among the converged ones
    where there are any, its fit to all the data made where the row still holds a screening fit. A screening fit
    that ran out of steps is measured like any other (its held-out error is that of the values it reached) and
    continued by the full-data fit; a warning says so if that one does not converge either."""
    own = [r for r in finite if r["spec"] in renders]
    if not own:
        raise ValueError(f"none of the target's models ({', '.join(renders)}) produced a finite score")
    own = [r for r in own if Status(r["status"]).converged] or own  # an unconverged fit only where all are
    threshold = _threshold(min(own, key=lambda r: r["score"]), criterion, margin)
    row = _simplest(own, lambda r: r["score"] <= threshold)
    spec = row["spec"]
    if screened is not None and done[spec] is screened.get(spec):
        done[spec] = fit(measurements, spec, init=done[spec].model, **options)
        row.update(_full_fit_fields(done[spec], train_error=False))
    if not Status(row["status"]).converged:
        warnings.append(f"the target's choice {spec} ended {row['status']} (fitted to all the data from its "
                        "screening fit); its values are the best found, not an optimum")
    return row


def _choose_by_criterion(rows, usable, criterion, margin, plausible, done, implausible, warnings, screened,
                         measurements, options, bar):
    """The ``aic``/``bic``/``cv`` choice: the simplest candidate within the margin (``cv``: one standard error) of
    the best; a choice or a bar that extrapolates implausibly (`_implausibility`) is passed over while another
    converged candidate remains, and the candidates a lower bar brings back are refitted (`_refit_contenders`).

    Returns:
        ``(best, threshold, chosen, usable)``: the best row, the largest score within the margin, the chosen row
        and the rows still eligible.
    """
    while True:
        best = min(usable, key=lambda r: r["score"])
        threshold = _threshold(best, criterion, margin)
        chosen = _simplest(usable, lambda r: r["score"] <= threshold)
        # Nor is a fit plausible where the data are that reflects far more light than it receives beyond them
        # while another converged candidate remains: it would render wrong there (docs/model-selection.md). A fit
        # implausible where the data are is kept: the data may be in other units (their summary says so).
        # Checked lazily: the choice and the bar.
        found = {r["spec"]: _implausibility(done[r["spec"]]) for r in (best, chosen)
                 if plausible and r["spec"] not in implausible}
        found = {k: v for k, v in found.items() if v}
        if not found:
            break
        remaining = [r for r in usable if r["spec"] not in found]
        if not remaining:
            warnings.append("every converged candidate reflects more than EXTRAPOLATION_ALBEDO beyond the data's "
                            "angles (its summary says so): the choice is among them")
            break
        implausible.update(found)
        usable = remaining
        if screened is not None:  # a lower bar's candidates, ruled out by the screening, may now be within it
            _refit_contenders(rows, measurements, screened, criterion, margin, options, done, bar,
                              excluded=set(implausible))
            for row in rows:
                row["score"] = _score(row, criterion)
            usable = [r for r in rows if Status(r["status"]).converged and math.isfinite(r["score"])
                      and r["spec"] not in implausible] or usable
    return best, threshold, chosen, usable


def _choose_by_scene(scene, reference, tolerance, scene_metric, rows, usable, best, measurements, done,
                     fit_options, bar, warnings):
    """The choice by what a scene shows: every candidate refitted to the reference radiance at the scene's
    directions (the data interpolated, or the best fit's model), and the simplest usable one within
    ``tolerance`` of it in ``scene_metric``; else the closest, with a warning. Each row gets its ``scene_error``.

    Returns:
        ``(spec, scene_results)``: the chosen spec and each candidate's scene fit.
    """
    from .interpolation import interpolate
    from .scene import scene_error

    scene_results = {}
    if reference == "data":
        seen = interpolate(measurements, scene.wi, scene.wo)
    else:
        seen = np.asarray(evaluate_dirs(done[best["spec"]].model, scene.wi, scene.wo))
    ref = scene.radiance(seen)
    scene_data = _scene_measurements(scene, seen, measurements.channels)
    for i, row in enumerate(rows):
        bar.update(len(rows) + i, f"fitting {row['spec']} to the scene")
        # Each candidate at its best for what the scene sees: fitted to the reference at the scene's
        # directions (cosine loss with the light intensity as weight, i.e. the error in radiance), starting
        # from its full-data fit.
        scene_fit = fit(scene_data, row["spec"], init=done[row["spec"]].model, loss="cosine",
                        **{k: v for k, v in fit_options.items() if k != "loss"})
        scene_results[row["spec"]] = scene_fit
        row["scene_error"] = float(scene_error(scene.radiance_of(scene_fit.model), ref, scene_metric))
    within = [r for r in usable if r["scene_error"] <= tolerance]
    if within:
        return _simplest(within, lambda r: True)["spec"], scene_results
    closest = min(usable, key=lambda r: r["scene_error"])
    warnings.append(f"no candidate stays within the scene tolerance {tolerance:g} ({scene_metric}); "
                    f"the closest is {closest['spec']} ({closest['scene_error']:.4g})")
    return closest["spec"], scene_results


def _choose_by_heldout(usable, margin, plausible, done, implausible, warnings):
    """The ``heldout`` choice: the simplest plausible candidate whose held-out error is within ``margin`` (a
    fraction) of the best; ``implausible`` gets the reason of every candidate passed over as IMPLAUSIBLE, and
    ``warnings`` a line when nothing plausible is within the margin.

    Returns:
        ``(best, threshold, chosen)``: the best row, the largest error within the margin, the chosen row.
    """
    best = min(usable, key=lambda r: r["score"])
    threshold = _threshold(best, "heldout", margin)
    within = sorted((r for r in usable if r["score"] <= threshold), key=_simplicity)
    for row in within:
        why = _implausible_where_measured(done[row["spec"]]) if plausible else ""
        if not why:
            return best, threshold, row
        implausible[row["spec"]] = why
    chosen = within[0]
    others = [r for r in usable if r["spec"] not in implausible
              and not _implausible_where_measured(done[r["spec"]])]
    closest = (f"; the most accurate plausible candidate is {min(others, key=lambda r: r['score'])['spec']} "
               f"(held-out error {min(r['score'] for r in others):.4g} against {best['score']:.4g})"
               if others else "; no candidate is plausible")
    warnings.append(f"no plausible candidate predicts the held-out directions within {margin:.0%} of the best: "
                    f"{chosen['spec']} is chosen although IMPLAUSIBLE{closest}. No candidate model represents "
                    "these data at this amplitude (check their units, or fit a model with the lobe they need)")
    return best, threshold, chosen


def _scored(rows: list[dict], criterion: str, warnings: list) -> tuple[list, list]:
    """Give every row its ``score`` under ``criterion``; return the rows with a finite score and those of them
    that can be chosen: the converged ones (an unconverged fit's score says little about the model), or all of
    them, with a line in ``warnings``, when none converged.

    Raises:
        ValueError: no row has a finite score.
    """
    for row in rows:
        row["score"] = _score(row, criterion)
    finite = [r for r in rows if r["status"] != Status.NONFINITE and math.isfinite(r["score"])]
    if not finite:
        raise ValueError("no candidate produced a finite score; check the data and candidates")
    usable = [r for r in finite if Status(r["status"]).converged]
    if not usable:
        usable = finite
        warnings.append("no candidate's fit converged: the choice is among unconverged fits (raise max_steps, "
                        "or check the data)")
    return finite, usable


def _refit_leader(rows, screened, *, measurements, margin, plausible, options):
    """The ``heldout`` choice among the candidates screened so far, refitted to all the data from its screening
    fit, as ``(spec, FitResult)``: `select` runs it on the first pool slot that the screen leaves idle, and keeps the
    refit when the choice among all the candidates is the same (the same fit from the same start), else refits its
    choice as before (the guess then cost only that slot's time, and the wait for it). A guess that fails is no
    guess (None): the refit of the final choice, made as before, raises what it raises."""
    try:
        _, usable = _scored(rows, "heldout", [])
        _, _, leader = _choose_by_heldout(usable, margin, plausible, screened, {}, [])
        return leader["spec"], fit(measurements, leader["spec"], init=screened[leader["spec"]].model, **options)
    except Exception:  # noqa: BLE001 - see the docstring
        return None


def _full_fit_fields(result: FitResult, *, train_error: bool = True) -> dict:
    """A row's entries that a fit to all the data determines (``train_error=False`` keeps the row's training
    error, that of the fit its held-out error comes from)."""
    fields = {"aic": result.aic, "bic": result.bic, "status": result.status, "samples": result.n_samples}
    if train_error:
        fields["train_error"] = float(np.sqrt(result.cost / max(result.n_samples, 1)))
    return fields


def _fitted_rows(candidates, measurements, fold_rows, options, done, bar):
    """The table of an unscreened selection: every candidate fitted to all the data, and refitted with each fold
    of ``fold_rows`` held out for its held-out error."""
    def work(spec, init):
        result = fit(measurements, spec, init=init, **options)
        # The held-out fits start from the full-data optimum (same shapes, so the same compiled programs): the
        # training optimum lies within the held-out rows' influence of it, and the global search has been done.
        start = result.model if result.model is not None else init
        errors, timed = [], None
        for k, held in enumerate(fold_rows):
            r, evaluation = _loss_residuals(fit(_masked(measurements, held), spec, init=start, **options),
                                            measurements)
            timed = timed or evaluation  # the evaluation is timed once, on the first fold's program
            errors.append(_rms(r[held]))
        return result, errors, timed

    rows = []
    outputs, _ = _each_candidate(candidates, work, bar, lambda spec: f"fitting {spec}")
    for spec, (result, errors, timed) in zip(candidates, outputs):
        done[spec] = result
        rows.append({
            "spec": spec,
            "n_params": result.n_params,
            "heldout_error": float(np.mean(errors)),
            "heldout_se": float(np.std(errors, ddof=1) / np.sqrt(len(errors))) if len(errors) > 1 else math.nan,
            "cost_ns": _cost_ns(timed),
            **_full_fit_fields(result),
        })
    return rows


def _screened_rows(candidates, measurements, screen_data, seen, held, options, done, bar, when_idle=None):
    """The table of a screened selection: every candidate fitted to ``screen_data`` (training rows only: a
    subsample, or all the data with the held-out rows masked) and scored on all the data at that fit.

    A row's ``train_error`` and ``heldout_error`` are its screening fit's error on the rows it was fitted to
    (``seen``) and on the held-out rows ``held``, which that fit never saw; ``aic``/``bic``/``status``/``samples``
    are those of the reported fit (``done[spec]``): the full-data fit where one is made later
    (`_refit_contenders`, or the ``heldout`` criterion's choice), else the screening fit scored on all the data.

    Arguments:
        when_idle: ``when_idle(rows, results)`` of the candidates screened by the time a pool slot falls idle
            (`_each_candidate`): their rows (without ``cost_ns``) and screening fits.

    Returns:
        ``(rows, screened, guess)``: the table, the screening fits by spec and ``when_idle``'s return (None without
        it).
    """
    screened: dict[str, FitResult] = {}
    n_values = int(np.isfinite(measurements.values).sum())
    training = int(np.any(np.isfinite(screen_data.values), axis=1).sum())
    # The screen is the coarse stage of a two-stage fit (`brdffit.fitting.api`), with its tolerances and solver: it
    # ranks the candidates, and whatever is reported as a fit is refitted from it to all the data at the caller's.
    # It does not search each sub-lobe again (`brdffit.fit`'s ``lobe_search``): on the RGL-EPFL paper that second
    # search, and the hold rounds of the lower optimum it found, made the default fit 1.5 times as long.
    loose = dict(options, rtol=max(COARSE_RTOL, options.get("rtol", 0.0)),
                 atol=max(COARSE_ATOL, options.get("atol", 0.0)), lobe_search=False)
    solver = options.get("solver", FIT.solver)
    if isinstance(solver, str):
        loose["solver"] = coarse_solver(solver, loose["rtol"], loose["atol"])

    def work(spec, init):
        result = fit(screen_data, spec, init=init, **loose)
        return (result,) + _loss_residuals(result, measurements)

    def row(spec, result, r):
        aic, bic = information_criteria(result.loss, float(np.nansum(r ** 2)), n_values, result.n_params)
        return {"spec": spec, "n_params": result.n_params, "train_error": _rms(r[seen]),
                "heldout_error": _rms(r[held]), "heldout_se": math.nan, "aic": aic, "bic": bic,
                "status": result.status, "samples": result.n_samples}

    def idle(finished):
        return when_idle([row(spec, result, r) for spec, (result, r, _) in finished.items()],
                         {spec: output[0] for spec, output in finished.items()})

    outputs, guess = _each_candidate(candidates, work, bar, lambda spec: f"screening {spec} on {training} samples",
                                     when_idle=None if when_idle is None else idle)
    rows = []
    for spec, (result, r, evaluation) in zip(candidates, outputs):
        screened[spec] = done[spec] = result
        rows.append(dict(row(spec, result, r), cost_ns=_cost_ns(evaluation)))
    return rows, screened, guess


def _refit_contenders(rows, measurements, screened, criterion, margin, options, done, bar, excluded=()):
    """Refit to all the data, from their screening fits, the screened candidates that can still come within the
    margin of the best eligible one (a converged fit not in ``excluded``), until none is left; a refitted row
    gets its full-data fields and ``done`` its full-data fit (a row whose ``done`` entry is still its screening
    fit has not been refitted)."""
    n_values = int(np.isfinite(measurements.values).sum())
    finite = [r for r in rows if r["status"] != Status.NONFINITE and math.isfinite(r[criterion])]
    while finite:
        # The best that can be chosen: a converged fit's score (a refit that ended unconverged is no longer the
        # bar, and the candidates it had ruled out are measured against the next best).
        eligible = [r for r in finite if Status(r["status"]).converged and r["spec"] not in excluded] or finite
        best = min(r[criterion] for r in eligible)
        todo = [row for row in finite if done[row["spec"]] is screened[row["spec"]] and row["spec"] not in excluded
                and row[criterion] - SCREEN_SLACK * row["n_params"] * n_values
                / max(screened[row["spec"]].n_samples, 1) <= best + margin]
        if not todo:  # the others cannot come within the margin of the best, even fitted to all the data
            return
        with ThreadPoolExecutor(max_workers=SELECT_THREADS) as pool:
            futures = [pool.submit(fit, measurements, row["spec"], init=screened[row["spec"]].model, **options)
                       for row in todo]
            for row, future in zip(todo, futures):
                bar.update(len(rows) - 1, f"fitting {row['spec']} to all {measurements.n} samples")
                done[row["spec"]] = future.result()
                row.update(_full_fit_fields(done[row["spec"]], train_error=False))


def _scene_measurements(scene, values, channels):
    """Measurements at a scene's rows: the reference BRDF values, weighted by the squared light intensity so
    that the cosine loss is the radiance error; rows whose view lies below the horizon are left out."""
    from .geometry import vector_to_spherical
    from .measurements import Measurements

    keep = (scene.wi[:, 2] > 0) & (scene.wo[:, 2] > 0) & np.all(np.isfinite(values), axis=1)
    theta_i, phi_i = (np.asarray(a) for a in vector_to_spherical(scene.wi[keep]))
    theta_o, phi_o = (np.asarray(a) for a in vector_to_spherical(scene.wo[keep]))
    return Measurements(theta_i, phi_i, theta_o, phi_o, np.maximum(values[keep], 0.0),
                        weights=np.asarray(scene.intensity, dtype=float)[keep] ** 2, channels=channels,
                        meta={"source": f"scene {scene.name}"})
