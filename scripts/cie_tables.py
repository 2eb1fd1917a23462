"""Write (or check) brdffit/data/cie_1931_2deg_d65.csv, the colour tables of `brdffit.colour`.

The table holds, at 1 nm from 360 to 830 nm:

- the CIE 1931 2° standard observer's colour-matching functions x̄, ȳ, z̄ (ISO/CIE 11664-1:2019, CIE 018:2019;
  the CIE's 1 nm data set, as colour-science ships it: ``colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]``);
- the relative spectral power of CIE standard illuminant D65 (ISO/CIE 11664-2:2022, CIE 015:2018 Table 5): the 5 nm
  values, 300–780 nm from colour-science (``colour.SDS_ILLUMINANTS["D65"]``) and 785–830 nm from the standard's
  table (below), interpolated linearly to 1 nm, which is how the standard's own 1 nm table is made.

Needs colour-science (``pip install colour-science``). Usage:

    .venv/bin/python scripts/cie_tables.py           # write the file
    .venv/bin/python scripts/cie_tables.py --check   # compare the file with colour-science (exit 1 on a mismatch)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parents[1] / "brdffit" / "data" / "cie_1931_2deg_d65.csv"
GRID = np.arange(360, 831)
# CIE 015:2018 Table 5 (= ISO/CIE 11664-2), D65 at 785..830 nm in steps of 5 nm: colour-science's table stops at
# 780 nm.
D65_TAIL = {785: 63.8434, 790: 64.3040, 795: 61.8779, 800: 59.4519, 805: 55.7054, 810: 51.9590, 815: 54.6998,
            820: 57.4406, 825: 58.8765, 830: 60.3125}
HEADER = """\
# CIE 1931 2-degree standard observer colour-matching functions and CIE standard illuminant D65, 360-830 nm at 1 nm.
# xbar, ybar, zbar: ISO/CIE 11664-1:2019 (CIE 018:2019), the CIE 1 nm data set, as shipped by colour-science
#   (colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]).
# d65: relative spectral power of D65, ISO/CIE 11664-2 (CIE 015:2018 Table 5) 5 nm values (300-780 nm from
#   colour.SDS_ILLUMINANTS["D65"], 785-830 nm from the standard's table), interpolated linearly to 1 nm as the
#   standard's own 1 nm table is.
# Written by scripts/cie_tables.py (colour-science {version}); checked with scripts/cie_tables.py --check.
# columns: wavelength_nm,xbar,ybar,zbar,d65
"""


def tables():
    """(version of colour-science, the (471, 5) table)."""
    import colour

    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    xyz = np.asarray(cmfs[GRID], dtype=float)
    d65 = colour.SDS_ILLUMINANTS["D65"]
    nodes = np.concatenate([np.asarray(d65.wavelengths, dtype=float), np.array(sorted(D65_TAIL), dtype=float)])
    values = np.concatenate([np.asarray(d65.values, dtype=float), np.array([D65_TAIL[k] for k in sorted(D65_TAIL)])])
    if not np.all(np.diff(nodes) == 5.0):
        raise SystemExit(f"colour-science's D65 is not the 5 nm table 300-780 nm (nodes {nodes[0]}..{nodes[-1]})")
    return colour.__version__, np.column_stack([GRID, xyz, np.interp(GRID, nodes, values)])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="compare the file with colour-science instead")
    args = parser.parse_args(argv)
    version, table = tables()
    if args.check:
        stored = np.loadtxt(OUT, delimiter=",", comments="#")
        worst = float(np.max(np.abs(stored - table)))
        print(f"{OUT}: largest difference from colour-science {version}: {worst:.3g}")
        return 0 if worst <= 1e-9 else 1
    rows = "".join(f"{int(r[0])}," + ",".join(format(float(v), ".12g") for v in r[1:]) + "\n" for r in table)
    OUT.parent.mkdir(exist_ok=True)
    OUT.write_text(HEADER.format(version=version) + rows, encoding="utf-8")
    print(f"wrote {OUT} ({len(table)} rows)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
