"""The fit option's brdffit fit: ``lambert + ggx`` lobes, which Mitsuba 3 has exactly, fitted to a source model.

For a model whose lobes have no exact plugin (Oren-Nayar, Ward, Lafortune, V-cavity shadowing, a Schlick term
too bright for Mitsuba's principled, ...), the export can instead fit ``lambert + ggx`` lobes (separable Smith;
conductor Fresnel where the source lobe is a conductor, dielectric otherwise) to the source's noise-free values
with brdffit's own fit and its default cosine-weighted loss (Ngan et al. 2005). The values are taken at pairs drawn
like those of the stated deviation (`brdffit.export.terms.deviation_pairs`: uniform and near the source lobes'
peaks), with another seed, and each pair's balance-heuristic weight is its quadrature weight, so that the fit
minimises an unbiased estimate of the cosine-weighted error over both hemispheres, peaks included.
`brdffit.export.export_details` compares the candidates and writes the closest (docs/export.md).
"""

from __future__ import annotations

import numpy as np

from ..models import Model

__all__ = ["fit_exportable", "exportable_spec", "exportable_specs", "fit_data", "FIT_SAMPLES"]

FIT_SAMPLES = 2000


def exportable_spec(model: Model) -> str:
    """The spec of the exportable family fitted in place of ``model``: each lobe's `brdffit.models.lobe.Lobe`
    ``stand_in`` (a lambert for a diffuse lobe, a lambert and a GGX lobe for a renderer's material with a diffuse
    base) or else one GGX lobe with the lobe's Fresnel term (conductor for a conductor lobe, dielectric otherwise);
    the lamberts merged into one, first."""
    parts = []
    for lobe in model.lobes:
        fresnel = "conductor" if getattr(lobe, "fresnel", None) == "conductor" else "dielectric"
        parts += (lobe.stand_in or f"ggx(fresnel={fresnel})").split("+")
    return "+".join((["lambert"] if "lambert" in parts else []) + [part for part in parts if part != "lambert"])


# (spec, channels, parameter values, seed) -> (fitted model, comment): exporting one model to both renderers
# fits once.
_FITS: dict = {}


def exportable_specs(model: Model) -> list[str]:
    """The exportable families fitted in place of ``model``: `exportable_spec`, and where the model has a diffuse
    lobe and more, ``lambert`` alone (a floor: a lobe fitted where the source has a spike that the hemisphere
    samples see but a renderer's own model cannot follow can end farther from the source than its diffuse part
    alone; the export writes whichever candidate deviates least)."""
    spec = exportable_spec(model)
    return [spec] + (["lambert"] if spec.startswith("lambert+") else [])


def fit_exportable(model: Model, seed: int = 0, spec: str | None = None) -> tuple[Model, str]:
    """Fit an exportable family to ``model`` (remembered per model, family and seed).

    Arguments:
        model: the source model.
        seed: seed of the direction pairs and of the fit.
        spec: the family (one of `exportable_specs`); default `exportable_spec`.

    Returns:
        (the fitted model, a comment line naming the fit).
    """
    from ..fitting.api import fit

    spec = exportable_spec(model) if spec is None else spec
    key = (model.spec, model.channels, seed, spec,
           tuple((name, np.asarray(value, dtype=float).tobytes()) for name, value in sorted(model.params.items())))
    if key not in _FITS:
        data, pairs = fit_data(model, seed)
        result = fit(data, spec, seed=seed)
        _FITS[key] = (result.model, f"fit: {spec} was fitted to the source model {model.spec} at {pairs.uniform} "
                                    f"uniform direction pairs and {int(pairs.near.sum())} near its lobes' peaks "
                                    "(balance-heuristic weights) by brdffit's cosine-weighted least squares (status "
                                    f"{result.status}); that fit is what is written")
    return _FITS[key]


def fit_data(model: Model, seed: int = 0):
    """The noise-free measurements the fit option fits: ``model``'s values at `brdffit.export.terms.deviation_pairs`
    near its peaks (seed `DEVIATION_SEED` + 1 + ``seed``, not the stated deviation's), weighted by their
    balance-heuristic weights (scaled to mean 1).

    Returns:
        (`brdffit.Measurements`, the `brdffit.export.terms.Pairs`).
    """
    from ..measurements import Measurements
    from . import terms as tm

    pairs = tm.deviation_pairs(tm.peaks(model), n=FIT_SAMPLES, seed=tm.DEVIATION_SEED + 1 + seed)
    values = np.asarray(tm.evaluate_dirs(model, pairs.wi, pairs.wo), dtype=float)

    def angles(w):
        return np.arccos(np.clip(w[:, 2], 0.0, 1.0)), np.mod(np.arctan2(w[:, 1], w[:, 0]), 2.0 * np.pi)

    data = Measurements(*angles(pairs.wi), *angles(pairs.wo), values, weights=pairs.weight / pairs.weight.mean(),
                        meta={"source": f"brdffit.export.refit of {model.spec}"})
    return data, pairs
