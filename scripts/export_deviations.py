"""Measure how far each renderer export is from the brdffit model it stands for, and write the tables into
docs/export.md (between the ``<!-- deviations:start -->`` and ``<!-- deviations:end -->`` markers).

Usage:
    python scripts/export_deviations.py [--print]

Mitsuba 3 exports are loaded with Mitsuba itself (``scalar_rgb``) and evaluated at the export's own direction
pairs (`brdffit.export.Export.pairs`: 2,000 uniform random pairs, `brdffit.export.terms.random_pairs`, and 1,000
draws near each lobe's peak, `brdffit.export.terms.deviation_pairs`); pbrt-v4 exports are read back and evaluated
with pbrt-v4's transcribed formulas (`brdffit.export.pbrt_reference`). Each table gives the errors of the uniform
pairs alone and of all pairs with their balance-heuristic weights: the cosine-weighted relative RMS and the largest
relative error over the values above 1e-3 of the largest one found (`brdffit.export.terms.measure`). The fit
option runs brdffit fits (a few minutes on two shared cores).
"""

from __future__ import annotations

import argparse
import datetime
import math
import os
import platform
import sys
from pathlib import Path

import numpy as np

import brdffit
from brdffit import synth
from brdffit.export import export_details, f0_to_eta
from brdffit.export.mitsuba import evaluate_in_mitsuba
from brdffit.export.terms import measure, schlick_to_conductor
from brdffit.models import fresnel, get

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "export.md"
START, END = "<!-- deviations:start -->", "<!-- deviations:end -->"
SYNTHETIC = ROOT / "data" / "synthetic"

CONDUCTOR = dict(eta=[0.18, 0.42, 1.37], k=[3.42, 2.35, 1.77])   # gold.h5's index
EXACT = [
    ("lambert", get("lambert", rho_d=[0.5, 0.25, 0.125])),
    ("ggx(fresnel=conductor), ks = 1.3", get("ggx(fresnel=conductor)", alpha=0.2, ks=1.3, **CONDUCTOR)),
    ("ggx(fresnel=dielectric)", get("ggx(fresnel=dielectric)", alpha=0.3, eta=1.5, ks=1.0)),
    ("ggx (Schlick f0 = 0.04)", get("ggx", alpha=0.2, ks=1.0, f0=0.04)),
    ("ggx (Schlick f0 = 0)", get("ggx", alpha=0.2, ks=0.8, f0=0.0)),
    ("lambert+ggx (Schlick), ks = 0.8", get("lambert+ggx", rho_d=[0.6, 0.3, 0.1], alpha=0.25, ks=0.8, f0=0.04)),
    ("lambert+ggx(fresnel=dielectric), ks = 2", get("lambert+ggx(fresnel=dielectric)", rho_d=0.3, alpha=0.1,
                                                     ks=2.0, eta=1.6)),
    ("lambert+ggx(fresnel=conductor)", get("lambert+ggx(fresnel=conductor)", rho_d=0.3, alpha=0.2, ks=0.7,
                                           **CONDUCTOR)),
]
APPROXIMATE = [
    ("Beckmann, Smith (Mitsuba's rational G1), m = 0.1",
     get("cook-torrance(shadowing=smith, fresnel=conductor)", m=0.1, **CONDUCTOR)),
    ("Beckmann, Smith (Mitsuba's rational G1), m = 0.4",
     get("cook-torrance(shadowing=smith, fresnel=conductor)", m=0.4, **CONDUCTOR)),
    ("V-cavity -> Smith, GGX, m = 0.1", get("ggx(shadowing=v-cavity, fresnel=conductor)", alpha=0.1, **CONDUCTOR)),
    ("V-cavity -> Smith, GGX, m = 0.4", get("ggx(shadowing=v-cavity, fresnel=conductor)", alpha=0.4, **CONDUCTOR)),
    ("V-cavity -> Smith, Beckmann, m = 0.4", get("cook-torrance(fresnel=conductor)", m=0.4, **CONDUCTOR)),
    ("shadowing=none -> Smith, GGX, m = 0.4", get("ggx(shadowing=none, fresnel=conductor)", alpha=0.4,
                                                  **CONDUCTOR)),
    ("Blinn -> Beckmann, m = 0.1", get("cook-torrance(distribution=blinn, shadowing=smith, fresnel=conductor)",
                                       m=0.1, **CONDUCTOR)),
    ("Blinn -> Beckmann, m = 0.4", get("cook-torrance(distribution=blinn, shadowing=smith, fresnel=conductor)",
                                       m=0.4, **CONDUCTOR)),
    ("Schlick with Beckmann -> conductor index, f0 = 0.04",
     get("cook-torrance(shadowing=smith)", m=0.2, ks=1.0, f0=0.04)),
    ("Schlick with Beckmann -> conductor index, f0 = 0",
     get("cook-torrance(shadowing=smith)", m=0.2, ks=1.0, f0=0.0)),
    ("Schlick GGX with ks (1 - f0) > 1 (ks = 1.38)", get("lambert+ggx", rho_d=[0.55, 0.12, 0.08], alpha=0.15,
                                                         ks=1.38, f0=0.04)),
    ("Schlick GGX alone, ks = 1, f0 = 0, beside a lambert", get("lambert+ggx", rho_d=0.3, alpha=0.2, ks=1.0,
                                                                 f0=0.0)),
    # Sharp lobes, where the uniform pairs miss the peak.
    ("Schlick with Beckmann -> conductor index, m = 0.01, beside a lambert",
     get("lambert+cook-torrance(shadowing=smith)", rho_d=0.3, m=0.01, ks=1.0, f0=0.04)),
    ("Blinn -> Beckmann, m = 0.02", get("cook-torrance(distribution=blinn, shadowing=smith, fresnel=conductor)",
                                        m=0.02, **CONDUCTOR)),
    ("V-cavity -> Smith, GGX, m = 0.02", get("ggx(shadowing=v-cavity, fresnel=conductor)", alpha=0.02,
                                             **CONDUCTOR)),
    ("Beckmann, Smith (Mitsuba's rational G1), m = 0.02",
     get("cook-torrance(shadowing=smith, fresnel=conductor)", m=0.02, **CONDUCTOR)),
]
PBRT = [
    ("lambert", get("lambert", rho_d=[0.5, 0.25, 0.125])),
    ("ggx(fresnel=conductor), alpha = 0.1", get("ggx(fresnel=conductor)", alpha=0.1, ks=1.0, **CONDUCTOR)),
    ("ggx(fresnel=conductor), alpha = 0.4", get("ggx(fresnel=conductor)", alpha=0.4, ks=1.0, **CONDUCTOR)),
    ("ggx(fresnel=conductor), ks = 0.5 (mix with black)", get("ggx(fresnel=conductor)", alpha=0.2, ks=0.5,
                                                              **CONDUCTOR)),
    ("ggx(fresnel=dielectric) (conductor with k = 0)", get("ggx(fresnel=dielectric)", alpha=0.2, ks=1.0, eta=1.5)),
    ("ggx (Schlick f0 = 0.04)", get("ggx", alpha=0.2, ks=1.0, f0=0.04)),
    ("cook-torrance(fresnel=conductor) (Beckmann, V-cavity), m = 0.2",
     get("cook-torrance(fresnel=conductor)", m=0.2, **CONDUCTOR)),
    ("lambert+ggx(fresnel=conductor), ks = 0.5", get("lambert+ggx(fresnel=conductor)", rho_d=0.2, alpha=0.2,
                                                     ks=0.5, **CONDUCTOR)),
    ("lambert+ggx (Schlick), ks = 0.8", get("lambert+ggx", rho_d=[0.6, 0.3, 0.1], alpha=0.25, ks=0.8, f0=0.04)),
    ("ggx(fresnel=conductor), alpha = 0.02", get("ggx(fresnel=conductor)", alpha=0.02, ks=1.0, **CONDUCTOR)),
    ("lambert+cook-torrance (Schlick, Beckmann), m = 0.01", get("lambert+cook-torrance(shadowing=smith)", rho_d=0.3,
                                                                m=0.01, ks=1.0, f0=0.04)),
]


def _synthetic(name: str):
    return synth.truth_model(brdffit.io.load(SYNTHETIC / f"{name}.h5"))


def _deviation(result, to, mitsuba=True):
    """The deviation of an export at its own pairs, from Mitsuba's own values for a Mitsuba export."""
    if to == "mitsuba" and mitsuba:
        return measure(result.source, lambda wi, wo: evaluate_in_mitsuba(result.text, wi, wo), pairs=result.pairs)
    return result.deviation


def _cells(d) -> str:
    return f"{d.uniform_rms:.3g} | {d.uniform_max_rel:.3g} | {d.rms:.3g} | {d.max_rel:.3g} | {d.near_pairs}"


def _row(label, model, to, fit=False, mitsuba=True):
    return f"| {label} | `{model.spec}` | {_cells(_deviation(export_details(model, to, fit=fit), to, mitsuba))} |"


HEAD = ("| uniform: RMS | uniform: largest | with near-peak pairs: RMS | with near-peak pairs: largest | "
        "near-peak pairs |")


def _fresnel_table() -> list[str]:
    rows = ["| f0 | dielectric η = (1 + √f0)/(1 − √f0): largest relative difference from Schlick (at θ) | "
            "closest complex index (η, k) | its largest absolute / relative difference |", "|---|---|---|---|"]
    theta = np.linspace(0.0, math.pi / 2, 9001)
    c = np.cos(theta)
    for f0 in (0.0, 0.02, 0.04, 0.1, 0.3, 0.6):
        schlick = f0 + (1 - f0) * (1 - c) ** 5
        if f0 > 0:
            diel = np.asarray(fresnel.dielectric(c, 1.0, f0_to_eta(f0)))
            rel = np.abs(diel - schlick) / schlick
            j = int(np.argmax(rel))
            dielectric = f"{rel[j]:.3g} (θ = {math.degrees(theta[j]):.0f}°)"
        else:
            dielectric = "η = 1: F = 0, Schlick is (1 − cosθ)⁵ (relative difference 1 everywhere)"
        eta, k, curve = schlick_to_conductor(f0)
        cond = np.asarray(fresnel.conductor(c, eta, k))
        keep = schlick > 1e-3
        rel = np.max(np.abs(cond - schlick)[keep] / schlick[keep])
        rows.append(f"| {f0:g} | {dielectric} | {eta:.4g}, {k:.3g} | {curve:.3g} / {rel:.3g} |")
    return rows


def tables() -> str:
    head = ["| mapping | model " + HEAD, "|---|---|---|---|---|---|---|"]
    stamp = (f"Measured {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC on {platform.machine()} "
             f"Linux, {os.cpu_count()} cores (shared), Python {platform.python_version()}, Mitsuba "
             f"{_mitsuba_version()}, by `python scripts/export_deviations.py`.")
    out = [stamp, "", "### Mitsuba 3, exact mappings (Mitsuba's own `eval`, float32)", ""] + head
    out += [_row(label, model, "mitsuba") for label, model in EXACT]
    out += ["", "### Mitsuba 3, approximate mappings (Mitsuba's own `eval`)", ""] + head
    out += [_row(label, model, "mitsuba") for label, model in APPROXIMATE]
    out += ["", "### pbrt-v4 (pbrt-v4's formulas, `brdffit.export.pbrt_reference`)", ""] + head
    out += [_row(label, model, "pbrt") for label, model in PBRT]
    out += ["", "### Shipped synthetic models (`data/synthetic/*.h5` truths)", "",
            "| file | model | export " + HEAD, "|---|---|---|---|---|---|---|---|"]
    for name in ("plastic", "gold", "clay", "brushed-aluminium", "lafortune-retro", "toon"):
        model = _synthetic(name)
        exportable = all(lobe.name in ("lambert", "cook-torrance", "ggx") for lobe in model.lobes)
        for to in ("mitsuba", "pbrt"):
            for fit in ((False, True) if exportable else (True,)):
                deviation = _deviation(export_details(model, to, fit=fit), to)
                how = f"{to}{' --fit' if fit else ''}"
                out.append(f"| `{name}.h5` | `{model.spec}` | {how} | {_cells(deviation)} |")
    out += ["", "### Fresnel: Schlick's curve against the exact terms the renderers have", ""] + _fresnel_table()
    return "\n".join(out) + "\n"


def _mitsuba_version() -> str:
    import mitsuba

    return mitsuba.__version__


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--print", action="store_true", help="print the tables instead of writing docs/export.md")
    args = parser.parse_args(argv)
    text = tables()
    if args.print:
        print(text)
        return 0
    doc = DOC.read_text()
    if START not in doc or END not in doc:
        print(f"{DOC}: markers {START} / {END} missing", file=sys.stderr)
        return 1
    before, rest = doc.split(START, 1)
    after = rest.split(END, 1)[1]
    DOC.write_text(before + START + "\n" + text + END + after)
    print(f"wrote the tables into {DOC}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
