"""NumPy transcriptions of pbrt-v4's random walk for ``coateddiffuse`` and ``coatedconductor``, the references of
tests/test_coateddiffuse.py and tests/test_coatedconductor.py.

pbrt-v4 (github.com/mmp/pbrt-v4), ``src/pbrt/bxdfs.h``: ``LayeredBxDF<DielectricBxDF, DiffuseBxDF, true>::f`` for
ωo and ωi above the surface and albedo 0 (no medium in the slab): the interface's reflection, then per walk the
transmission sampled from ωo (radiance mode) and from ωi (importance mode, ``wis``), up to ``maxDepth`` scattering
events alternating between the base (next-event estimation along ``wis`` weighted by the power heuristic against
the base's density, then a cosine sample whose exit through the interface is weighted against the interface's
transmission density) and the interface (a reflection from inside), Russian roulette after depth 3 where the
throughput falls below 0.25, and ``Tr(thickness, w)`` at every crossing. ``DielectricBxDF`` (``Sample_f``, ``f``,
``PDF`` with ``BxDFReflTransFlags``), ``TrowbridgeReitzDistribution`` (``D``, ``Lambda``, ``G1``, ``G``, ``PDF``,
``Sample_wm``: visible normals) and ``FrDielectric``, ``Refract`` (``src/pbrt/util/scattering.h``) are transcribed
below. ``coatedconductor`` (``LayeredBxDF<DielectricBxDF, ConductorBxDF, true>::f``) is transcribed for a smooth
interface (``DielectricBxDF``'s specular branch: refraction and mirror reflection with the Fresnel weights, no
next-event estimate towards the exit) over a rough ``ConductorBxDF`` (``f``, ``Sample_f``; ``FrComplex`` in complex
arithmetic), whose index pbrt-v4 divides by the interface's (``CoatedConductorMaterial::GetBxDF``), and so is its
``LayeredBxDF::Sample_f`` (the walk that samples a direction: every step sampled, the smooth interface choosing
reflection or transmission with its Fresnel probabilities, the path's f and pdf multiplied up). Nothing here
imports brdffit. Walks run in parallel as arrays; the mean of ``n`` walks and its standard error estimate pbrt-v4's
f.
"""

from __future__ import annotations

import numpy as np

__all__ = ["coated_diffuse_f", "coated_conductor_f", "coated_conductor_sample", "reflectance_index", "EXIT",
           "MIRROR"]


def _dot(a, b):
    return np.sum(a * b, axis=-1)


def _normalize(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


class _TrowbridgeReitz:
    """``TrowbridgeReitzDistribution`` (isotropic α)."""

    def __init__(self, alpha: float):
        self.a = max(alpha, 1e-4)

    def d(self, wm):
        c2 = wm[..., 2] ** 2
        t2 = (1.0 - c2) / np.where(c2 > 0, c2, 1.0)
        return np.where(c2 > 0, 1.0 / (np.pi * self.a**2 * c2 * c2 * (1.0 + t2 / self.a**2) ** 2), 0.0)

    def lam(self, w):
        c2 = w[..., 2] ** 2
        t2 = (1.0 - c2) / np.maximum(c2, 1e-300)
        return 0.5 * (np.sqrt(1.0 + self.a**2 * t2) - 1.0)

    def g1(self, w):
        return 1.0 / (1.0 + self.lam(w))

    def g(self, wo, wi):
        return 1.0 / (1.0 + self.lam(wo) + self.lam(wi))

    def pdf(self, w, wm):
        """The visible normals' density D_ω(m) = G1(ω) / |cos ω| D(m) |ω·m|."""
        return self.g1(w) / np.abs(w[..., 2]) * self.d(wm) * np.abs(_dot(w, wm))

    def sample_wm(self, w, u):
        """``Sample_wm``: a visible normal of ω (Heitz 2018's construction, as pbrt-v4 writes it)."""
        wh = _normalize(np.stack([self.a * w[..., 0], self.a * w[..., 1], w[..., 2]], -1))
        wh = np.where(wh[..., 2:3] < 0, -wh, wh)
        z = np.zeros_like(wh)
        z[..., 2] = 1.0
        t1 = np.cross(z, wh)
        n1 = np.linalg.norm(t1, axis=-1, keepdims=True)
        t1 = np.where(wh[..., 2:3] < 0.99999, t1 / np.maximum(n1, 1e-300), np.array([1.0, 0.0, 0.0]))
        t2 = np.cross(wh, t1)
        r, phi = np.sqrt(u[..., 0]), 2.0 * np.pi * u[..., 1]  # SampleUniformDiskPolar
        px, py = r * np.cos(phi), r * np.sin(phi)
        h = np.sqrt(1.0 - px * px)
        s = (1.0 + wh[..., 2]) / 2.0
        py = (1.0 - s) * h + s * py
        pz = np.sqrt(np.maximum(0.0, 1.0 - px * px - py * py))
        nh = px[..., None] * t1 + py[..., None] * t2 + pz[..., None] * wh
        return _normalize(np.stack([self.a * nh[..., 0], self.a * nh[..., 1], np.maximum(1e-6, nh[..., 2])], -1))


def _fr_dielectric(cos_i, eta):
    """``FrDielectric``: from the other side (cos < 0) the index is inverted; 1 under total internal reflection."""
    cos_i = np.clip(cos_i, -1.0, 1.0)
    eta = np.where(cos_i < 0, 1.0 / eta, eta)
    cos_i = np.abs(cos_i)
    sin2_t = (1.0 - cos_i * cos_i) / eta**2
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - sin2_t))
    r_parl = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    return np.where(sin2_t >= 1.0, 1.0, 0.5 * (r_parl**2 + r_perp**2))


def _refract(wi, n, eta):
    """``Refract``: (valid, ωt, the relative index seen)."""
    cos_i = _dot(n, wi)
    flip = cos_i < 0
    eta = np.where(flip, 1.0 / eta, eta)
    cos_i = np.abs(cos_i)
    n = np.where(flip[..., None], -n, n)
    sin2_t = np.maximum(0.0, 1.0 - cos_i * cos_i) / eta**2
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - sin2_t))
    return sin2_t < 1.0, -wi / eta[..., None] + (cos_i / eta - cos_t)[..., None] * n, eta


def _slab(dz, w):
    """``Tr(dz, w)`` = exp(−|dz / cos w|)."""
    return np.exp(-np.abs(dz / w[..., 2]))


class _Dielectric:
    """``DielectricBxDF`` of index η over a Trowbridge-Reitz distribution (rough: α ≥ 1e-3)."""

    def __init__(self, eta: float, alpha: float):
        self.eta, self.mf = eta, _TrowbridgeReitz(alpha)

    def _half(self, wo, wi, transmission_only: bool):
        co, ci = wo[..., 2], wi[..., 2]
        reflect = co * ci > 0
        etap = np.where(co > 0, self.eta, 1.0 / self.eta)
        if not transmission_only:
            etap = np.where(reflect, 1.0, etap)
        wm = wi * etap[..., None] + wo
        length = np.linalg.norm(wm, axis=-1)
        wm = wm / np.maximum(length, 1e-300)[..., None]
        wm = np.where(wm[..., 2:3] < 0, -wm, wm)
        bad = (co == 0) | (ci == 0) | (length == 0) | (_dot(wm, wi) * ci < 0) | (_dot(wm, wo) * co < 0)
        return reflect, etap, wm, bad

    def f(self, wo, wi, radiance: bool):
        reflect, etap, wm, bad = self._half(wo, wi, False)
        co, ci = wo[..., 2], wi[..., 2]
        fr = _fr_dielectric(_dot(wo, wm), self.eta)
        d, g = self.mf.d(wm), self.mf.g(wo, wi)
        reflection = d * g * fr / np.abs(4.0 * ci * co)
        denom = (_dot(wi, wm) + _dot(wo, wm) / etap) ** 2 * ci * co
        transmission = d * (1.0 - fr) * g * np.abs(_dot(wi, wm) * _dot(wo, wm) / denom)
        if radiance:
            transmission = transmission / etap**2
        return np.where(bad, 0.0, np.where(reflect, reflection, transmission))

    def pdf_transmission(self, wo, wi):
        """``PDF(wo, wi, mode, BxDFReflTransFlags::Transmission)``."""
        reflect, etap, wm, bad = self._half(wo, wi, True)
        t = 1.0 - _fr_dielectric(_dot(wo, wm), self.eta)
        denom = (_dot(wi, wm) + _dot(wo, wm) / etap) ** 2
        p = self.mf.pdf(wo, wm) * np.abs(_dot(wi, wm)) / denom
        return np.where(reflect | bad | (t <= 0), 0.0, p)

    def sample(self, wo, u, radiance: bool, reflection: bool):
        """``Sample_f`` with only ``Reflection`` or only ``Transmission`` allowed: (valid, f, ωi, pdf)."""
        wm = self.mf.sample_wm(wo, u)
        fr = _fr_dielectric(_dot(wo, wm), self.eta)
        if reflection:
            wi = -wo + 2.0 * _dot(wo, wm)[..., None] * wm
            ok = (wo[..., 2] * wi[..., 2] > 0) & (fr > 0)
            pdf = self.mf.pdf(wo, wm) / (4.0 * np.abs(_dot(wo, wm)))
            f = self.mf.d(wm) * self.mf.g(wo, wi) * fr / (4.0 * wi[..., 2] * wo[..., 2])
            return ok & (pdf > 0), f, wi, pdf
        ok, wi, etap = _refract(wo, wm, np.full(wo.shape[:-1], self.eta))
        ok = ok & ~(wo[..., 2] * wi[..., 2] > 0) & (wi[..., 2] != 0) & (fr < 1)
        denom = (_dot(wi, wm) + _dot(wo, wm) / etap) ** 2
        pdf = self.mf.pdf(wo, wm) * np.abs(_dot(wi, wm)) / denom
        f = (1.0 - fr) * self.mf.d(wm) * self.mf.g(wo, wi) * np.abs(
            _dot(wi, wm) * _dot(wo, wm) / (wi[..., 2] * wo[..., 2] * denom))
        if radiance:
            f = f / etap**2
        return ok & (pdf > 0) & np.isfinite(f), f, wi, pdf


def _cosine_hemisphere(u):
    """``SampleCosineHemisphere`` (the direction only; the concentric disk's area is what matters here)."""
    r, phi = np.sqrt(u[..., 0]), 2.0 * np.pi * u[..., 1]
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0.0, 1.0 - u[..., 0]))], -1)


def _power(a, b):
    """``PowerHeuristic(1, a, 1, b)``."""
    return a * a / (a * a + b * b)


def coated_diffuse_f(wo, wi, rho: float, eta: float, alpha: float, thickness: float = 0.01, max_depth: int = 10,
                     walks: int = 200_000, seed: int = 0):
    """pbrt-v4's f(ωo, ωi) of ``coateddiffuse`` (one channel), estimated by ``walks`` walks.

    Arguments:
        wo, wi: unit vectors ``(3,)`` above the surface (ωo towards the camera, ωi towards the light).
        rho: the base's reflectance; eta, alpha: the interface's index and Trowbridge-Reitz width.
        thickness, max_depth: the slab's thickness and pbrt's ``maxdepth``.
        walks: the number of walks (``nSamples``, all at once); seed: their random numbers.

    Returns:
        ``(mean, standard error)`` in 1/sr.
    """
    rng = np.random.default_rng(seed)
    top = _Dielectric(eta, alpha)
    wo = np.broadcast_to(wo, (walks, 3)).copy()
    wi = np.broadcast_to(wi, (walks, 3)).copy()
    reflection = float(top.f(wo[:1], wi[:1], True)[0])
    ok_o, f_o, w, pdf_o = top.sample(wo, rng.random((walks, 2)), True, False)
    ok_i, f_i, wis, pdf_i = top.sample(wi, rng.random((walks, 2)), False, False)
    alive = ok_o & ok_i & (w[..., 2] != 0) & (wis[..., 2] != 0)
    beta = np.where(alive, f_o * np.abs(w[..., 2]) / np.where(pdf_o > 0, pdf_o, 1.0), 0.0)
    z = np.full(walks, thickness)
    total = np.zeros(walks)
    for depth in range(max_depth):
        if depth > 3:  # Russian roulette
            roulette = alive & (beta < 0.25)
            q = np.maximum(0.0, 1.0 - beta)
            alive &= ~(roulette & (rng.random(walks) < q))
            beta = np.where(roulette & alive, beta / np.where(1.0 - q > 0, 1.0 - q, 1.0), beta)
        z = np.where(z == thickness, 0.0, thickness)
        beta = beta * _slab(thickness, w)
        at_exit = z == thickness
        ok_r, f_r, w_r, pdf_r = top.sample(-w, rng.random((walks, 2)), True, True)  # reflection from inside
        at_base = alive & ~at_exit
        # Next-event estimation along wis, weighted against the base's cosine density.
        base_f = rho / np.pi * ((-w)[..., 2] * (-wis)[..., 2] > 0)
        weight = _power(pdf_i, np.abs(wis[..., 2]) / np.pi)
        total += np.where(at_base, beta * base_f * np.abs(wis[..., 2]) * weight * _slab(thickness, wis) * f_i
                          / np.where(pdf_i > 0, pdf_i, 1.0), 0.0)
        # The base's cosine sample, and its exit through the interface towards ωi.
        w_b = _cosine_hemisphere(rng.random((walks, 2)))
        w_b = np.where((-w)[..., 2:3] < 0, w_b * np.array([1.0, 1.0, -1.0]), w_b)
        beta_b = beta * rho  # f cos / pdf of the Lambertian base
        exit_f = top.f(-w_b, wi, True)
        weight = _power(np.abs(w_b[..., 2]) / np.pi, top.pdf_transmission(-w_b, wi))
        total += np.where(at_base, beta_b * _slab(thickness, w_b) * exit_f * weight, 0.0)
        new_w = np.where(at_exit[..., None], w_r, w_b)
        new_beta = np.where(at_exit, beta * f_r * np.abs(w_r[..., 2]) / np.where(pdf_r > 0, pdf_r, 1.0), beta_b)
        alive &= np.where(at_exit, ok_r & (w_r[..., 2] != 0), True)
        beta = np.where(alive, new_beta, 0.0)
        w = np.where(alive[..., None], new_w, w)
    return reflection + total.mean(), total.std() / np.sqrt(walks)


def _fr_complex(cos_i, eta):
    """``FrComplex``: the Fresnel reflectance of the complex index ``eta`` (η + ik), principal square root."""
    cos_i = np.clip(cos_i, 0.0, 1.0).astype(complex)
    sin2_t = (1.0 - cos_i * cos_i) / (eta * eta)
    cos_t = np.sqrt(1.0 - sin2_t)
    r_parl = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    r_perp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    return (np.abs(r_parl) ** 2 + np.abs(r_perp) ** 2) / 2.0


class _Conductor:
    """``ConductorBxDF`` over a Trowbridge-Reitz distribution (rough), complex index per channel ``(C,)``."""

    def __init__(self, eta, k, alpha: float):
        self.n, self.mf = np.asarray(eta, dtype=float) + 1j * np.asarray(k, dtype=float), _TrowbridgeReitz(alpha)

    def f(self, wo, wi):
        same = wo[..., 2] * wi[..., 2] > 0
        wm = wo + wi
        length = np.linalg.norm(wm, axis=-1, keepdims=True)
        wm = wm / np.maximum(length, 1e-300)
        fr = _fr_complex(np.abs(_dot(wo, wm))[..., None], self.n)
        value = (self.mf.d(wm) * self.mf.g(wo, wi) / (4.0 * np.abs(wi[..., 2] * wo[..., 2])))[..., None] * fr
        return np.where((same & (length[..., 0] > 0))[..., None], value, 0.0)

    def sample(self, wo, u):
        """``Sample_f`` (reflection): (valid, f ``(..., C)``, ωi, pdf)."""
        wm = self.mf.sample_wm(wo, u)
        wi = -wo + 2.0 * _dot(wo, wm)[..., None] * wm
        ok = (wo[..., 2] * wi[..., 2] > 0) & (wi[..., 2] != 0)
        pdf = self.mf.pdf(wo, wm) / (4.0 * np.abs(_dot(wo, wm)))
        fr = _fr_complex(np.abs(_dot(wo, wm))[..., None], self.n)
        f = (self.mf.d(wm) * self.mf.g(wo, wi) / (4.0 * np.abs(wi[..., 2] * wo[..., 2])))[..., None] * fr
        return ok & (pdf > 0), f, wi, pdf


def reflectance_index(r):
    """``CoatedConductorMaterial::GetBxDF`` given ``reflectance`` r instead of an index: r clamped to [0, 0.9999],
    η = 1, k = 2√r/√(1 − r) (before the division by the interface's index)."""
    r = np.clip(np.asarray(r, dtype=float), 0.0, 0.9999)
    return np.ones_like(r), 2.0 * np.sqrt(r) / np.sqrt(np.maximum(0.0, 1.0 - r))


def _smooth_transmission(w, eta):
    """``DielectricBxDF::Sample_f`` of a smooth interface with only ``Transmission`` allowed (probability 1):
    (valid, T = 1 − FrDielectric, the refracted direction, the relative index seen)."""
    ok, wt, etap = _refract(w, np.broadcast_to(np.array([0.0, 0.0, 1.0]), w.shape), np.full(w.shape[:-1], eta))
    return ok, 1.0 - _fr_dielectric(w[..., 2], eta), wt, etap


def coated_conductor_f(wo, wi, conductor_eta, conductor_k, alpha: float, eta: float, thickness: float = 0.01,
                       max_depth: int = 10, walks: int = 200_000, seed: int = 0):
    """pbrt-v4's f(ωo, ωi) of ``coatedconductor`` with a smooth interface (``interface.roughness`` 0), estimated
    by ``walks`` walks.

    Arguments:
        wo, wi: unit vectors ``(3,)`` above the surface (ωo towards the camera, ωi towards the light).
        conductor_eta, conductor_k: the metal's complex index as given to pbrt (``(C,)``; divided by ``eta`` here,
            as ``CoatedConductorMaterial::GetBxDF`` does); alpha: its Trowbridge-Reitz width.
        eta: the interface's index of refraction.
        thickness, max_depth: the slab's thickness and pbrt's ``maxdepth``.
        walks: the number of walks; seed: their random numbers.

    Returns:
        ``(mean, standard error)``, each ``(C,)``, in 1/sr.
    """
    rng = np.random.default_rng(seed)
    bottom = _Conductor(np.asarray(conductor_eta, dtype=float) / eta, np.asarray(conductor_k, dtype=float) / eta,
                        alpha)
    channels = bottom.n.shape[0]
    wo = np.broadcast_to(wo, (walks, 3)).copy()
    wi = np.broadcast_to(wi, (walks, 3)).copy()
    # The smooth interface's f is 0 off its mirror direction: the walk is all of f.
    ok_o, t_o, w, etap_o = _smooth_transmission(wo, eta)
    ok_i, t_i, wis, _ = _smooth_transmission(wi, eta)  # importance mode: no 1/η'²
    alive = ok_o & ok_i & (w[..., 2] != 0) & (wis[..., 2] != 0)
    beta = np.where(alive[:, None], (t_o / etap_o**2)[:, None] * np.ones(channels), 0.0)  # f |cos| / pdf
    z = np.full(walks, thickness)
    total = np.zeros((walks, channels))
    for depth in range(max_depth):
        if depth > 3:  # Russian roulette on the largest channel
            top = beta.max(axis=1)
            roulette = alive & (top < 0.25)
            q = np.maximum(0.0, 1.0 - top)
            alive &= ~(roulette & (rng.random(walks) < q))
            beta = np.where((roulette & alive)[:, None], beta / np.where(1.0 - q > 0, 1.0 - q, 1.0)[:, None], beta)
        z = np.where(z == thickness, 0.0, thickness)
        beta = beta * _slab(thickness, w)[:, None]
        at_exit = z == thickness
        at_base = alive & ~at_exit
        # At the conductor: next-event estimation along wis (weight 1: the exit interface is specular), ...
        total += np.where(at_base[:, None], beta * bottom.f(-w, -wis) * (t_i * _slab(thickness, wis))[:, None],
                          0.0)
        # ... then a sample of the conductor. At the interface: its mirror reflection from inside.
        ok_b, f_b, w_b, pdf_b = bottom.sample(-w, rng.random((walks, 2)))
        reflectance = _fr_dielectric((-w)[..., 2], eta)  # ω = −w going down from inside: cos < 0 inverts η
        w_r = w * np.array([-1.0, -1.0, 1.0]) * -1.0  # (−wo'.x, −wo'.y, wo'.z) of wo' = −w
        new_w = np.where(at_exit[:, None], w_r, w_b)
        new_beta = np.where(at_exit[:, None], beta * reflectance[:, None],
                            beta * f_b * (np.abs(w_b[..., 2]) / np.where(pdf_b > 0, pdf_b, 1.0))[:, None])
        alive &= np.where(at_exit, True, ok_b)
        beta = np.where(alive[:, None], new_beta, 0.0)
        w = np.where(alive[:, None], new_w, w)
    return total.mean(axis=0), total.std(axis=0) / np.sqrt(walks)


# The kinds of sample `coated_conductor_sample` returns (0: none, the walk was absorbed, cut by Russian roulette or
# ran out of depth).
MIRROR = 1  # the interface's mirror reflection at the entrance (a delta, outside f)
EXIT = 2  # the walk left through the interface after visiting the conductor


def _smooth_sample(w, eta, u):
    """``DielectricBxDF::Sample_f`` of a smooth interface, every lobe allowed, radiance mode: reflection with
    probability R/(R + T), else refraction. Returns (reflected, valid, f ``(...)``, ωi, pdf); from below (w.z < 0)
    ``FrDielectric`` and ``Refract`` invert η."""
    ok, t, wt, etap = _smooth_transmission(w, eta)
    r = 1.0 - t
    reflected = u < r / (r + t)
    wi = np.where(reflected[..., None], w * np.array([-1.0, -1.0, 1.0]), wt)
    cos = np.abs(wi[..., 2])
    f = np.where(reflected, r, t / etap**2) / np.where(cos > 0, cos, 1.0)
    pdf = np.where(reflected, r, t) / (r + t)
    return reflected, reflected | ok, f, wi, pdf


def coated_conductor_sample(wo, conductor_eta, conductor_k, alpha: float, eta: float, thickness: float = 0.01,
                            max_depth: int = 10, samples: int = 200_000, seed: int = 0):
    """pbrt-v4's ``LayeredBxDF<DielectricBxDF, ConductorBxDF, true>::Sample_f`` of ``coatedconductor`` with a smooth
    interface, radiance mode, drawn ``samples`` times from ωo.

    The first step samples the interface: its mirror reflection (returned at once, a delta) or the refraction into
    the slab. Then, up to ``max_depth`` times: Russian roulette after depth 3 where the path's f/pdf falls below
    0.25 (on the largest channel; the survivors' pdf scaled by 1 − q), ``Tr`` for the crossing, and a sample of the
    layer reached: the conductor (``ConductorBxDF::Sample_f``) or the interface from inside (mirror or refraction);
    f and pdf multiply, f also by |cosθ| after a scattering inside; a refraction out of the slab returns the sample.

    Arguments:
        wo: a unit vector ``(3,)`` above the surface (towards the camera).
        conductor_eta, conductor_k: the metal's complex index as given to pbrt (``(C,)``; divided by ``eta``);
            alpha: its Trowbridge-Reitz width.
        eta: the interface's index of refraction.
        thickness, max_depth: the slab's thickness and pbrt's ``maxdepth``.
        samples: how many samples; seed: their random numbers.

    Returns:
        ``(kind, weight, wi)``: `MIRROR`, `EXIT` or 0 for each sample ``(samples,)``; the weight a path tracer
        multiplies its throughput by, f |cosθi| / pdf ``(samples, C)`` (0 for a sample of kind 0); and ωi
        ``(samples, 3)``.
    """
    rng = np.random.default_rng(seed)
    bottom = _Conductor(np.asarray(conductor_eta, dtype=float) / eta, np.asarray(conductor_k, dtype=float) / eta,
                        alpha)
    channels = bottom.n.shape[0]
    wo = np.broadcast_to(wo, (samples, 3)).copy()
    kind = np.zeros(samples, dtype=int)
    weight = np.zeros((samples, channels))
    reflected, ok, f0, w, pdf = _smooth_sample(wo, eta, rng.random(samples))
    first = np.abs(w[..., 2]) * f0
    kind[reflected & ok] = MIRROR
    weight[reflected & ok] = (first / pdf)[reflected & ok, None]
    out = w.copy()
    alive = ok & ~reflected & (pdf > 0) & (w[..., 2] != 0)
    f = np.where(alive[:, None], first[:, None] * np.ones(channels), 0.0)
    pdf = np.where(alive, pdf, 1.0)
    z = np.full(samples, thickness)
    for depth in range(max_depth):
        rr = f.max(axis=1) / pdf
        roulette = alive & (depth > 3) & (rr < 0.25)
        q = np.maximum(0.0, 1.0 - rr)
        alive &= ~(roulette & (rng.random(samples) < q))
        pdf = np.where(roulette & alive, pdf * (1.0 - q), pdf)
        alive &= w[..., 2] != 0
        z = np.where(z == thickness, 0.0, thickness)
        f = f * _slab(thickness, w)[:, None]
        at_base = z == 0.0
        # The conductor, seen from −w (above it); the interface, seen from −w below it.
        ok_b, f_b, w_b, pdf_b = bottom.sample(-w, rng.random((samples, 2)))
        refl_t, ok_t, f_t, w_t, pdf_t = _smooth_sample(-w, eta, rng.random(samples))
        w_next = np.where(at_base[:, None], w_b, w_t)
        alive &= np.where(at_base, ok_b & (pdf_b > 0), ok_t & (pdf_t > 0)) & (w_next[..., 2] != 0)
        f = f * np.where(at_base[:, None], f_b, f_t[:, None])
        pdf = pdf * np.where(at_base, pdf_b, pdf_t)
        w = np.where(alive[:, None], w_next, w)
        leaving = alive & ~at_base & ~refl_t
        kind[leaving] = EXIT
        weight[leaving] = f[leaving] * np.abs(w[leaving, 2:3]) / pdf[leaving, None]
        out[leaving] = w[leaving]
        alive &= ~leaving
        f = np.where(alive[:, None], f * np.abs(w[..., 2:3]), 0.0)
        pdf = np.where(alive, pdf, 1.0)
    return kind, weight, out
