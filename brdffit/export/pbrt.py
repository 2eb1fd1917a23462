"""pbrt-v4: a fitted model as ``MakeNamedMaterial`` statements of its scene syntax.

Materials written (pbrt-v4 ``src/pbrt/materials.{h,cpp}``, ``bxdfs.h``; checked against the transcribed
formulas of `brdffit.export.pbrt_reference`):

- ``diffuse`` (``rgb reflectance``, clamped by pbrt to [0, 1]): R/π, for every ``lambert`` lobe (summed): exact.
- ``conductor`` (``rgb eta``, ``rgb k``, ``float roughness`` = α, ``bool remaproughness`` false):
  F_complex D_TR G / (4 cosθi cosθo) with G = 1/(1 + Λ(ωo) + Λ(ωi)), for the microfacet lobes;
  ``fresnel=dielectric`` as k = 0 (the same Fresnel term).
- ``mix`` (``string materials`` [a b], ``float amount`` t): the expected value (1 − t) f_a + t f_b, for sums and
  the amplitude ks.

pbrt-v4 has no amplitude on its conductor: a microfacet lobe enters the mix with weight ks (one value, so a
per-channel ks is averaged), the diffuse part takes the rest with its reflectance divided by its weight. A
microfacet lobe is exact when it is what pbrt-v4 renders (GGX with ``shadowing=smith-correlated``, a conductor or
dielectric Fresnel, one ks); otherwise it is approximate (Trowbridge-Reitz only, height-correlated Smith, no
Schlick Fresnel), and the export states the deviation measured with those formulas.

brdffit's ``pbrt`` model (`brdffit.models.pbrt`) is such a mix of one ``diffuse`` and one ``conductor`` as pbrt-v4
evaluates it, with every parameter in the range pbrt-v4 takes: a model that is that lobe alone is written as it is
(the diffuse ``reflectance`` R, the conductor's ``eta``, ``k`` and ``roughness``, the mix ``amount`` t; numbers to
round-trip precision), exact and with nothing clamped. So is brdffit's ``coateddiffuse`` model
(`brdffit.models.coateddiffuse`), pbrt-v4's ``coateddiffuse`` material as the expectation of its random walk:
written with its ``reflectance``, ``roughness`` (``remaproughness`` false) and ``eta``, and the slab's parameters
the model assumes (``thickness`` 0.01, ``albedo`` 0, ``g`` 0, ``maxdepth`` 10, ``nsamples`` 1) stated rather than
left to pbrt's defaults; and brdffit's ``coatedconductor`` model (`brdffit.models.coatedconductor`), pbrt-v4's
``coatedconductor`` under a smooth coat: ``interface.roughness`` 0, ``interface.eta``, the metal of reflectance r as
``conductor.eta`` 1 and ``conductor.k`` 2√r/√(1 − r) (the index pbrt-v4's own ``reflectance`` parameter sets),
``conductor.roughness`` (``remaproughness`` false) and the same slab. Those three are what ``brdffit fit --for
pbrt`` fits.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from . import pbrt_reference
from . import terms as tm
from .terms import check_channels

__all__ = ["write", "EXPORTABLE"]

EXPORTABLE = ("lambert (any number, summed) and isotropic cook-torrance or ggx lobes with any Fresnel mode, summed; "
              "or the pbrt, coateddiffuse or coatedconductor model alone")
# With a diffuse part beside the conductors, the conductors' weights sum to at most 1 minus this.
_MIN_DIFFUSE_WEIGHT = 1e-3


@dataclasses.dataclass
class _Part:
    """One material of the mix: its type, its parameters (tag, name, value) and its weight."""

    kind: str
    params: list
    weight: float


def _candidates(model, notes: list) -> list[tuple[list[_Part], list]]:
    """The mixes that could stand for ``model``, each with its own notes (``notes`` gets the shared ones)."""
    rho, conductors = None, []
    for term in tm.terms(model, EXPORTABLE, "pbrt-v4"):
        if term.diffuse:
            rho = term.params["rho_d"] if rho is None else rho + term.params["rho_d"]
            continue
        lobe, alpha = term.lobe, term.alpha
        if lobe.fresnel == "conductor":
            eta, k = term.params["eta"], term.params["k"]
        elif lobe.fresnel == "dielectric":
            eta, k = term.params["eta"], np.zeros(1)
            if tm.reflects_nothing(eta):
                notes.append(f"the {lobe.name} lobe has eta = 1: it reflects nothing and was left out (exact)")
                continue
        else:
            f0 = float(term.params["f0"])
            e, kk, curve = tm.schlick_to_conductor(f0)
            eta, k = np.array([e]), np.array([kk])
            notes.append(f"pbrt-v4 has no Schlick Fresnel: f0 = {tm.number(f0)} became the closest complex index "
                         f"eta = {tm.number(e)}, k = {tm.number(kk)} (the curves differ by up to {curve:.3g} "
                         "absolute)")
        if lobe.distribution != "ggx":
            notes.append(f"pbrt-v4 has only the Trowbridge-Reitz (GGX) distribution: the {lobe.distribution} "
                         f"width m = {tm.number(alpha)} was written as the GGX alpha")
        if lobe.shadowing != "smith-correlated":
            notes.append(f"{lobe.name} shadowing={lobe.shadowing} became pbrt-v4's height-correlated Smith "
                         "1/(1 + Lambda(wo) + Lambda(wi))")
        ks = np.atleast_1d(term.params["ks"])
        if np.ptp(ks) > 0:
            notes.append(f"pbrt-v4's conductor has no amplitude: ks = {', '.join(tm.number(v) for v in ks)} "
                         f"entered the mix as its mean {tm.number(ks.mean())}")
        conductors.append(_Part("conductor", [("rgb", "eta", eta), ("rgb", "k", k), ("float", "roughness", alpha),
                                              ("bool", "remaproughness", False)], float(ks.mean())))
    candidates = [_mix(rho, conductors, 1.0, [])]
    limit = 1.0 - float(np.max(rho)) if rho is not None else 1.0
    total = sum(p.weight for p in conductors)
    if rho is not None and total > limit > 0.0:
        # The diffuse part would clamp: also try the conductors scaled down until it fits; keep the closer one.
        candidates.append(_mix(rho, conductors, limit / total, [f"the microfacet weights were scaled by "
                                                                f"{limit / total:.6g} so that the diffuse "
                                                                "reflectance stays within pbrt's [0, 1]"]))
    return candidates


def _mix(rho, conductors: list[_Part], scale: float, notes: list) -> tuple[list[_Part], list]:
    """The mix of the diffuse part and the conductors with their weights times ``scale``, and its notes."""
    conductors = [dataclasses.replace(p, weight=p.weight * scale) for p in conductors]
    total = sum(p.weight for p in conductors)
    cap = 1.0 - _MIN_DIFFUSE_WEIGHT if rho is not None and np.any(rho > 0) else 1.0
    if total > cap:
        notes.append(f"the microfacet amplitudes sum to {total:.6g}; pbrt-v4's mix takes at most {cap:g}: scaled "
                     "down, so the highlight is too dark")
        for p in conductors:
            p.weight *= cap / total
        total = cap
    parts = [p for p in conductors if p.weight > 0]
    if total < 1.0:
        base = np.zeros(1) if rho is None else np.asarray(rho) / (1.0 - total)
        if np.any(base > 1.0):
            # pbrt-v4's scene parser refuses an "rgb reflectance" above 1 (paramdict.cpp, SpectrumType::Albedo):
            # written as 1, which is also what DiffuseMaterial's clamp would make of it.
            notes.append(f"the diffuse part needs reflectance {', '.join(tm.number(v) for v in tm.rgb(base))} "
                         f"beside microfacet weights {total:.6g}; pbrt-v4 takes at most 1, written as 1")
            base = np.minimum(base, 1.0)
        parts.insert(0, _Part("diffuse", [("rgb", "reflectance", base)], 1.0 - total))
    return parts, notes


def _statement(name: str, kind: str, params: list, number=tm.number) -> list[str]:
    """The ``MakeNamedMaterial`` lines of one material; ``number`` writes a float (10 significant digits by
    default)."""
    lines = [f'MakeNamedMaterial "{name}"', f'    "string type" [ "{kind}" ]']
    for tag, key, value in params:
        if tag == "rgb":
            text = " ".join(number(v) for v in tm.rgb(value))
        elif tag == "float":
            text = number(value)
        elif tag == "string":
            text = " ".join(f'"{v}"' for v in value)
        elif tag == "integer":
            text = str(int(value))
        else:
            text = "true" if value else "false"
        lines.append(f'    "{tag} {key}" [ {text} ]')
    return lines


def _statements(parts: list[_Part], name: str, number=tm.number) -> list[str]:
    """Leaves first (pbrt needs a name defined before a mix uses it), then a chain of mixes ending in ``name``;
    ``number`` writes a float (`_statement`)."""
    if len(parts) == 1:
        return _statement(name, parts[0].kind, parts[0].params, number)
    lines, names = [], []
    for j, part in enumerate(parts):
        names.append(f"{name}:{part.kind}-{j + 1}")
        lines += _statement(names[-1], part.kind, part.params, number)
    # mix(t, a, rest) = (1 − t) a + t rest, built from the last pair up: t is the weight of the parts after a over
    # that of a and them (MixMaterial::ChooseMaterial picks materials[1], the rest, with probability t); for two
    # parts of weights 1 − t and t it is t itself.
    rest, later = names[-1], parts[-1].weight
    for j in range(len(parts) - 2, -1, -1):
        mix = name if j == 0 else f"{name}:mix-{j + 1}"
        lines += _statement(mix, "mix", [("string", "materials", [names[j], rest]),
                                         ("float", "amount", later / (later + parts[j].weight))], number)
        rest, later = mix, later + parts[j].weight
    return lines


def _evaluator(parts: list[_Part], name: str):
    """(text of the statements, f_r of the written material by pbrt-v4's formulas, read back from that text)."""
    body = "\n".join(_statements(parts, name)) + "\n"
    materials = pbrt_reference.parse(body)

    def written(wi, wo):
        return pbrt_reference.evaluate(materials, name, wi, wo)

    return body, written


# Bounds of pbrt-v4's parameters in the refinement: reflectance as pbrt clamps it, the index as brdffit's
# conductor lobe declares it, roughness as brdffit's widths.
_BOUNDS = {"weight": (1e-6, 1.0), "reflectance": (0.0, 1.0), "eta": (1e-3, 10.0), "k": (0.0, 20.0),
           "roughness": (1e-3, 1.0)}


def _peaks(parts: list[_Part]) -> list:
    """The peaks of the written conductors, coated interfaces and coated conductors (Trowbridge-Reitz of width α =
    roughness, remaproughness false; a coated conductor's seen through its coat, about η times wider)."""
    peaks = []
    for part in parts:
        values = dict((key, value) for _, key, value in part.params)
        if part.kind in ("conductor", "coateddiffuse"):
            peaks.append(tm.Peak("half", float(np.clip(values["roughness"], 1e-4, 1.0)), lobe=f"pbrt {part.kind}"))
        elif part.kind == "coatedconductor":
            width = values["conductor.roughness"] * values["interface.eta"]
            peaks.append(tm.Peak("half", float(np.clip(width, 1e-4, 1.0)), lobe=f"pbrt {part.kind}"))
    return peaks


def _refine(parts: list[_Part], source, model, name: str) -> list[_Part]:
    """The fit option: pbrt-v4's own parameters (mix weights, reflectance, roughness, η, k) of ``parts`` refined
    by least squares on the cosine-weighted residual √w (f_pbrt − f) cosθi against ``source``, at pairs drawn
    like those of the stated deviation (uniform and near the peaks of ``source``, ``model`` and ``parts``, with
    their balance-heuristic weights w, `brdffit.export.terms.Pairs`) but with another seed, so that the stated
    error is measured at pairs the refinement did not see; pbrt's formulas are evaluated on the written text
    itself."""
    from scipy.optimize import least_squares

    pairs = tm.deviation_pairs(tm.peaks(source, model, extra=_peaks(parts)), seed=tm.DEVIATION_SEED + 1)
    wi, wo = pairs.wi, pairs.wo
    f = np.broadcast_to(np.asarray(tm.evaluate_dirs(source, wi, wo), dtype=float), (len(wi), 3))
    cos = wi[:, 2:3] * np.sqrt(pairs.weight / pairs.weight.mean())[:, None]
    slots, x0 = [], []                                  # (part, parameter index or None for the weight, size)
    for j, part in enumerate(parts):
        entries = [(None, "weight", [part.weight])]
        entries += [(i, key, tm.rgb(value) if tag == "rgb" else [float(value)])
                    for i, (tag, key, value) in enumerate(part.params) if key in _BOUNDS]
        for i, key, values in entries:
            slots.append((j, i, key, len(values)))
            x0.extend(np.clip(values, *_BOUNDS[key]))
    lo = [_BOUNDS[key][0] for _, _, key, size in slots for _ in range(size)]
    hi = [_BOUNDS[key][1] for _, _, key, size in slots for _ in range(size)]

    def build(x):
        new = [dataclasses.replace(part, params=list(part.params)) for part in parts]
        at = 0
        for j, i, key, size in slots:
            values = np.asarray(x[at:at + size])
            at += size
            if i is None:
                new[j].weight = float(values[0])
            else:
                tag, _, _ = new[j].params[i]
                new[j].params[i] = (tag, key, values if tag == "rgb" else float(values[0]))
        total = sum(part.weight for part in new)
        for part in new:
            part.weight /= total
        return new

    def residual(x):
        _, written = _evaluator(build(x), name)
        return ((written(wi, wo) - f) * cos).ravel()

    return build(least_squares(residual, x0, bounds=(lo, hi), diff_step=1e-4, max_nfev=25).x)


def _round_trip(value) -> str:
    """A float as the shortest text that reads back to the same double."""
    return repr(float(value))


def _mix_parts(v: dict) -> list[_Part]:
    """brdffit's ``pbrt`` model as pbrt-v4 materials: a diffuse, a conductor and their mix with amount t."""
    t = float(v["amount"])
    return [_Part("diffuse", [("rgb", "reflectance", v["reflectance"])], 1.0 - t),
            _Part("conductor", [("rgb", "eta", v["eta"]), ("rgb", "k", v["k"]),
                                ("float", "roughness", float(v["roughness"])), ("bool", "remaproughness", False)], t)]


def _coated_diffuse_parts(v: dict) -> list[_Part]:
    """brdffit's ``coateddiffuse`` model as pbrt-v4's ``coateddiffuse``, the slab's parameters stated."""
    from ..models import coateddiffuse as cd

    return [_Part("coateddiffuse", [("rgb", "reflectance", v["reflectance"]),
                                    ("float", "roughness", float(v["roughness"])), ("bool", "remaproughness", False),
                                    ("float", "eta", float(v["eta"])), ("float", "thickness", cd.THICKNESS),
                                    ("rgb", "albedo", np.zeros(3)), ("float", "g", 0.0),
                                    ("integer", "maxdepth", cd.MAX_DEPTH), ("integer", "nsamples", 1)], 1.0)]


def _coated_conductor_parts(v: dict) -> list[_Part]:
    """brdffit's ``coatedconductor`` model as pbrt-v4's ``coatedconductor``: the smooth interface, the metal of
    reflectance r as the index pbrt-v4's ``reflectance`` parameter sets (η 1, k 2√r/√(1 − r), which every pbrt-v4
    version reads), and the slab's parameters stated."""
    from ..models import coateddiffuse as cd

    r = np.asarray(v["reflectance"], dtype=float)
    return [_Part("coatedconductor", [("float", "interface.roughness", 0.0), ("float", "interface.eta",
                                                                               float(v["interface_eta"])),
                                      ("rgb", "conductor.eta", np.ones_like(r)),
                                      ("rgb", "conductor.k", 2.0 * np.sqrt(r) / np.sqrt(1.0 - r)),
                                      ("float", "conductor.roughness", float(v["conductor_roughness"])),
                                      ("bool", "remaproughness", False), ("float", "thickness", cd.THICKNESS),
                                      ("rgb", "albedo", np.zeros(3)), ("float", "g", 0.0),
                                      ("integer", "maxdepth", cd.MAX_DEPTH), ("integer", "nsamples", 1)], 1.0)]


# The brdffit models that are pbrt-v4 materials as they stand, and their materials.
_OWN = {"pbrt": _mix_parts, "coateddiffuse": _coated_diffuse_parts, "coatedconductor": _coated_conductor_parts}


def _own_model(model, name: str):
    """The statements of a model of `_OWN`, as parts and text; every value as it is, so that the text reads back
    to the model's own parameters."""
    v = {key: np.asarray(value, dtype=float) for key, value in model.layout.local_params(model.params, 0).items()}
    parts = _OWN[model.lobes[0].name](v)
    return parts, "\n".join(_statements(parts, name, _round_trip)) + "\n"


def _write_own(model, name: str, header: list[str], source=None):
    """`write` for a model of `_OWN` alone: written as it is, no approximation; the deviation (from ``source``
    under the fit option, else from the model) measured with pbrt-v4's formulas on the text."""
    parts, body = _own_model(model, name)
    materials = pbrt_reference.parse(body)

    def written(wi, wo):
        return pbrt_reference.evaluate(materials, name, wi, wo)

    reference = model if source is None else source
    deviation = tm.measure(reference, written, pairs=tm.deviation_pairs(tm.peaks(reference, model,
                                                                                 extra=_peaks(parts))))
    notes: list[str] = []
    lines = [f"# {line}" for line in tm.stated(header, notes, deviation,
                                               "pbrt-v4's formulas, brdffit.export.pbrt_reference")]
    return "\n".join(lines) + "\n" + body, written, notes, deviation


def write(model, name: str, header: list[str], source=None):
    """The pbrt-v4 statements of ``model``.

    Arguments:
        model: the brdffit model (1 or 3 channels).
        name: the material name (the last statement; parts are named ``name:kind-j``).
        header: comment lines that open the text.
        source: for the fit option, the model that pbrt-v4's parameters of the mapping of ``model`` are then
            refined against (`_refine`) and the deviation measured against; None writes the mapping. brdffit's
            ``pbrt``, ``coateddiffuse`` and ``coatedconductor`` models alone are written as they are (`_write_own`),
            not refined.

    Returns:
        (text, a function (wi, wo) -> f_r of the written material by pbrt-v4's formulas, notes, `Deviation` from
        ``model``).

    Raises:
        ExportError: a lobe with no equivalent, more than RGB channels, or a name with quotes or newlines.
    """
    check_channels(model, "pbrt-v4")
    if '"' in name or "\n" in name:
        raise tm.ExportError(f"a pbrt material name cannot hold quotes or newlines: {name!r}")
    if len(model.lobes) == 1 and model.lobes[0].name in _OWN:
        return _write_own(model, name, header, source)
    notes: list[str] = []
    best = None
    candidates = _candidates(model, notes)
    # The candidates are compared at the same pairs: uniform and near the peaks of the model and of each mix.
    pairs = tm.deviation_pairs(tm.peaks(model, extra=[p for parts, _ in candidates for p in _peaks(parts)]))
    for parts, own in candidates:
        deviation = tm.measure(model, _evaluator(parts, name)[1], pairs=pairs)
        if best is None or deviation.rms < best[1].rms:
            best = (parts, deviation, own)
    parts, deviation, own = best
    notes = notes + own
    reference = model if source is None else source
    if source is not None:
        parts = _refine(parts, source, model, name)
        notes.append("fit: pbrt-v4's own parameters (mix weights, reflectance, roughness, eta, k) were then refined "
                     "by least squares on the cosine-weighted error against the source model")
        pairs = tm.deviation_pairs(tm.peaks(reference, model, extra=_peaks(parts)))
    body, written = _evaluator(parts, name)
    deviation = tm.measure(reference, written, pairs=pairs)
    lines = [f"# {line}" for line in tm.stated(header, notes, deviation,
                                               "pbrt-v4's formulas, brdffit.export.pbrt_reference")]
    return "\n".join(lines) + "\n" + body, written, notes, deviation
