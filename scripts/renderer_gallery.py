"""Every shared real material fitted for each renderer that has declared models (`brdffit fit --for TARGET`), its
cost against the unconstrained default fit on the same held-out rows, and its exports loaded in the real tools.

For each material of the real-data gallery (`scripts/real_data_gallery.py`: NIST PTFE at each wavelength, the five
RGL-EPFL materials, CEA's retro-reflective tape) and each target of `brdffit.export.FIT_TARGETS`:

- `brdffit.select(m, DEFAULT_CANDIDATES, target=TARGET)`: the target's choice and the unconstrained choice, with
  their held-out errors on the selection's own held-out rows (the 20% it holds out, seed 0), and their ratio;
- every parameter of the target's fit inside its declared bounds (the target's ranges);
- its export to the target (glTF: the Khronos glTF-Validator, no error; MaterialX and OpenPBR:
  `Document.validate()`; Mitsuba: `mitsuba.load_string`, no ``blendbsdf`` and no ``unbounded`` texture but a
  conductor's η and k; pbrt-v4, which cannot be installed here: the statements read back and every value in the
  ranges its scene parser takes), and whether the export states it exact.

Writes docs/real-data/renderers.json and prints the markdown table of docs/export.md ("Shared real materials").

Usage: python scripts/renderer_gallery.py [--only NAME ...] [--targets gltf,mitsuba]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from xml.etree import ElementTree

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT_JSON = ROOT / "docs" / "real-data" / "renderers.json"
VALIDATOR = ROOT / "tests" / "clients" / "validate_gltf.cjs"


def _gallery():
    spec = importlib.util.spec_from_file_location("real_data_gallery", ROOT / "scripts" / "real_data_gallery.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _in_range(result) -> bool:
    declared = result.model.param_specs
    return all(np.all(declared[name].lower <= np.asarray(v)) and np.all(np.asarray(v) <= declared[name].upper)
               for name, v in result.params.items())


def _cycles_difference(text: str, model) -> str:
    """Cycles' render of a Blender export against brdffit's of the model, as tests/test_export_blender.py compares
    them (tests/clients/cycles_comparison.py): 'ok (...)' within 3%, else 'FAILED (...)'."""
    sys.path.insert(0, str(ROOT / "tests"))
    from clients.cycles_comparison import brdffit_render, cycles_render, difference

    value = difference(cycles_render(text), brdffit_render(model))
    return f"{'ok' if value <= 0.03 else 'FAILED'} (Cycles render: {value:.2%})"


def _loads(text: str, target: str, model=None) -> str:
    """'ok' or what the real tool said of the export (``model``: the exported model, for the Cycles render)."""
    if target == "gltf":
        node = shutil.which("node")
        if node is None or not (ROOT / "node_modules" / "gltf-validator").is_dir():
            return "validator not installed"
        with tempfile.NamedTemporaryFile("w", suffix=".gltf", delete=False) as f:
            f.write(text)
        report = json.loads(subprocess.run([node, str(VALIDATOR), f.name], cwd=ROOT, capture_output=True, text=True,
                                           check=True, timeout=120).stdout)
        issues = report["issues"]
        return "ok" if issues["numErrors"] == 0 and issues["numWarnings"] == 0 else json.dumps(issues["messages"])
    if target in ("materialx", "openpbr"):  # both write a MaterialX document
        sys.path.insert(0, str(ROOT / "tests"))
        from clients.materialx_document import load

        valid, message = load(text).validate()
        return "ok" if valid else message
    if target == "blender":
        return _cycles_difference(text, model)
    if target == "mitsuba":
        import mitsuba as mi

        mi.set_variant("scalar_rgb")
        mi.load_string(text)
        # Unbounded textures only where the declared ranges allow them: a conductor's η and k (indices, not
        # reflectances; docs/export.md's --for table).
        root = ElementTree.fromstring(text)
        unbounded = {t.get("name") for t in root.iter("texture")
                     if any(b.get("name") == "unbounded" and b.get("value") == "true" for b in t.iter("boolean"))}
        if unbounded - {"eta", "k"} or root.find(".//bsdf[@type='blendbsdf']") is not None or \
                root.get("type") == "blendbsdf":
            return "unbounded values or a blend"
        return "ok" if not unbounded else "ok (η and k unbounded: indices)"
    if target == "pbrt":
        # No pbrt-v4 binary installs here: the statements are read back and held to what pbrt-v4's scene parser
        # and materials take (paramdict.cpp: an RGB albedo in [0, 1], no negative RGB; FrComplex needs η > 0; a
        # coated interface's η above 1, its slab's albedo in [0, 1]).
        from brdffit.export.pbrt_reference import parse

        def out_of_range(kind: str, key: str, value) -> bool:
            v = np.atleast_1d(np.asarray(value, dtype=float))
            if key in ("reflectance", "albedo"):
                return not np.all((v >= 0.0) & (v <= 1.0))
            if key == "eta":
                return not np.all(v > (1.0 if kind == "coateddiffuse" else 0.0))
            return key in ("k", "roughness", "thickness") and not np.all(v >= 0.0)

        bad = [f"{name}: {key} {value}" for name, material in parse(text).items() for key, value in material.items()
               if key not in ("type", "materials", "remaproughness") and out_of_range(material["type"], key, value)]
        return "read back, in pbrt-v4's ranges (no pbrt-v4 binary)" if not bad else "out of range: " + "; ".join(bad)
    return "not checked"


def run(entry: dict, target: str, gallery) -> dict:
    from brdffit import select
    from brdffit.export import export_details
    from brdffit.select import DEFAULT_CANDIDATES

    measurements = gallery.load_measurements(entry)
    start = time.perf_counter()
    selection = select(measurements, DEFAULT_CANDIDATES, target=target)
    seconds = time.perf_counter() - start
    rows = {row["spec"]: row for row in selection.table}
    mine, free = rows[selection.chosen], rows[selection.chosen_by_criterion]
    details = export_details(selection.result, target, name=entry["name"])
    return {"material": entry["name"], "target": target, "chosen": selection.chosen,
            "heldout": mine["heldout_error"], "free_chosen": selection.chosen_by_criterion,
            "free_heldout": free["heldout_error"], "ratio": mine["heldout_error"] / free["heldout_error"],
            "plausible": selection.plausible, "in_range": _in_range(selection.result),
            "exact": details.exact, "loads": _loads(details.text, target, selection.result.model), "seconds": seconds,
            "params": {k: np.asarray(v).tolist() for k, v in selection.result.params.items()}}


def markdown(records: list[dict]) -> str:
    lines = ["| material | target | its choice | held-out error | unconstrained choice | its held-out error | ratio "
             "| in range | export loads | exact |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in records:
        loads = r["loads"] + (f"; MaterialX: {r['loads_materialx']}" if "loads_materialx" in r else "")
        lines.append(f"| {r['material']} | {r['target']} | `{r['chosen']}` | {r['heldout']:.4g} | `{r['free_chosen']}` "
                     f"| {r['free_heldout']:.4g} | {r['ratio']:.2f} | {'yes' if r['in_range'] else '**no**'} "
                     f"| {loads} | {'yes' if r['exact'] else 'no'} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    from brdffit.compilation_cache import enable_compilation_cache
    from brdffit.export import FIT_TARGETS

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="*", help="material names (default: all)")
    parser.add_argument("--targets", default=",".join(t for t in FIT_TARGETS if t != "materialx"),
                        help="comma-separated targets (default: every --for target but materialx, whose fit is "
                             "gltf's; its export is checked from the gltf fit)")
    args = parser.parse_args(argv)
    enable_compilation_cache()
    gallery = _gallery()
    entries = [e for e in gallery.materials() if not args.only or e["name"] in args.only]
    previous = {(r["material"], r["target"]): r for r in json.loads(OUT_JSON.read_text())} if OUT_JSON.exists() else {}
    for entry in entries:
        for target in args.targets.split(","):
            record = run(entry, target, gallery)
            if target == "gltf":  # the MaterialX document of the same fit
                from brdffit import models
                from brdffit.export import export

                model = models.get("gltf", channels=len(record["params"]["base_color"]), **record["params"])
                record["loads_materialx"] = _loads(export(model, "materialx", name=entry["name"]), "materialx")
            previous[(record["material"], target)] = record
            print(f"{entry['name']:>20} {target:>8}: {record['chosen']} {record['heldout']:.4g} vs "
                  f"{record['free_chosen']} {record['free_heldout']:.4g} ({record['ratio']:.2f}x), loads "
                  f"{record['loads']}, {record['seconds']:.1f} s", flush=True)
    records = sorted(previous.values(), key=lambda r: (r["target"], r["material"]))
    OUT_JSON.write_text(json.dumps(records, indent=1) + "\n")
    print(markdown(records))
    return 0


if __name__ == "__main__":
    sys.exit(main())
