"""Mitsuba 3: a fitted model as a ``<bsdf version="3.0.0">`` document that ``mitsuba.load_string`` takes.

Plugins written (Mitsuba 3 ``src/bsdfs/``; parameters as its plugin tables document them):

- ``diffuse`` (``reflectance``): ρ/π, for every ``lambert`` lobe (summed).
- ``roughconductor`` (``distribution``, ``alpha``, ``eta``, ``k``, ``specular_reflectance``):
  ks F_conductor D G1 G1 / (4 cosθi cosθo), for ``fresnel=conductor``; with ``material`` none (η = 0, k = 1,
  F = 1) the constant part of a Schlick term.
- ``roughplastic`` (``diffuse_reflectance`` 0, ``int_ior``, ``ext_ior`` 1, ``specular_reflectance``):
  ks F_dielectric D G1 G1 / (4 cosθi cosθo), for ``fresnel=dielectric``.
- ``principled`` (``metallic`` 1, ``base_color`` = f0', ``roughness`` = √α): Schlick(f0') D_GGX G1 G1 /
  (4 cosθi cosθo), for ``fresnel=schlick`` with GGX: the only Schlick Fresnel in Mitsuba (its metallic term,
  ``calc_schlick(base_color, cos, eta)`` in ``src/bsdfs/principledhelpers.h``, is f0 + (1 − f0)(1 − cos)⁵ for
  eta > 1; the default ``specular`` 0.5 gives eta = 1.5; the diffuse, sheen and clearcoat terms vanish).
- ``blendbsdf`` (``weight`` t): (1 − t) first + t second, for sums: each part scaled by 1/its weight.
- ``principled`` with every parameter of brdffit's ``principled`` lobe, for a model that is that lobe alone: the
  lobe evaluates what the plugin evaluates (`brdffit.models.principled`), so the export is exact.
- ``roughplastic`` (GGX, ``nonlinear`` false) with the parameters of brdffit's ``roughplastic`` lobe, for a model
  that is that lobe alone, the diffuse reflectance corrected by the plugin's own internal reflectance
  (`brdffit.models.roughplastic`): exact.

A sum A + B is written exactly as a blend of 2A and 2B: ``blendbsdf`` takes convex combinations, and each part's
amplitude (``reflectance``, ``specular_reflectance``) is scaled by the inverse of its weight. Values above 1 go
through an ``srgb`` texture with ``unbounded`` true, which Mitsuba takes as given (a plain ``<rgb>`` reflectance
must lie in [0, 1]). ``principled`` has no amplitude: its weight in the blend is its amplitude, so a Schlick lobe
ks (f0 + (1 − f0) x) is split into a principled part of weight w and base colour f0' with w (1 − f0') = ks (1 − f0),
plus a mirror ``roughconductor`` (F = 1) with the remaining ks − w. That is exact while ks (1 − f0) <= w <= ks in
every channel with the weights summing to at most 1; otherwise the nearest split is written and its measured
deviation is stated.

Mitsuba's ``bsdf.eval`` returns f_r cosθ of the sampled direction (``wo`` in Mitsuba's naming, the direction to
the light in brdffit's); the BRDF is reciprocal, so only that cosine differs from brdffit's f_r (docs/export.md).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from xml.sax.saxutils import quoteattr

import jax
import numpy as np

from . import terms as tm
from .terms import check_channels

__all__ = ["write", "evaluate_in_mitsuba", "check_channels", "EXPORTABLE"]

EXPORTABLE = ("lambert (any number, summed) and isotropic cook-torrance or ggx lobes with any Fresnel mode, any "
              "number, summed; or principled or roughplastic alone")
# Where a principled part shares a blend with other parts, their weight is at least this much.
_MIN_OTHER_WEIGHT = 1e-3


@dataclasses.dataclass
class _Leaf:
    """One plugin of the blend.

    Attributes:
        plugin: the Mitsuba plugin type.
        params: (tag, name, value) of its parameters other than the amplitude.
        amplitude: the name of its amplitude parameter (None for ``principled``).
        coefficient: the amplitude it must contribute, per channel (for a leaf with an amplitude).
        weight: its blend weight, fixed for ``principled``, assigned for the others.
        parts: what it contributes, in brdffit terms: (lobe, local parameters) at the final amplitudes.
    """

    plugin: str
    params: list
    amplitude: str | None
    coefficient: np.ndarray | None = None
    weight: float | None = None
    parts: list = dataclasses.field(default_factory=list)


def _microfacet_params(distribution, alpha):
    return [("string", "distribution", distribution), ("float", "alpha", alpha)]


def _conductor_leaf(distribution, alpha, ks, eta, k) -> _Leaf:
    return _Leaf("roughconductor", _microfacet_params(distribution, alpha) + [("rgb", "eta", eta), ("rgb", "k", k)],
                 "specular_reflectance", ks, parts=[(tm.microfacet_lobe(distribution, "conductor"),
                                                     {"ks": ks, "m": alpha, "eta": eta, "k": k})])


def _schlick_split(term, channels):
    """(amplitude of the F = 1 part, amplitude of the (1 − cos)⁵ part) of a Schlick lobe, per channel."""
    ks = np.broadcast_to(term.params["ks"], (channels,)).astype(float)
    f0 = float(term.params["f0"])
    return ks * f0, ks * (1.0 - f0)


def _leaves(model: tm.Model, notes: list) -> list[_Leaf]:
    """Map the model's terms to plugins (the principled weights are set by `_weigh`)."""
    channels = model.channels
    leaves, schlick = [], []
    rho = None
    for term in tm.terms(model, EXPORTABLE, "Mitsuba 3"):
        if term.diffuse:
            rho = term.params["rho_d"] if rho is None else rho + term.params["rho_d"]
            continue
        lobe, alpha, ks = term.lobe, term.alpha, term.params["ks"]
        distribution = "ggx" if lobe.distribution == "ggx" else "beckmann"
        if lobe.distribution == "blinn":
            notes.append(f"the Blinn distribution of width m = {tm.number(alpha)} became Mitsuba's Beckmann of "
                         "the same m")
        if lobe.distribution != "ggx":
            notes.append("Mitsuba evaluates the Beckmann Smith G1 with Walter et al.'s rational approximation "
                         "(within 0.35%)")
        if lobe.shadowing != "smith":
            notes.append(f"{lobe.name} shadowing={lobe.shadowing} became Mitsuba's separable Smith G1(wi) G1(wo)")
        if lobe.fresnel == "conductor":
            leaves.append(_conductor_leaf(distribution, alpha, ks, term.params["eta"], term.params["k"]))
        elif lobe.fresnel == "dielectric":
            eta = float(term.params["eta"])
            if tm.reflects_nothing(eta):
                notes.append(f"the {lobe.name} lobe has eta = 1: its Fresnel term is 0, it reflects nothing and "
                             "was left out (exact)")
                continue
            leaves.append(_Leaf("roughplastic", _microfacet_params(distribution, alpha)
                                + [("float", "int_ior", eta), ("float", "ext_ior", 1.0),
                                   ("rgb", "diffuse_reflectance", np.zeros(3)), ("boolean", "nonlinear", False)],
                                "specular_reflectance", ks, parts=[
                                    (tm.microfacet_lobe(distribution, "dielectric"), {"ks": ks, "m": alpha,
                                                                                      "eta": eta})]))
        elif distribution == "ggx":
            schlick.append(term)
        else:
            f0 = float(term.params["f0"])
            eta, k, curve = tm.schlick_to_conductor(f0)
            notes.append(f"Schlick f0 = {tm.number(f0)} with the Beckmann distribution: Mitsuba's only Schlick "
                         f"Fresnel is principled's (GGX), so the conductor Fresnel of the closest index eta = "
                         f"{tm.number(eta)}, k = {tm.number(k)} was written (the curves differ by up to "
                         f"{curve:.3g} absolute)")
            leaves.append(_conductor_leaf(distribution, alpha, ks, eta, k))
    if rho is not None:
        leaves.insert(0, _Leaf("diffuse", [], "reflectance", rho, parts=[(tm.lambert_lobe(), {"rho_d": rho})]))
    leaves.extend(_schlick_leaves(schlick, channels, bool(leaves), notes))
    return leaves


def _schlick_leaves(schlick: list, channels: int, others: bool, notes: list) -> list[_Leaf]:
    """Principled (+ mirror) leaves of the GGX Schlick lobes, with weights as small as exactness allows."""
    if not schlick:
        return []
    split = [_schlick_split(term, channels) for term in schlick]
    weights = np.array([float(np.max(x)) for _, x in split])      # w >= ks (1 - f0) keeps f0' >= 0
    mirror_needed = any(np.any(a - (w - x) > 1e-15) for (a, x), w in zip(split, weights))
    cap = 1.0 - _MIN_OTHER_WEIGHT if (others or mirror_needed) else 1.0
    if weights.sum() > cap:
        notes.append(f"the Schlick lobes need principled weights summing to {weights.sum():.6g} > {cap:g} "
                     f"(ks (1 - f0) = {', '.join(f'{w:.6g}' for w in weights)}): scaled down to fit, so their "
                     "(1 - cos)^5 part is too dark (measured deviation below); no exact construction exists in "
                     "Mitsuba 3 for ks (1 - f0) > 1")
        weights = weights * (cap / weights.sum())
    leaves = []
    for term, (a, x), w in zip(schlick, split, weights):
        if w <= 0.0:
            continue
        base = np.clip(1.0 - x / w, 0.0, 1.0)
        alpha = term.alpha
        lobe_f1 = tm.microfacet_lobe("ggx", "schlick")
        leaves.append(_Leaf("principled", [("rgb", "base_color", base), ("float", "metallic", 1.0),
                                           ("float", "roughness", math.sqrt(alpha))], None, weight=float(w),
                            parts=[(lobe_f1, {"ks": w * base, "m": alpha, "f0": 1.0}),
                                   (lobe_f1, {"ks": w * (1.0 - base), "m": alpha, "f0": 0.0})]))
        rest = np.maximum(a - w * base, 0.0)
        if np.any(rest > 0.0):
            leaves.append(_Leaf("roughconductor", _microfacet_params("ggx", alpha)
                                + [("string", "material", "none")], "specular_reflectance", rest,
                                parts=[(lobe_f1, {"ks": rest, "m": alpha, "f0": 1.0})]))
    return leaves


def _principled_leaf(model: tm.Model, local: dict, notes: list) -> _Leaf:
    """The ``principled`` plugin of brdffit's ``principled`` lobe, parameter for parameter (every one in [0, 1], as
    the plugin takes them)."""
    params = [("rgb", "base_color", local["base_color"])]
    params += [("float", name, float(value)) for name, value in local.items() if name != "base_color"]
    return _Leaf("principled", params, None, weight=1.0, parts=[(model.lobes[0], local)])


def _roughplastic_leaf(model: tm.Model, local: dict, notes: list) -> _Leaf:
    """The ``roughplastic`` plugin of brdffit's ``roughplastic`` lobe: its parameters, with the diffuse reflectance
    ρ (1 − R_int)/(1 − R_table), R_int the plugin's own internal reflectance (`brdffit.models.roughplastic`), so
    that the plugin's ρ/(1 − R_int) is the lobe's; clipped to the plugin's [0, 1] where that exceeds it (the
    part evaluated is then the clipped one, and the deviation says so)."""
    from ..models import roughplastic as rp

    alpha, eta = float(local["alpha"]), float(local["int_ior"])
    table = float(rp.internal_reflectance_table(alpha, eta, xp=np))
    factor = (1.0 - rp.internal_reflectance(alpha, eta)) / (1.0 - table)
    exact = local["diffuse_reflectance"] * factor
    rho = np.clip(exact, 0.0, 1.0)
    if np.any(exact > 1.0):
        notes.append(f"the diffuse reflectance that reproduces the fit, {', '.join(tm.number(v) for v in exact)}, "
                     f"exceeds the plugin's 1 (it is ρ (1 - R_int)/(1 - R_table) = ρ × {factor:.6g}, R_int the "
                     "plugin's internal reflectance, R_table brdffit's): written clipped to 1")
    params = [("string", "distribution", "ggx"), ("float", "alpha", alpha), ("float", "int_ior", eta),
              ("float", "ext_ior", 1.0), ("boolean", "nonlinear", False), ("rgb", "diffuse_reflectance", rho),
              ("rgb", "specular_reflectance", local["specular_reflectance"])]
    return _Leaf("roughplastic", params, None, weight=1.0,
                 parts=[(model.lobes[0], {**local, "diffuse_reflectance": rho / factor})])


# Mitsuba plugins that are one brdffit lobe exactly: a model of that lobe alone is written as the plugin.
_PLUGIN_LOBES = {"principled": _principled_leaf, "roughplastic": _roughplastic_leaf}


def _plugin_alone(model: tm.Model, notes: list) -> _Leaf | None:
    """The plugin of a model that is one of `_PLUGIN_LOBES` alone; None for any other model."""
    if len(model.lobes) != 1 or model.lobes[0].name not in _PLUGIN_LOBES:
        return None
    local = {k: np.asarray(v, dtype=float) for k, v in model.layout.local_params(model.params, 0).items()}
    return _PLUGIN_LOBES[model.lobes[0].name](model, local, notes)


def _weigh(leaves: list[_Leaf]) -> list[_Leaf]:
    """Blend weights summing to 1, heaviest part first.

    Principled parts keep theirs; the others share the rest in proportion to their mean amplitude, so that
    Mitsuba's blend, which samples a part with the probability of its weight, samples each about as often as it
    reflects (parts with amplitude 0 are left out). Heaviest first: a blend computes 1 − t in float32, which is
    exact to rounding when the rest's share t is the smaller one.
    """
    fixed = sum(leaf.weight for leaf in leaves if leaf.amplitude is None)
    scalable = [leaf for leaf in leaves if leaf.amplitude is not None]
    amplitudes = [float(np.mean(leaf.coefficient)) for leaf in scalable]
    if sum(amplitudes) > 0.0:
        scalable = [leaf for leaf, a in zip(scalable, amplitudes) if a > 0.0]
        amplitudes = [a for a in amplitudes if a > 0.0]
    elif fixed < 1.0:
        # Nothing to scale (a principled part alone, or a black material): one black diffuse takes the rest.
        scalable, amplitudes = [_Leaf("diffuse", [], "reflectance", np.zeros(3))], [1.0]
    else:
        scalable, amplitudes = [], []
    for leaf, a in zip(scalable, amplitudes):
        leaf.weight = (1.0 - fixed) * a / sum(amplitudes)
    kept = [leaf for leaf in leaves if leaf.amplitude is None] + scalable
    return sorted(kept, key=lambda leaf: -leaf.weight)


def _beckmann_g1(cos_v, alpha):
    # Mitsuba 3 include/mitsuba/render/microfacet.h, MicrofacetDistribution::smith_g1 (Beckmann): Walter et al.
    # 2007's rational approximation (their Eq. 27) of a = 1/(α tanθ): 1 for a >= 1.6, else
    # (3.535 a + 2.181 a²)/(1 + 2.276 a + 2.577 a²).
    a = cos_v / (alpha * np.sqrt(np.maximum(1.0 - cos_v * cos_v, 1e-300)))
    return np.where(a >= 1.6, 1.0, (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a))


def _evaluator(parts: list, channels: int):
    """f_r of the written blend as Mitsuba evaluates it: the parts in brdffit terms, with the Beckmann parts'
    separable Smith G1 G1 replaced by Mitsuba's rational approximation."""
    models = [(lobe, tm.assemble([(lobe, local)], channels)) for lobe, local in parts]

    def written(wi, wo):
        total = np.zeros((len(wi), channels))
        for lobe, model in models:
            value = np.asarray(tm.evaluate_dirs(model, wi, wo), dtype=float)
            if getattr(lobe, "distribution", "ggx") == "beckmann":
                m = float(model.params["m"])
                exact = np.asarray(_smith_g(lobe_distribution(lobe), wi[:, 2], wo[:, 2], m))
                value = value * (_beckmann_g1(wi[:, 2], m) * _beckmann_g1(wo[:, 2], m) / exact)[:, None]
            total = total + value
        return total

    return written


@functools.partial(jax.jit, static_argnums=0)
def _smith_g(dist, cos_i, cos_o, m):
    """brdffit's separable Smith G1(ωi) G1(ωo) of a distribution as one compiled program: run operation by
    operation, each of its ~15 operations was compiled anew for every number of pairs."""
    return dist.G(cos_i, cos_o, m)


def lobe_distribution(lobe):
    from ..models.microfacet import DISTRIBUTIONS

    return DISTRIBUTIONS[lobe.distribution]


def _colour(name: str, values, indent: str) -> list[str]:
    values = tm.rgb(values)
    text = ", ".join(tm.number(v) for v in values)
    if all(0.0 <= v <= 1.0 for v in values):
        return [f'{indent}<rgb name="{name}" value="{text}"/>']
    # An unbounded srgb texture: Mitsuba's <rgb> reflectance refuses values outside [0, 1].
    return [f'{indent}<texture type="srgb" name="{name}">', f'{indent}    <rgb name="color" value="{text}"/>',
            f'{indent}    <boolean name="unbounded" value="true"/>', f"{indent}</texture>"]


def _param(tag, name, value, indent) -> list[str]:
    if tag == "rgb":
        return _colour(name, value, indent)
    if tag == "float":
        return [f'{indent}<float name="{name}" value="{tm.number(value)}"/>']
    if tag == "boolean":
        return [f'{indent}<boolean name="{name}" value="{"true" if value else "false"}"/>']
    return [f'{indent}<string name="{name}" value="{value}"/>']


def _leaf_xml(leaf: _Leaf, indent: str, head: str) -> list[str]:
    lines = [f'{indent}<bsdf {head}type="{leaf.plugin}">']
    for tag, name, value in leaf.params:
        lines += _param(tag, name, value, indent + "    ")
    if leaf.amplitude is not None:
        lines += _colour(leaf.amplitude, np.asarray(leaf.coefficient, float) / leaf.weight, indent + "    ")
    return lines + [f"{indent}</bsdf>"]


def _tree(leaves: list[_Leaf], indent: str, head: str) -> list[str]:
    """A chain of blends: blend(t, first, rest) = (1 − t) first + t rest with 1 − t the first leaf's share."""
    if len(leaves) == 1:
        return _leaf_xml(leaves[0], indent, head)
    share = leaves[0].weight / sum(leaf.weight for leaf in leaves)
    return ([f'{indent}<bsdf {head}type="blendbsdf">',
             f'{indent}    <float name="weight" value="{tm.number(1.0 - share)}"/>']
            + _leaf_xml(leaves[0], indent + "    ", "")
            + _tree(leaves[1:], indent + "    ", "")
            + [f"{indent}</bsdf>"])


def _comment(text: str) -> str:
    # "--" may not appear inside an XML comment.
    while "--" in text:
        text = text.replace("--", "- -")
    return f"<!-- {text.rstrip('-')} -->"


def write(model: tm.Model, name: str, header: list[str], source=None):
    """The Mitsuba 3 document of ``model``.

    Arguments:
        model: the brdffit model (1 or 3 channels).
        name: the ``id`` of the root ``<bsdf>``.
        header: comment lines that open the document (source, version, fit notes).
        source: the model the deviation is measured against (the original under the fit option, where
            ``model`` may be brdffit's fit of Mitsuba's own plugins to it, `brdffit.export.refit`); default
            ``model``.

    Returns:
        (text, a function (wi, wo) -> f_r of the written material as Mitsuba evaluates it, notes, `Deviation` from
        ``model``).

    Raises:
        ExportError: a lobe with no equivalent, or a channel count other than 1 or 3.
    """
    check_channels(model, "Mitsuba 3")
    notes: list[str] = []
    alone = _plugin_alone(model, notes)
    leaves = [alone] if alone is not None else _weigh(_leaves(model, notes))
    parts = [part for leaf in leaves for part in leaf.parts]
    written = _evaluator(parts, model.channels)
    reference = model if source is None else source
    # Uniform pairs and pairs near the peaks of the source, of the model written and of the parts written.
    pairs = tm.deviation_pairs(tm.peaks(reference, model, parts=parts))
    deviation = tm.measure(reference, written, pairs=pairs)
    lines = [_comment(line) for line in tm.stated(header, notes, deviation)]
    head = f'version="3.0.0" id={quoteattr(name)} '
    lines += _tree(leaves, "", head)
    return "\n".join(lines) + "\n", written, notes, deviation


def evaluate_in_mitsuba(text: str, wi, wo) -> np.ndarray:
    """Load an export with Mitsuba 3 (``scalar_rgb``) and evaluate its BSDF, as a check of what it renders.

    Mitsuba's ``eval(ctx, si, wo)`` takes ``si.wi`` towards the viewer (brdffit's ωo) and ``wo`` towards the
    light (brdffit's ωi) and returns f_r cosθ of the latter, which is divided out here. Switches Mitsuba to the
    ``scalar_rgb`` variant if another one is active.

    Arguments:
        text: the export.
        wi, wo: ``(n, 3)`` unit vectors above the surface (brdffit's convention).

    Returns:
        ``(n, 3)`` f_r in 1/sr.

    Raises:
        ImportError: Mitsuba 3 is not installed (``pip install mitsuba``; it is in brdffit's test extra).
    """
    import mitsuba as mi

    if mi.variant() != "scalar_rgb":
        mi.set_variant("scalar_rgb")
    bsdf = mi.load_string(text)
    ctx = mi.BSDFContext()
    si = mi.SurfaceInteraction3f()
    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    out = np.empty((len(wi), 3))
    for j in range(len(wi)):
        si.wi = mi.Vector3f(*wo[j])
        out[j] = np.array(bsdf.eval(ctx, si, mi.Vector3f(*wi[j]))) / wi[j, 2]
    return out
