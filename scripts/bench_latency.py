"""Latency of what a user runs once per material, in fresh processes.

Each figure is the wall time of a new ``brdffit`` process, as a user starts it: the light commands (``--help``,
``models``, ``info``), a single-model fit of a 20,000-sample CSV with an empty and with a warm persistent
compilation cache (and a 17,000-sample file after the 20,000-sample one: another size), the default fit (model
selection over the standard candidates) with an empty and a warm cache, the README's Quick start job, and the
default fit of a real RGL-EPFL file (report included) with an empty and a warm cache, where ../shared is, and the
default fit of a 31-band ASTM E1392 file of 1,500 rows (report included) with an empty and a warm cache. The
host is shared, so each light command is run ``--repeats`` times and the median reported, and ``python -c
"import jax"`` is timed in the same run as the machine's baseline. The package's bytecode is compiled first, as
``pip install`` compiles it.

Usage: ``python scripts/bench_latency.py [--repeats 3] [--skip-selection]``; prints a Markdown table.
"""

from __future__ import annotations

import argparse
import compileall
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BRDFFIT = [sys.executable, "-m", "brdffit.cli"]

# (what, target seconds or None)
TARGETS = {
    "brdffit --help": 0.5, "brdffit models": 0.5, "brdffit info FILE": 0.5,
    "single fit, 20,000 samples, empty cache": 5.0, "single fit, 20,000 samples, warm cache": None,
    "single fit, 17,000 samples, warm cache (another size)": 3.0,
    "default fit (selection), 20,000 samples, empty cache": 20.0,
    "default fit (selection), 20,000 samples, warm cache": 8.0,
    "Quick start job (plastic.h5), empty cache": 30.0,
    "default fit of an RGL-EPFL file (paper_white_rgb.bsdf), empty cache": 10.0,
    "default fit of an RGL-EPFL file (paper_white_rgb.bsdf), warm cache": 5.0,
    "default fit of a 31-band ASTM E1392 file, 1,500 rows, empty cache": 30.0,
    "default fit of a 31-band ASTM E1392 file, 1,500 rows, warm cache": None,
}
# A real tabulated file, read as `brdffit fit FILE.bsdf` reads it (docs/formats.md); left out where ../shared is absent.
RGL_FILE = ROOT.parent / "shared" / "data" / "rgl-epfl" / "paper_white_rgb.bsdf"


def _run(command: list[str], env: dict) -> float:
    start = time.perf_counter()
    done = subprocess.run(command, env=env, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    seconds = time.perf_counter() - start
    if done.returncode not in (0, 1):  # 1: a fit that did not converge still timed the path
        raise SystemExit(f"{' '.join(command)} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    return seconds


def _data(folder: Path) -> tuple[Path, Path]:
    """The benchmark's CSV files: Lambert + Cook-Torrance, uniform directions, 1% noise."""
    import brdffit

    paths = []
    for n in (20_000, 17_000):
        path = folder / f"lambert-ct-{n}.csv"
        m = brdffit.synth.generate("lambert+cook-torrance", n=n, noise="relative:0.01", seed=5, max_theta=1.4)
        brdffit.io.save(m, path)
        paths.append(path)
    return paths[0], paths[1]


def _spectral(folder: Path) -> Path:
    """A 31-band ASTM E1392 file (400-700 nm every 10 nm) of 1,500 gonio-grid rows: Lambert + GGX with per-band
    amplitudes and one roughness, 1% relative noise (the material of tests/test_spectral.py)."""
    import numpy as np

    import brdffit

    bands = np.arange(400, 701, 10)
    rho = 0.2 + 0.5 * np.exp(-((bands - 470) / 60.0) ** 2)
    truth = brdffit.models.get("lambert+ggx", channels=len(bands), rho_d=rho, ks=np.full(len(bands), 0.3),
                               alpha=0.15)
    m = brdffit.synth.generate(truth, pattern="gonio-grid", n=1500, noise="relative:0.01", seed=3)
    path = folder / "paint-31-bands.astm"
    brdffit.io.save(m.replace(channels=[f"{w}nm" for w in bands]), path)
    return path


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="runs of each light command (median reported)")
    parser.add_argument("--skip-selection", action="store_true", help="leave out the two selection runs")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    # Every process starts from compiled bytecode, as an installed package does (pip compiles it at install). In a
    # checkout each module's is written at its first import, except under PYTHONDONTWRITEBYTECODE: every process
    # would then compile the modules edited since their bytecode was last written.
    compileall.compile_dir(str(ROOT / "brdffit"), quiet=1)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        big, other = _data(tmp)
        env = dict(os.environ, BRDFFIT_CACHE_DIR=str(tmp / "cache"))
        rows = {}
        rows["python -c 'import jax' (baseline)"] = statistics.median(
            _run([sys.executable, "-c", "import jax"], env) for _ in range(args.repeats))
        for what, command in [("brdffit --help", ["--help"]), ("brdffit models", ["models"]),
                              ("brdffit info FILE", ["info", str(big)])]:
            rows[what] = statistics.median(_run(BRDFFIT + command, env) for _ in range(args.repeats))
        def single(path, out):
            return BRDFFIT + ["fit", str(path), "--model", "lambert+cook-torrance", "--no-report", "--quiet",
                              "--out", str(tmp / out)]

        rows["single fit, 20,000 samples, empty cache"] = _run(single(big, "o1"), env)
        rows["single fit, 20,000 samples, warm cache"] = _run(single(big, "o2"), env)
        rows["single fit, 17,000 samples, warm cache (another size)"] = _run(single(other, "o3"), env)
        if not args.skip_selection:
            cold = dict(env, BRDFFIT_CACHE_DIR=str(tmp / "cache-selection"))
            selection = BRDFFIT + ["fit", str(big), "--no-report", "--quiet", "--out"]
            rows["default fit (selection), 20,000 samples, empty cache"] = _run(selection + [str(tmp / "s1")], cold)
            rows["default fit (selection), 20,000 samples, warm cache"] = _run(selection + [str(tmp / "s2")], cold)
        quick = dict(env, BRDFFIT_CACHE_DIR=str(tmp / "cache-quick"))
        rows["Quick start job (plastic.h5), empty cache"] = _run(
            BRDFFIT + ["fit", "data/synthetic/plastic.h5", "--out", str(tmp / "quick")], quick)
        if RGL_FILE.is_file():  # the whole default command, report included, as a user runs it
            rgl = dict(env, BRDFFIT_CACHE_DIR=str(tmp / "cache-rgl"))
            for k, state in enumerate(("empty", "warm")):
                rows[f"default fit of an RGL-EPFL file (paper_white_rgb.bsdf), {state} cache"] = _run(
                    BRDFFIT + ["fit", str(RGL_FILE), "--quiet", "--out", str(tmp / f"rgl{k}")], rgl)
        astm, spectral = _spectral(tmp), dict(env, BRDFFIT_CACHE_DIR=str(tmp / "cache-astm"))
        for k, state in enumerate(("empty", "warm")):
            rows[f"default fit of a 31-band ASTM E1392 file, 1,500 rows, {state} cache"] = _run(
                BRDFFIT + ["fit", str(astm), "--quiet", "--out", str(tmp / f"astm{k}")], spectral)
    print("| what | seconds | target | met |")
    print("|---|---|---|---|")
    for what, seconds in rows.items():
        target = TARGETS.get(what)
        met = "" if target is None else ("yes" if seconds <= target else "**no**")
        print(f"| {what} | {seconds:.2f} | {'' if target is None else f'≤ {target:g}'} | {met} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
