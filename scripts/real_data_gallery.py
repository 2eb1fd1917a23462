"""Regenerate docs/real-data.md: the default fit of every shared real material, checked on data it never saw.

For each material of ``../shared/data`` (NIST PTFE at each wavelength of its CSV, the five RGL-EPFL ``.bsdf``
files, the ALTA retro-reflective tape) this runs exactly what a user runs, ``brdffit fit FILE`` with no fit options
(the table options only where the file needs them to be read), as a subprocess with an empty compilation cache, and
times it. From its output folder it takes the chosen fit and the selection table, then measures:

- the held-out (test) error on directions the fit did not use, cosine-weighted (‖(f_m − f_d) cosθi‖ / ‖f_d cosθi‖)
  and relative (RMS and median of |f_m − f_d| / f_d over f_d > 0):
  RGL-EPFL: the default fit against the file's own interpolation (`RglTable.lookup`, ``negative="clip"``) at
  `TEST_PAIRS` direction pairs uniform in solid angle with θi, θo <= 80° (`reference_fit.uniform_pairs` with
  ``default_rng(TEST_SEED)``; the default fit draws its own quasi-random pairs from the file, never these);
  tables and ALTA: the chosen model refitted to the training rows of the selection's own split (NumPy
  ``default_rng(SPLIT_SEED).permutation`` of the valid rows, the first `SPLIT_FRACTION` held out, as
  `brdffit.select` draws it), starting from the default fit's values, and scored on the held-out rows;
- the same error of the independent reference fitter (scripts/reference_fit.py, NumPy/SciPy only: the best of
  Lambert + {GGX, Cook-Torrance, Blinn-Phong, Ward}), fitted to training data disjoint from the test data
  (RGL-EPFL: the protocol's `reference_fit.TRAIN_PAIRS` pairs of ``default_rng(reference_fit.TRAIN_SEED)``;
  tables: the same training rows) and scored on the same test pairs or rows, and the ratio default / reference,
  against the accuracy target (ratio <= `TARGET_EACH` on every material, median <= `TARGET_MEDIAN`); for RGL-EPFL
  also the issue's protocol figure on `reference_fit.TEST_PAIRS` pairs of ``default_rng(TEST_SEED)`` and its
  spread over `SPREAD_SEEDS` seeds;
- the Mitsuba 3 export of the default fit (`brdffit.export.export_details`, ``fit=True`` only where a lobe has no
  Mitsuba equivalent), loaded with ``mitsuba.load_string``, its stated deviation, and what Mitsuba evaluates
  against the held-out data;
- pictures: in-plane slices (`brdffit.report.figures.plot_slices`) and sphere previews, measured beside fitted.

It writes ``docs/real-data/gallery.json`` (every number), ``docs/real-data/fits/<name>.h5`` (the fits:
``default``, and ``train`` for the split materials; no measurements), ``docs/real-data/fits/<name>.xml`` (the Mitsuba
export), ``docs/images/real-data/<name>-{slices,spheres}.png`` and ``docs/real-data.md``. tests/test_real_data.py
checks the stored fits against the shared files.

Usage (from the project root; 14-30 min for the ten rows on the 2-core development machine shared with other jobs,
at load averages 3-10)::

    .venv/bin/python scripts/real_data_gallery.py                 # every material
    .venv/bin/python scripts/real_data_gallery.py --only paper_white ptfe-0.532um   # some, the others kept
    .venv/bin/python scripts/real_data_gallery.py --markdown-only  # docs/real-data.md from gallery.json
    .venv/bin/python scripts/real_data_gallery.py --rescore        # the stored fits' errors and references again
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
OUT_JSON = ROOT / "docs" / "real-data" / "gallery.json"
FITS = ROOT / "docs" / "real-data" / "fits"
IMAGES = ROOT / "docs" / "images" / "real-data"
DOC = ROOT / "docs" / "real-data.md"
BRDFFIT = Path(sys.executable).with_name("brdffit")

sys.path.insert(0, str(Path(__file__).resolve().parent))
import reference_fit as ref  # noqa: E402  (scripts/reference_fit.py: the independent reference fitter)

# RGL test pairs: uniform in solid angle with θi, θo <= 80° (reference_fit's protocol): the files measure
# incidences up to 78.5° and interpolate beyond towards a horizon row, where lookup's division by cosθo gives
# values up to ~900 1/sr at θo = 89.9° (paper_white). 100,000 pairs, not the protocol's 2,000: on the peaked
# materials the error on 2,000 pairs depends on how many fall near the mirror direction and varies by tens of
# percent between seeds (each row stores that spread, `SPREAD_SEEDS`).
TEST_PAIRS = 100_000
TEST_SEED = ref.TEST_SEED                 # 202
TEST_MAX_THETA_DEG = ref.MAX_THETA_DEG    # 80
PROTOCOL_PAIRS = ref.TEST_PAIRS           # 2,000: the protocol figure, uniform_pairs(2000, default_rng(202))
SPREAD_SEEDS = 40                         # the protocol figure over seeds 0..39: how much 2,000 pairs vary
TEST_SPREAD_SEEDS = 5                     # the test error over seeds 202..206 of 100,000 pairs: how much those vary
TARGET_EACH, TARGET_MEDIAN = 1.0, 0.8     # default / reference <= 1.0 on every material, median <= 0.8
SPLIT_SEED = 0          # brdffit.select's default seed and held-out fraction: the same rows it holds out
SPLIT_FRACTION = 0.2
MITSUBA_PAIRS = 2_000   # held-out points evaluated through Mitsuba (one scalar eval each)
SPHERE_RESOLUTION = 96

PTFE = "nist-ptfe/PTFE.data.csv"
PTFE_COLUMNS = "theta_i=thetai,phi_i=phi,theta_o=thetar,phi_o=phir"
RGL = ("paper_white_rgb", "acrylic_felt_green_rgb", "satin_rosaline_rgb", "cg_sunflower_rgb", "cc_ibiza_sunset_rgb")
ALTA = "alta-cea-retro/retro-gray-tape.dat"


# ------------------------------------------------------------------------------------------------ materials
def materials() -> list[dict]:
    """One entry per gallery row: name, file (relative to ../shared/data), kind, the CLI's table options and the
    same options as `brdffit.io.load` keywords."""
    from brdffit import io

    rows = []
    every = io.load(DATA / PTFE, format="table", columns=_columns(PTFE_COLUMNS), values="f_r11",
                    channel_column="lambda")
    for channel in every.channels:                       # "lambda=0.351", ...
        wavelength = channel.split("=", 1)[1]
        rows.append({"name": f"ptfe-{wavelength}um", "file": PTFE, "kind": "table",
                     "material": f"sintered PTFE (NIST), λ = {wavelength} µm",
                     "cli": ["--columns", PTFE_COLUMNS, "--values", "f_r11", "--where", f"lambda={wavelength}"],
                     "load": {"format": "table", "columns": _columns(PTFE_COLUMNS), "values": "f_r11",
                              "where": {"lambda": float(wavelength)}}})
    for stem in RGL:
        rows.append({"name": stem.removesuffix("_rgb"), "file": f"rgl-epfl/{stem}.bsdf", "kind": "rgl",
                     "material": None, "cli": [], "load": {}})
    rows.append({"name": "retro-gray-tape", "file": ALTA, "kind": "alta",
                 "material": "retro-reflective gray tape (CEA, ALTA data)", "cli": [], "load": {}})
    return rows


def _columns(text: str) -> dict:
    return dict(item.split("=", 1) for item in text.split(","))


def load_measurements(entry: dict):
    from brdffit import io

    return io.load(DATA / entry["file"], **entry["load"])


# ------------------------------------------------------------------------------------------------ held-out data
def test_pairs(n: int = TEST_PAIRS, seed: int = TEST_SEED, max_theta_deg: float = TEST_MAX_THETA_DEG):
    """(θi, φi, θo, φo) of n direction pairs uniform in solid angle on θ <= max_theta_deg for both directions:
    `reference_fit.uniform_pairs` with ``numpy.random.default_rng(seed)``."""
    return ref.uniform_pairs(n, np.random.default_rng(seed), max_theta_deg)


def split_rows(measurements, seed: int = SPLIT_SEED, fraction: float = SPLIT_FRACTION) -> np.ndarray:
    """The held-out rows of `brdffit.select`'s split: a seeded permutation of the valid rows, the first part."""
    rng = np.random.default_rng(seed)
    valid = np.flatnonzero(np.any(np.isfinite(measurements.values), axis=1))
    order = rng.permutation(valid)
    return np.sort(order[: int(round(fraction * len(order)))])


def errors(f_model, f_data, cos_i) -> dict:
    """Cosine-weighted relative error ‖(f_m − f_d) cosθi‖ / ‖f_d cosθi‖ and relative errors |f_m − f_d| / f_d
    (RMS, median) over the values with f_d > 0, all channels together."""
    f_model, f_data = np.asarray(f_model, float), np.asarray(f_data, float)
    c = np.asarray(cos_i, float).reshape(-1, 1)
    ok = np.isfinite(f_data) & np.isfinite(f_model)
    d = np.where(ok, (f_model - f_data) * c, 0.0)
    ref = np.where(ok, f_data * c, 0.0)
    pos = ok & (f_data > 0)
    rel = np.abs(f_model[pos] - f_data[pos]) / f_data[pos]
    return {"cosine": float(np.sqrt(np.sum(d ** 2) / np.sum(ref ** 2))),
            "relative_rms": float(np.sqrt(np.mean(rel ** 2))), "relative_median": float(np.median(rel)),
            "values": int(ok.sum())}


def training_rows(measurements, seed: int = SPLIT_SEED, fraction: float = SPLIT_FRACTION) -> np.ndarray:
    """The other valid rows of the split: what the ``train`` refit and the reference are fitted to."""
    valid = np.flatnonzero(np.any(np.isfinite(measurements.values), axis=1))
    return np.setdiff1d(valid, split_rows(measurements, seed, fraction))


def _angles_at(measurements, rows):
    return tuple(np.asarray(a, float)[rows] for a in (measurements.theta_i, measurements.phi_i,
                                                      measurements.theta_o, measurements.phi_o))


def heldout_points(row: dict, measurements, max_theta_deg: float | None = None):
    """(θi, φi, θo, φo), the measured f_r there, and the held-out rows (None for RGL)."""
    if row["kind"] == "rgl":         # the file's own interpolation (negative="clip") at the test pairs
        from brdffit.io.rgl import read_rgl

        angles = test_pairs(max_theta_deg=TEST_MAX_THETA_DEG if max_theta_deg is None else max_theta_deg)
        return angles, read_rgl(DATA / row["file"]).lookup(*angles), None
    rows = split_rows(measurements)
    return _angles_at(measurements, rows), np.asarray(measurements.values, float)[rows], rows


def reference(row: dict, measurements, scored, angles, f_data, rows) -> dict:
    """The independent reference (`reference_fit.fit_reference`) fitted to training data disjoint from the test
    data, its error on the same test pairs or rows as ``scored`` (the default fit, or the ``train`` refit of a
    split material), and the ratio of the two; for RGL-EPFL also the issue's protocol figure (2,000 pairs) and
    its spread over `SPREAD_SEEDS` seeds of 2,000 pairs, for both fits."""
    t0 = time.perf_counter()
    if rows is None:                 # RGL-EPFL: the protocol's training pairs, looked up in the file
        from brdffit.io.rgl import read_rgl

        table = read_rgl(DATA / row["file"])
        train_angles = ref.uniform_pairs(ref.TRAIN_PAIRS, np.random.default_rng(ref.TRAIN_SEED))
        f_train, weights = table.lookup(*train_angles), None
        training = {"kind": "rgl-lookup", "pairs": ref.TRAIN_PAIRS, "seed": ref.TRAIN_SEED,
                    "max_theta_deg": ref.MAX_THETA_DEG}
    else:                            # the split's training rows, with the measurement's weights and angles
        train_rows = training_rows(measurements)
        train_angles = _angles_at(measurements, train_rows)
        f_train = np.asarray(measurements.values, float)[train_rows]
        weights = None if measurements.weights is None else np.asarray(measurements.weights, float)[train_rows]
        training = {"kind": "split", "rows": int(len(train_rows)), "weights": weights is not None}
    fit = ref.fit_reference(*train_angles, f_train, weights)
    fit_s = time.perf_counter() - t0
    test = errors(fit.predict(*angles), f_data, np.cos(angles[0]))
    default_error = row["heldout"]["cosine"]
    out = {"model": fit.model, "shape": fit.shape_dict, "rho_d": fit.rho_d.tolist(), "ks": fit.ks.tolist(),
           "training": training, "fit_s": fit_s,
           "train_error": ref.cosine_error(fit.predict(*train_angles), f_train, train_angles[0]),
           "test": test, "test_error": test["cosine"], "default_test_error": default_error,
           "default_fit": row["heldout"]["fit"], "ratio": default_error / test["cosine"]}
    if rows is None:
        def both(pairs, f):
            d = errors(np.asarray(scored.predict(*pairs)), f, np.cos(pairs[0]))["cosine"]
            r = errors(fit.predict(*pairs), f, np.cos(pairs[0]))["cosine"]
            return d, r

        pairs = test_pairs(PROTOCOL_PAIRS, TEST_SEED)
        d, r = both(pairs, table.lookup(*pairs))
        out["protocol"] = {"pairs": PROTOCOL_PAIRS, "seed": TEST_SEED, "default": d, "reference": r,
                           "ratio": d / r}
        per_seed = [test_pairs(PROTOCOL_PAIRS, seed) for seed in range(SPREAD_SEEDS)]
        stacked = tuple(np.concatenate([p[k] for p in per_seed]) for k in range(4))
        f_all = table.lookup(*stacked)
        f_default, f_reference = np.asarray(scored.predict(*stacked)), fit.predict(*stacked)
        d_s, r_s = [], []
        for k in range(SPREAD_SEEDS):
            part = slice(k * PROTOCOL_PAIRS, (k + 1) * PROTOCOL_PAIRS)
            cos_k = np.cos(stacked[0][part])
            d_s.append(errors(f_default[part], f_all[part], cos_k)["cosine"])
            r_s.append(errors(f_reference[part], f_all[part], cos_k)["cosine"])
        ratios = np.asarray(d_s) / np.asarray(r_s)
        out["protocol_spread"] = {"pairs": PROTOCOL_PAIRS, "seeds": [0, SPREAD_SEEDS - 1], "percentiles": [5, 50, 95],
                                  "default": np.percentile(d_s, [5, 50, 95]).tolist(),
                                  "reference": np.percentile(r_s, [5, 50, 95]).tolist(),
                                  "ratio": np.percentile(ratios, [5, 50, 95]).tolist()}
        seeds = range(TEST_SEED, TEST_SEED + TEST_SPREAD_SEEDS)
        spread = [both(pairs, table.lookup(*pairs)) for pairs in (test_pairs(TEST_PAIRS, seed) for seed in seeds)]
        out["test_spread"] = {"pairs": TEST_PAIRS, "seeds": [seeds[0], seeds[-1]],
                              "default": [min(d for d, _ in spread), max(d for d, _ in spread)],
                              "reference": [min(r for _, r in spread), max(r for _, r in spread)],
                              "ratio": [min(d / r for d, r in spread), max(d / r for d, r in spread)]}
    return out


def target(rows: list[dict]) -> dict:
    """Issue 36's target over the rows: ratio (default fit's test error / the reference's) <= `TARGET_EACH` on
    every material and median <= `TARGET_MEDIAN`. Rows without a reference count as failing."""
    ratios = {r["name"]: (r["reference"]["ratio"] if "reference" in r else None) for r in rows}
    known = [v for v in ratios.values() if v is not None]
    median = float(np.median(known)) if known else math.nan
    over = {name: v for name, v in ratios.items() if v is None or not v <= TARGET_EACH}
    return {"each": TARGET_EACH, "median_target": TARGET_MEDIAN, "ratios": ratios, "median": median,
            "over": over, "median_holds": bool(median <= TARGET_MEDIAN),
            "holds": bool(not over and median <= TARGET_MEDIAN)}


def score(row: dict, measurements) -> None:
    """The held-out errors of a row's stored fits and of its stored Mitsuba export (``row["heldout"]``,
    ``row["mitsuba"]["heldout"]``), from the files under docs/real-data/fits/ (what the tests read)."""
    from brdffit import FitResult
    from brdffit.export.mitsuba import evaluate_in_mitsuba

    h5 = ROOT / "docs" / row["fit_file"]
    default = FitResult.load(h5, "default")
    row["parameters"] = parameters(default)
    angles, f_data, rows = heldout_points(row, measurements)
    cos_i = np.cos(angles[0])
    if rows is None:
        scored = default
        h = {"kind": "rgl-lookup", "pairs": TEST_PAIRS, "seed": TEST_SEED,
             "max_theta_deg": TEST_MAX_THETA_DEG, "fit": "default",
             **errors(default.predict(*angles), f_data, cos_i)}
        whole, f_whole, _ = heldout_points(row, measurements, 90.0)
        h["whole_hemisphere"] = errors(default.predict(*whole), f_whole, np.cos(whole[0]))
        h["whole_hemisphere"]["largest_value"] = float(np.max(f_whole))
    else:
        scored = train = FitResult.load(h5, "train")
        h = {**{k: v for k, v in row.get("heldout", {}).items() if k == "train_s"}, "kind": "split",
             "seed": SPLIT_SEED, "fraction": SPLIT_FRACTION,
             "rows": int(len(rows)), "fit": "train", "train_status": train.status,
             **errors(train.predict(*angles), f_data, cos_i)}
        h["default_on_same_rows"] = errors(default.predict(*angles), f_data, cos_i)
    row["heldout"] = h
    row["reference"] = reference(row, measurements, scored, angles, f_data, rows)
    n = min(MITSUBA_PAIRS, len(cos_i))
    wi, wo = _directions(*(a[:n] for a in angles))
    text = (ROOT / "docs" / row["mitsuba"]["file"]).read_text()
    g = evaluate_in_mitsuba(text, wi, wo)
    data = f_data[:n]
    row["mitsuba"]["heldout"] = errors(g[:, : data.shape[1]], data, cos_i[:n])
    row["mitsuba"]["stated_uniform_rms"] = stated_uniform_rms(text)


def stated_uniform_rms(text: str) -> float:
    """The deviation an export states for its uniform random pairs alone (`brdffit.export.terms.random_pairs`):
    "the uniform pairs alone: X" where it also measured near the lobes' peaks, else its one number."""
    alone = re.search(r"the uniform pairs alone: ([0-9.e+-]+)", text)
    return float((alone or re.search(r"cosine-weighted relative RMS error ([0-9.e+-]+)", text)).group(1))


def _directions(theta_i, phi_i, theta_o, phi_o):
    from brdffit.geometry import spherical_to_vector

    return (np.asarray(spherical_to_vector(theta_i, phi_i)), np.asarray(spherical_to_vector(theta_o, phi_o)))


# ------------------------------------------------------------------------------------------------ one material
def run_cli(entry: dict, out: Path) -> dict:
    """``brdffit fit FILE [table options] --out OUT`` with an empty compilation cache: the first run a user makes."""
    cache = out.parent / "jax-cache"
    cmd = [str(BRDFFIT), "fit", str(DATA / entry["file"]), *entry["cli"], "--out", str(out)]
    env = dict(os.environ, BRDFFIT_CACHE_DIR=str(cache))
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=out.parent)
    wall = time.perf_counter() - t0
    shown = ["brdffit", "fit", f"../shared/data/{entry['file']}", *entry["cli"]]
    if proc.returncode not in (0, 1):
        raise RuntimeError(f"{' '.join(shown)} exited {proc.returncode}: {proc.stderr[-2000:]}")
    done = re.findall(r"select done in ([0-9.]+) s", proc.stderr)   # the progress line's last word on the selection
    return {"command": " ".join(shown), "exit_code": proc.returncode, "wall_s": wall,
            "selection_s": float(done[-1]) if done else None}


def compact_png(path: Path, scale: float = 1.0, colours: int = 96) -> None:
    """Shrink a figure for the docs: resampled by ``scale`` and reduced to a palette of ``colours``."""
    from PIL import Image

    with Image.open(path) as image:
        image = image.convert("RGB")
        if scale != 1.0:
            image = image.resize((round(image.width * scale), round(image.height * scale)), Image.Resampling.LANCZOS)
        image.quantize(colors=colours).save(path, optimize=True)


def parameters(result) -> list[dict]:
    rows = []
    for name, value in result.params.items():
        value = np.atleast_1d(np.asarray(value, float))
        err = np.atleast_1d(np.asarray(result.stderr[name], float))
        robust = np.atleast_1d(np.asarray(result.stderr_robust.get(name, np.nan), float))
        for i, v in enumerate(value):
            label = name if np.ndim(result.params[name]) == 0 else f"{name}[{i}]"
            rows.append({"label": label, "value": float(v), "stderr": _num(err[min(i, err.size - 1)]),
                         "stderr_robust": _num(robust[min(i, robust.size - 1)]),
                         "fixed": name in result.fixed, "at_bound": label in result.bounds_hit})
    return rows


def _num(x):
    """A float for JSON: "inf" for a parameter the data do not determine, None for NaN."""
    x = float(x)
    return x if math.isfinite(x) else ("inf" if math.isinf(x) else None)


def mitsuba_export(result, stem: str) -> dict:
    """Export the fit to Mitsuba 3, check that Mitsuba loads it, and write it beside the fit."""
    import mitsuba as mi

    from brdffit.export import ExportError, export_details

    used_fit = False
    try:
        details = export_details(result, "mitsuba", name=stem)
    except ExportError:
        used_fit = True
        details = export_details(result, "mitsuba", name=stem, fit=True)
    if mi.variant() != "scalar_rgb":
        mi.set_variant("scalar_rgb")
    mi.load_string(details.text)                     # raises if Mitsuba refuses it
    (FITS / f"{stem}.xml").write_text(details.text)
    return {"fit": used_fit, "file": f"real-data/fits/{stem}.xml", "notes": list(details.notes),
            "stated_rms": float(details.deviation.rms), "stated_max_rel": float(details.deviation.max_rel),
            "stated_pairs": int(details.deviation.pairs)}


def spheres(path: Path, measured_hdr, fitted_hdr, title: str) -> None:
    """Measured | fitted | relative difference, small (the report's spheres figure, at gallery size)."""
    from matplotlib.figure import Figure

    from brdffit.io._common import atomic_path
    from brdffit.render import difference, tonemap

    diff = difference(fitted_hdr, measured_hdr)
    fig = Figure(figsize=(7.2, 2.6), dpi=80)
    axes = fig.subplots(1, 3)
    for ax, img, name in ((axes[0], measured_hdr, "measured"), (axes[1], fitted_hdr, "fitted")):
        shown = np.clip(tonemap(img, "reinhard", 1.0), 0, 1)
        shown = shown[..., 0] if shown.shape[-1] == 1 else shown
        ax.imshow(shown, cmap="gray" if shown.ndim == 2 else None, vmin=0, vmax=1)
        ax.set_title(name, fontsize=9)
        ax.set_xticks([]), ax.set_yticks([])
    lit = diff[np.asarray(measured_hdr).sum(axis=-1) > 0]
    image = axes[2].imshow(diff, cmap="magma", vmin=0.0, vmax=max(float(np.percentile(lit, 99)), 1e-3))
    axes[2].set_title(f"|ΔY| / Y (median {float(np.median(lit)):.2g})", fontsize=9)
    axes[2].set_xticks([]), axes[2].set_yticks([])
    fig.colorbar(image, ax=axes[2], fraction=0.046, pad=0.04)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, format="png", dpi=80)


def pictures(entry: dict, measurements, result) -> dict:
    from brdffit.io.rgl import read_rgl
    from brdffit.render import DEFAULT_LIGHTS, render_sphere
    from brdffit.report.figures import plot_slices
    from brdffit.scene import Scene

    stem = entry["name"]
    slices = IMAGES / f"{stem}-slices.png"
    plot_slices(slices, measurements, result)
    compact_png(slices, scale=0.7)
    fitted = render_sphere(result.model, resolution=SPHERE_RESOLUTION)
    if entry["kind"] == "rgl":       # the file's own interpolation at every pixel's direction pair
        scene = Scene.sphere(DEFAULT_LIGHTS, resolution=SPHERE_RESOLUTION)
        table = read_rgl(DATA / entry["file"])
        ti, pi_ = np.arccos(np.clip(scene.wi[:, 2], -1, 1)), np.arctan2(scene.wi[:, 1], scene.wi[:, 0])
        to, po = np.arccos(np.clip(scene.wo[:, 2], -1, 1)), np.arctan2(scene.wo[:, 1], scene.wo[:, 0])
        measured = scene.image(scene.radiance(table.lookup(ti, pi_, to, po)))
        how = "measured: RglTable.lookup"
    else:
        measured = render_sphere(measurements, resolution=SPHERE_RESOLUTION)
        how = "measured: k-NN interpolation of the samples"
    sphere = IMAGES / f"{stem}-spheres.png"
    spheres(sphere, measured, fitted, f"{stem}: {result.spec} ({how}; key/fill/rim lights)")
    compact_png(sphere)
    return {"slices": f"images/real-data/{slices.name}", "spheres": f"images/real-data/{sphere.name}"}


def gallery_row(entry: dict, work: Path) -> dict:
    import brdffit
    from brdffit import FitResult

    stem = entry["name"]
    out = work / stem
    print(f"[{stem}] brdffit fit ...", flush=True)
    cli = run_cli(entry, out)
    result = FitResult.load(out / "result.h5")
    selection = json.loads((out / "selection.json").read_text())
    measurements = load_measurements(entry)
    print(f"[{stem}] {result.spec} {result.status} in {cli['wall_s']:.1f} s; held-out, export, pictures", flush=True)
    h5 = FITS / f"{stem}.h5"
    h5.unlink(missing_ok=True)
    result.save(h5, "default")
    row = {"name": stem, "file": entry["file"], "kind": entry["kind"], "measured": _now(), "commit": _commit(),
           "load_average": os.getloadavg()[0],
           "material": entry["material"] or measurements.meta.get("description", stem),
           "load": entry["load"], "samples": int(measurements.n), "channels": list(measurements.channels), **cli,
           "model": result.spec, "status": result.status, "loss": result.loss, "parameters": parameters(result),
           "warnings": list(result.warnings), "summary": result.summary(),
           "in_sample": {k: np.atleast_1d(v).astype(float).tolist() for k, v in result.metrics.items()},
           "selection": [{k: r.get(k) for k in ("spec", "n_params", "samples", "bic", "heldout_error", "status",
                                                  "verdict")} for r in selection["table"]],
           "chosen": selection["chosen"], "selection_warnings": selection.get("warnings", []),
           "fit_file": f"real-data/fits/{h5.name}"}
    if entry["kind"] != "rgl":      # the chosen model refitted without the selection's held-out rows
        values = np.array(measurements.values, dtype=float)
        values[split_rows(measurements)] = np.nan
        t0 = time.perf_counter()
        train = brdffit.fit(measurements.replace(values=values), result.spec, init=result.model, loss=result.loss)
        train.save(h5, "train")
        row["heldout"] = {"train_s": time.perf_counter() - t0}
    row["mitsuba"] = mitsuba_export(result, stem)
    row["images"] = pictures(entry, measurements, result)
    score(row, measurements)
    print(f"[{stem}] held-out cosine {row['heldout']['cosine']:.4g}, Mitsuba stated "
          f"{row['mitsuba']['stated_rms']:.3g}", flush=True)
    return row


# ------------------------------------------------------------------------------------------------ the page
def _g(x, digits=3) -> str:
    return "–" if x is None else "∞" if x == "inf" else f"{x:.{digits}g}"


def _commit() -> str:
    """HEAD, and the library files that differ from it (other work in the same checkout runs with the fits)."""
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                          cwd=ROOT).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--", "brdffit"], capture_output=True, text=True,
                           cwd=ROOT).stdout.split("\n")
    changed = sorted(line[3:] for line in dirty if line.strip())
    return head + (f" with uncommitted {', '.join(changed)}" if changed else "")


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


def _machine() -> str:
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (f"{platform.system()} {platform.machine()}, {cpu}, {os.cpu_count()} cores, "
            f"Python {platform.python_version()}")


def markdown(gallery: dict) -> str:
    rows = gallery["rows"]
    lines = [
        "# Real data: the default fit of every shared real material",
        "",
        "One row per real measurement in `../shared/data` (see its README): NIST's sintered PTFE at each wavelength "
        "of its CSV, the five RGL-EPFL materials and CEA's retro-reflective tape (ALTA data). Each row is what "
        "`brdffit fit FILE` gives with no fit options (table options only where the file needs them to be read): "
        "model selection over `brdffit.select.DEFAULT_CANDIDATES` by the criterion `auto` (none of these files "
        "states σ, so: the error on held-out directions, the simplest plausible candidate within 5% of the best; "
        "docs/model-selection.md), the chosen model fitted with the cosine loss; an RGL-EPFL file read as its "
        "interpolation at importance-weighted direction pairs (docs/formats.md). Nothing here was tuned per "
        "material.",
        "",
        "**Held-out error**, on directions the fit did not use (the test set, disjoint from every fit's training "
        "data), over all channels: *cosine* is ‖(f_fit − f_data) cosθi‖ / ‖f_data cosθi‖ (the relative error in "
        "reflected radiance), *relative* the RMS and the median of |f_fit − f_data| / f_data over f_data > 0.",
        f"- RGL-EPFL: the default fit against the file's own interpolation (`RglTable.lookup` with its default "
        f"`negative=\"clip\"`, the values a renderer reads) at {TEST_PAIRS:,} direction pairs uniform in solid "
        f"angle with θi, θo ≤ {TEST_MAX_THETA_DEG:g}° (`reference_fit.uniform_pairs({TEST_PAIRS}, "
        f"numpy.random.default_rng({TEST_SEED}))`). The default fit never sees them: `brdffit fit FILE` draws its "
        "own quasi-random direction pairs from the file. The files measure incidences up to 78.5° and only "
        "interpolate beyond, towards a horizon row, where the lookup's division by cosθo gives values of "
        "hundreds of 1/sr at θo → 90°: on the whole hemisphere those few pairs dominate every norm (the details "
        "give that number too).",
        f"- PTFE and the tape: the chosen model refitted to the training rows of the selection's own split "
        f"(`numpy.random.default_rng({SPLIT_SEED}).permutation` of the valid rows, the first "
        f"{SPLIT_FRACTION:.0%} held out, as `brdffit.select` draws them), starting from the default fit's values "
        "(as the selection's cross-validation does), scored on the held-out rows. The default fit itself saw "
        "every row; its error on the same rows is in the details.",
        "",
        "**Reference**: the same error of `scripts/reference_fit.py`, a fitter written apart from the engine "
        "(NumPy and SciPy only; none of brdffit's models, fitting or selection code): of Lambert plus one lobe of "
        "GGX or Cook-Torrance (each with Schlick's f0), Blinn-Phong or Ward, the one with the lowest training cost, "
        "each found by a grid over the lobe's shape with the amplitudes solved by bounded linear least squares, "
        "then refined. It is fitted to training data disjoint from the test data and scored on the same test "
        "pairs or rows as the default fit; *ratio* is the default fit's test error over the reference's (below 1: "
        "the default fit is the better one).",
        f"- RGL-EPFL: the reference is fitted to the lookup at the protocol's {ref.TRAIN_PAIRS:,} training pairs "
        f"(`uniform_pairs({ref.TRAIN_PAIRS}, default_rng({ref.TRAIN_SEED}))`, θ ≤ {ref.MAX_THETA_DEG:g}°). The "
        f"test set has {TEST_PAIRS:,} pairs, not the protocol's {PROTOCOL_PAIRS:,}: on the peaked materials "
        f"(satin_rosaline, cc_ibiza_sunset, cg_sunflower) the error on {PROTOCOL_PAIRS:,} pairs depends on how "
        "many fall near the mirror direction, and varies by tens of percent between seeds"
        + _spread_example(rows) + ". The issue's protocol figure "
        f"(`uniform_pairs({PROTOCOL_PAIRS}, default_rng({TEST_SEED}))`), each fit's spread over "
        f"{SPREAD_SEEDS} seeds of {PROTOCOL_PAIRS:,} pairs, and its range over seeds {TEST_SEED}–"
        f"{TEST_SEED + TEST_SPREAD_SEEDS - 1} of {TEST_PAIRS:,} pairs (where a sharp peak still moves it) are in "
        "each row's details.",
        "- PTFE and the tape: the reference is fitted to the same training rows as the refit (with the "
        "measurement's angles, and its weights where it has any: these files have none) and scored on the same "
        "held-out rows.",
        "",
        f"**Target**: ratio ≤ {TARGET_EACH:.1f} on every material and median ≤ {TARGET_MEDIAN:.1f}. "
        + target_line(rows),
        "",
        "**Parameters**: value ± the fit's standard error (`FitResult.stderr`) and its sandwich standard error "
        "(`stderr_robust`, valid where the residual variance differs between samples); – where the stored value is "
        "not a number: a stored fit keeps an infinite stderr (a parameter the data do not determine, JᵀJ singular) "
        "as NaN, and the fit's warnings in its summary name those parameters.",
        "",
        "**Mitsuba**: the default fit exported with `brdffit.export.export_details(result, \"mitsuba\")` (`fit=True` "
        "where a lobe has no Mitsuba equivalent), loaded with `mitsuba.load_string`; *stated* is the export's own "
        "cosine-weighted deviation from the fit (its comments, 2,000 random pairs); *vs data* is what Mitsuba "
        f"evaluates against the held-out data (the first {MITSUBA_PAIRS:,} held-out points).",
        "",
        f"**Time**: wall time of the `brdffit fit` command (a subprocess, report included, an empty compilation "
        f"cache: a user's first run) on {gallery['machine']}, shared with other jobs: each row's details give "
        f"when it was measured, at which commit (and which library files were uncommitted then) and the load "
        f"average. Measured between {min(r['measured'] for r in rows)} and {max(r['measured'] for r in rows)}; "
        f"the last run: {gallery['load']}.",
        "",
        "| material | chosen model | status | exit | held-out cosine | reference | ratio | "
        "held-out relative RMS / median | Mitsuba stated / vs data | time (s): command / selection |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        h, m, f = r["heldout"], r["mitsuba"], r.get("reference")
        lines.append(f"| [{r['name']}](#{r['name'].replace('.', '')}) | `{r['model']}` | {r['status']} | "
                     f"{r['exit_code']} | {h['cosine']:.3g} | "
                     + (f"{f['test_error']:.3g} | {_ratio(f['ratio'])} | " if f else "– | – | ")
                     + f"{h['relative_rms']:.3g} / {h['relative_median']:.3g} | "
                     f"{m['stated_rms']:.3g} / {m['heldout']['cosine']:.3g} | {r['wall_s']:.1f} / "
                     f"{_g(r.get('selection_s'))} |")
    lines += ["", "## What does not hold", ""] + shortfalls(rows)
    lines += ["", "## Regenerate", "",
              "```bash",
              ".venv/bin/python scripts/real_data_gallery.py            # every material (about "
              f"{sum(r['wall_s'] for r in rows) / 60 + 3:.0f} min here)",
              ".venv/bin/python scripts/real_data_gallery.py --only paper_white   # some rows; the others are kept",
              ".venv/bin/python scripts/real_data_gallery.py --markdown-only      # this page from gallery.json",
              ".venv/bin/python scripts/real_data_gallery.py --rescore            # errors and references, no fits",
              "```",
              "",
              "The script writes [`real-data/gallery.json`](real-data/gallery.json) (every number on this page), the "
              "fits as `real-data/fits/<name>.h5` (`FitResult.load(path, \"default\")`; `\"train\"` for the split "
              "materials; parameters only, no measurements), their Mitsuba exports `real-data/fits/<name>.xml`, the "
              "pictures under `images/real-data/`, and this page. `tests/test_real_data.py` checks every stored fit "
              "against the shared file (held-out errors, Mitsuba), fits the reference afresh and checks its error and "
              "the ratio, asserts the target (marked as an expected failure, naming the materials, while it does not "
              "hold) and runs one default fit through the CLI; it skips where `../shared/data` is absent. "
              "`--rescore` recomputes the errors and the references of the stored fits without fitting them again.",
              ""]
    for r in rows:
        h, m = r["heldout"], r["mitsuba"]
        lines += [f"## {r['name']}", "",
                  f"{r['material']}: `../shared/data/{r['file']}`, {r['samples']:,} samples × "
                  f"{len(r['channels'])} channel(s). Command: `{r['command']}` (exit {r['exit_code']}, "
                  f"{r['wall_s']:.1f} s, of which the selection {_g(r.get('selection_s'))} s; measured "
                  f"{r['measured']} at "
                  f"commit {r.get('commit', '?')}, load average {r.get('load_average', math.nan):.1f}).", "",
                  f"**{r['model']}**, {r['status']}.", "",
                  "| parameter | value | ± stderr | ± sandwich stderr | |", "|---|---|---|---|---|"]
        for p in r["parameters"]:
            note = "fixed" if p["fixed"] else ("at bound" if p["at_bound"] else "")
            lines.append(f"| {p['label']} | {p['value']:.6g} | {_g(p['stderr'])} | {_g(p['stderr_robust'])} | "
                         f"{note} |")
        lines.append("")
        if h["kind"] == "rgl-lookup":
            w = h["whole_hemisphere"]
            lines.append(f"Held-out ({h['pairs']:,} random pairs with θi, θo ≤ {h['max_theta_deg']:g}°, seed "
                         f"{h['seed']}, against "
                         f"`RglTable.lookup`): cosine {h['cosine']:.4g}, relative RMS {h['relative_rms']:.4g}, median "
                         f"{h['relative_median']:.4g}. On the whole hemisphere (same seed, θ up to 90°, lookup values "
                         f"up to {w['largest_value']:.3g} 1/sr): cosine {w['cosine']:.4g}, relative RMS "
                         f"{w['relative_rms']:.4g}, median {w['relative_median']:.4g}. At the fit's "
                         f"own samples: Ngan {', '.join(f'{v:.3g}' for v in r['in_sample'].get('ngan', []))} 1/sr, "
                         f"relative RMS {', '.join(f'{v:.3g}' for v in r['in_sample'].get('rmse_rel', []))}.")
        else:
            d = h["default_on_same_rows"]
            lines.append(f"Held-out ({h['rows']:,} rows; the refit to the other rows ended {h['train_status']}, "
                         f"{_g(h.get('train_s'))} s): cosine {h['cosine']:.4g}, relative RMS {h['relative_rms']:.4g}, "
                         f"median {h['relative_median']:.4g}. The default fit (which saw these rows) on them: "
                         f"cosine {d['cosine']:.4g}, relative RMS {d['relative_rms']:.4g}.")
        lines += ["", reference_details(r.get("reference"))]
        lines += ["",
                  f"Mitsuba export ([{Path(m['file']).name}]({m['file']}), "
                  f"{'fit=True: ' if m['fit'] else ''}loads): stated deviation from the fit {m['stated_rms']:.3g}, "
                  f"{_g(m.get('stated_uniform_rms'))} at its uniform pairs alone "
                  f"(largest relative {m['stated_max_rel']:.3g}); against the held-out data "
                  f"{m['heldout']['cosine']:.3g} "
                  f"cosine, {m['heldout']['relative_rms']:.3g} relative RMS."
                  + (" Approximations: " + "; ".join(m["notes"]) + "." if m["notes"] else ""), "",
                  "Why the others were not chosen:", ""]
        for s in r["selection"]:
            if s["spec"] != r["chosen"]:
                lines.append(f"- `{s['spec']}` ({s['status']}): {s['verdict']}")
        lines += [f"- chosen `{r['chosen']}`: "
                  + next((s["verdict"] for s in r["selection"] if s["spec"] == r["chosen"]), "")]
        lines += [f"- selection warning: {w}" for w in r["selection_warnings"]]
        lines += ["", f"![slices of {r['name']}]({r['images']['slices']})",
                  f"![spheres of {r['name']}]({r['images']['spheres']})", "",
                  "<details><summary>summary printed by brdffit fit</summary>", "", "```", r["summary"], "```", "",
                  "</details>", ""]
    return "\n".join(lines)


def _shape_text(shape: dict) -> str:
    names = {"alpha": "α", "f0": "f0", "m": "m", "n": "n"}
    return ", ".join(f"{names.get(k, k)} = {v:.4g}" for k, v in shape.items())


def _spread_example(rows: list[dict]) -> str:
    """": e.g. satin_rosaline's reference ..." from a peaked material's stored spread, or nothing."""
    for name in ("satin_rosaline", "cc_ibiza_sunset", "cg_sunflower"):
        r = next((r for r in rows if r["name"] == name and "protocol_spread" in r.get("reference", {})), None)
        if r:
            s = r["reference"]["protocol_spread"]
            return (f" (on {name}, over seeds {s['seeds'][0]}–{s['seeds'][1]}: the default fit's error "
                    f"{s['default'][1]:.3g}, 5–95% [{s['default'][0]:.3g}, {s['default'][2]:.3g}], the reference's "
                    f"{s['reference'][1]:.3g} [{s['reference'][0]:.3g}, {s['reference'][2]:.3g}], their ratio "
                    f"{_ratio(s['ratio'][1])} [{_ratio(s['ratio'][0])}, {_ratio(s['ratio'][2])}])")
    return ""


def _ratio(v: float) -> str:
    """A ratio to 3 decimals, or more where 3 would put it on the wrong side of a threshold of the target."""
    for digits in range(3, 8):
        text = f"{v:.{digits}f}"
        if all((float(text) <= limit) == (v <= limit) for limit in (TARGET_EACH, TARGET_MEDIAN)):
            return text
    return text


def target_verdict(rows: list[dict]) -> str:
    """Whether the target holds, and where not."""
    t = target(rows)
    if t["holds"]:
        return "It holds."
    misses = []
    over = {name: v for name, v in t["over"].items() if v is not None}
    if over:
        misses.append(f"over {TARGET_EACH:.1f} on " + ", ".join(f"{name} ({_ratio(v)})" for name, v in over.items()))
    if not t["median_holds"]:
        misses.append(f"the median {_ratio(t['median'])} > {TARGET_MEDIAN:.1f}")
    missing = [name for name, v in t["over"].items() if v is None]
    if missing:
        misses.append(f"no reference measured on {', '.join(missing)} (`--rescore` measures it)")
    return "It does not hold: " + "; ".join(misses) + "."


def target_line(rows: list[dict]) -> str:
    """The page's summary of the target: each material's ratio, the median, and whether it holds."""
    if not rows:
        return "No rows yet."
    t = target(rows)
    each = ", ".join(f"{name} {_ratio(v) if v is not None else '–'}" for name, v in t["ratios"].items())
    measured = sum(v is not None for v in t["ratios"].values())
    return (f"Ratio on each material: {each}; median {_ratio(t['median'])} over {measured} of {len(rows)} rows "
            f"(each PTFE wavelength is a row). **{target_verdict(rows)}**")


def reference_details(f: dict | None) -> str:
    if not f:
        return "Reference: not measured for this row (run the script with `--rescore`)."
    training = (f"the protocol's {f['training']['pairs']:,} training pairs (seed {f['training']['seed']})"
                if f["training"]["kind"] == "rgl-lookup" else
                f"the same {f['training']['rows']:,} training rows")
    text = (f"Reference (`scripts/reference_fit.py`): lambert+{f['model']} ({_shape_text(f['shape'])}; ρd = "
            f"{', '.join(f'{v:.4g}' for v in f['rho_d'])}, ks = {', '.join(f'{v:.4g}' for v in f['ks'])}), fitted to "
            f"{training} in {f['fit_s']:.1f} s (training error {f['train_error']:.4g}): test cosine "
            f"{f['test_error']:.4g}, relative RMS {f['test']['relative_rms']:.4g}, median "
            f"{f['test']['relative_median']:.4g}; the {'default fit' if f['default_fit'] == 'default' else 'refit'}'s "
            f"{f['default_test_error']:.4g} on the same {'pairs' if f['training']['kind'] == 'rgl-lookup' else 'rows'}"
            f": ratio {_ratio(f['ratio'])}.")
    if "protocol" in f:
        p, s = f["protocol"], f["protocol_spread"]
        text += (f" The issue's protocol figure ({p['pairs']:,} pairs, `uniform_pairs({p['pairs']}, "
                 f"default_rng({p['seed']}))`): default fit {p['default']:.4g}, reference {p['reference']:.4g}, ratio "
                 f"{_ratio(p['ratio'])}. Over seeds {s['seeds'][0]}–{s['seeds'][1]} of {s['pairs']:,} pairs, median "
                 f"and 5–95%: default fit {s['default'][1]:.3g} [{s['default'][0]:.3g}, {s['default'][2]:.3g}], reference "
                 f"{s['reference'][1]:.3g} [{s['reference'][0]:.3g}, {s['reference'][2]:.3g}], ratio "
                 f"{_ratio(s['ratio'][1])} [{_ratio(s['ratio'][0])}, {_ratio(s['ratio'][2])}].")
    if "test_spread" in f:
        s = f["test_spread"]
        text += (f" Over seeds {s['seeds'][0]}–{s['seeds'][1]} of {s['pairs']:,} pairs, smallest–largest: default fit "
                 f"{s['default'][0]:.3g}–{s['default'][1]:.3g}, reference {s['reference'][0]:.3g}–"
                 f"{s['reference'][1]:.3g}, ratio {_ratio(s['ratio'][0])}–{_ratio(s['ratio'][1])}.")
    return text


def shortfalls(rows: list[dict]) -> list[str]:
    """Where the rows miss what issue 17 asks (≤ 60 s, converged, parameters determined, a faithful export)."""
    out = []
    t = target(rows)
    if rows and not t["holds"]:
        out.append("- The reference target (ratio ≤ "
                   f"{TARGET_EACH:.1f} on every material, median ≤ {TARGET_MEDIAN:.1f}): "
                   + target_verdict(rows)[0].lower() + target_verdict(rows)[1:])
    slow = [r for r in rows if r["wall_s"] > 60.0]
    if slow:
        out.append(f"- Time: {len(slow)} of {len(rows)} commands took longer than 60 s here (issue 17 point 1): "
                   + ", ".join(f"{r['name']} {r['wall_s']:.1f} s at load {r.get('load_average', math.nan):.1f}"
                               for r in slow) + ".")
    failed = [r for r in rows if r["exit_code"] != 0 or r["status"] not in ("converged", "converged-at-bound")]
    if failed:
        out.append("- Not converged: " + ", ".join(f"{r['name']} ({r['status']}, exit {r['exit_code']})"
                                                  for r in failed) + ".")
    at_bound = [r for r in rows if r["status"] == "converged-at-bound"]
    if at_bound:
        out.append("- Converged at a bound: " + "; ".join(
            f"{r['name']} ({', '.join(p['label'] for p in r['parameters'] if p['at_bound']) or 'see its summary'})"
            for r in at_bound) + ".")
    undetermined = [(r["name"], sum(p["stderr"] is None for p in r["parameters"] if not p["fixed"]),
                     sum(not p["fixed"] for p in r["parameters"])) for r in rows]
    undetermined = [u for u in undetermined if u[1]]
    if undetermined:
        out.append("- Parameters the data do not determine (no finite stderr): "
                   + ", ".join(f"{name} {k} of {n}" for name, k, n in undetermined) + ".")
    poor = [r for r in rows if r["mitsuba"]["heldout"]["cosine"] > 2 * max(r["heldout"]["cosine"], 0.05)]
    if poor:
        out.append("- Mitsuba exports far worse than the fit against the held-out data: " + ", ".join(
            f"{r['name']} ({r['mitsuba']['heldout']['cosine']:.3g} against the fit's {r['heldout']['cosine']:.3g}"
            f"{', fit=True' if r['mitsuba']['fit'] else ''})" for r in poor) + ".")
    return out or ["- Nothing: every row converged within 60 s with every parameter determined."]


# ------------------------------------------------------------------------------------------------ main
def write_json(gallery: dict) -> None:
    """gallery.json, with the target's state over its rows (`target`)."""
    gallery["target"] = target(gallery["rows"])
    OUT_JSON.write_text(json.dumps(gallery, indent=1) + "\n")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", nargs="+", metavar="NAME",
                        help="rows to (re)make, in this order; the others are kept")
    parser.add_argument("--markdown-only", action="store_true", help="rewrite docs/real-data.md from gallery.json")
    parser.add_argument("--rescore", action="store_true",
                        help="recompute the held-out errors of the stored fits and exports and the references (no "
                             "fitting by brdffit), then the page")
    args = parser.parse_args(argv)
    if not DATA.is_dir():
        print(f"{DATA} is absent: the shared real data are needed", file=sys.stderr)
        return 2
    gallery = json.loads(OUT_JSON.read_text()) if OUT_JSON.exists() else {"rows": []}
    if args.rescore:
        for row in gallery["rows"]:
            if not args.only or row["name"] in args.only:
                row.pop("stdout", None)     # written by the first version of this script; the page never showed it
                score(row, load_measurements(row))
                print(f"[{row['name']}] held-out cosine {row['heldout']['cosine']:.4g}", flush=True)
        write_json(gallery)
    elif not args.markdown_only:
        entries = materials()
        known = {e["name"] for e in entries}
        if args.only and set(args.only) - known:
            parser.error(f"unknown names {sorted(set(args.only) - known)}; choose from {sorted(known)}")
        by_name = {e["name"]: e for e in entries}
        todo = [by_name[name] for name in args.only] if args.only else entries   # in the order given
        for folder in (FITS, IMAGES):
            folder.mkdir(parents=True, exist_ok=True)
        previous = {r["name"]: r for r in gallery["rows"]}
        load = os.getloadavg()
        t0 = time.perf_counter()
        with tempfile.TemporaryDirectory(prefix="brdffit-gallery-") as tmp:
            for k, entry in enumerate(todo):
                previous[entry["name"]] = gallery_row(entry, Path(tmp))
                shutil.rmtree(Path(tmp) / "jax-cache", ignore_errors=True)
                # Written after every row, so that an interrupted run leaves a consistent page (each row says when
                # and at which commit it was measured).
                gallery = {"date": _now(), "commit": _commit(), "machine": _machine(),
                           "load": f"load average {load[0]:.1f} at the start and {os.getloadavg()[0]:.1f} at the end "
                                   f"(other jobs shared the cores), {time.perf_counter() - t0:.0f} s for "
                                   f"{k + 1} row(s) in all",
                           "rows": [previous[e["name"]] for e in entries if e["name"] in previous]}
                write_json(gallery)
                DOC.write_text(markdown(gallery))
    DOC.write_text(markdown(gallery))
    print(f"wrote {DOC.relative_to(ROOT)}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
