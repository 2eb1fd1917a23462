"""What the tests hold an exact Mitsuba 3 export to (tests/test_principled.py, tests/test_roughplastic.py): a
brdffit lobe that claims to evaluate what a Mitsuba plugin evaluates, against the plugin itself.

Mitsuba runs in float32 (``scalar_rgb``), brdffit in float64: the comparison is relative, at the 95th percentile of
2,000 direction pairs uniform in solid angle (the largest differences sit where a lobe is steep and float32 rounds
the angles), as the models issue states it.
"""

from __future__ import annotations

import numpy as np

import brdffit
from brdffit.cli import EXIT_OK, main
from brdffit.export.mitsuba import evaluate_in_mitsuba
from brdffit.export.terms import random_pairs
from brdffit.models.model import evaluate_dirs

TOLERANCE = 1e-4  # relative, 95th percentile (float32 against float64)


def relative(f, g):
    """|f − g| / |g| elementwise (g the plugin's value)."""
    return np.abs(f - g) / np.maximum(np.abs(g), 1e-30)


def both(model, text: str, seed: int):
    """(``model``'s f_r, f_r of Mitsuba's plugin read from ``text``) at 2,000 random pairs, each ``(2000, 3)``."""
    wi, wo = random_pairs(2000, seed=seed)
    return np.asarray(evaluate_dirs(model, wi, wo)), evaluate_in_mitsuba(text, wi, wo)


def deviations(model, text: str, seed: int) -> np.ndarray:
    """The relative differences of ``model`` from Mitsuba's plugin read from ``text`` at 2,000 random pairs."""
    return relative(*both(model, text, seed))


def synth_fit_export(tmp_path, spec: str, truth: dict, n: int):
    """``brdffit synth SPEC`` (half-diff pattern, 0.5% relative noise, seed 4) -> ``brdffit fit --model SPEC`` ->
    ``brdffit export --to mitsuba``, run in this process (`brdffit.cli.main`; each command has a run as a process
    of its own in tests/test_memory_limits.py), each asserted to succeed.

    Returns:
        (the fit's `FitResult`, the export's text).
    """
    data, fit, out = tmp_path / "synth.h5", tmp_path / "fit", tmp_path / "material.xml"
    params = [arg for k, v in truth.items()
              for arg in ("--param", f"{k}={','.join(map(str, v)) if isinstance(v, list) else v}")]
    assert main(["synth", spec, *params, "--pattern", "half-diff", "--n", str(n), "--noise", "relative:0.005",
                 "--seed", "4", "--out", str(data), "--quiet"]) == EXIT_OK
    assert main(["fit", str(data), "--model", spec, "--out", str(fit), "--no-report", "--quiet"]) == EXIT_OK
    assert main(["export", str(fit / "result.h5"), "--to", "mitsuba", "--out", str(out)]) == EXIT_OK
    return brdffit.FitResult.load(fit / "result.h5"), out.read_text()
