"""Lafortune et al.'s generalized cosine lobes, with Ngan et al.'s normalisation."""

from __future__ import annotations

import dataclasses
import itertools

from .._lazy import module
from ..geometry import LocalPair, safe_pow
from ..params import ParamSpec
from .lobe import Lobe
from .peaks import Peak, power_width, scalar
from .specs import KS, exponent

jnp = module("jax.numpy")  # loaded on first use: the registry (`brdffit models`) does not need JAX
np = module("numpy")

__all__ = ["Lafortune"]


def _coefficient(name: str, default: float, doc: str) -> ParamSpec:
    return ParamSpec(name, default, -2.0, 2.0, unit="1", doc=doc)


def _cz(name: str, doc: str) -> ParamSpec:
    # Under the normalisation only the direction of (cxy, cz) matters: cz is held at 1 so that a fit is identifiable.
    return ParamSpec(name, 1.0, -1.0, 1.0, unit="1", doc=doc, fixed=True)


# Starting directions of a lobe (cxy with cz = 1) and sharpness values for `start_candidates`.
_DIRECTIONS = {"forward": -1.0, "off-specular": 0.0, "retro": 1.0}
_SHARPNESS = (3.0, 10.0, 30.0, 100.0, 300.0)
# A spike on the mirror direction (`sub_lobe_candidates`): exponents n and attenuations g = n ε of
# cxy = −cz (1 + ε), which keep the spike at incidence θ as exp(−g cos²θ) (g > 0) or exp(g sin²θ) (g < 0).
_SPIKE_SHARPNESS = (1e3, 1e4, 1e5, 1e6)
_SPIKE_ATTENUATION = (-30.0, 10.0, 30.0, 100.0, 300.0)


@dataclasses.dataclass(frozen=True)
class Lafortune(Lobe):
    r"""Sum of K generalized cosine lobes (Lafortune et al. 1997, Eq. 3) normalised as in Ngan et al. (2005):

    lobe j: ks_j (n_j + 2)/(2π) max(0, cxy_j (ωi.x ωo.x + ωi.y ωo.y) + cz_j ωi.z ωo.z)^n_j / max(cxy_j², cz_j²)^(n_j/2).

    With ``anisotropic=True`` the tangent and bitangent terms have their own coefficients cx_j and cy_j and the
    normalisation uses max(cx_j², cy_j², cz_j²). cxy = −cz gives a specular lobe, cxy = cz a retro-reflective
    one and cxy = 0 an off-specular lobe towards the normal. Because of the normalisation only the direction of
    (cxy, cz) matters, not its length, so cz_j is declared fixed at 1 (fits hold it unless freed) and cxy_j ranges
    over [−2, 2]. Reciprocal. Fits start the lobes apart (`start_candidates`) and report them sorted by
    sharpness, n_1 <= n_2 <= ... (`canonical`).

    Options:
        lobes: number of lobes K (parameters ``ks_j``, ``cxy_j``, ``cz_j``, ``n_j`` for j = 1..K).
        anisotropic: separate ``cx_j`` and ``cy_j`` instead of ``cxy_j``.
    """

    name = "lafortune"
    reference = ("Lafortune et al., Non-linear approximation of reflectance functions, SIGGRAPH 1997, Eq. 3; "
                 "Ngan et al., Experimental analysis of BRDF models, EGSR 2005")

    lobes: int = 1
    anisotropic: bool = False

    def __post_init__(self):
        if not isinstance(self.lobes, int) or isinstance(self.lobes, bool) or self.lobes < 1:
            raise ValueError(f"lafortune: lobes must be a positive integer, got {self.lobes!r}")
        if not isinstance(self.anisotropic, bool):
            raise ValueError(f"lafortune: anisotropic must be True or False, got {self.anisotropic!r}")

    def param_specs(self):
        specs = []
        for j in range(1, self.lobes + 1):
            specs.append(KS.renamed(f"ks_{j}"))
            if self.anisotropic:
                specs.append(_coefficient(f"cx_{j}", -1.0, f"lobe {j}: weight of ωi.x ωo.x"))
                specs.append(_coefficient(f"cy_{j}", -1.0, f"lobe {j}: weight of ωi.y ωo.y"))
            else:
                specs.append(_coefficient(f"cxy_{j}", -1.0, f"lobe {j}: weight of ωi.x ωo.x + ωi.y ωo.y"))
            specs.append(_cz(f"cz_{j}", f"lobe {j}: weight of ωi.z ωo.z"))
            specs.append(exponent(f"n_{j}", 10.0, doc=f"lobe {j}: exponent"))
        return tuple(specs)

    def _lobe_names(self, j: int) -> tuple[str, ...]:
        xy = (f"cx_{j}", f"cy_{j}") if self.anisotropic else (f"cxy_{j}",)
        return (f"ks_{j}",) + xy + (f"cz_{j}", f"n_{j}")

    def start_candidates(self):
        """Every assignment of forward / off-specular / retro directions to the lobes, with sharpness increasing
        from lobe to lobe (e.g. for K = 2: 9 direction pairs x 10 increasing pairs of exponents)."""
        candidates = []
        for directions in itertools.product(_DIRECTIONS.values(), repeat=self.lobes):
            for sharpness in itertools.combinations(_SHARPNESS, self.lobes):
                start = {}
                for j, (c, n) in enumerate(zip(directions, sharpness), start=1):
                    xy = (f"cx_{j}", f"cy_{j}") if self.anisotropic else (f"cxy_{j}",)
                    start.update({name: c for name in xy})
                    start[f"n_{j}"] = n
                candidates.append(start)
        return candidates

    def sub_lobe_candidates(self, amplitude, params):
        """Sub-lobe j as a spike on the mirror direction: cxy_j = −cz_j (1 + ε) (both cx_j and cy_j when
        anisotropic) with n_j ε = g. At the mirror direction of incidence θ the lobe is then
        ((1 + ε sin²θ)/(1 + ε))^n ≈ exp(−g cos²θ) for ε > 0 and (1 − |ε| sin²θ)^n ≈ exp(−|g| sin²θ) for ε < 0:
        g chooses the band of incidence whose samples near the mirror direction the spike fits. Such a spike is
        the least-squares optimum of a sum of lobes on data with a sharper peak than the others can follow, and
        a grid over [−2, 2] does not come within g/n (1e-4 at n = 1e5) of cxy = −cz."""
        j = int(amplitude.rsplit("_", 1)[1])
        cz = float(np.asarray(params[f"cz_{j}"]))
        if cz <= 0.0:  # a lobe about the lower hemisphere's axis has no mirror direction above the surface
            return []
        xy = (f"cx_{j}", f"cy_{j}") if self.anisotropic else (f"cxy_{j}",)
        return [{**{name: -cz * (1.0 + g / n) for name in xy}, f"n_{j}": n}
                for n, g in itertools.product(_SPIKE_SHARPNESS, _SPIKE_ATTENUATION)]

    def amplitude_partners(self, amplitude):
        """The other parameters of the same sub-lobe (``ks_j`` -> ``cxy_j``, ``cz_j``, ``n_j``)."""
        j = int(amplitude.rsplit("_", 1)[1])
        return tuple(name for name in self._lobe_names(j) if name != amplitude)

    def canonical(self, params):
        """Lobes sorted by exponent, n_1 <= n_2 <= ... (the sum does not depend on their order)."""
        order = sorted(range(1, self.lobes + 1), key=lambda j: float(np.asarray(params[f"n_{j}"])))
        out = dict(params)
        for new, old in enumerate(order, start=1):
            for new_name, old_name in zip(self._lobe_names(new), self._lobe_names(old)):
                out[new_name] = params[old_name]
        return out

    def peaks(self, params):
        """A cone about each sub-lobe's axis (cx, cy, cz), as wide as its cosine power."""
        found = []
        for j in range(1, self.lobes + 1):
            cx = scalar(params, f"cx_{j}" if self.anisotropic else f"cxy_{j}")
            cy = scalar(params, f"cy_{j}" if self.anisotropic else f"cxy_{j}")
            found.append(Peak("cone", power_width(scalar(params, f"n_{j}")), (cx, cy, scalar(params, f"cz_{j}"))))
        return tuple(found)

    def __call__(self, params, pair: LocalPair):
        wi, wo = pair.wi, pair.wo
        total = 0.0
        for j in range(1, self.lobes + 1):
            cx = params[f"cx_{j}"] if self.anisotropic else params[f"cxy_{j}"]
            cy = params[f"cy_{j}"] if self.anisotropic else params[f"cxy_{j}"]
            cz, n = params[f"cz_{j}"], params[f"n_{j}"]
            dot = cx * wi[..., 0] * wo[..., 0] + cy * wi[..., 1] * wo[..., 1] + cz * wi[..., 2] * wo[..., 2]
            norm2 = jnp.maximum(jnp.maximum(cx * cx, cy * cy), cz * cz)
            # max(0, dot)^n / (norm2)^(n/2) = max(0, dot/√norm2)^n, computed in that stabler form.
            lobe = (n + 2.0) / (2.0 * jnp.pi) * safe_pow(dot / jnp.sqrt(norm2), n)
            total = total + params[f"ks_{j}"] * lobe[..., None]
        return total
