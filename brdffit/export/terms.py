"""What every export target shares: the lobes of a model read off as renderer-neutral terms, the written
material as a brdffit model again, the measured deviation of an approximate mapping, and the Schlick -> complex
index fit.

A target (`brdffit.export.mitsuba`, `brdffit.export.pbrt`) maps the source model's terms onto its plugins and
returns, with the text, what it wrote as a function of the direction pair. `measure` compares that with the source
at fixed random direction pairs, and the deviation goes into the export's comments (docs/export.md).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from ..models import Model
from ..models.cook_torrance import CookTorrance
from ..models.diffuse import Lambert
from ..models.layout import layout
from ..models.model import evaluate_dirs
from .registry import ExportError

__all__ = ["ExportError", "Term", "terms", "assemble", "evaluate_dirs", "reflects_nothing", "f0_to_eta",
           "schlick_to_conductor", "Deviation", "measure", "random_pairs", "number", "rgb"]

MICROFACET_LOBES = ("cook-torrance", "ggx")
# Direction pairs of the measured deviation (uniform in solid angle on each hemisphere).
DEVIATION_PAIRS = 2000
DEVIATION_SEED = 20260
# The deviation reports the largest relative error over the values above this fraction of the peak, where a
# relative error means something; the cosine-weighted RMS covers all.
RELATIVE_FLOOR = 1e-3


@dataclasses.dataclass(frozen=True)
class Term:
    """One lobe of a model in the renderers' vocabulary.

    Attributes:
        lobe: the brdffit lobe (a `Lambert` or a `CookTorrance`/`GGX`; other lobes are not terms).
        params: its parameters under the lobe's own names (``rho_d``; ``ks``, ``m`` or ``alpha``, ``f0`` or
            ``eta`` and ``k``), as float arrays.
    """

    lobe: object
    params: dict

    @property
    def diffuse(self) -> bool:
        return self.lobe.name == "lambert"

    @property
    def alpha(self) -> float:
        """The microfacet width (Walter et al.'s m = GGX α)."""
        return float(self.params[self.lobe.roughness_name])


def terms(model: Model, exportable: str) -> list[Term]:
    """The model's lobes as `Term`s.

    Arguments:
        model: the source model.
        exportable: the sentence naming what the target takes, for the error message.

    Returns:
        One `Term` per lobe, in the model's order.

    Raises:
        ExportError: for a lobe that is neither ``lambert`` nor a microfacet lobe (naming it).
    """
    out = []
    for j, lobe in enumerate(model.lobes):
        if lobe.name != "lambert" and lobe.name not in MICROFACET_LOBES:
            raise ExportError(f"lobe {lobe.name!r} of model {model.spec!r} has no equivalent in Mitsuba 3 or "
                              f"pbrt-v4; exportable: {exportable}; or export with fit=True (--fit), which fits "
                              "the renderer's own model to it (docs/export.md)")
        local = model.layout.local_params(model.params, j)
        out.append(Term(lobe, {k: np.asarray(v, dtype=float) for k, v in local.items()}))
    return out


def assemble(parts: list[tuple[object, dict]], channels: int) -> Model:
    """A brdffit model that is the sum of ``parts``.

    Arguments:
        parts: (lobe, parameters under the lobe's own names) pairs.
        channels: the channel count.

    Returns:
        The `Model` (the written material, read back in brdffit's terms).
    """
    lobes = tuple(lobe for lobe, _ in parts)
    table = layout(lobes, channels)
    values = {}
    for j, (_, local) in enumerate(parts):
        values.update(table.global_names(j, local))
    model = Model(params={s.name: s.initial(channels) for s in table.specs}, lobes=lobes, channels=channels)
    return model.replace(**values)


def lambert_lobe() -> Lambert:
    return Lambert()


def microfacet_lobe(distribution: str, fresnel: str) -> CookTorrance:
    """The brdffit lobe of a renderer's microfacet plugin: separable Smith, the given D and Fresnel mode."""
    return CookTorrance(distribution=distribution, shadowing="smith", fresnel=fresnel)


def reflects_nothing(eta) -> bool:
    """True for a dielectric index of 1 (to rounding): its Fresnel term is 0 at every angle, the lobe is 0."""
    return float(eta) <= 1.0 + 1e-12


def f0_to_eta(f0: float) -> float:
    """Refractive index η of the dielectric (seen from vacuum) whose normal-incidence reflectance is f0.

    Inverts f0 = ((η − 1)/(η + 1))²: η = (1 + √f0)/(1 − √f0); f0 = 0.04 gives η = 1.5.

    Arguments:
        f0: Schlick's normal-incidence reflectance.

    Returns:
        η >= 1.

    Raises:
        ExportError: for f0 outside [0, 1).
    """
    f0 = float(f0)
    if not 0.0 <= f0 < 1.0:
        raise ExportError(f"Schlick f0 must lie in [0, 1) to have a dielectric index, got {f0}")
    s = math.sqrt(f0)
    return (1.0 + s) / (1.0 - s)


def _conductor_fresnel(c, eta, k):
    # Unpolarised Fresnel reflectance of a complex index η + ik from vacuum (Born & Wolf 1.5.2; pbrt-v4
    # util/scattering.h FrComplex), in complex arithmetic.
    n = eta + 1j * k
    cos_t = np.sqrt(1.0 - (1.0 - c * c) / (n * n))
    r_par = (n * c - cos_t) / (n * c + cos_t)
    r_perp = (c - n * cos_t) / (c + n * cos_t)
    return 0.5 * (np.abs(r_par) ** 2 + np.abs(r_perp) ** 2)


@functools.lru_cache(maxsize=256)
def schlick_to_conductor(f0: float) -> tuple[float, float, float]:
    """The complex index (η, k) whose exact Fresnel curve is closest to Schlick's with this f0.

    Schlick (1994, Eq. 24) F = f0 + (1 − f0)(1 − cosθ)⁵ is no physical Fresnel term; the renderers' microfacet
    plugins take an index. η is searched on a grid and refined by least squares over cosθ in [0, 1] (uniform
    in cosθ, the measure of the reflected radiance), relative to Schlick's value plus 0.05 so that the small
    values near normal incidence count as much as the grazing ones.

    Arguments:
        f0: Schlick's normal-incidence reflectance in [0, 1].

    Returns:
        (η, k, largest absolute difference of the two curves over cosθ in [0, 1]).
    """
    from scipy.optimize import least_squares

    c = np.linspace(0.0, 1.0, 201)
    target = f0 + (1.0 - f0) * (1.0 - c) ** 5

    def residual(x):
        return (_conductor_fresnel(c, x[0], x[1]) - target) / (target + 0.05)

    best = None
    lower, upper = [1e-3, 0.0], [10.0, 20.0]
    # Starts: the dielectric of the same f0 (inside the bounds: f0 = 0.68 is η = 10.3), a weak and a strong
    # conductor.
    for start in ((f0_to_eta(min(f0, 0.99)), 0.0), (1.0, 0.3), (0.5, 2.0)):
        sol = least_squares(residual, np.clip(start, lower, upper), bounds=(lower, upper))
        if best is None or sol.cost < best.cost:
            best = sol
    eta, k = (float(v) for v in best.x)
    return eta, k, float(np.max(np.abs(_conductor_fresnel(c, eta, k) - target)))


def random_pairs(n: int = DEVIATION_PAIRS, seed: int = DEVIATION_SEED):
    """Direction pairs uniform in solid angle on the upper hemisphere, the same every call.

    Arguments:
        n: number of pairs.
        seed: NumPy seed.

    Returns:
        (wi, wo), each ``(n, 3)`` unit vectors with z > 0.
    """
    rng = np.random.default_rng(seed)

    def draw():
        v = rng.normal(size=(n, 3))
        v[:, 2] = np.abs(v[:, 2]) + 1e-9
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    return draw(), draw()


@dataclasses.dataclass(frozen=True)
class Deviation:
    """How far a written material is from the source model.

    Attributes:
        rms: cosine-weighted relative RMS error, ‖(f_written − f) cosθi‖ / ‖f cosθi‖ over all pairs and channels
            (the error in reflected radiance that the "cosine" loss of a fit minimises).
        max_rel: largest |f_written − f| / f over the values above `RELATIVE_FLOOR` times the peak.
        pairs: number of direction pairs.
    """

    rms: float
    max_rel: float
    pairs: int

    def exact(self, tol: float = 1e-6) -> bool:
        """True where the mapping is exact up to rounding."""
        return self.rms <= tol and self.max_rel <= tol

    def describe(self) -> str:
        return (f"cosine-weighted relative RMS error {self.rms:.3g}, largest relative error {self.max_rel:.3g} "
                f"(values above {RELATIVE_FLOOR:g} of the peak), over {self.pairs} random direction pairs")


def measure(source: Model, written, n: int = DEVIATION_PAIRS, seed: int = DEVIATION_SEED) -> Deviation:
    """The deviation of a written material from the source model at `random_pairs`.

    Arguments:
        source: the brdffit model.
        written: a function (wi, wo) -> f_r of shape ``(n, channels)`` (or ``(n, 3)`` for an RGB material of a
            single-channel model), or a `Model`.
        n, seed: as `random_pairs`.

    Returns:
        The `Deviation`.
    """
    wi, wo = random_pairs(n, seed)
    f = np.asarray(evaluate_dirs(source, wi, wo), dtype=float)
    evaluate = (lambda a, b: np.asarray(evaluate_dirs(written, a, b))) if isinstance(written, Model) else written
    g = np.asarray(evaluate(wi, wo), dtype=float)
    f = np.broadcast_to(f, g.shape)
    cos = wi[:, 2:3]
    denominator = np.sqrt(np.sum((f * cos) ** 2))
    rms = float(np.sqrt(np.sum(((g - f) * cos) ** 2)) / denominator) if denominator > 0 else float(np.abs(g).max())
    keep = f > RELATIVE_FLOOR * f.max() if f.max() > 0 else np.zeros(f.shape, bool)
    max_rel = float(np.max(np.abs(g - f)[keep] / f[keep])) if keep.any() else 0.0
    return Deviation(rms=rms, max_rel=max_rel, pairs=n)


def number(v) -> str:
    """A float as text, exact to 10 significant digits."""
    return format(float(v), ".10g")


def rgb(values) -> list[float]:
    """Three floats: a single channel repeated, or the three channels."""
    values = np.atleast_1d(np.asarray(values, dtype=float))
    return [float(values[0])] * 3 if values.size == 1 else [float(v) for v in values]
