"""Write (or check) brdffit/data/roughplastic_internal_reflectance.npz, the table of the smooth counterpart of
Mitsuba 3's ``roughplastic`` internal reflectance, R_smooth(α, η), that `brdffit.models.roughplastic` reads.

Each node is `brdffit.models.roughplastic.smooth_internal_reflectance` at √α = 0, 0.025, …, 1.025 and at 73 values
of √(η − 1) evenly spaced on [0, 1.44] (η from 1 to 3.07): one node beyond the declared ranges (α ≤ 1, η ≤ 3) on
the upper side, so that the lobe's cubic interpolation has its four nodes inside the table there.

Usage:

    .venv/bin/python scripts/roughplastic_table.py           # write the file (~10 minutes on 2 cores)
    .venv/bin/python scripts/roughplastic_table.py --check   # recompute 40 random nodes, exit 1 on a mismatch
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from brdffit.models import roughplastic as rp

OUT = Path(__file__).resolve().parents[1] / "brdffit" / rp.TABLE_FILE
SQRT_ALPHA = np.round(np.arange(0.0, 1.02501, 0.025), 10)
# √(η − 1): R_smooth rises from 0 at η = 1 like (η − 1)^(3/2), a cubic in this variable.
SQRT_ETA_MINUS_1 = np.linspace(0.0, 1.44, 73)
ETA = 1.0 + SQRT_ETA_MINUS_1**2


def _row(sqrt_alpha: float) -> list[float]:
    return [rp.smooth_internal_reflectance(sqrt_alpha * sqrt_alpha, eta) for eta in ETA]


def compute() -> np.ndarray:
    """The table, (len(SQRT_ALPHA), len(ETA)), computed on the host's cores."""
    with ProcessPoolExecutor() as pool:
        return np.array(list(pool.map(_row, SQRT_ALPHA)))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="recompute random nodes and compare with the file")
    args = parser.parse_args(argv)
    if args.check:
        table = np.load(OUT)
        rng = np.random.default_rng(0)
        worst = 0.0
        for _ in range(40):
            i, j = rng.integers(len(SQRT_ALPHA)), rng.integers(len(ETA))
            value = rp.smooth_internal_reflectance(SQRT_ALPHA[i] ** 2, ETA[j])
            worst = max(worst, abs(value - table["values"][i, j]))
        print(f"largest difference at 40 random nodes: {worst:.3g}")
        return 0 if worst <= 1e-12 else 1
    values = compute()
    tmp = OUT.with_suffix(".tmp.npz")
    np.savez(tmp, sqrt_alpha=SQRT_ALPHA, sqrt_eta_minus_1=SQRT_ETA_MINUS_1, values=values)
    tmp.replace(OUT)
    print(f"wrote {OUT} ({values.shape[0]} x {values.shape[1]} nodes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
