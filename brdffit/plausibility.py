"""Plausibility of a fitted model: the verdicts printed in every fit summary, selection and report.

`plausibility` checks a fitted model against physics and gives each check a verdict (``ok``, ``caution`` or
``implausible``), the numbers it judged and a line of what to do (docs/fitting.md#plausibility):

- energy: the largest directional albedo (`brdffit.properties.scan_albedo`, θi 0-89°) must not exceed 1
  (+ 1e-3): a passive surface cannot reflect more light than it receives. Above 1 only beyond the data's largest
  θi it is a caution (the lobes of a sum are not energy-coupled, so Lambert + a Fresnel lobe passes 1 towards
  grazing), within them it is implausible. A model that is not reciprocal (a renderer's layered material) is
  judged by its albedo at each view, ∫ f_r cosθi dωi (`brdffit.properties.judged_at_the_view` says why);
- specular: every unbounded amplitude (ks, ks_j) times the largest value of its lobe's Fresnel factor over the
  angles must not exceed 1 by more than `PLAUSIBILITY_SIGMAS` standard errors; every Fresnel factor of the
  library reaches 1 at grazing (and lobes without one have F = 1), so that largest ks·F is ks;
- bounds: parameters that ended on a bound (a caution), each with a line of advice.

`FitResult.plausibility()` calls it; the physical properties it relies on are measured in `brdffit.properties`.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .models import Model
from .properties import PLAUSIBILITY_PHI_I, PLAUSIBILITY_THETA_I, judged_at_the_view, scan_albedo

__all__ = [
    "plausibility",
    "Plausibility",
    "Check",
    "PLAUSIBILITY_TOL",
    "PLAUSIBILITY_SIGMAS",
]

# An albedo or a specular factor counts as above 1 beyond this allowance (the quadrature's accuracy) and, for a
# fitted amplitude, beyond this many of its standard errors.
PLAUSIBILITY_TOL = 1e-3
PLAUSIBILITY_SIGMAS = 2.0


@dataclasses.dataclass(frozen=True)
class Check:
    """One plausibility check of a fitted model.

    Attributes:
        name: ``"energy"``, ``"specular"`` or ``"bounds"``.
        level: ``"ok"``, ``"caution"`` (holds where the data are, not beyond them) or ``"implausible"``.
        message: what was measured, with its numbers.
        advice: what the user can do (empty when ok).
        value: the number judged (the largest albedo, the largest ks·F, the count of parameters at a bound).
    """

    name: str
    level: str
    message: str
    advice: str = ""
    value: float = float("nan")

    def to_dict(self) -> dict:
        return {"name": self.name, "level": self.level, "message": self.message, "advice": self.advice,
                "value": self.value if math.isfinite(self.value) else None}


@dataclasses.dataclass(frozen=True)
class Plausibility:
    """The plausibility checks of a fit (`plausibility`): ``checks`` in the order energy, specular, bounds."""

    checks: tuple

    @property
    def ok(self) -> bool:
        """True if no check is ``implausible``."""
        return not self.implausible

    @property
    def implausible(self) -> tuple:
        """The checks at level ``implausible``, in order (empty for a plausible fit)."""
        return tuple(c for c in self.checks if c.level == "implausible")

    def __getitem__(self, name: str) -> Check:
        return next(c for c in self.checks if c.name == name)

    def lines(self) -> list[str]:
        """One line per check (``plausible``/``CAUTION``/``IMPLAUSIBLE``: message), then its advice."""
        tag = {"ok": "plausible", "caution": "CAUTION", "implausible": "IMPLAUSIBLE"}
        out = []
        for c in self.checks:
            out.append(f"{tag[c.level]} {c.name}: {c.message}")
            if c.advice:
                out.append(f"  what to do: {c.advice}")
        return out

    def to_dict(self) -> dict:
        return {"ok": self.ok, "checks": [c.to_dict() for c in self.checks]}


def _energy(models, theta_max) -> Check:
    worst, where, inside = -math.inf, (0.0, 0.0, 0), -math.inf
    for k, model in enumerate(models):
        albedo = scan_albedo(model, view=judged_at_the_view(model))  # (T, P, C)
        i, j, c = np.unravel_index(int(np.argmax(albedo)), albedo.shape)
        if albedo[i, j, c] > worst:
            # φi is worth naming only where the albedo depends on it (an anisotropic model, off the normal).
            azimuthal = np.ptp(albedo[i, :, c]) > 1e-4 * max(abs(float(albedo[i, j, c])), 1e-12)
            worst = float(albedo[i, j, c])
            where = (PLAUSIBILITY_THETA_I[i], PLAUSIBILITY_PHI_I[j] if azimuthal else 0.0, c + k)
        measured = PLAUSIBILITY_THETA_I <= theta_max + 1e-9
        if measured.any():
            inside = max(inside, float(albedo[measured].max()))
    theta, phi, channel = where
    side = "o" if any(judged_at_the_view(model) for model in models) else "i"
    at = f"θ{side} = {math.degrees(theta):.1f}°" + (f", φ{side} = {math.degrees(phi):.0f}°" if phi else "")
    limit = 1.0 + PLAUSIBILITY_TOL
    if worst <= limit:
        return Check("energy", "ok", f"max albedo {worst:.4g} at {at} (channel {channel}) ≤ 1: energy conserving",
                     value=worst)
    cause = ("the data may be scaled wrong (brdffit wants f_r in 1/sr without the cosine: a reflectance factor is "
             "π f_r), or the model makes up for a missing lobe or a Fresnel rise it lacks with too large an "
             "amplitude")
    if inside <= limit:
        return Check("energy", "caution",
                     f"max albedo {inside:.4g} ≤ 1 over the data's θ{side} ≤ {math.degrees(theta_max):.0f}°, but "
                     f"{worst:.4g} at {at} (channel {channel}) beyond them: the fitted lobes, uncoupled, reflect "
                     "more than 1 towards grazing",
                     "trust the model only within the measured angles, or fit one whose Fresnel term limits it at "
                     "grazing (e.g. --model lambert+ggx(fresnel=dielectric))", worst)
    return Check("energy", "implausible",
                 f"max albedo {worst:.4g} at {at} (channel {channel}) > 1: the fit reflects more light than it "
                 "receives", _energy_advice(models, cause), worst)


def _energy_advice(models, cause: str) -> str:
    """What to do about an albedo above 1, for this fit: fixing f0 only where the model has one, and a lobe the
    model lacks where an amplitude is far beyond 1 (retro-reflection, a mirror peak)."""
    names = {name for model in models for name in model.params}
    largest = max((float(np.max(np.asarray(model.params[slot.name], dtype=float))) for model in models
                   for slot in model.layout.slots if slot.spec.linear and math.isinf(slot.spec.upper)), default=0.0)
    steps = ["check the data's units"]
    if "f0" in names or any(n.startswith("eta") for n in names):
        steps.append("fix f0 (0.04 for dielectrics) or use fresnel='dielectric'")
    if largest > 100:
        steps.append(f"an amplitude of {largest:.3g} says the data hold a lobe far sharper or stronger than this "
                     "model reaches (a retro-reflector, a mirror): fit a model with that lobe, and trust this one "
                     "only at the measured directions")
    return f"{cause}; " + "; ".join(steps)


def _specular(models, stderr) -> Check:
    # Every Fresnel factor of the library reaches 1 at grazing (Schlick, dielectric and conductor alike) and
    # lobes without one have F = 1, so the largest ks·F over the angles is ks itself: no evaluation needed.
    worst, label, err = -math.inf, "", 0.0
    for k, model in enumerate(models):
        for slot in model.layout.slots:
            spec = slot.spec
            if not (spec.linear and spec.colour and math.isinf(spec.upper)):
                continue  # only unbounded amplitudes can exceed 1 (ρd, rs, the toon tones are declared ≤ 1)
            amplitude = np.asarray(model.params[slot.name], dtype=float).reshape(-1)
            c = int(np.argmax(amplitude))
            if amplitude[c] > worst:
                e = np.asarray((stderr or {}).get(slot.name, 0.0), dtype=float).reshape(-1)
                e = float(e[min(c, e.size - 1)]) if e.size else 0.0
                worst, err = float(amplitude[c]), (e if math.isfinite(e) else 0.0)
                fresnel = "·F" if hasattr(model.lobes[slot.lobe], "fresnel_term") else ""
                label = (f"{slot.name}[{c}]" if slot.shape else slot.name) + fresnel
                label += f"@{k}" if len(models) > 1 else ""
    if not math.isfinite(worst):
        return Check("specular", "ok", "no unbounded specular amplitude")
    if worst <= 1.0 + PLAUSIBILITY_TOL + PLAUSIBILITY_SIGMAS * err:
        within = f" within {PLAUSIBILITY_SIGMAS:g} standard errors" if worst > 1.0 + PLAUSIBILITY_TOL else ""
        return Check("specular", "ok", f"largest ks·F {worst:.4g} ({label}) ≤ 1{within}", value=worst)
    return Check("specular", "implausible",
                 f"largest ks·F {worst:.4g} ({label}, ± {err:.2g}) > 1: the specular term reflects more than the "
                 "light it receives where its Fresnel factor reaches 1 (towards grazing)",
                 ("ks trades off against f0/η or the roughness over the measured angles: fix f0 (0.04 for "
                  "dielectrics), use fresnel='dielectric', or check the data's scale" if "·F" in label
                  else "this lobe has no Fresnel term to bound it: check the data's scale, or fit a model whose "
                       "lobe the data's peak fits without an amplitude above 1"), worst)


def _bound_advice(label: str, spec, value: float) -> str:
    lower = math.isfinite(spec.lower) and abs(value - spec.lower) <= abs(value - spec.upper)
    if spec.linear and lower:
        return f"{label} = {value:.3g}: its lobe adds nothing there; a model without that lobe fits as well"
    if spec.name.startswith("rho") and not lower:
        return (f"{label} = {value:.3g} at 1: brighter than any passive diffuse surface; check the data's scale "
                "or add a lobe for the light the diffuse term takes")
    if spec.name in ("f0",) or spec.name.startswith(("eta", "k")) and not spec.linear:
        return (f"{label} = {value:.3g} on its bound: the data cannot separate ks from the Fresnel term; fix it "
                "(fixed={'f0': 0.04} for dielectrics) or use fresnel='dielectric'")
    if spec.scale and lower:
        return (f"{label} = {value:.3g} at its lower bound: sharper than these data resolve; sample the peak "
                "more densely or accept a mirror-like lobe")
    return (f"{label} = {value:.3g} on its bound [{spec.lower:g}, {spec.upper:g}]: the optimum lies outside the "
            "model's range; this model may not describe the material (a selection's table, selection.json, shows "
            "how the other candidates predict)")


def _bounds(models, bounds_hit) -> Check:
    if not bounds_hit:
        return Check("bounds", "ok", "no parameter at a bound", value=0.0)
    advice = []
    for entry in bounds_hit:
        label, _, channel = entry.partition("@")
        model = models[int(channel)] if channel and int(channel) < len(models) else models[0]
        name, _, index = label.partition("[")
        try:
            spec = model.param_specs[name]
        except KeyError:
            advice.append(f"{entry} on a bound")
            continue
        value = np.asarray(model.params[name], dtype=float).reshape(-1)
        value = float(value[int(index[:-1])] if index else value[0])
        advice.append(_bound_advice(entry, spec, value))
    return Check("bounds", "caution", f"{len(bounds_hit)} at a bound: {', '.join(bounds_hit)}", "; ".join(advice),
                 float(len(bounds_hit)))


def plausibility(models, *, bounds_hit=(), stderr=None, theta_max: float | None = None) -> Plausibility:
    """Whether a fitted model is physically plausible, and what to do where it is not.

    - energy: the largest directional albedo (`scan_albedo`, θi 0-89°) must not exceed 1 (+ 1e-3); above 1
      only beyond the data's largest θi it is a caution (the lobes of a sum are not energy-coupled, so Lambert +
      a Fresnel lobe passes 1 towards grazing), within them it is implausible; a model that is not reciprocal is
      judged by its albedo at each view (`scan_albedo` with ``view``, module doc);
    - specular: every unbounded amplitude (ks, ks_j) times the largest value of its lobe's Fresnel factor over
      the angles must not exceed 1 by more than `PLAUSIBILITY_SIGMAS` standard errors; every Fresnel factor of the
      library reaches 1 at grazing (and lobes without one have F = 1), so that largest ks·F is ks;
    - bounds: parameters that ended on a bound, each with a line of advice.

    Arguments:
        models: the fitted `Model` (or a list: one per channel of an independent fit).
        bounds_hit: labels at a bound (`FitResult.bounds_hit`).
        stderr: name -> standard error (`FitResult.stderr`), to judge ks·F against its uncertainty.
        theta_max: the data's largest θi (radians); None: every θi counts as measured.

    Returns:
        A `Plausibility`.
    """
    models = [models] if isinstance(models, Model) else list(models)
    theta_max = PLAUSIBILITY_THETA_I[-1] if theta_max is None else float(theta_max)
    return Plausibility((_energy(models, theta_max), _specular(models, stderr), _bounds(models, bounds_hit)))
