"""Regenerate the shipped synthetic data sets in data/synthetic/ and their README.

Usage:
    python scripts/make_synthetic.py [OUT_DIR] [--only NAME ...]

Every material is one call of `brdffit.synth.generate` with a fixed seed, so running the script twice gives the
same values (tests/test_synth.py regenerates one file and compares it with the shipped one). The README table is
written from the same list, so the documented truths cannot drift from the files.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

import numpy as np

from brdffit import io, models, synth

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "data" / "synthetic"


@dataclasses.dataclass(frozen=True)
class Material:
    """One shipped data set: a model with its true parameters, a sampling pattern, a noise and a seed."""

    name: str
    title: str
    spec: str
    params: dict
    pattern: str
    n: int | None
    noise: str
    seed: int
    max_theta_deg: float | None = None
    options: dict = dataclasses.field(default_factory=dict)

    @property
    def filename(self) -> str:
        return f"{self.name}.h5"

    def model(self) -> models.Model:
        return models.get(self.spec, channels=3, **self.params)


MATERIALS = (
    Material(
        name="clay", title="matte clay", spec="oren-nayar",
        params={"rho_d": (0.62, 0.42, 0.30), "sigma": 0.4},
        pattern="uniform", n=2000, noise="signal-dependent:0.0005,0.01", seed=101,
    ),
    Material(
        name="plastic", title="red plastic (the Quick start file)", spec="lambert+cook-torrance",
        params={"rho_d": (0.55, 0.12, 0.08), "ks": 1.0, "m": 0.15, "f0": 0.04},
        pattern="gonio-grid", n=None, noise="relative:0.01", seed=102, max_theta_deg=80.0,
        options={"theta_i": tuple(math.radians(t) for t in range(0, 80, 10)), "n_theta_o": 12, "n_phi_o": 32},
    ),
    Material(
        name="gold", title="rough gold (conductor Fresnel, GGX, Smith)",
        spec="cook-torrance(distribution=ggx, shadowing=smith, fresnel=conductor)",
        params={"ks": 1.0, "m": 0.2, "eta": (0.18, 0.42, 1.37), "k": (3.42, 2.35, 1.77)},
        pattern="merl", n=2500, noise="relative:0.02", seed=103,
    ),
    Material(
        name="brushed-aluminium", title="brushed aluminium (anisotropic Ward, brushed along y)",
        spec="lambert+ward-aniso",
        params={"rho_d": (0.05, 0.05, 0.06), "ks": (0.75, 0.76, 0.78), "alpha_x": 0.25, "alpha_y": 0.06},
        pattern="gonio-grid", n=None, noise="signal-dependent:0.001,0.01", seed=104, max_theta_deg=80.0,
        options={"theta_i": tuple(math.radians(t) for t in (20, 40, 60)),
                 "phi_i": tuple(math.radians(p) for p in (0, 45, 90)), "n_theta_o": 8, "n_phi_o": 32},
    ),
    Material(
        name="lafortune-retro", title="forward and retro-reflective lobes (two-lobe Lafortune)",
        spec="lambert+lafortune(lobes=2)",
        params={"rho_d": (0.25, 0.30, 0.35),
                "ks_1": 0.6, "cxy_1": -0.95, "cz_1": 0.9, "n_1": 40.0,
                "ks_2": (0.30, 0.25, 0.20), "cxy_2": 0.8, "cz_2": 0.8, "n_2": 6.0},
        pattern="half-diff", n=2500, noise="relative:0.01", seed=105,
    ),
    Material(
        name="toon", title="cel-shaded orange (toon diffuse + toon highlight)", spec="toon-diffuse+toon-specular",
        params={"rho_d": (0.80, 0.45, 0.20), "rho_shade": (0.25, 0.12, 0.05), "threshold": 0.5, "width": 0.02,
                "ks": 0.6, "threshold_2": 0.97, "width_2": 0.02},
        pattern="in-plane", n=1500, noise="gaussian:0.002", seed=106,
    ),
)


def build(material: Material):
    """The `Measurements` of one material (deterministic)."""
    max_theta = None if material.max_theta_deg is None else math.radians(material.max_theta_deg)
    data = synth.generate(material.model(), material.pattern, n=material.n, noise=material.noise,
                          seed=material.seed, max_theta=max_theta, **material.options)
    meta = {**data.meta, "name": material.name, "description": material.title,
            "source": f"scripts/make_synthetic.py ({material.name})"}
    return data.replace(meta=meta)


def _number(x: float) -> str:
    return f"{x:.6g}"


def format_params(model: models.Model) -> str:
    """``name=value`` for every parameter; a colour parameter with equal channels is written once."""
    parts = []
    for name, value in model.params.items():
        value = np.asarray(value, dtype=float)
        if value.ndim and np.all(value == value[0]):
            value = value[0]
        text = _number(float(value)) if value.ndim == 0 else "(" + ", ".join(_number(v) for v in value) + ")"
        parts.append(f"`{name}`={text}")
    return ", ".join(parts)


def _degrees(values) -> str:
    return ", ".join(_number(round(math.degrees(v), 6)) for v in values)


def format_pattern(material: Material, data) -> str:
    """The pattern with its resolved options, in degrees as a person reads them."""
    options = data.meta["pattern_options"]
    text = material.pattern
    if material.pattern == "gonio-grid":
        text += (f": θi = {_degrees(options['theta_i'])}°; φi = {_degrees(options['phi_i'])}°; "
                 f"{options['n_theta_o']} θo × {options['n_phi_o']} φo")
    elif material.pattern == "in-plane":
        phi_i = options["phi_i"]
        text += f": φi = {'random' if phi_i is None else _degrees([phi_i]) + '°'}, φo = φi + 180°"
    elif material.pattern == "merl":
        text += f": {data.n} of {options['cells']} cells"
    if material.max_theta_deg is not None:
        text += f"; θ ≤ {_number(material.max_theta_deg)}°"
    return text


def readme(materials=MATERIALS, built=None) -> str:
    """The text of data/synthetic/README.md."""
    built = built or {m.name: build(m) for m in materials}
    rows = []
    for m in materials:
        data = built[m.name]
        rows.append(f"| `{m.filename}` | {m.title} | `{m.model().spec}` | {format_params(m.model())} | "
                    f"{format_pattern(m, data)} | {data.n} | `{data.meta['noise']}` | {m.seed} |")
    table = "\n".join(rows)
    return f"""# Synthetic data

Measurements generated from known models by `brdffit.synth.generate`, so that fits can be checked against the
truth. Every file is HDF5 in brdffit's schema (docs/formats.md) and carries its ground truth in its metadata:

```python
import brdffit
from brdffit import synth

m = brdffit.io.load("data/synthetic/plastic.h5")
truth = synth.truth_model(m)          # the brdffit.Model the values were drawn from
print(m.meta["pattern"], m.meta["noise"], m.meta["seed"])
```

The files are written by `scripts/make_synthetic.py`, which also writes this README; do not edit either by hand.
Running the script again gives the same values (checked by `tests/test_synth.py`). Patterns, weights and noise
models are described in docs/synthesis.md. Angles in this table are in degrees; the files store radians. All
files have three channels R, G, B; a colour parameter written with one value has it in every channel.

| file | material | model spec | true parameters | pattern | samples | noise | seed |
|---|---|---|---|---|---|---|---|
{table}

Noise spec strings (`brdffit.synth.parse_noise`): `relative:r` is σ = r·f, `gaussian:s` is σ = s (1/sr),
`signal-dependent:a,b` is σ = a + b·f. The σ used is stored with each value. No value of these files fell below
zero, so none is missing.
"""


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", default=str(DEFAULT_OUT), help="output folder (default data/synthetic)")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="write only these materials (no README)")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    known = {m.name for m in MATERIALS}
    unknown = set(args.only or ()) - known
    if unknown:
        parser.error(f"unknown material {sorted(unknown)[0]!r}; known: {', '.join(sorted(known))}")
    chosen = [m for m in MATERIALS if args.only is None or m.name in args.only]
    built = {}
    for material in chosen:
        data = build(material)
        if data.meta["negatives"]:
            raise RuntimeError(f"{material.name}: {data.meta['negatives']} noisy values fell below zero; the README "
                               "promises none")
        built[material.name] = data
        path = out / material.filename
        io.save(data, path)
        print(f"{path}: {data.n} samples, {path.stat().st_size / 1024:.0f} KiB")
    if args.only is None:
        (out / "README.md").write_text(readme(MATERIALS, built), encoding="utf-8")
        print(f"{out / 'README.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
