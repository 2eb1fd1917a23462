"""Assemble a fit report: the figures, ``report.md`` and a self-contained ``report.html``.

The report's content is built once as a list of blocks (headings, paragraphs, tables, figures, lists) and then
written twice: as Markdown (figures as relative links to the PNGs) and as one HTML file with inline CSS and the
PNGs embedded as base64 ``data:`` URIs, so that it can be mailed or archived alone. docs/report.md describes it.
"""

from __future__ import annotations

import base64
import datetime
import html
import math
import os
import platform
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from ..export.records import ExportLog
from ..output_folder import FOLDER
from ..io._common import atomic_path
from . import figures as F

__all__ = ["write_report", "format_value"]


def format_value(x, digits: int = 6) -> str:
    """How the report writes a number: ``digits`` significant digits (``%g``), "–" for None/NaN."""
    if x is None:
        return "–"
    x = float(x)
    return "–" if not math.isfinite(x) and not math.isinf(x) else f"{x:.{digits}g}"


def _flat(params: dict) -> list[tuple[str, str, float]]:
    rows = []
    for name, value in params.items():
        value = np.asarray(value, dtype=float)
        if value.ndim == 0:
            rows.append((name, name, float(value)))
        else:
            rows.extend((f"{name}[{i}]", name, float(v)) for i, v in enumerate(value.ravel()))
    return rows


def _flat_stderr(stderr: dict) -> dict:
    return {label: v for label, _, v in _flat(stderr)}


_KIND = {"laplace": "Laplace", "sandwich": "sandwich", "noise-model": "noise-model"}


def _other_stderr(fit_result) -> tuple[str, dict]:
    """The standard error shown beside the default: the sandwich, which assumes no noise model, or the Laplace
    where the sandwich is the default."""
    if fit_result.stderr_kind == "sandwich":
        return "laplace", fit_result.stderr_laplace
    return "sandwich", fit_result.stderr_robust


# --------------------------------------------------------------------------------------------- content
def _parameter_table(fit_result, posterior):
    specs = fit_result.models[0].param_specs
    errors = _flat_stderr(fit_result.stderr)
    other_kind, other = _other_stderr(fit_result)
    others = _flat_stderr(other)
    kind = _KIND.get(fit_result.stderr_kind, fit_result.stderr_kind)
    headers = ["parameter", "least squares", f"± stderr ({kind})", f"± {_KIND[other_kind]}"]
    if posterior is not None:
        headers += ["posterior median", "68 % interval", "95 % interval"]
    headers += ["unit", "bounds", "note"]
    rows = []
    for label, name, value in _flat(fit_result.params):
        spec = specs[name]
        row = [label, format_value(value), format_value(errors.get(label), 3), format_value(others.get(label), 3)]
        if posterior is not None:
            s = posterior.summary.get(label)
            if s is None:
                row += ["–", "–", "–"]
            else:
                row += [format_value(s["median"]), f"[{format_value(s['q16'])}, {format_value(s['q84'])}]",
                        f"[{format_value(s['q2.5'])}, {format_value(s['q97.5'])}]"]
        note = "fixed" if name in fit_result.fixed else ("AT BOUND" if label in fit_result.bounds_hit else "")
        row += [spec.unit, f"[{spec.lower:g}, {spec.upper:g}]", note]
        rows.append(row)
    if posterior is not None:  # the sampled noise scales have no least-squares value
        for label in posterior.names:
            if label.startswith("noise_sigma"):
                s = posterior.summary[label]
                rows.append([label, "–", "–", "–", format_value(s["median"]),
                             f"[{format_value(s['q16'])}, {format_value(s['q84'])}]",
                             f"[{format_value(s['q2.5'])}, {format_value(s['q97.5'])}]",
                             f"{fit_result.loss}-loss residual units", "(0, inf)", "noise scale"])
    return headers, rows


def _metrics_table(fit_result, channels):
    headers = ["metric"] + [f"channel {c}" for c in channels]
    rows = []
    for name, values in fit_result.metrics.items():
        values = np.atleast_1d(np.asarray(values, dtype=float))
        rows.append([name] + [format_value(v, 4) for v in values] + ["–"] * (len(channels) - len(values)))
    return headers, rows


def _cell(v) -> str:
    """A selection-table cell: counts and text as they are, every other number (a Python, NumPy or JAX scalar, so
    that the chosen fit's own AIC reads like the others') with 5 significant digits, "–" when missing."""
    if v is None or isinstance(v, (str, bool, int, np.integer)):
        return "–" if v is None else str(v)
    try:
        return format_value(float(v), 5)
    except (TypeError, ValueError):
        return str(v)


def _selection_table(selection):
    keys = ["spec", "n_params", "samples", "train_error", "heldout_error", "heldout_se", "aic", "bic", "cost_ns",
            "status"]
    if any("scene_error" in row for row in selection.table):
        keys.insert(-1, "scene_error")
    # A column no candidate has a value in (heldout_se of an AIC/BIC selection, which holds out no folds) is left out.
    keys = [k for k in keys if k == "spec" or any(_cell(row.get(k)) != "–" for row in selection.table)]
    rows = []
    for row in selection.table:
        cells = [_cell(row.get(k)) for k in keys]
        if row["spec"] == selection.chosen:
            cells[0] = f"**{cells[0]} (chosen)**"  # closed, so that Markdown viewers bold it too
        rows.append(cells)
    return ["candidate"] + keys[1:], rows


def _noise_blocks(fit_result) -> list:
    """The noise-model section: what the residuals chose, which standard error follows, and every candidate."""
    from ..fitting.noise import NOISE_FORMULAS

    noise = fit_result.noise_model
    blocks = [("h2", "Noise model")]
    if noise is None:
        text = ("The noise model was chosen channel by channel and is not recorded in this merged result; each "
                "channel's standard errors follow its own choice." if fit_result.channel_mode == "independent"
                else "The noise model was not recorded (a result written before noise models were compared); the "
                     "standard errors are Laplace.")
        return blocks + [("p", text)]
    blocks += [("p", line) for line in noise.describe(fit_result.loss)]
    gaps = noise.aic_gap()
    rows = []
    for name, ll in sorted(noise.loglik.items(), key=lambda kv: -kv[1]):
        label = f"**{name} (chosen)**" if name == noise.name else name
        if name == noise.loss_model:
            label += " (the loss's own)"
        rows.append([label, NOISE_FORMULAS[name], ", ".join(format_value(x, 3) for x in noise.scale[name]),
                     format_value(ll, 7), format_value(gaps[name], 4)])
    return blocks + [("table", ["noise", "σ", "s per channel", "log-likelihood", "ΔAIC"], rows)]


def _plausibility_blocks(fit_result) -> list:
    """The plausibility section: one row per check with what to do."""
    checks = fit_result.plausibility().checks
    tag = {"ok": "plausible", "caution": "caution", "implausible": "**IMPLAUSIBLE**"}
    rows = [[c.name, tag[c.level], c.message, c.advice or "–"] for c in checks]
    return [("h2", "Plausibility"), ("table", ["check", "verdict", "measured", "what to do"], rows)]


def _renderer_table(fit_result, recorded, wavelengths=None):
    """One row per renderer target for ``fit_result`` (or a `Model`): the direct mapping's verdict with its
    measured deviation (3 significant digits, as the export's comments state it) or the reason it has none, then
    the fit-option exports of this fit in ``recorded`` (`brdffit.export.records.ExportRecord`) with their achieved
    error. A spectral fit (``wavelengths``, nm) is exported as its sRGB model, as `brdffit export` does."""
    from ..export import TARGETS, ExportError, export_details

    rows = []
    for target in (t for t in TARGETS.values() if t.renderer):
        try:
            direct = export_details(fit_result, target.name, wavelengths=wavelengths)
        except ExportError as exc:
            rows.append([target.name, "direct", "no equivalent", "–", "–", str(exc)])
        else:
            rows.append([target.name, "direct", "exact" if direct.exact else "approximate",
                         format_value(direct.deviation.rms, 3), format_value(direct.deviation.max_rel, 3),
                         "; ".join(direct.notes) or "–"])
        for r in (r for r in recorded if r.target == target.name):
            verdict = f"fitted {r.written}" if r.fitted else "exact" if r.exact else "approximate"
            notes = [f"written to {r.out}" if r.out else "printed"] + ([r.fitted] if r.fitted else [])
            rows.append([target.name, f"--fit, {r.date}", verdict, format_value(r.rms, 3), format_value(r.max_rel, 3),
                         "; ".join(notes + list(r.approximations))])
    return ["renderer", "export", "verdict", "cosine-weighted relative RMS", "largest relative error",
            "approximations and notes"], rows


def _renderer_blocks(fit_result, exports: ExportLog, wavelengths=None) -> list:
    """The renderer-exports section (docs/report.md), with the exports recorded for this fit (a spectral fit's, of
    its sRGB model: ``wavelengths``)."""
    exported = fit_result.model
    if wavelengths is not None and exported is not None:  # `brdffit export` wrote (and recorded) the sRGB model
        from ..colour import ColourError, rgb_model

        try:
            exported = rgb_model(exported, wavelengths)[0]
        except ColourError:
            pass
    recorded = exports.for_model(exported)
    blocks = [("h2", "Renderer exports"),
              ("p", "How this fit is written for each renderer `brdffit export RESULT.h5 --to T` writes to "
                    "(docs/export.md). **direct**: the mapping onto the renderer's own plugins, exact or with the "
                    "approximations it makes and the measured deviation of what it writes from the fit: the "
                    "cosine-weighted relative RMS error over both hemispheres and the largest relative error, as "
                    "the export's comments state them; a model with a lobe the renderer has no equivalent for has "
                    "none, and `brdffit export RESULT.h5 --to T --fit` fits the renderer's own model to it. "
                    "**--fit**: the fit option's exports of this fit recorded in exports.json beside result.h5, "
                    "with their achieved error."),
              ("table",) + _renderer_table(fit_result, recorded, wavelengths)]
    others = len(exports.records) - len(recorded)
    if others:
        blocks.append(("p", f"{exports.path} also records {others} export{'s' if others > 1 else ''} of another "
                            "fit (another model or other parameter values), not shown."))
    if exports.problem:
        blocks.append(("p", "The recorded exports could not be read and are not shown (see Warnings)."))
    return blocks


def _run_info(run_info) -> list[str]:
    import jax

    from .. import __version__

    info = {"brdffit": __version__, "jax": jax.__version__, "numpy": np.__version__,
            "python": platform.python_version(), "platform": platform.platform(),
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "command": " ".join(sys.argv) if sys.argv and sys.argv[0] else "–", "seed": "–"}
    info.update({k: v for k, v in (run_info or {}).items() if v is not None})
    return [f"{k}: {v}" for k, v in info.items()]


def _blocks(measurements, fit_result, posterior, selection, run_info, figure_paths, report_warnings=(),
            exports=ExportLog(None)):
    b = [("h1", f"BRDF fit report: {fit_result.spec}")]
    if selection is not None:  # the answer to "is this good?" first
        b.extend(("p", "**" + line + "**" if i == 0 else line) for i, line in enumerate(selection.verdict().split("\n")))
    b.append(("p", f"{measurements.n} samples × {measurements.n_channels} channels "
                   f"({', '.join(map(str, measurements.channels))}); loss {fit_result.loss}, solver "
                   f"{fit_result.solver}, channel mode {fit_result.channel_mode}; status **{fit_result.status}** "
                   f"after {fit_result.steps} steps."))
    b.append(("h2", "Parameters"))
    kind = _KIND.get(fit_result.stderr_kind, fit_result.stderr_kind)
    b.append(("p", f"Least-squares values with the standard errors the noise model supports ({kind}; see Noise "
                   "model) and the other kind beside them"
                   + ("; posterior medians and central 68 % / 95 % credible intervals from the MCMC samples"
                      if posterior is not None else "") + ". f_r is in 1/sr; unit 1 means dimensionless."))
    b.append(("table",) + _parameter_table(fit_result, posterior))
    if fit_result.bounds_hit:
        b.append(("p", "Parameters on a bound: " + ", ".join(fit_result.bounds_hit) + "."))
    b.extend(_noise_blocks(fit_result))
    b.extend(_plausibility_blocks(fit_result))
    b.append(("h2", "Fit metrics"))
    b.append(("table",) + _metrics_table(fit_result, measurements.channels))
    b.append(("p", f"samples {fit_result.n_samples}, free parameters {fit_result.n_params}, dof {fit_result.dof}, "
                   f"cost {format_value(fit_result.cost)}, AIC {format_value(fit_result.aic)}, "
                   f"BIC {format_value(fit_result.bic)}; compile {fit_result.compile_time:.2f} s, run "
                   f"{fit_result.run_time:.2f} s."))
    if posterior is not None:
        d = posterior.diagnostics
        b.append(("h2", "Posterior sampling"))
        b.append(("p", f"{d.get('walkers')} walkers × {d.get('steps')} steps, burn-in {posterior.burn}, thin "
                       f"{posterior.thin}, {len(posterior.samples)} samples kept; likelihood {posterior.likelihood}, "
                       f"noise {posterior.noise}; acceptance fraction {format_value(d.get('acceptance_fraction'), 3)}, "
                       f"max autocorrelation time {format_value(d.get('tau_max'), 3)} steps, min effective sample "
                       f"size {format_value(d.get('ess_min'), 3)}, max split R-hat "
                       f"{format_value(d.get('r_hat_max'), 4)}."))
    if selection is not None:
        b.append(("h2", "Model selection"))
        b.append(("p", f"criterion {selection.criterion}; best {selection.best}; chosen **{selection.chosen}**."))
        b.append(("table",) + _selection_table(selection))
    wavelengths = F.spectral_axis(measurements, fit_result.model.channels) if fit_result.model is not None else None
    b.extend(_renderer_blocks(fit_result, exports, None if wavelengths is None else list(wavelengths)))
    warnings = list(fit_result.warnings) + [f"posterior: {w}" for w in (posterior.warnings if posterior else [])] \
        + [f"selection: {w}" for w in (selection.warnings if selection else [])] + list(report_warnings)
    b.append(("h2", "Warnings"))
    b.append(("list", warnings) if warnings else ("p", "None."))
    b.append(("h2", "Figures"))
    for path, caption in figure_paths:
        b.append(("figure", path, caption))
    b.append(("h2", "Run information"))
    b.append(("list", _run_info(run_info)))
    return b


_CAPTIONS = {
    "slices": "In-plane slices: measured samples near the plane of incidence (circles) and the fitted model "
              "(lines) against the signed outgoing angle, log scale.",
    "hemisphere": "The fitted model times cosθo over the outgoing hemisphere (orthographic projection).",
    "residuals": "Relative residual (model − data)/data averaged in bins of the half and difference angles.",
    "corner": "Corner plot of the posterior samples.",
    "traces": "Walker traces with the integrated autocorrelation time of each parameter.",
    "albedo": "Directional albedo of the fitted model against the incidence angle (for a model that is not "
              "reciprocal, a renderer's layered material, its albedo at each view against the viewing angle, as its "
              "plausibility check judges it); a passive surface stays at or below 1 (dashed line).",
    "spheres": "Sphere previews: the measurement (interpolated), the fit and their relative difference. Rings and "
               "speckle in the difference come from interpolating scattered samples (k nearest neighbours), not "
               "necessarily from the fit. Spectral data are rendered band by band and shown in sRGB (CIE 1931 XYZ "
               "under D65, brdffit.colour); the difference compares their luminance Y.",
    "spectra": "The fitted amplitudes of a spectral measurement against wavelength, with their ±1 and ±2 standard "
               "error bands.",
    "renderer": "The renderer's view: the measurement, the best model without the renderer's limits and the fit "
                "made for the renderer (its models, every parameter in its ranges), each with its error on the "
                "held-out directions of the selection.",
}


def _captions(posterior, albedo_max: float) -> dict:
    """The figure captions, saying only what the figures show: posterior bands only when a posterior was run, the
    albedo limit broken when the fit breaks it."""
    captions = dict(_CAPTIONS)
    if posterior is not None:
        captions["slices"] += " Shaded: posterior 68 % / 95 % bands."
    if albedo_max > 1.0:
        captions["albedo"] += f" This fit exceeds it: max {albedo_max:.3f} (see Warnings)."
    return captions


def _albedo_warnings(albedo: np.ndarray, channels) -> list[str]:
    """A warning per channel whose directional albedo exceeds 1 (the model reflects more than it receives)."""
    peaks = np.nanmax(albedo, axis=0)
    return [f"the fitted model's directional albedo in channel {name} reaches {peak:.3f} > 1: it reflects more "
            "energy than it receives (not energy-conserving), e.g. a specular amplitude fitted too high"
            for name, peak in zip(channels, peaks) if peak > 1.0]


# ---------------------------------------------------------------------------------------------- writers
def _markdown_table(headers, rows) -> list[str]:
    def cell(x):
        return str(x).replace("|", "\\|")

    lines = ["| " + " | ".join(cell(h) for h in headers) + " |", "|" + "---|" * len(headers)]
    lines += ["| " + " | ".join(cell(x) for x in row) + " |" for row in rows]
    return lines


def _to_markdown(blocks, out_dir: Path) -> str:
    lines = []
    for block in blocks:
        kind = block[0]
        if kind == "h1":
            lines += [f"# {block[1]}", ""]
        elif kind == "h2":
            lines += [f"## {block[1]}", ""]
        elif kind == "p":
            lines += [block[1], ""]
        elif kind == "list":
            lines += [f"- {item}" for item in block[1]] + [""]
        elif kind == "table":
            lines += _markdown_table(block[1], block[2]) + [""]
        elif kind == "figure":
            rel = os.path.relpath(block[1], out_dir)
            lines += [f"![{block[2]}]({rel})", "", f"*{block[2]}*", ""]
    return "\n".join(lines)


def _inline(text: str) -> str:
    """HTML for a paragraph: escaped, with ``**bold**`` kept."""
    parts = html.escape(text).split("**")
    return "".join(f"<b>{p}</b>" if i % 2 else p for i, p in enumerate(parts))


_CSS = """
body{font-family:system-ui,Helvetica,Arial,sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}
h1{border-bottom:2px solid #444}h2{border-bottom:1px solid #bbb;margin-top:1.6em}
table{border-collapse:collapse;margin:.6em 0;font-size:.92em}
th,td{border:1px solid #ccc;padding:.25em .6em;text-align:right}th{background:#f0f0f0}
td:first-child,th:first-child{text-align:left}tr:nth-child(even){background:#fafafa}
figure{margin:1.2em 0}figure img{max-width:100%;border:1px solid #ddd}figcaption{font-size:.9em;color:#555}
"""


def _to_html(blocks) -> str:
    body = []
    title = "BRDF fit report"
    for block in blocks:
        kind = block[0]
        if kind == "h1":
            title = block[1]
            body.append(f"<h1>{html.escape(block[1])}</h1>")
        elif kind == "h2":
            body.append(f"<h2>{html.escape(block[1])}</h2>")
        elif kind == "p":
            body.append(f"<p>{_inline(block[1])}</p>")
        elif kind == "list":
            body.append("<ul>" + "".join(f"<li>{_inline(str(i))}</li>" for i in block[1]) + "</ul>")
        elif kind == "table":
            head = "".join(f"<th>{html.escape(str(h))}</th>" for h in block[1])
            rows = "".join("<tr>" + "".join(f"<td>{_inline(str(x))}</td>" for x in row) + "</tr>"
                           for row in block[2])
            body.append(f"<table><thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>")
        elif kind == "figure":
            data = base64.b64encode(Path(block[1]).read_bytes()).decode("ascii")
            caption = html.escape(block[2])
            body.append(f'<figure><img alt="{caption}" src="data:image/png;base64,{data}">'
                        f"<figcaption>{caption}</figcaption></figure>")
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>\n"
            + "\n".join(body) + "\n</body></html>\n")


def _write_text(path: Path, text: str) -> None:
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text, encoding="utf-8")


# The figures queued for a `brdffit.report.worker.DrawingWorker`, where the report has one: about half of the drawing
# time of a fit's report (the slices take a third of it, the residuals and the albedo curve a quarter together), the
# other half being drawn here meanwhile; those the worker has not taken by then are drawn here too.
HANDED = frozenset({"slices", "residuals", "albedo"})


# ------------------------------------------------------------------------------------------------- API
def write_report(out_dir, measurements, fit_result, *, posterior=None, selection=None, run_info=None,
                 exports=None, worker=None) -> dict:
    """Write a fit report into ``out_dir``: the figures (PNG), ``report.md`` and a self-contained ``report.html``.

    Arguments:
        out_dir: the folder (created when missing); existing files of the same names are replaced atomically.
        measurements: the `Measurements` that were fitted.
        fit_result: the `FitResult`.
        posterior: an optional `Posterior` of that fit: adds the posterior columns of the parameter table, the
            bands of the slices, the corner and the trace plots.
        selection: an optional `Selection`: adds the model-selection table.
        run_info: optional dict of run information (``command``, ``seed``, ``date``, anything else); versions of
            brdffit, JAX, NumPy and Python, the date and the command line are filled in when not given.
        exports: the `brdffit.export.records.ExportLog` of the results file the fit was read from
            (`brdffit.export.records.read`): the renderer-exports section then also shows the fit option's
            recorded exports of this fit with their achieved error, and a log that could not be read is named
            under Warnings. Without it, the section shows the direct mappings only.
        worker: an optional `brdffit.report.worker.DrawingWorker` (started earlier, so that its imports are done):
            the figures of `HANDED` are queued for it while this process computes and draws the others (those it
            has not taken by then are drawn here).

    Returns:
        ``{"html": path, "md": path, "figures": [paths]}`` (strings).
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    channels = measurements.channels
    # The albedo curve's quadrature (compiled, and run by XLA outside Python's lock) in a thread of its own while the
    # figures before it are drawn (matplotlib, in Python): with an empty cache its compilation was a sizeable share
    # of a first report's time.
    pool = ThreadPoolExecutor(max_workers=1)
    curve = pool.submit(F.albedo_curve, fit_result)
    pool.shutdown(wait=False)  # the curve is computed all the same; `curve.result()` waits for it
    jobs = [
        ("slices", lambda: F.slices_drawing(measurements, fit_result, posterior)),
        ("hemisphere", lambda: F.hemisphere_drawing(fit_result, channels=channels)),
        ("residuals", lambda: F.residual_drawing(measurements, fit_result)),
    ]
    if posterior is not None:
        jobs += [("corner", lambda: lambda p: F.plot_corner(p, posterior, fit_result)),
                 ("traces", lambda: lambda p: F.plot_traces(p, posterior, fit_result))]
    jobs += [("albedo", lambda: F.albedo_drawing(fit_result, channels=channels, albedo=curve.result())),
             ("spheres", lambda: F.spheres_drawing(measurements, fit_result))]
    wavelengths = F.spectral_axis(measurements, fit_result.models[0].channels) \
        if fit_result.channel_mode != "independent" else None
    if wavelengths is not None and F.spectral_parameters(fit_result):  # with every amplitude fixed, no panel
        jobs.append(("spectra", lambda: lambda p: F.plot_spectra(p, fit_result, wavelengths)))
    if selection is not None and selection.target and selection.chosen_by_criterion != selection.chosen:
        rows = {row["spec"]: row for row in selection.table}
        free = selection.results[selection.chosen_by_criterion]
        errors = (rows[selection.chosen_by_criterion]["heldout_error"], rows[selection.chosen]["heldout_error"])
        jobs.append(("renderer", lambda: F.renderer_drawing(measurements, free, fit_result, selection.target,
                                                            errors)))
    drawn = []
    with F.drawing_style():
        for name, make in jobs:  # each gives a `Drawing`, or a function that draws the figure
            path = out / f"{name}.png"
            drawing = make()
            if worker is not None and name in HANDED:
                worker.send(path, drawing)
            else:
                drawing(path)
            drawn.append((name, str(path)))
    if worker is not None:
        worker.finish()
    albedo = curve.result()
    captions = _captions(posterior, float(np.nanmax(albedo)))
    figure_paths = [(path, captions[name]) for name, path in drawn]
    exports = exports if exports is not None else ExportLog(None)
    problems = [exports.problem] if exports.problem else []
    blocks = _blocks(measurements, fit_result, posterior, selection, run_info, figure_paths,
                     _albedo_warnings(albedo, channels) + problems, exports)
    md_path, html_path = out / FOLDER.report_md, out / FOLDER.report_html
    _write_text(md_path, _to_markdown(blocks, out))
    _write_text(html_path, _to_html(blocks))
    return {"html": str(html_path), "md": str(md_path), "figures": [p for p, _ in figure_paths]}
