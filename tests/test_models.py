"""Every lobe against an independent NumPy re-derivation of its paper's formula, and the model API.

The references live in tests/reference_brdfs.py and do not import brdffit. Values are compared in float64 with
rtol = 1e-10 (the two sides evaluate the same formula along different algebraic routes: vectors versus spherical
angles, so only rounding may differ) and atol = 1e-15 1/sr, far below any value a lobe takes where it is not zero
(it only matters where a lobe is switched off, e.g. a cosine power of a negative cosine).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdffit
from brdffit import cli, models

import reference_brdfs as ref

RTOL, ATOL = 1e-10, 1e-15
CHANNELS = 3

# Per-channel colour values, all different from each other and from the declared defaults.
RHO = [0.15, 0.45, 0.85]
KS = [0.3, 0.6, 0.9]
RS = [0.04, 0.3, 0.9]


@dataclasses.dataclass(frozen=True)
class Case:
    """One lobe configuration: spec, lobe options, (non-default) parameter values."""

    spec: str
    options: dict
    params: dict

    @property
    def id(self) -> str:
        opts = ",".join(f"{k}={v}" for k, v in self.options.items())
        return self.spec + (f"({opts})" if opts else "")

    def model(self):
        return models.get(self.spec, channels=CHANNELS, **self.options, **self.params)

    def reference(self, ti, pi_, to, po):
        options = {k: v for k, v in self.options.items() if k != "material"}
        params = {k: np.asarray(v, dtype=float) if np.ndim(v) else float(v) for k, v in self.params.items()}
        return ref.REFERENCES[self.spec](ti, pi_, to, po, params, **options)


def _fresnel_params(fresnel):
    if fresnel == "schlick":
        return {"f0": 0.08}
    if fresnel == "dielectric":
        return {"eta": 1.6}
    return {"eta": [0.2, 0.6, 1.1], "k": [3.0, 2.4, 1.8]}


CT_CASES = [
    Case("cook-torrance", {"distribution": d, "shadowing": s, "fresnel": f},
         {"ks": KS, "m": 0.35, **_fresnel_params(f)})
    for d, s, f in itertools.product(("beckmann", "ggx", "blinn"), ("v-cavity", "smith", "none"),
                                     ("schlick", "dielectric", "conductor"))
] + [  # the height-correlated masking with each distribution (the Fresnel modes do not interact with it)
    Case("cook-torrance", {"distribution": d, "shadowing": "smith-correlated", "fresnel": "schlick"},
         {"ks": KS, "m": 0.35, "f0": 0.08})
    for d in ("beckmann", "ggx", "blinn")
] + [
    Case("cook-torrance", {"distribution": d, "shadowing": s, "fresnel": "schlick", "anisotropic": True},
         {"ks": KS, "m_x": 0.12, "m_y": 0.45, "f0": 0.08})
    for d, s in itertools.product(("beckmann", "ggx"), ("v-cavity", "smith", "smith-correlated"))
] + [
    Case("cook-torrance", {"distribution": "std", "shadowing": s, "fresnel": "schlick"},
         {"ks": KS, "m": 0.3, "gamma": 3.5, "f0": 0.08})
    for s in ("v-cavity", "smith", "smith-correlated", "none")
] + [
    Case("cook-torrance", {"distribution": "gtr", "shadowing": s, "fresnel": "schlick"},
         {"ks": KS, "m": 0.25, "gamma": 1.3, "f0": 0.08})
    for s in ("v-cavity", "smith", "smith-correlated")
] + [
    Case("cook-torrance", {"distribution": "std", "shadowing": "smith-correlated", "fresnel": "conductor",
                           "anisotropic": True},
         {"ks": KS, "m_x": 0.4, "m_y": 0.1, "gamma": 1.8, **_fresnel_params("conductor")}),
]

OTHER_CASES = [
    Case("lambert", {}, {"rho_d": RHO}),
    Case("oren-nayar", {}, {"rho_d": RHO, "sigma": 0.45}),
    Case("phong", {}, {"ks": KS, "n": 7.5}),
    Case("blinn-phong", {}, {"ks": KS, "n": 12.0}),
    Case("ward", {}, {"ks": KS, "alpha": 0.27}),
    Case("ward-aniso", {}, {"ks": KS, "alpha_x": 0.12, "alpha_y": 0.4}),
    Case("ward-duer", {}, {"ks": KS, "alpha": 0.33}),
    Case("ggx", {}, {"ks": KS, "alpha": 0.3, "f0": 0.07}),
    Case("ggx", {"fresnel": "conductor", "material": "copper"},
         {"ks": KS, "alpha": 0.22, **_fresnel_params("conductor")}),
    Case("ggx", {"anisotropic": True, "shadowing": "smith-correlated"},
         {"ks": KS, "alpha_x": 0.5, "alpha_y": 0.08, "f0": 0.07}),
    Case("burley", {}, {"rho_d": RHO, "roughness": 0.7}),
    Case("sheen", {}, {"ks": KS}),
    Case("charlie-sheen", {}, {"ks": KS, "alpha": 0.35}),
    Case("abc-smooth", {}, {"A": KS, "B": 350.0, "C": 0.8, "eta": 1.6}),
    Case("abc-microfacet", {}, {"A": KS, "B": 60.0, "C": 1.7, "eta": 1.45}),
    Case("sgd", {}, {"ks": KS, "alpha": 0.07, "p": 0.45, "f0": 0.06, "f1": 0.02, "shadow_lambda": 0.4,
                     "shadow_c": 0.8, "shadow_k": 1.5, "shadow_theta0": 1.0}),
    Case("principled", {}, {"base_color": [0.7, 0.4, 0.15], "metallic": 0.3, "roughness": 0.45, "specular": 0.65,
                            "spec_tint": 0.25, "anisotropic": 0.6, "sheen": 0.4, "sheen_tint": 0.3, "clearcoat": 0.7,
                            "clearcoat_gloss": 0.55}),
    Case("blender", {}, {"base_color": [0.7, 0.4, 0.15], "metallic": 0.35, "roughness": 0.45, "ior": 1.7}),
    Case("blender", {"coat": True}, {"base_color": [0.7, 0.4, 0.15], "metallic": 0.35, "roughness": 0.45, "ior": 1.7,
                                     "coat_weight": 0.7, "coat_roughness": 0.25, "coat_ior": 1.6,
                                     "coat_tint": [0.9, 0.75, 0.6]}),
    Case("blender", {"coat": True, "sheen": True},
         {"base_color": [0.7, 0.4, 0.15], "metallic": 0.35, "roughness": 0.45, "ior": 1.7, "coat_weight": 0.7,
          "coat_roughness": 0.25, "coat_ior": 1.6, "coat_tint": [0.9, 0.75, 0.6], "sheen_weight": 0.8,
          "sheen_tint": [0.3, 0.9, 0.6], "sheen_roughness": 0.4}),
    Case("openpbr", {}, {"base_color": [0.7, 0.4, 0.15], "base_metalness": 0.35, "base_diffuse_roughness": 0.6,
                         "specular_weight": 0.8, "specular_color": [0.95, 0.6, 0.9], "specular_roughness": 0.45,
                         "specular_ior": 1.7}),
    Case("openpbr", {"fuzz": True}, {"base_color": [0.7, 0.4, 0.15], "base_metalness": 0.35,
                                     "base_diffuse_roughness": 0.6, "specular_weight": 0.8,
                                     "specular_color": [0.95, 0.6, 0.9], "specular_roughness": 0.45,
                                     "specular_ior": 1.7, "fuzz_weight": 0.7, "fuzz_color": [0.3, 0.9, 0.6],
                                     "fuzz_roughness": 0.35}),
    Case("openpbr", {"coat": True, "fuzz": True},
         {"base_color": [0.7, 0.4, 0.15], "base_metalness": 0.35, "base_diffuse_roughness": 0.6,
          "specular_weight": 0.8, "specular_color": [0.95, 0.6, 0.9], "specular_roughness": 0.45, "specular_ior": 1.7,
          "coat_weight": 0.6, "coat_color": [0.9, 0.8, 0.5], "coat_roughness": 0.2, "coat_ior": 1.45,
          "coat_darkening": 0.7, "fuzz_weight": 0.3, "fuzz_color": [0.3, 0.9, 0.6], "fuzz_roughness": 0.35}),
    # The base's index below the coat's: the graph takes coat_ior / specular_ior (its fix of total internal
    # reflection) instead of the ratio.
    Case("openpbr", {"coat": True},
         {"base_color": [0.2, 0.5, 0.75], "base_metalness": 0.15, "base_diffuse_roughness": 0.3,
          "specular_weight": 0.9, "specular_color": [0.85, 0.9, 0.7], "specular_roughness": 0.6, "specular_ior": 1.3,
          "coat_weight": 0.85, "coat_color": [0.6, 0.7, 0.95], "coat_roughness": 0.08, "coat_ior": 1.8,
          "coat_darkening": 0.4}),
    Case("gltf", {}, {"base_color": [0.7, 0.4, 0.15], "metallic": 0.35, "roughness": 0.4, "specular": 0.8,
                      "ior": 1.7, "specular_color": [0.95, 0.6, 0.9], "clearcoat": 0.6,
                      "clearcoat_roughness": 0.25, "sheen_color": [0.6, 0.3, 0.45], "sheen_roughness": 0.4}),
    Case("pbrt", {}, {"reflectance": [0.7, 0.4, 0.15], "amount": 0.35, "roughness": 0.3, "eta": [0.2, 0.9, 1.45],
                      "k": [3.2, 0.6, 0.001]}),
    Case("coateddiffuse", {}, {"reflectance": [0.7, 0.4, 0.15], "roughness": 0.3, "eta": 1.7}),
    Case("coatedconductor", {}, {"reflectance": [0.9, 0.6, 0.25], "conductor_roughness": 0.3, "interface_eta": 1.7}),
    Case("roughplastic", {}, {"diffuse_reflectance": [0.7, 0.4, 0.15], "specular_reflectance": [0.9, 0.8, 0.95],
                              "alpha": 0.3, "int_ior": 1.7}),
    Case("ashikhmin-shirley", {}, {"rs": RS, "n": 35.0}),
    Case("ashikhmin-shirley-aniso", {}, {"rs": RS, "nu": 12.0, "nv": 150.0}),
    Case("lafortune", {}, {"ks_1": KS, "cxy_1": -0.8, "cz_1": 0.6, "n_1": 6.5}),
    Case("lafortune", {"lobes": 2}, {"ks_1": KS, "cxy_1": -0.8, "cz_1": 0.6, "n_1": 6.5,
                                     "ks_2": [0.5, 0.25, 0.1], "cxy_2": 0.3, "cz_2": 0.9, "n_2": 3.0}),
    Case("lafortune", {"anisotropic": True}, {"ks_1": KS, "cx_1": -0.9, "cy_1": -0.5, "cz_1": 0.7, "n_1": 8.0}),
    Case("toon-diffuse", {}, {"rho_d": RHO, "rho_shade": [0.05, 0.12, 0.2], "threshold": 0.45, "width": 0.07}),
    Case("toon-specular", {}, {"ks": KS, "threshold": 0.9, "width": 0.03}),
]

CASES = OTHER_CASES + CT_CASES
CASES_BY_ID = {case.id: case for case in CASES}

# One model with every registered lobe (parameters numbered _2, _3, ... where names repeat): jit and vmap are
# checked on it once instead of once per lobe.
ALL_LOBES = models.get("+".join(models.names()), channels=CHANNELS)

# Direction pairs (θi, φi, θo, φo) in degrees.
CONFIGS = {
    "normal-incidence": [(0, 0, 0, 0), (0, 0, 25, 40), (0, 115, 60, 200)],
    "off-specular": [(30, 10, 50, 120), (20, 200, 65, 300), (45, 0, 10, 90), (60, 30, 40, 250), (15, 80, 75, 100)],
    "in-plane-specular": [(35, 40, 35, 220), (60, 0, 60, 180), (10, 300, 10, 120)],
    "near-grazing": [(89, 20, 89, 200), (89, 20, 30, 250), (15, 100, 89, 300), (89, 0, 89, 0)],
}
BELOW = [(100, 0, 30, 180), (30, 0, 95, 180), (120, 10, 120, 190), (91, 45, 40, 225), (70, 0, 179, 0)]


def _radians(points):
    return tuple(np.radians(np.array(points, dtype=float)).T)


def _evaluate(model, points):
    return np.asarray(brdffit.evaluate(model, *_radians(points)))


# Every case is evaluated once on all points (one array shape for every lobe, so JAX's per-primitive compilation
# cache is shared across cases and the suite stays fast); the tests then look at the rows of one configuration.
ALL_POINTS = [p for points in CONFIGS.values() for p in points] + BELOW
_ROWS = {}
for _name, _points in [*CONFIGS.items(), ("below-horizon", BELOW)]:
    _start = sum(len(v) for v in _ROWS.values())
    _ROWS[_name] = list(range(_start, _start + len(_points)))


@functools.lru_cache(maxsize=None)
def _values(case_id):
    case = CASES_BY_ID[case_id]
    return _evaluate(case.model(), ALL_POINTS), case.reference(*_radians(ALL_POINTS))


# The lobes and options of the modern microfacet, Burley and sheen models: against the reference at random
# directions above the horizon to 1e-12 relative (the fixed configurations above hold every lobe to 1e-10).
MODERN = [case for case in CASES if case.spec in ("burley", "sheen", "charlie-sheen", "principled", "gltf", "blender",
                                                  "openpbr", "pbrt", "coateddiffuse", "coatedconductor", "roughplastic", "abc-smooth", "abc-microfacet",
                                                  "sgd")
          or case.options.get("distribution") in ("std", "gtr")
          or case.options.get("anisotropic") is True and case.spec != "lafortune"
          or case.options.get("shadowing") == "smith-correlated"]


@pytest.mark.parametrize("case", MODERN, ids=lambda c: c.id)
def test_modern_lobe_matches_reference_at_random_directions(case):
    rng = np.random.default_rng(12)
    n = 400
    angles = (np.arccos(rng.uniform(0.1, 1.0, n)), rng.uniform(-np.pi, np.pi, n),
              np.arccos(rng.uniform(0.1, 1.0, n)), rng.uniform(-np.pi, np.pi, n))
    got = np.asarray(brdffit.evaluate(case.model(), *angles))
    want = case.reference(*angles)
    assert np.all(want >= 0) and np.mean(want > 1e-6) > 0.25  # a narrow Beckmann width underflows off its peak
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=ATOL)  # ATOL: see the module doc


@pytest.mark.parametrize("alpha, p", [(1e-3, 0.2), (0.05, 0.64), (0.3, 0.9), (1.0, 0.01)])
def test_sgd_distribution_is_normalised(alpha, p):
    """The SGD's D with its closed-form K (1/(α Γ(1 − p, α))) integrates to 1 with cosθh: over the slope plane
    that is ∫_0^∞ K P22(x) dx, x = tan²θh, by adaptive quadrature in x/α²."""
    from scipy import integrate

    from brdffit.models.sgd import sgd_normalisation

    k = float(sgd_normalisation(alpha, p))
    value, _ = integrate.quad(lambda t: k * np.exp(-(alpha + t * alpha)) * (alpha + t * alpha) ** (-p) * alpha**2,
                              0.0, np.inf, epsabs=0.0, epsrel=1e-12, limit=400)
    assert value == pytest.approx(1.0, abs=1e-10)


def test_every_registered_lobe_has_a_case_and_a_reference():
    assert set(models.names()) == {case.spec for case in CASES} == set(ref.REFERENCES)


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.id)
def test_case_sets_every_parameter_to_a_non_default_value(case):
    model = case.model()
    assert set(model.params) == set(case.params)
    for spec in model.param_specs:
        assert not np.any(np.asarray(model.params[spec.name]) == spec.default), spec.name


@pytest.mark.parametrize("config", list(CONFIGS))
@pytest.mark.parametrize("case", CASES, ids=lambda c: c.id)
def test_lobe_matches_reference(case, config):
    got, want = (v[_ROWS[config]] for v in _values(case.id))
    assert got.shape == want.shape == (len(CONFIGS[config]), CHANNELS)
    assert np.all(np.isfinite(want)) and np.any(want > 0)
    np.testing.assert_allclose(got, want, rtol=RTOL, atol=ATOL)


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.id)
def test_lobe_is_exactly_zero_below_the_horizon(case):
    got, want = (v[_ROWS["below-horizon"]] for v in _values(case.id))
    assert got.shape == (len(BELOW), CHANNELS)
    assert np.all(got == 0.0) and np.all(want == 0.0)


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.id)
def test_channels_differ_as_their_colour_values(case):
    """The per-channel colour values reach the right channel (no channel mix-up)."""
    got = _values(case.id)[0][_ROWS["off-specular"]]
    assert not np.allclose(got[:, 0], got[:, 1])


# Gradient configurations: exactly normal incidence (h = n, every azimuth undefined), 89.9° (cosines ~ 1.7e-3),
# below the horizon (masked points must not poison a fit's Jacobian with NaN), and retro-reflection within 1e-5° of
# the horizon (h within ~2e-7 rad of horizontal).
GRAD_CONFIGS = {
    "theta=0": [(0, 0, 0, 0)],
    "theta=0/view-off-normal": [(0, 0, 40, 30)],
    "theta=89.9-specular": [(89.9, 10, 89.9, 190)],
    "theta=89.9-mixed": [(89.9, 10, 0, 0), (0, 0, 89.9, 100), (89.9, 10, 45, 100), (89.9, 0, 89.9, 0)],
    "below-horizon": [(100, 0, 30, 180), (30, 0, 95, 180)],
}
GRAD_POINTS = [p for points in GRAD_CONFIGS.values() for p in points]
# The near-horizon retro point, repeated so that its batch has the same shape as GRAD_POINTS (JAX then reuses the
# compiled primitives) but stays separate: a NaN derivative at one point poisons the gradient of the whole batch.
RETRO_POINTS = [(89.99999, 0, 89.99999, 0)] * len(GRAD_POINTS)
BELOW_POINTS = [GRAD_CONFIGS["below-horizon"][i % 2] for i in range(len(GRAD_POINTS))]


def _grad(model, points):
    """The issue's call: jax.grad of evaluate(...).sum() w.r.t. the model, a model of gradients."""
    angles = _radians(points)
    return jax.grad(lambda m: brdffit.evaluate(m, *angles).sum())(model)


def _non_finite(grads):
    return [name for name, value in grads.params.items() if not np.all(np.isfinite(np.asarray(value)))]


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.id)
def test_gradient_wrt_model_is_finite(case):
    """At θ = 0 and θ = 89.9° (GRAD_CONFIGS) the gradient is a model of finite, not all zero, arrays."""
    model = case.model()
    grads = _grad(model, GRAD_POINTS)
    assert isinstance(grads, brdffit.Model) and set(grads.params) == set(model.params)
    if _non_finite(grads):  # name the configuration(s) in the failure message
        bad = {config: _non_finite(_grad(model, points)) for config, points in GRAD_CONFIGS.items()}
        pytest.fail(f"non-finite gradients: { {k: v for k, v in bad.items() if v} }")
    assert any(np.any(np.asarray(v) != 0) for v in grads.params.values())
    below = _grad(model, BELOW_POINTS)
    assert all(np.all(np.asarray(v) == 0) for v in below.params.values())


@pytest.mark.parametrize("case", CASES, ids=[case.id for case in CASES])
def test_gradient_wrt_model_is_finite_at_the_horizon(case):
    grads = _grad(case.model(), RETRO_POINTS)
    assert not _non_finite(grads), _non_finite(grads)


def test_gradient_matches_finite_differences():
    """The gradient is not only finite but right: central differences on a sum of lobes."""
    model = models.get("lambert+cook-torrance+ward-aniso", channels=CHANNELS, rho_d=RHO, ks=KS, m=0.3,
                       ks_2=[0.2, 0.1, 0.4], alpha_x=0.2, alpha_y=0.35)
    angles = _radians(CONFIGS["off-specular"])
    loss = jax.jit(lambda m: brdffit.evaluate(m, *angles).sum())
    grads = jax.grad(loss)(model)
    for name in ("m", "alpha_x", "alpha_y", "f0"):
        h = 1e-6
        up = loss(model.replace(**{name: model.params[name] + h}))
        down = loss(model.replace(**{name: model.params[name] - h}))
        np.testing.assert_allclose(grads.params[name], (up - down) / (2 * h), rtol=1e-6)


def test_jit_matches_eager_for_every_lobe():
    angles = _radians(ALL_POINTS)
    eager = brdffit.evaluate(ALL_LOBES, *angles)
    jitted = jax.jit(brdffit.evaluate)(ALL_LOBES, *angles)
    np.testing.assert_allclose(jitted, eager, rtol=1e-13, atol=1e-300)
    assert np.all(np.asarray(jitted)[_ROWS["below-horizon"]] == 0.0)


def test_vmap_over_directions_matches_broadcasting_for_every_lobe():
    angles = _radians(ALL_POINTS)
    batched = brdffit.evaluate(ALL_LOBES, *angles)
    mapped = jax.jit(jax.vmap(lambda ti, pi_, to, po: brdffit.evaluate(ALL_LOBES, ti, pi_, to, po)))(*angles)
    assert mapped.shape == batched.shape
    np.testing.assert_allclose(mapped, batched, rtol=1e-13, atol=1e-300)


def test_vmap_and_jit_over_a_stack_of_models():
    """A batch of parameter sets is a model whose leaves have a leading axis; vmap maps over it."""
    stack = [models.get("lambert+ggx", channels=CHANNELS, rho_d=r, alpha=a) for r, a in ((0.2, 0.1), (0.5, 0.3))]
    stacked = jax.tree.map(lambda *leaves: jnp.stack(leaves), *stack)
    angles = _radians(CONFIGS["off-specular"])
    out = jax.jit(jax.vmap(lambda m: brdffit.evaluate(m, *angles)))(stacked)
    assert out.shape == (2, len(CONFIGS["off-specular"]), CHANNELS)
    for i, model in enumerate(stack):
        np.testing.assert_allclose(out[i], brdffit.evaluate(model, *angles), rtol=1e-13)


def test_evaluate_dirs_matches_evaluate():
    model = CASES[4].model()
    angles = _radians(CONFIGS["off-specular"])
    wi = brdffit.geometry.spherical_to_vector(angles[0], angles[1])
    wo = brdffit.geometry.spherical_to_vector(angles[2], angles[3])
    np.testing.assert_array_equal(brdffit.evaluate_dirs(model, wi, wo), brdffit.evaluate(model, *angles))
    np.testing.assert_array_equal(model(wi, wo), brdffit.evaluate(model, *angles))


def test_evaluate_broadcasts_its_inputs():
    model = CASES_BY_ID["phong"].model()
    theta_o = np.linspace(0.1, 1.4, len(ALL_POINTS))
    scalar = brdffit.evaluate(model, 0.3, 0.0, theta_o, np.pi)
    full = brdffit.evaluate(model, np.full_like(theta_o, 0.3), np.zeros_like(theta_o), theta_o,
                            np.full_like(theta_o, np.pi))
    assert scalar.shape == (len(ALL_POINTS), CHANNELS)
    np.testing.assert_array_equal(scalar, full)
    grid = jax.eval_shape(brdffit.evaluate, model, np.zeros((2, 1)), 0.0, np.zeros((1, 4)), np.pi)
    assert grid.shape == (2, 4, CHANNELS)



def test_evaluations_of_every_size_share_one_compiled_program():
    """A host call of any size runs in padded calls of one shape (`EVALUATION_ROWS`): one compilation per model
    structure serves them all, and the values are those of the traced expression at the same pairs."""
    from brdffit.models.model import EVALUATION_ROWS, _evaluate_rows

    model = models.get("lambert+ggx+lafortune", channels=CHANNELS, alpha=0.23)  # a structure no other test uses
    rng = np.random.default_rng(5)
    before = len(_evaluate_rows._compiled)
    for n in (1, 357, EVALUATION_ROWS, EVALUATION_ROWS + 1, 3 * EVALUATION_ROWS - 7):
        angles = [rng.uniform(0.0, 1.5, n), rng.uniform(0, 2 * np.pi, n), rng.uniform(0.0, 1.5, n),
                  rng.uniform(0, 2 * np.pi, n)]
        values = brdffit.evaluate(model, *angles)
        assert isinstance(values, np.ndarray) and values.shape == (n, CHANNELS)
        traced = jax.jit(brdffit.evaluate)(model, *angles)
        np.testing.assert_allclose(values, traced, rtol=1e-13, atol=1e-300)
    assert len(_evaluate_rows._compiled) == before + 1

# --------------------------------------------------------------------------------------------------------------
# Sums of lobes and the naming rule


def test_sum_of_lobes_is_the_sum_of_its_parts():
    angles = _radians(ALL_POINTS)
    total = models.get("lambert+ward", channels=CHANNELS, rho_d=RHO, ks=KS, alpha=0.2)
    parts = (models.get("lambert", channels=CHANNELS, rho_d=RHO),
             models.get("ward", channels=CHANNELS, ks=KS, alpha=0.2))
    np.testing.assert_allclose(brdffit.evaluate(total, *angles),
                               sum(brdffit.evaluate(p, *angles) for p in parts), rtol=1e-14, atol=0)


def test_sum_of_three_lobes_with_options_matches_references():
    points = CONFIGS["off-specular"] + CONFIGS["near-grazing"]
    angles = _radians(points)
    model = models.get("oren-nayar+cook-torrance(distribution=ggx, shadowing=smith)+lafortune(lobes=2)",
                       channels=CHANNELS, rho_d=RHO, sigma=0.3, ks=KS, m=0.25, f0=0.1,
                       ks_1=[0.1, 0.2, 0.3], cxy_1=-0.7, cz_1=0.7, n_1=9.0,
                       ks_2=[0.3, 0.2, 0.1], cxy_2=0.5, cz_2=0.5, n_2=2.0)
    want = (ref.oren_nayar(*angles, np.array(RHO), 0.3)
            + ref.cook_torrance(*angles, np.array(KS), 0.25, distribution="ggx", shadowing="smith", f0=0.1)
            + ref.lafortune(*angles, [{"ks": np.array([0.1, 0.2, 0.3]), "cx": -0.7, "cy": -0.7, "cz": 0.7, "n": 9.0},
                                      {"ks": np.array([0.3, 0.2, 0.1]), "cx": 0.5, "cy": 0.5, "cz": 0.5, "n": 2.0}]))
    np.testing.assert_allclose(brdffit.evaluate(model, *angles), want, rtol=RTOL, atol=ATOL)


def test_repeated_lobes_get_numbered_parameter_names():
    model = models.get("lambert+ward+ward", channels=CHANNELS)
    assert list(model.params) == ["rho_d", "ks", "alpha", "ks_2", "alpha_2"]
    assert model.param_specs.names == ("rho_d", "ks", "alpha", "ks_2", "alpha_2")
    assert models.get("ward+ward+ward").param_specs.names == ("ks", "alpha", "ks_2", "alpha_2", "ks_3", "alpha_3")
    # The renamed declarations keep everything but the name.
    assert model.param_specs["alpha_2"].lower == model.param_specs["alpha"].lower
    assert model.param_specs["ks_2"].colour and not model.param_specs["alpha_2"].colour


def test_each_numbered_lobe_reads_its_own_parameters():
    angles = _radians(CONFIGS["off-specular"])
    model = models.get("lambert+ward+ward", channels=CHANNELS, rho_d=RHO, ks=KS, alpha=0.1,
                       ks_2=[0.05, 0.1, 0.2], alpha_2=0.5)
    want = (ref.lambert(*angles, np.array(RHO)) + ref.ward(*angles, np.array(KS), 0.1)
            + ref.ward(*angles, np.array([0.05, 0.1, 0.2]), 0.5))
    np.testing.assert_allclose(brdffit.evaluate(model, *angles), want, rtol=RTOL, atol=ATOL)


def test_shared_options_apply_to_every_lobe_that_accepts_them():
    model = models.get("lambert+cook-torrance+cook-torrance", distribution="ggx")
    assert [lobe.options().get("distribution") for lobe in model.lobes] == [None, "ggx", "ggx"]
    own = models.get("cook-torrance(distribution=blinn)+cook-torrance", distribution="ggx")
    assert [lobe.distribution for lobe in own.lobes] == ["blinn", "ggx"]


# Two GGX lobes with one Fresnel term (the `share` option every lobe has): the second lobe reads the first's f0.
SHARED = "lambert+ggx+ggx(share=f0)"
SHARED_PARAMS = dict(rho_d=RHO, ks=KS, alpha=0.08, ks_2=[0.2, 0.1, 0.05], alpha_2=0.4, f0=0.3)


def test_a_shared_parameter_is_one_slot_that_both_lobes_read():
    model = models.get(SHARED, channels=CHANNELS, **SHARED_PARAMS)
    assert list(model.params) == ["rho_d", "ks", "alpha", "f0", "ks_2", "alpha_2"]
    assert model.names_by_lobe == (("rho_d",), ("ks", "alpha", "f0"), ("ks_2", "alpha_2", "f0"))
    assert model.spec == SHARED and model.reciprocal
    angles = _radians(ALL_POINTS)
    want = (ref.lambert(*angles, np.array(RHO))
            + ref.cook_torrance(*angles, np.array(KS), 0.08, distribution="ggx", shadowing="smith", f0=0.3)
            + ref.cook_torrance(*angles, np.array([0.2, 0.1, 0.05]), 0.4, distribution="ggx", shadowing="smith",
                                f0=0.3))
    np.testing.assert_allclose(brdffit.evaluate(model, *angles), want, rtol=RTOL, atol=ATOL)
    # f0 acts through both amplitudes, so neither lobe's amplitude at 0 leaves it undetermined.
    assert model.layout.partners(1, "ks") == ("alpha",) and model.layout.partners(2, "ks") == ("alpha_2",)
    # One declaration shared by any lobes declaring the name alike: three Ward lobes with one width.
    assert models.get("ward+ward(share=alpha)+ward(share=alpha)").param_specs.names == ("ks", "alpha", "ks_2",
                                                                                         "ks_3")


def test_shared_lobes_are_reciprocal_with_finite_gradients_and_conserve_energy():
    from brdffit import properties

    model = models.get(SHARED, channels=CHANNELS, **SHARED_PARAMS)
    points = np.array(ALL_POINTS, dtype=float)
    np.testing.assert_allclose(_evaluate(model, ALL_POINTS), _evaluate(model, points[:, [2, 3, 0, 1]]),
                               rtol=1e-11, atol=ATOL)
    for points in (GRAD_POINTS, RETRO_POINTS):
        assert not _non_finite(_grad(model, points))
    # The shared f0's gradient is the sum of what each lobe's own f0 would get.
    apart = models.get("lambert+ggx+ggx", channels=CHANNELS, **SHARED_PARAMS, f0_2=0.3)
    together, separate = _grad(model, CONFIGS["off-specular"]), _grad(apart, CONFIGS["off-specular"])
    np.testing.assert_allclose(together.params["f0"], separate.params["f0"] + separate.params["f0_2"], rtol=1e-12)
    # Amplitudes summing to 1 with f0 = 1 (the largest Fresnel term): the directional albedo stays at or below 1.
    bright = models.get("ggx+ggx(share=f0)", channels=1, ks=0.6, alpha=0.05, ks_2=0.4, alpha_2=0.5, f0=1.0)
    albedo = np.asarray(properties.directional_albedo(bright, np.radians([0.0, 30.0, 60.0, 85.0])))
    assert np.all(albedo <= 1.0 + 1e-3) and np.all(albedo > 0.5), albedo


@pytest.mark.parametrize("spec, words", [
    ("ggx(share=f0)", ["lobe 1", "f0", "no lobe before it"]),
    ("lambert+ggx+ggx(share=ks)", ["lobe 3", "amplitude cannot be shared"]),
    ("lambert+ggx+ggx(share=beta)", ["beta", "does not declare", "ks, alpha, f0"]),
    ("ggx(fresnel=conductor)+ggx(fresnel=conductor, share=eta)", []),  # alike: fine
    ("ggx(fresnel=dielectric)+cook-torrance(fresnel=conductor, share=eta)", ["eta", "declares it differently"]),
])
def test_sharing_errors_name_the_lobe_and_the_parameter(spec, words):
    if not words:
        assert models.get(spec).param_specs.names == ("ks", "alpha", "eta", "k", "ks_2", "alpha_2", "k_2")
        return
    with pytest.raises(ValueError) as info:
        models.get(spec)
    assert all(word in str(info.value) for word in words), str(info.value)


def test_params_and_param_specs_have_the_declared_shapes():
    model = models.get("lambert+cook-torrance(fresnel=conductor)", channels=5)
    for spec in model.param_specs:
        value = model.params[spec.name]
        assert value.shape == ((5,) if spec.colour else ())
        np.testing.assert_array_equal(value, spec.default)
    assert [s.kind for s in model.param_specs] == ["colour", "colour", "shape", "colour", "colour"]
    gold_eta, gold_k = models.fresnel.CONDUCTORS["gold"]
    assert model.param_specs["eta"].default == gold_eta and model.param_specs["k"].default == gold_k


def test_material_preset_sets_defaults():
    copper = models.get("cook-torrance", fresnel="conductor", material="copper", channels=2)
    np.testing.assert_array_equal(copper.params["eta"], [0.617, 0.617])
    np.testing.assert_array_equal(copper.params["k"], [2.63, 2.63])
    water = models.get("cook-torrance(fresnel=dielectric, material=water)")
    assert float(water.params["eta"]) == 1.333


# --------------------------------------------------------------------------------------------------------------
# replace, errors, serialisation, CLI


def test_replace_returns_a_new_model_and_keeps_the_old():
    model = models.get("lambert+ward", channels=CHANNELS)
    new = model.replace(rho_d=RHO, alpha=0.4)
    np.testing.assert_array_equal(new.params["rho_d"], RHO)
    assert float(new.params["alpha"]) == 0.4
    np.testing.assert_array_equal(model.params["rho_d"], [0.5, 0.5, 0.5])
    assert float(model.params["alpha"]) == 0.2
    np.testing.assert_array_equal(model.replace(ks=0.7).params["ks"], [0.7, 0.7, 0.7])
    assert new.lobes == model.lobes and new.channels == model.channels
    assert models.get(model, ks=0.3).params["ks"].shape == (CHANNELS,)


def test_replace_rejects_unknown_names_and_wrong_shapes():
    model = models.get("lambert+ward", channels=CHANNELS)
    with pytest.raises(KeyError, match="alpha_2"):
        model.replace(alpha_2=0.1)
    with pytest.raises(ValueError, match="rho_d"):
        model.replace(rho_d=[0.1, 0.2])
    with pytest.raises(ValueError, match="alpha"):
        model.replace(alpha=[0.1, 0.2, 0.3])
    # Device values are held to the same shapes (one of the stored shape is kept as it is, without a copy).
    with pytest.raises(ValueError, match="rho_d"):
        model.replace(rho_d=jnp.asarray([0.1, 0.2]))
    with pytest.raises(ValueError, match="alpha"):
        model.replace(alpha=jnp.asarray([0.1, 0.2, 0.3]))
    on_device = jnp.asarray(RHO, dtype=float)
    assert model.replace(rho_d=on_device).params["rho_d"] is on_device
    np.testing.assert_array_equal(model.replace(rho_d=jnp.asarray(0.25)).params["rho_d"], [0.25] * CHANNELS)


@pytest.mark.parametrize(
    "call, exc, words",
    [
        (lambda: models.get("lambrt"), KeyError, ["lambrt", "lambert", "oren-nayar"]),
        (lambda: models.get("lambert+wrd"), KeyError, ["wrd", "ward"]),
        (lambda: models.get(""), ValueError, ["non-empty"]),
        (lambda: models.get("lambert+"), ValueError, ["lambert+"]),
        (lambda: models.get("cook-torrance", distribution="phong"), ValueError, ["distribution", "beckmann", "ggx"]),
        (lambda: models.get("cook-torrance", shadowing="smit"), ValueError, ["shadowing", "v-cavity", "smith"]),
        (lambda: models.get("cook-torrance", fresnel="metal"), ValueError, ["fresnel", "schlick", "conductor"]),
        (lambda: models.get("cook-torrance", fresnel="conductor", material="glass"), ValueError, ["glass", "gold"]),
        (lambda: models.get("cook-torrance(distribution=foo)"), ValueError, ["foo", "beckmann"]),
        (lambda: models.get("ward(lobes=2)"), ValueError, ["lobes", "ward"]),
        (lambda: models.get("cook-torrance(ggx)"), ValueError, ["key=value"]),
        (lambda: models.get("ward", sigma=0.2), ValueError, ["sigma", "ks", "alpha"]),
        (lambda: models.get("lafortune", lobes=0), ValueError, ["lobes"]),
        (lambda: models.get("lambert", channels=0), ValueError, ["channels"]),
        (lambda: models.get("lambert", rho_d=[0.1, 0.2]), ValueError, ["rho_d"]),
    ],
    ids=lambda v: None,
)
def test_unknown_names_and_options_raise_clear_errors(call, exc, words):
    with pytest.raises(exc) as info:
        call()
    message = str(info.value)
    for word in words:
        assert word in message, (word, message)


SERIALISED_SPECS = [
    "lambert",
    "lambert+ward+ward",
    "cook-torrance(distribution=ggx, fresnel=conductor, material=gold)",
    "oren-nayar+cook-torrance(shadowing=smith, fresnel=dielectric)",
    "lafortune(lobes=2, anisotropic=true)",
    "ggx(fresnel=conductor)+toon-specular",
    SHARED,
]


@pytest.mark.parametrize("spec", SERIALISED_SPECS)
def test_model_dict_round_trip(spec):
    model = models.get(spec, channels=CHANNELS)
    model = model.replace(**{s.name: np.linspace(0.3, 0.4, CHANNELS) if s.colour else
                             min(s.upper, s.default * 0.9 + 0.01) for s in model.param_specs})
    description = json.loads(json.dumps(models.model_to_dict(model)))
    back = models.model_from_dict(description)
    assert back.lobes == model.lobes and back.channels == model.channels
    assert list(back.params) == list(model.params)
    for name in model.params:
        np.testing.assert_array_equal(back.params[name], model.params[name])
    angles = _radians(CONFIGS["off-specular"])
    np.testing.assert_array_equal(brdffit.evaluate(back, *angles), brdffit.evaluate(model, *angles))


def test_cli_models_lists_every_lobe_with_its_parameters(capsys):
    assert cli.main(["models"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    for name in models.names():
        assert any(line.startswith(name + ":") for line in lines), name
        for spec in models.get(name, channels=1).param_specs:
            assert any(line.split()[:1] == [spec.name] for line in lines), (name, spec.name)


def test_reciprocal_flags():
    """Every lobe but toon-diffuse, blender (Cycles' diffuse weight depends on the view alone), openpbr
    (MaterialX's layer weight does), gltf (the clearcoat's Fresnel weight does) and coateddiffuse (pbrt-v4's walk
    weights its two ends differently) is reciprocal by construction, and the flag says so."""
    flags = {name: models.lobe_class(name).reciprocal for name in models.names()}
    assert [flags.pop(name) for name in ("toon-diffuse", "blender", "openpbr", "gltf", "coateddiffuse")] == [False] * 5
    assert all(flags.values())
    assert not models.get("lambert+toon-diffuse").reciprocal
    assert models.get("lambert+toon-specular").reciprocal


@pytest.mark.parametrize("case", CASES, ids=lambda c: c.id)
def test_reciprocal_lobes_are_symmetric_and_the_others_are_not(case):
    points = np.array(ALL_POINTS, dtype=float)
    model = case.model()
    forward = _values(case.id)[0]
    backward = _evaluate(model, points[:, [2, 3, 0, 1]])
    if model.reciprocal:
        np.testing.assert_allclose(forward, backward, rtol=1e-11, atol=ATOL)
    else:
        assert not np.allclose(forward, backward)


def test_models_doc_is_up_to_date():
    """docs/models.md is generated by scripts/make_models_doc.py from the declarations; rerun it when they change."""
    import importlib.util
    import pathlib

    root = pathlib.Path(__file__).resolve().parent.parent
    spec = importlib.util.spec_from_file_location("make_models_doc", root / "scripts" / "make_models_doc.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert (root / "docs" / "models.md").read_text(encoding="utf-8") == module.render(), \
        "docs/models.md is stale: run python scripts/make_models_doc.py"


def test_suffixed_names_never_collide_with_declared_names():
    # A second Phong's "ks_2" would clash with Lafortune lobe 2's own ks_2: the suffix skips to _3.
    model = models.get("phong+phong+lafortune(lobes=2)", channels=1)
    names = list(model.params)
    assert len(names) == len(set(names)) == 12
    assert names[:4] == ["ks", "n", "ks_3", "n_3"]
    assert sum(len(n) for n in model.names_by_lobe) == len(model.params)


def test_bounded_option_caps_every_unbounded_amplitude_at_one():
    """`bounded=true`, an option every lobe has: the amplitudes a lobe declares without an upper bound (ks, ks_j)
    get the upper bound 1, nothing else changes, and the spec round-trips."""
    free = models.get("lambert+ggx+lafortune")
    bounded = models.get("lambert+ggx(bounded=true)+lafortune(bounded=true)")
    assert bounded.spec == "lambert+ggx(bounded=True)+lafortune(bounded=True)"  # as every option token prints
    assert models.get(bounded.spec).spec == bounded.spec
    for name in free.param_specs.names:
        spec, capped = free.param_specs[name], bounded.param_specs[name]
        if spec.linear and spec.upper == float("inf"):
            assert (capped.lower, capped.upper) == (spec.lower, 1.0), name
        else:
            assert (capped.lower, capped.upper) == (spec.lower, spec.upper), name
    assert {n for n in free.param_specs.names
            if bounded.param_specs[n].upper == 1.0 and free.param_specs[n].upper != 1.0} == {"ks", "ks_1"}


def _declares_peaks(name: str) -> bool:
    model = models.get(name)
    return bool(model.lobes[0].peaks(model.layout.local_params(model.params, 0)))


@pytest.mark.parametrize("name", [n for n in models.names() if _declares_peaks(n)])
def test_a_declared_peak_is_where_the_lobe_is_large(name):
    """Every peak a lobe declares (`Lobe.peaks`, at its default values) points where the lobe is large: at θi = 40°,
    the lobe at the peak's centre direction (the mirror direction for a half-vector peak, normalize(A ωi) for a
    cone) is above the 90th percentile of its values over 4,096 outgoing directions uniform on the hemisphere, and
    the declared width is a width (0 < α ≤ 1 after the export's clipping)."""
    from brdffit.export.terms import lobe_peaks

    model = models.get(name)
    lobe = model.lobes[0]
    theta = np.radians(40.0)
    wi = np.array([np.sin(theta), 0.0, np.cos(theta)])
    rng = np.random.default_rng(5)
    z = rng.uniform(0.0, 1.0, 4096)
    phi = rng.uniform(0.0, 2 * np.pi, 4096)
    wo = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], axis=-1)
    background = np.percentile(np.asarray(models.evaluate_dirs(model, wi, wo)).sum(axis=-1), 90)
    peaks = lobe_peaks(lobe, model.layout.local_params(model.params, 0))
    assert peaks
    for peak in peaks:
        axis = np.array([-1.0, -1.0, 1.0]) if peak.kind == "half" else np.asarray(peak.axis, dtype=float)
        centre = axis * wi / np.linalg.norm(axis * wi)
        at_peak = float(np.asarray(models.evaluate_dirs(model, wi, centre)).sum())
        assert at_peak > background, (peak, at_peak, background)
        assert 0.0 < peak.width <= 1.0 and peak.lobe == name


@pytest.mark.parametrize("anisotropic", [False, True])
def test_lafortune_spike_candidates_keep_the_band_of_incidence_their_attenuation_says(anisotropic):
    """`Lafortune.sub_lobe_candidates`: cxy = −cz (1 + ε) with n ε = g. At the mirror direction of incidence θ the
    normalised lobe (the NumPy transcription of Lafortune et al. 1997, Eq. 3 with Ngan et al.'s normalisation,
    `reference_brdfs.lafortune`) is ((1 + ε sin²θ)/(1 + ε))^n for ε > 0 and (1 + ε sin²θ)^n for ε < 0, which for
    large n is exp(−g cos²θ) and exp(g sin²θ)."""
    lobe = models.get("lafortune", lobes=2, anisotropic=anisotropic).lobes[0]
    # cz at its declared value 1: the transcription forms dot^n and max(|c|)^n apart, which underflow for cz < 1.
    params = {"ks_2": 1.0, "cz_2": 1.0, "n_2": 10.0, "cxy_2": -1.0, "cx_2": -1.0, "cy_2": -1.0}
    candidates = lobe.sub_lobe_candidates("ks_2", params)
    assert len(candidates) == 20
    theta = np.radians([5.0, 30.0, 60.0, 80.0])
    phi = np.radians([0.0, 40.0, 130.0, 250.0])
    for c in candidates:
        n = c["n_2"]
        xy = (c["cx_2"], c["cy_2"]) if anisotropic else (c["cxy_2"], c["cxy_2"])
        assert xy[0] == xy[1]
        eps = -xy[0] - 1.0
        g = n * eps
        assert any(abs(g - a) <= 1e-9 * abs(a) for a in (-30.0, 10.0, 30.0, 100.0, 300.0)), g
        value = ref.lafortune(theta, phi, theta, phi + np.pi, [{"ks": np.ones(1), "cx": xy[0], "cy": xy[1],
                                                                 "cz": 1.0, "n": n}])[:, 0]
        s2 = np.sin(theta) ** 2
        expected = ((1 + eps * s2) / (1 + eps)) ** n if eps > 0 else (1 + eps * s2) ** n
        np.testing.assert_allclose(value * 2 * np.pi / (n + 2), expected, rtol=1e-9, atol=1e-300)
        if g * g / n <= 0.01:  # the limit's exponent is off by about g² sin⁴θ / 2n
            limit = np.exp(-g * np.cos(theta) ** 2) if eps > 0 else np.exp(g * s2)
            np.testing.assert_allclose(expected, limit, rtol=0.02)
    assert lobe.sub_lobe_candidates("ks_2", dict(params, cz_2=0.0)) == []


# Every layer a lobe declares (`Lobe.layers`), with all of its lobe's layers on: (spec, the form one layer fewer,
# the values that make it that form).
LAYERS = [(models.get(name, **{option: True for option in cls.layers}), form, values)
          for name in models.names() for cls in [models.lobe_class(name)] if cls.layers
          for form, values in models.get(name, **{option: True for option in cls.layers}).lobes[0].nested()]


@pytest.mark.parametrize("full, form, values", LAYERS,
                         ids=[f"{full.spec}->{form.token()}" for full, form, _ in LAYERS])
def test_a_layer_of_weight_zero_is_the_form_without_it(full, form, values):
    """`Lobe.nested`: each form one layer fewer is the lobe with that layer's weight at 0, at random directions
    (what `brdffit.select` relies on when it starts a layered candidate from the form without the layer)."""
    rng = np.random.default_rng(6)
    angles = (rng.uniform(0, 1.5, 300), rng.uniform(-3, 3, 300), rng.uniform(0, 1.5, 300), rng.uniform(-3, 3, 300))
    layered = models.get(full, **values)
    reduced = models.get(form.token(), **{k: v for k, v in layered.params.items()
                                          if k in models.get(form.token()).params})
    assert not (set(full.lobes[0].layers) - set(full.lobes[0].options())), "a layer names an option the lobe lacks"
    np.testing.assert_allclose(np.asarray(brdffit.evaluate(layered, *angles)),
                               np.asarray(brdffit.evaluate(reduced, *angles)), rtol=1e-12, atol=0.0)
