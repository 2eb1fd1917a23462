"""Measure how far each renderer export is from the brdffit model it stands for, and write the tables into
docs/export.md (between the ``<!-- deviations:start -->`` and ``<!-- deviations:end -->`` markers).

Usage:
    python scripts/export_deviations.py [--print]

Mitsuba 3 exports are loaded with Mitsuba itself (``scalar_rgb``) and evaluated at the export's 2,000 random
direction pairs (`brdffit.export.terms.random_pairs`); pbrt-v4 exports are read back and evaluated with pbrt-v4's
transcribed formulas (`brdffit.export.pbrt_reference`). Errors are the cosine-weighted relative RMS and the
largest relative error over the values above 1e-3 of the peak (`brdffit.export.terms.measure`). The fit option
runs brdffit fits (about a minute on two cores).
"""

from __future__ import annotations

import argparse
import math
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
]


def _synthetic(name: str):
    return synth.truth_model(brdffit.io.load(SYNTHETIC / f"{name}.h5"))


def _row(label, model, to, fit=False, mitsuba=True):
    result = export_details(model, to, fit=fit)
    if to == "mitsuba" and mitsuba:
        deviation = measure(result.source, lambda wi, wo: evaluate_in_mitsuba(result.text, wi, wo))
    else:
        deviation = result.deviation
    return f"| {label} | `{model.spec}` | {deviation.rms:.3g} | {deviation.max_rel:.3g} |"


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
    head = ["| mapping | model | cosine-weighted relative RMS | largest relative |", "|---|---|---|---|"]
    out = ["### Mitsuba 3, exact mappings (Mitsuba's own `eval`, float32)", ""] + head
    out += [_row(label, model, "mitsuba") for label, model in EXACT]
    out += ["", "### Mitsuba 3, approximate mappings (Mitsuba's own `eval`)", ""] + head
    out += [_row(label, model, "mitsuba") for label, model in APPROXIMATE]
    out += ["", "### pbrt-v4 (pbrt-v4's formulas, `brdffit.export.pbrt_reference`)", ""] + head
    out += [_row(label, model, "pbrt") for label, model in PBRT]
    out += ["", "### Shipped synthetic models (`data/synthetic/*.h5` truths)", "",
            "| file | model | export | cosine-weighted relative RMS | largest relative |", "|---|---|---|---|---|"]
    for name in ("plastic", "gold", "clay", "brushed-aluminium", "lafortune-retro", "toon"):
        model = _synthetic(name)
        exportable = all(lobe.name in ("lambert", "cook-torrance", "ggx") for lobe in model.lobes)
        for to in ("mitsuba", "pbrt"):
            for fit in ((False, True) if exportable else (True,)):
                result = export_details(model, to, fit=fit)
                deviation = (measure(model, lambda wi, wo: evaluate_in_mitsuba(result.text, wi, wo))
                             if to == "mitsuba" else result.deviation)
                how = f"{to}{' --fit' if fit else ''}"
                out.append(f"| `{name}.h5` | `{model.spec}` | {how} | {deviation.rms:.3g} | {deviation.max_rel:.3g} |")
    out += ["", "### Fresnel: Schlick's curve against the exact terms the renderers have", ""] + _fresnel_table()
    return "\n".join(out) + "\n"


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
