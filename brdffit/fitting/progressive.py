"""Progressive fitting of multi-lobe models: K lobes start from the fitted K − 1 plus one new lobe.

Fitting K Lafortune lobes from scratch tends to end with two lobes sharing the work of one (a flat valley where
the solver crawls). Ngan et al. (2005) and Lafortune et al. (1997) fit lobes one after another instead; here
the K-lobe fit starts from the (K − 1)-lobe solution plus a new lobe tried forward, off-specular and retro at
several sharpnesses, all amplitudes re-solved by bounded linear least squares (`brdffit.fitting.separable`). A new
lobe the data do not need starts, and usually stays, at ks = 0, which the fit's status and warnings report.
"""

from __future__ import annotations

import itertools

import numpy as np

from .api import fit
from .result import FitResult

__all__ = ["fit_lobes", "lobe_spec", "new_lobe_candidates", "NEW_LOBE_DIRECTIONS", "NEW_LOBE_SHARPNESS"]

NEW_LOBE_DIRECTIONS = (-1.0, 0.0, 1.0)  # cxy of a forward, an off-specular and a retro-reflective lobe (cz = 1)
NEW_LOBE_SHARPNESS = (3.0, 10.0, 30.0, 100.0, 300.0)


def lobe_spec(k: int, base: str = "lambert", anisotropic: bool = False) -> str:
    """The spec of a base plus k Lafortune lobes, e.g. ``"lambert+lafortune(lobes=2)"``."""
    options = f"lobes={k}" + (", anisotropic=True" if anisotropic else "")
    lobes = f"lafortune({options})"
    return f"{base}+{lobes}" if base else lobes


def new_lobe_candidates(previous: FitResult | None, k: int, anisotropic: bool) -> list[dict] | str:
    """Start candidates of a K-lobe fit: the (K − 1)-lobe solution's shape parameters plus lobe K forward,
    off-specular or retro at each of `NEW_LOBE_SHARPNESS` (``"auto"`` when there is no previous fit)."""
    if previous is None:
        return "auto"
    kept = {name: np.asarray(value) for name, value in previous.params.items()
            if not name.startswith("ks") and not name.startswith("rho")}
    # Names of lobe j shift only when the base shares names with the lobes, which a Lafortune sum does not.
    candidates = []
    xy = ("cx", "cy") if anisotropic else ("cxy",)
    for c, n in itertools.product(NEW_LOBE_DIRECTIONS, NEW_LOBE_SHARPNESS):
        candidate = dict(kept)
        candidate.update({f"{name}_{k}": c for name in xy})
        candidate[f"n_{k}"] = n
        candidates.append(candidate)
    return candidates


def fit_lobes(measurements, kmax: int = 3, *, base: str = "lambert", anisotropic: bool = False,
              **fit_options) -> list[FitResult]:
    """Fit a base lobe plus K = 1..kmax Lafortune lobes, each K starting from the fitted K − 1.

    Arguments:
        measurements: `brdffit.Measurements`.
        kmax: the largest number of lobes.
        base: the spec of the base term (``"lambert"``; ``""`` for none).
        anisotropic: separate cx, cy per lobe.
        **fit_options: passed to `brdffit.fit` (loss, solver, fixed, ...; not ``init``).

    Returns:
        The K = 1..kmax `FitResult`s, in order (lobes sorted by exponent in each).
    """
    if kmax < 1:
        raise ValueError(f"kmax must be at least 1, got {kmax}")
    results: list[FitResult] = []
    for k in range(1, kmax + 1):
        init = new_lobe_candidates(results[-1] if results else None, k, anisotropic)
        results.append(fit(measurements, lobe_spec(k, base, anisotropic), init=init, **fit_options))
    return results
