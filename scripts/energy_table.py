"""Measure the physical properties of every lobe and print them as Markdown tables (pasted into docs/properties.md).

For each lobe, at ks = 1 (or rs = 1, rho_d = 1, Fresnel f0 = 1 where the lobe has a Schlick term) and a rough and
a smooth setting, this prints:

- the reciprocity and isotropy errors (`brdffit.properties.reciprocity_error`, `isotropy_error`);
- the directional albedo at a few θi, its maximum over the 0-89.5° grid and where it occurs, and whether the lobe
  conserves energy (`max_albedo`, `is_energy_conserving`);
- the quadrature error estimate: the largest |a(default rule) − a(rule with 4x the nodes in θh and in azimuth)|
  over a grid of θi (and, for anisotropic lobes, of φi).

Usage:
    python scripts/energy_table.py [--factor 4]
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from brdffit import models
from brdffit import properties as props

# (lobe spec, setting label, parameters). Amplitudes are 1 so that the albedo is the lobe's own energy balance.
SETTINGS = [
    ("lambert", "rho_d=1", dict(rho_d=1.0)),
    ("oren-nayar", "σ=0.2", dict(rho_d=1.0, sigma=0.2)),
    ("oren-nayar", "σ=0.5", dict(rho_d=1.0, sigma=0.5)),
    ("phong", "n=10", dict(ks=1.0, n=10.0)),
    ("phong", "n=1000", dict(ks=1.0, n=1000.0)),
    ("blinn-phong", "n=10", dict(ks=1.0, n=10.0)),
    ("blinn-phong", "n=1000", dict(ks=1.0, n=1000.0)),
    ("ward", "α=0.5", dict(ks=1.0, alpha=0.5)),
    ("ward", "α=0.02", dict(ks=1.0, alpha=0.02)),
    ("ward-aniso", "αx=0.5, αy=0.2", dict(ks=1.0, alpha_x=0.5, alpha_y=0.2)),
    ("ward-aniso", "αx=0.02, αy=0.1", dict(ks=1.0, alpha_x=0.02, alpha_y=0.1)),
    ("ward-duer", "α=0.5", dict(ks=1.0, alpha=0.5)),
    ("ward-duer", "α=0.02", dict(ks=1.0, alpha=0.02)),
    ("cook-torrance", "m=0.5, f0=1", dict(ks=1.0, m=0.5, f0=1.0)),
    ("cook-torrance", "m=0.02, f0=1", dict(ks=1.0, m=0.02, f0=1.0)),
    ("cook-torrance(shadowing=smith)", "m=0.5, f0=1", dict(ks=1.0, m=0.5, f0=1.0)),
    ("cook-torrance(shadowing=smith)", "m=0.02, f0=1", dict(ks=1.0, m=0.02, f0=1.0)),
    ("cook-torrance(shadowing=none)", "m=0.5, f0=1", dict(ks=1.0, m=0.5, f0=1.0)),
    ("cook-torrance(shadowing=none)", "m=0.02, f0=1", dict(ks=1.0, m=0.02, f0=1.0)),
    ("cook-torrance(distribution=ggx)", "m=0.5, f0=1", dict(ks=1.0, m=0.5, f0=1.0)),
    ("cook-torrance(distribution=blinn)", "m=0.5, f0=1", dict(ks=1.0, m=0.5, f0=1.0)),
    ("cook-torrance(fresnel=conductor)", "gold, m=0.5", dict(ks=1.0, m=0.5)),
    ("cook-torrance(fresnel=dielectric)", "glass, m=0.5", dict(ks=1.0, m=0.5)),
    ("ggx", "α=0.5, f0=1", dict(ks=1.0, alpha=0.5, f0=1.0)),
    ("ggx", "α=0.02, f0=1", dict(ks=1.0, alpha=0.02, f0=1.0)),
    ("ggx(shadowing=smith-correlated)", "α=0.5, f0=1", dict(ks=1.0, alpha=0.5, f0=1.0)),
    ("ggx(anisotropic=true)", "αx=0.1, αy=0.5, f0=1", dict(ks=1.0, alpha_x=0.1, alpha_y=0.5, f0=1.0)),
    ("ggx(anisotropic=true, shadowing=smith-correlated)", "αx=0.1, αy=0.5, f0=1",
     dict(ks=1.0, alpha_x=0.1, alpha_y=0.5, f0=1.0)),
    ("cook-torrance(anisotropic=true, shadowing=smith-correlated)", "mx=0.3, my=0.08, f0=1",
     dict(ks=1.0, m_x=0.3, m_y=0.08, f0=1.0)),
    ("cook-torrance(distribution=std, shadowing=smith)", "m=0.5, γ=1.6, f0=1", dict(ks=1.0, m=0.5, gamma=1.6, f0=1.0)),
    ("cook-torrance(distribution=std, shadowing=smith-correlated)", "m=0.5, γ=1.6, f0=1",
     dict(ks=1.0, m=0.5, gamma=1.6, f0=1.0)),
    ("cook-torrance(distribution=gtr, shadowing=smith)", "m=0.5, γ=1, f0=1", dict(ks=1.0, m=0.5, gamma=1.0, f0=1.0)),
    ("burley", "roughness=0", dict(rho_d=1.0, roughness=0.0)),
    ("burley", "roughness=1", dict(rho_d=1.0, roughness=1.0)),
    ("sheen", "ks=1", dict(ks=1.0)),
    ("charlie-sheen", "α=0.3", dict(ks=1.0, alpha=0.3)),
    ("charlie-sheen", "α=1", dict(ks=1.0, alpha=1.0)),
    ("ashikhmin-shirley", "n=10, rs=1", dict(rs=1.0, n=10.0)),
    ("ashikhmin-shirley", "n=1000, rs=1", dict(rs=1.0, n=1000.0)),
    ("ashikhmin-shirley-aniso", "nu=10, nv=100", dict(rs=1.0, nu=10.0, nv=100.0)),
    ("ashikhmin-shirley-aniso", "nu=100, nv=1000", dict(rs=1.0, nu=100.0, nv=1000.0)),
    ("lafortune", "specular, n=10", dict(ks_1=1.0, cxy_1=-1.0, cz_1=1.0, n_1=10.0)),
    ("lafortune", "specular, n=1000", dict(ks_1=1.0, cxy_1=-1.0, cz_1=1.0, n_1=1000.0)),
    ("lafortune", "retro, n=10", dict(ks_1=1.0, cxy_1=1.0, cz_1=1.0, n_1=10.0)),
    ("lafortune", "off-specular cxy=-0.5, n=10", dict(ks_1=1.0, cxy_1=-0.5, cz_1=1.0, n_1=10.0)),
    ("lafortune(anisotropic=true)", "cx=-1, cy=-0.5, n=10", dict(ks_1=1.0, cx_1=-1.0, cy_1=-0.5, cz_1=1.0, n_1=10.0)),
    ("lafortune(anisotropic=true)", "cx=-1, cy=-0.9, n=1000",
     dict(ks_1=1.0, cx_1=-1.0, cy_1=-0.9, cz_1=1.0, n_1=1000.0)),
    ("toon-diffuse", "rho_d=1, shade 0.1", dict(rho_d=1.0, rho_shade=0.1)),
    ("toon-specular", "threshold 0.95", dict(ks=1.0)),
    ("toon-specular", "threshold 0.5", dict(ks=1.0, threshold=0.5)),
]

SHOWN_THETA = (0.0, 45.0, 75.0, 85.0, 89.5)
ERROR_THETA = np.deg2rad([0, 5, 10, 20, 30, 40, 50, 60, 70, 75, 80, 83, 85, 86, 87, 88, 88.5, 89, 89.25, 89.5])
ERROR_PHI = np.deg2rad([0.0, 30.0, 60.0, 90.0])


def measure(spec, params, factor):
    model = models.get(spec, channels=1, **params)
    report = props.check(model)
    shown = np.asarray(props.directional_albedo(model, np.deg2rad(SHOWN_THETA)))[:, 0]
    # The default rule, as directional_albedo picks it, and the reference with `factor` times the nodes.
    n_theta = props.DEFAULT_RESOLUTION
    n_phi = props.DEFAULT_RESOLUTION if report.isotropic else props.ANISOTROPIC_AZIMUTH_RESOLUTION
    phi = ERROR_PHI if not report.isotropic else np.zeros(1)
    theta_all, phi_all = np.repeat(ERROR_THETA, phi.size), np.tile(phi, ERROR_THETA.size)
    base = np.asarray(props.directional_albedo(model, theta_all, phi_all))
    ref = np.asarray(props.directional_albedo(model, theta_all, phi_all,
                                              resolution=(factor * n_theta, factor * n_phi)))
    return report, shown, float(np.max(np.abs(base - ref)))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--factor", type=int, default=4,
                        help="node multiplier of the reference rule for the quadrature error estimate")
    args = parser.parse_args(argv)

    start = time.time()
    header = ("| lobe | setting | reciprocity error | isotropy error | "
              + " | ".join(f"a({t:g}°)" for t in SHOWN_THETA)
              + " | max a (θi) | conserving | quadrature error |")
    print(header)
    print("|" + "---|" * (header.count("|") - 1))
    worst = 0.0
    for spec, label, params in SETTINGS:
        report, shown, error = measure(spec, params, args.factor)
        worst = max(worst, error)
        where = f"{math.degrees(report.theta_i_max):.1f}°"
        if not report.isotropic and report.theta_i_max > 0.0:
            where += f", φi {math.degrees(report.phi_i_max):.0f}°"
        print(f"| `{spec}` | {label} | {report.reciprocity_error:.1e} | {report.isotropy_error:.1e} | "
              + " | ".join(f"{a:.4f}" for a in shown)
              + f" | {report.max_albedo:.4f} ({where}) | {'yes' if report.energy_conserving else '**no**'} | "
              f"{error:.1e} |")
    print()
    print(f"Largest quadrature error estimate (default rule against {args.factor}x the nodes in θh and azimuth, "
          f"over {ERROR_THETA.size} θi from 0 to 89.5°, and {ERROR_PHI.size} φi for anisotropic lobes): "
          f"{worst:.1e}. Energy grid: θi = 0-89.5° in 0.5° steps (and φi = 0-90° in 22.5° steps for anisotropic "
          f"lobes). {time.time() - start:.0f} s.")


if __name__ == "__main__":
    main()
