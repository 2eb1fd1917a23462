"""What every export target shares: the lobes of a model read off as renderer-neutral terms, the written
material as a brdffit model again, the measured deviation of an approximate mapping, and the Schlick -> complex
index fit.

A target (`brdffit.export.mitsuba`, `brdffit.export.pbrt`) maps the source model's terms onto its plugins and
returns, with the text, what it wrote as a function of the direction pair. `measure` compares that with the source
at fixed direction pairs — uniform ones and ones concentrated near each lobe's peak (`peaks`, `deviation_pairs`),
combined by the balance heuristic — and the deviation goes into the export's comments (docs/export.md).
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
from ..models.peaks import Peak
from .registry import ExportError

__all__ = ["ExportError", "Term", "terms", "assemble", "evaluate_dirs", "reflects_nothing", "f0_to_eta",
           "check_channels", "own_model",
           "schlick_to_conductor", "Deviation", "measure", "random_pairs", "Peak", "peaks", "lobe_peaks", "Pairs",
           "deviation_pairs", "is_exact", "stated", "number", "rgb"]

MICROFACET_LOBES = ("cook-torrance", "ggx")
# The distributions the renderers' microfacet materials take (Beckmann or GGX; Blinn as Beckmann of the same m).
RENDERED_DISTRIBUTIONS = ("beckmann", "ggx", "blinn")
# Direction pairs of the measured deviation (uniform in solid angle on each hemisphere).
DEVIATION_PAIRS = 2000
DEVIATION_SEED = 20260
# Draws per peak sampling strategy (one per lobe width and kind, `peaks`), beside the uniform pairs.
PEAK_PAIRS = 1000
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


def terms(model: Model, exportable: str, target: str) -> list[Term]:
    """The model's lobes as `Term`s.

    Arguments:
        model: the source model.
        exportable: the sentence naming what the target takes, for the error message.
        target: the renderer's name, for the error message.

    Returns:
        One `Term` per lobe, in the model's order.

    Raises:
        ExportError: for a lobe that is neither ``lambert`` nor a microfacet lobe (naming it).
    """
    out = []
    for j, lobe in enumerate(model.lobes):
        if lobe.name != "lambert" and (lobe.name not in MICROFACET_LOBES or lobe.anisotropic
                                       or lobe.distribution not in RENDERED_DISTRIBUTIONS):
            raise ExportError(f"lobe {lobe.token()!r} of model {model.spec!r} has no equivalent in {target}; "
                              f"exportable: {exportable}; or export with fit=True (--fit), which fits the "
                              "renderer's own model to it (docs/export.md)")
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


_MIN_WIDTH, _MAX_WIDTH = 1e-4, 1.0


def lobe_peaks(lobe, params: dict) -> list[Peak]:
    """The peaks one lobe declares (`brdffit.models.lobe.Lobe.peaks`) at its parameter values, their widths
    clipped to [1e-4, 1] and named by the lobe.

    Arguments:
        lobe: a brdffit lobe.
        params: its parameters under the lobe's own names.

    Returns:
        A list of `Peak` (empty for a lobe that declares none, e.g. a diffuse one: the uniform pairs cover those).
    """
    return [dataclasses.replace(p, width=float(np.clip(p.width, _MIN_WIDTH, _MAX_WIDTH)), lobe=lobe.name)
            for p in lobe.peaks(params) if math.isfinite(p.width)]


def peaks(*models, parts=(), extra=()) -> list[Peak]:
    """The peaks of every lobe of the models (duplicates, same kind and axis with widths within 5%, once).

    Arguments:
        *models: brdffit models (the source, the written material read back as a model).
        parts: (lobe, parameters under the lobe's own names) pairs, as a target's written parts.
        extra: further `Peak`s (a renderer's own lobes, e.g. pbrt-v4's conductor roughness).

    Returns:
        A list of `Peak`.
    """
    found = [p for model in models for j, lobe in enumerate(model.lobes)
             for p in lobe_peaks(lobe, model.layout.local_params(model.params, j))]
    found += [p for lobe, local in parts for p in lobe_peaks(lobe, local)] + list(extra)
    out = []
    for p in found:
        if not any(q.kind == p.kind and q.axis == p.axis and abs(math.log(q.width / p.width)) < 0.05 for q in out):
            out.append(p)
    return out


@dataclasses.dataclass(frozen=True)
class Pairs:
    """Direction pairs of a measured deviation, with the solid-angle measure each stands for.

    Attributes:
        wi, wo: ``(n, 3)`` unit vectors above the surface.
        weight: ``(n,)`` in sr²: 1/Σ_k n_k p_k(ωi, ωo) over the sampling strategies k (the uniform pairs and one
            per `Peak`), with n_k the draws of strategy k and p_k its density in dωi dωo. Σ_j w_j F(pair j) is
            then an unbiased estimate of ∫∫ F dωi dωo: Veach's multi-sample estimator with the balance heuristic
            (Veach 1997, Robust Monte Carlo Methods for Light Transport Simulation, ch. 9, Eq. 9.8:
            w_k(x) = n_k p_k(x)/Σ_l n_l p_l(x)). A uniform pair away from every peak weighs (2π)²/n_uniform.
        near: ``(n,)`` True for the pairs drawn near a peak.
        peaks: the `Peak` strategies.
        uniform: the number of uniform pairs (the first ones).
    """

    wi: np.ndarray
    wo: np.ndarray
    weight: np.ndarray
    near: np.ndarray
    peaks: tuple
    uniform: int

    def __len__(self):
        return len(self.wi)


def _ggx_density(cos, alpha):
    """D(m) cosθm of the isotropic GGX distribution, the density in solid angle of `_ggx_draw` (0 for cos <= 0)."""
    c = np.maximum(cos, 0.0)
    a2 = alpha * alpha
    return np.where(cos > 0.0, a2 * c / (np.pi * (c * c * (a2 - 1.0) + 1.0) ** 2), 0.0)


def _ggx_draw(rng, n, alpha):
    """Directions about +z with density D cosθ: tan²θ = α² u/(1 − u), φ = 2π v (Walter et al. 2007, Eqs. 35-36)."""
    u, v = rng.random(n), rng.random(n)
    cos = 1.0 / np.sqrt(1.0 + alpha * alpha * u / (1.0 - u))
    sin = np.sqrt(np.maximum(1.0 - cos * cos, 0.0))
    phi = 2.0 * np.pi * v
    return np.stack([sin * np.cos(phi), sin * np.sin(phi), cos], axis=1)


def _frame(d):
    """Two unit vectors completing each row of d to an orthonormal basis (Duff et al. 2017, branchless)."""
    sign = np.where(d[:, 2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + d[:, 2])
    b = d[:, 0] * d[:, 1] * a
    t = np.stack([1.0 + sign * d[:, 0] ** 2 * a, sign * b, -sign * d[:, 0]], axis=1)
    s = np.stack([b, sign + d[:, 1] ** 2 * a, -d[:, 1]], axis=1)
    return t, s


def _cone_axis(peak: Peak, wi):
    d = wi * np.asarray(peak.axis, dtype=float)
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    return d / np.maximum(norm, 1e-300), norm[:, 0] > 0.0


def _draw(peak: Peak, wi, rng):
    """ωo of one strategy for each ωi (some fall below the horizon; the caller drops them)."""
    local = _ggx_draw(rng, len(wi), peak.width)
    if peak.kind == "half":
        h = local
        return 2.0 * np.sum(wi * h, axis=1, keepdims=True) * h - wi
    d, _ = _cone_axis(peak, wi)
    t, s = _frame(d)
    return local[:, :1] * t + local[:, 1:2] * s + local[:, 2:] * d


def _density(peak: Peak, wi, wo):
    """p(ωi, ωo) in dωi dωo of one strategy: ωi uniform, 1/(2π), times the density of ωo given ωi."""
    if peak.kind == "half":
        # dωo = 4 (ωo·h) dωh (Walter et al. 2007, Eq. 14), h = normalize(ωi + ωo).
        h = wi + wo
        h = h / np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-300)
        o_h = np.sum(wo * h, axis=1)
        p = np.where(o_h > 0.0, _ggx_density(h[:, 2], peak.width) / (4.0 * np.maximum(o_h, 1e-300)), 0.0)
    else:
        d, ok = _cone_axis(peak, wi)
        p = np.where(ok, _ggx_density(np.sum(wo * d, axis=1), peak.width), 0.0)
    return p / (2.0 * np.pi)


def deviation_pairs(peak_list=(), n: int = DEVIATION_PAIRS, seed: int = DEVIATION_SEED,
                    per_peak: int = PEAK_PAIRS) -> Pairs:
    """The direction pairs of a measured deviation: `random_pairs` plus ``per_peak`` draws near each peak.

    Each near-peak draw takes ωi uniform on the hemisphere and ωo from the `Peak`'s distribution about the mirror
    (or back-scattering, or Lafortune) direction of ωi; draws below the horizon are dropped (they count as draws,
    so the weights stay unbiased). The weights combine the strategies by the balance heuristic (`Pairs`).

    Arguments:
        peak_list: the `Peak` strategies (`peaks` of the models compared); none gives the uniform pairs alone.
        n: uniform pairs.
        seed: NumPy seed (the same arguments give the same pairs).
        per_peak: draws per peak.

    Returns:
        `Pairs`, the uniform pairs first.
    """
    peak_list = tuple(peak_list)
    wi, wo = random_pairs(n, seed)
    near = [np.zeros(n, bool)]
    wis, wos = [wi], [wo]
    for k, peak in enumerate(peak_list):
        rng = np.random.default_rng([seed, k + 1])
        v = rng.normal(size=(per_peak, 3))
        v[:, 2] = np.abs(v[:, 2]) + 1e-9
        a = v / np.linalg.norm(v, axis=1, keepdims=True)
        b = _draw(peak, a, rng)
        keep = b[:, 2] > 1e-9
        b = b[keep] / np.linalg.norm(b[keep], axis=1, keepdims=True)
        wis.append(a[keep])
        wos.append(b)
        near.append(np.ones(len(b), bool))
    wi, wo = np.concatenate(wis), np.concatenate(wos)
    combined = np.full(len(wi), n / (2.0 * np.pi) ** 2) + sum(per_peak * _density(peak, wi, wo) for peak in peak_list)
    return Pairs(wi, wo, 1.0 / combined, np.concatenate(near), peak_list, n)


@dataclasses.dataclass(frozen=True)
class Deviation:
    """How far a written material is from the source model.

    Attributes:
        rms: cosine-weighted relative RMS error, (∫∫ ((f_written − f) cosθi)² / ∫∫ (f cosθi)²)^½ over both
            hemispheres and all channels (the error in reflected radiance that the "cosine" loss of a fit
            minimises), estimated from the uniform and the near-peak pairs with their balance-heuristic weights
            (`Pairs`).
        max_rel: largest |f_written − f| / f over all the pairs, at the values above `RELATIVE_FLOOR` times the
            largest value found.
        pairs: number of direction pairs (uniform and near-peak).
        uniform_rms, uniform_max_rel: the same from the uniform pairs alone (what they would have said; they
            can miss a sharp peak).
        near_pairs: how many of the pairs were drawn near a peak.
        sample: the `Pairs` (not compared, not shown).
    """

    rms: float
    max_rel: float
    pairs: int
    uniform_rms: float = math.nan
    uniform_max_rel: float = math.nan
    near_pairs: int = 0
    sample: Pairs | None = dataclasses.field(default=None, repr=False, compare=False)

    def exact(self, tol: float = 1e-6) -> bool:
        """True where the mapping is exact up to rounding (near the peaks too)."""
        return self.rms <= tol and self.max_rel <= tol

    def describe(self) -> str:
        text = (f"cosine-weighted relative RMS error {self.rms:.3g}, largest relative error {self.max_rel:.3g} "
                f"(values above {RELATIVE_FLOOR:g} of the peak), over {self.pairs - self.near_pairs} uniform random "
                "direction pairs")
        if not self.near_pairs:
            return text + " (no lobe with a peak)"
        return text + (f" and {self.near_pairs} near the lobes' mirror or back-scattering directions, combined by "
                       f"the balance heuristic; the uniform pairs alone: {self.uniform_rms:.3g}, "
                       f"{self.uniform_max_rel:.3g}")


def is_exact(deviation: Deviation, notes) -> bool:
    """Whether an export calls itself exact: the deviation is at rounding level and nothing was approximated (a
    deviation at rounding level alone is not enough: before the near-peak pairs, the 2,000 uniform pairs missed an
    RGL gloss film's m = 0.005 Beckmann peak and measured 1.7e-27 through three approximations).

    Arguments:
        deviation: the measured `Deviation`.
        notes: the approximations the mapping made.

    Returns:
        True for an exact export.
    """
    return not notes and deviation.exact()


def stated(header: list[str], notes: list[str], deviation: Deviation, measured_by: str = "") -> list[str]:
    """The lines every renderer output opens with (as comments, or a glTF file's ``asset.extras``): ``header`` (the
    source, the version, the fit), one ``approximation:`` line per note, then ``exact:`` (`is_exact`) or the
    measured deviation, followed by `Deviation.describe`.

    Arguments:
        header: the opening lines.
        notes: the approximations the mapping made.
        deviation: the measured `Deviation`.
        measured_by: how the written material was evaluated, where that needs saying (pbrt-v4's formulas).

    Returns:
        The lines, without comment markers.
    """
    how = f" ({measured_by})" if measured_by else ""
    verdict = "exact: " if is_exact(deviation, notes) else f"measured deviation from the source model{how}: "
    return list(header) + [f"approximation: {note}" for note in notes] + [verdict + deviation.describe()]


def _errors(f, g, cos, weight):
    """(cosine-weighted relative RMS with these weights, largest relative error above the floor)."""
    w = weight[:, None]
    denominator = np.sqrt(np.sum(w * (f * cos) ** 2))
    rms = float(np.sqrt(np.sum(w * ((g - f) * cos) ** 2)) / denominator) if denominator > 0 else float(np.abs(g).max())
    keep = f > RELATIVE_FLOOR * f.max() if f.max() > 0 else np.zeros(f.shape, bool)
    max_rel = float(np.max(np.abs(g - f)[keep] / f[keep])) if keep.any() else 0.0
    return rms, max_rel


def measure(source: Model, written, n: int = DEVIATION_PAIRS, seed: int = DEVIATION_SEED,
            pairs: Pairs | None = None) -> Deviation:
    """The deviation of a written material from the source model.

    Arguments:
        source: the brdffit model.
        written: a function (wi, wo) -> f_r of shape ``(n, channels)`` (or ``(n, 3)`` for an RGB material of a
            single-channel model), or a `Model`.
        n, seed: as `deviation_pairs`, whose pairs near the `peaks` of ``source`` (and of ``written`` when it is
            a `Model`) are used unless ``pairs`` is given.
        pairs: the `Pairs` to measure at (a target passes the pairs near the peaks of both models).

    Returns:
        The `Deviation`.
    """
    if pairs is None:
        pairs = deviation_pairs(peaks(source, *([written] if isinstance(written, Model) else [])), n, seed)
    wi, wo = pairs.wi, pairs.wo
    f = np.asarray(evaluate_dirs(source, wi, wo), dtype=float)
    evaluate = (lambda a, b: np.asarray(evaluate_dirs(written, a, b))) if isinstance(written, Model) else written
    g = np.asarray(evaluate(wi, wo), dtype=float)
    f = np.broadcast_to(f, g.shape)
    cos = wi[:, 2:3]
    rms, max_rel = _errors(f, g, cos, pairs.weight)
    u = slice(0, pairs.uniform)
    uniform_rms, uniform_max_rel = _errors(f[u], g[u], cos[u], np.ones(pairs.uniform))
    return Deviation(rms=rms, max_rel=max_rel, pairs=len(pairs), uniform_rms=uniform_rms,
                     uniform_max_rel=uniform_max_rel, near_pairs=int(pairs.near.sum()), sample=pairs)


def check_channels(model, target: str):
    """Raise `ExportError` unless the model has 1 or 3 channels (the renderers take RGB)."""
    if model.channels not in (1, 3):
        raise ExportError(f"{target} takes RGB colours; model {model.spec!r} has {model.channels} channels. A "
                          "spectral fit is written as its sRGB equivalent when the wavelengths are given (export's "
                          "wavelengths=...; `brdffit export RESULT.h5` reads them from the measurements that `brdffit "
                          "fit` stores in the results file); otherwise fit RGB or single-channel data")


def own_model(model: Model, family: str, target: str, exportable: str, source=None):
    """The values of a target that writes one brdffit model of its own (glTF's ``gltf``, Blender's ``blender``),
    the material as written and its deviation from ``source`` (default ``model``).

    Arguments:
        model: the model to write: that lobe alone, 1 or 3 channels.
        family: the lobe's name; target: the target's name in messages; exportable: what the target writes, in words.
        source: the model the deviation is measured against (the original under the fit option).

    Returns:
        ``(values, written, deviation)``: the lobe's parameters as floats and RGB lists (what the file writes), a
        function (wi, wo) -> f_r of the material as written, and the `Deviation`.

    Raises:
        ExportError: another model, or a channel count other than 1 or 3.
    """
    check_channels(model, target)
    if len(model.lobes) != 1 or model.lobes[0].name != family:
        raise ExportError(f"{target} has no equivalent of {model.spec!r}: it writes {exportable}; fit that model "
                          f"for {target} (brdffit fit --for {family}), or export with the fit option (--fit), which "
                          "fits it to this one and states the deviation")
    local = model.layout.local_params(model.params, 0)
    values = {name: (rgb(value) if np.ndim(value) else float(value)) for name, value in local.items()}
    material = assemble([(model.lobes[0], {k: np.asarray(v, dtype=float) for k, v in values.items()})], 3)
    reference = model if source is None else source
    deviation = measure(reference, material, pairs=deviation_pairs(peaks(reference, material)))
    return values, (lambda wi, wo: np.asarray(evaluate_dirs(material, wi, wo))), deviation


def number(v) -> str:
    """A float as text, exact to 10 significant digits."""
    return format(float(v), ".10g")


def rgb(values) -> list[float]:
    """Three floats: a single channel repeated, or the three channels."""
    values = np.atleast_1d(np.asarray(values, dtype=float))
    return [float(values[0])] * 3 if values.size == 1 else [float(v) for v in values]
