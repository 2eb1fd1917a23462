"""Do the newer models earn a place among the selection's candidates? Their error on unseen directions of the
shared real materials, beside the default fit's and the independent reference's.

For each RGL-EPFL material of ../shared/data this fits every model of `MODELS` (plain `brdffit.fit`, default
options, to the same fit data as `brdffit fit FILE`: the file's interpolation at its default direction pairs) and
scores it exactly as scripts/real_data_gallery.py scores the default fit: the cosine-weighted error
‖(f_m − f_d) cosθi‖ / ‖f_d cosθi‖ at the gallery's 100,000 test pairs (`real_data_gallery.heldout_points`, seed
202, θ <= 80°), which no fit used. The default fit's and the reference's errors are read from
docs/real-data/gallery.json (same pairs). Writes docs/real-data/candidates.json and prints a Markdown table for
docs/model-selection.md.

Usage: ``.venv/bin/python scripts/candidate_gallery.py [--only NAME ...]`` (about 10 minutes on the 2-core
development machine).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts"))

import real_data_gallery as gallery  # noqa: E402

MODELS = (
    "lambert+ggx(shadowing=smith-correlated)",
    "lambert+cook-torrance(distribution=std, shadowing=smith)",
    "burley+ggx",
    "lambert+ggx+sheen",
    "lambert+ggx+charlie-sheen",
    "lambert+abc-microfacet",
    "lambert+abc-smooth",
    "principled",
    "lambert+cook-torrance(distribution=gtr, shadowing=smith)",
    "lambert+sgd",
)
OUTPUT = ROOT / "docs" / "real-data" / "candidates.json"


def markdown(out: dict) -> str:
    """The table of docs/model-selection.md: one row per model, one column per material."""
    rows = out["rows"]
    lines = ["| model | " + " | ".join(r["name"] for r in rows) + " |", "|---|" + "---|" * len(rows),
             "| default fit (its model) | " + " | ".join(f"{r['default']:.3f} (`{r['default_model']}`)" for r in rows)
             + " |",
             "| independent reference | " + " | ".join(f"{r['reference']:.3f}" for r in rows) + " |"]
    for m in out["models"]:
        lines.append(f"| `{m}` | " + " | ".join(f"{r['models'][m]['test']:.3f} ({r['models'][m]['test'] / r['default']:.2f}×)"
                                                for r in rows) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", metavar="NAME", help="materials to measure (default: every RGL one)")
    parser.add_argument("--models", nargs="+", metavar="SPEC", default=list(MODELS),
                        help="models to fit (default: all of MODELS); the others' stored numbers are kept")
    args = parser.parse_args(argv)

    import brdffit
    from brdffit.compilation_cache import enable_compilation_cache

    enable_compilation_cache()
    stored = {row["name"]: row for row in json.loads((ROOT / "docs" / "real-data" / "gallery.json").read_text())["rows"]}
    out = json.loads(OUTPUT.read_text()) if OUTPUT.exists() else {"rows": []}
    out["models"] = [m for m in MODELS if m in args.models or m in out.get("models", [])]
    kept = {row["name"]: row for row in out["rows"]}
    for entry in gallery.materials():
        if entry["kind"] != "rgl" or (args.only and entry["name"] not in args.only):
            continue
        measurements = gallery.load_measurements(entry)
        row = stored[entry["name"]]
        angles, f_data, _ = gallery.heldout_points(row, measurements)
        cos_i = np.cos(angles[0])
        result = {"name": entry["name"], "default_model": row["model"], "default": row["heldout"]["cosine"],
                  "reference": row["reference"]["test_error"], "models": dict(kept.get(entry["name"], {})
                                                                                .get("models", {}))}
        for spec in args.models:
            fitted = brdffit.fit(measurements, spec)
            error = gallery.errors(fitted.predict(*angles), f_data, cos_i)["cosine"]
            result["models"][spec] = {"test": error, "status": str(fitted.status), "n_params": fitted.n_params}
            print(f"{entry['name']:20s} {spec:58s} {error:.4f} (default {result['default']:.4f}, reference "
                  f"{result['reference']:.4f}) {fitted.status}", flush=True)
        kept[entry["name"]] = result
    out["rows"] = list(kept.values())
    OUTPUT.write_text(json.dumps(out, indent=1) + "\n")
    print()
    print(markdown(out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
