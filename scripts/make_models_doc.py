"""Write docs/models.md, the models reference, from the lobe declarations.

The equations and option notes are written here once; every parameter table (name, colour or shape, default,
bounds, unit, meaning), every option list, the references and the reciprocity table are read from the library, so
they are never typed by hand. tests/test_models.py checks that docs/models.md is up to date.

Usage:
    python scripts/make_models_doc.py            # (re)write docs/models.md
    python scripts/make_models_doc.py --check    # exit 1 if docs/models.md differs from what would be written
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import pathlib
import sys

from brdffit import models
from brdffit.models import fresnel, microfacet
from brdffit.models.cook_torrance import FRESNEL_MODES
from brdffit.models.lobe import COMMON_OPTIONS

OUTPUT = pathlib.Path(__file__).resolve().parent.parent / "docs" / "models.md"

# Notation used below: ci = cosθi, co = cosθo, h = normalize(ωi + ωo), ch = n·h = cosθh, cd = ωi·h = ωo·h = cosθd,
# r = 2(n·ωi)n − ωi the mirror direction of ωi, x and y the tangent and bitangent.
EQUATIONS = {
    "lambert": "f = ρd / π",
    "oren-nayar": (
        "f = ρd/π · (A + B · max(0, cos(φi − φo)) · sin α · tan β)\n"
        "A = 1 − 0.5 σ²/(σ² + 0.33),  B = 0.45 σ²/(σ² + 0.09),  α = max(θi, θo),  β = min(θi, θo)"
    ),
    "phong": "f = ks · (n + 2)/(2π) · max(0, r·ωo)^n",
    "blinn-phong": "f = ks · (n + 8)/(8π) · ch^n",
    "ward": "f = ks · exp(−tan²θh / α²) / (4π α² √(ci co))",
    "ward-aniso": "f = ks · exp(−((h·x/αx)² + (h·y/αy)²) / ch²) / (4π αx αy √(ci co))",
    "ward-duer": "f = ks · exp(−tan²θh / α²) / (4π α² ci co)",
    "cook-torrance": (
        "f = ks · F(cd) · D(h) · G(ωi, ωo) / (4 ci co)\n"
        "D beckmann = exp(−tan²θh/m²) / (π m² ch⁴)\n"
        "D ggx      = m² / (π (ch² (m² − 1) + 1)²)\n"
        "D blinn    = (αp + 2)/(2π) · ch^αp,  αp = 2/m² − 2\n"
        "D std      = (1 + tan²θh/(m² (γ − 1)))^(−γ) / (π m² ch⁴)  (Student-t slopes; γ = 2 is GGX, γ → ∞ Beckmann)\n"
        "D gtr      = c / (m² ch² + 1 − ch²)^γ,  c = (γ − 1)(m² − 1) / (π (1 − m^(2 − 2γ)))  (γ = 1: GTR1, 2: GGX)\n"
        "G v-cavity = min(1, 2 ch co / cd, 2 ch ci / cd)\n"
        "G smith    = G1(ωi) G1(ωo),  G1 = 1/(1 + Λ):\n"
        "             beckmann Λ = (erf(a) − 1)/2 + exp(−a²)/(2a√π),  a = 1/(m tanθ)\n"
        "             ggx      Λ = (√(1 + m² tan²θ) − 1)/2\n"
        "             blinn    Λ = Beckmann's Λ with a = √(αp/2 + 1)/tanθ (Walter et al.'s approximation)\n"
        "             std      Λ = c (γ − 1 + μ²)^(3/2−γ) / ((2γ − 3) μ) − ½ I_x(γ − 1, ½),  μ = 1/(m tanθ),\n"
        "                        c = (γ − 1)^γ Γ(γ − ½)/(√π Γ(γ)),  x = (γ − 1)/(γ − 1 + μ²)  (exact)\n"
        "             gtr      Λ = 2μ² ∫_0^1 (√(1 − s²) − s acos s) P22(μ/s) s⁻⁴ ds,  μ = cotθ, P22 = D ch⁴\n"
        "                        (Smith's definition with its angular integral done by hand; Gauss-Legendre panels)\n"
        "G smith-correlated = 1/(1 + Λ(ωi) + Λ(ωo))  (height-correlated)\n"
        "G none     = 1\n"
        "anisotropic=True (beckmann, ggx, std), widths αx = m_x, αy = m_y, e = ((h·x/αx)² + (h·y/αy)²)/ch²:\n"
        "D beckmann = exp(−e) / (π αx αy ch⁴),  D ggx = 1 / (π αx αy ch⁴ (1 + e)²),\n"
        "D std      = (1 + e/(γ − 1))^(−γ) / (π αx αy ch⁴)\n"
        "Λ          = the isotropic Λ at m = α(φ) = √(cos²φ αx² + sin²φ αy²), φ the azimuth of the direction\n"
        "F schlick    = f0 + (1 − f0)(1 − cd)⁵\n"
        "F dielectric = (r_s² + r_p²)/2 for a dielectric of index η seen from vacuum (1 under total reflection)\n"
        "F conductor  = (|r_s|² + |r_p|²)/2 for the complex index η + iκ"
    ),
    "ggx": "cook-torrance with distribution=ggx and shadowing=smith; the roughness is named alpha:\n"
           "f = ks · F(cd) · α² / (π (ch² (α² − 1) + 1)²) · G1(ωi) G1(ωo) / (4 ci co),  "
           "G1 = 2/(1 + √(1 + α² tan²θ))",
    "ashikhmin-shirley": (
        "f = (n + 1)/(8π) · ch^n / (cd · max(ci, co)) · F(cd),  F = rs + (1 − rs)(1 − cd)⁵"
    ),
    "ashikhmin-shirley-aniso": (
        "f = √((nu + 1)(nv + 1))/(8π) · ch^e / (cd · max(ci, co)) · F(cd),  F = rs + (1 − rs)(1 − cd)⁵\n"
        "e = (nu (h·x)² + nv (h·y)²) / (1 − ch²)"
    ),
    "lafortune": (
        "f = Σ_j ks_j · (n_j + 2)/(2π) · max(0, cxy_j (ωi.x ωo.x + ωi.y ωo.y) + cz_j ωi.z ωo.z)^n_j"
        " / max(cxy_j², cz_j²)^(n_j/2)\n"
        "anisotropic=True: cx_j ωi.x ωo.x + cy_j ωi.y ωo.y in place of the cxy_j term, "
        "normalised by max(cx_j², cy_j², cz_j²)^(n_j/2)"
    ),
    "burley": ("f = ρd/π · (1 + (F_D90 − 1)(1 − ci)⁵) · (1 + (F_D90 − 1)(1 − co)⁵),  "
               "F_D90 = 0.5 + 2 roughness cd²"),
    "sheen": "f = ks · (1 − cd)⁵",
    "charlie-sheen": (
        "f = ks · D(h) · G / (4 ci co),  D = (2 + 1/α) sin^(1/α)θh / (2π),  G = 1/(1 + Λ(ωi) + Λ(ωo))\n"
        "Λ(θ) = exp(L(cosθ)) for cosθ < ½, else exp(2 L(½) − L(1 − cosθ)),  L(x) = a/(1 + b x^c) + d x + e,\n"
        "(a, b, c, d, e) linear in (1 − α)² between Estevez & Kulla's Table 1 rows"
    ),
    "abc-smooth": ("f = A · (1 + B Dp²)^(−C) · F(cd', η),  Dp = |ωi,xy + ωo,xy|,  cd' = √(1 − |ωi,xy − ωo,xy|²/4)\n"
                   "F the exact dielectric Fresnel term of index η"),
    "abc-microfacet": ("f = A · (1 + B (1 − ch))^(−C) · F(cd, η) · G / (π ci co),  G = min(1, 2 ch co / cd, 2 ch ci / cd)\n"
                       "F the exact dielectric Fresnel term of index η"),
    "sgd": ("f = ks · F · D · G1(θi) G1(θo) / (π ci co),  D = K · exp(−(α + t/α)) (α + t/α)^(−p) / (π ch⁴),  "
            "t = tan²θh\n"
            "K = 1 / (α Γ(1 − p, α))  (exact normalisation; Γ the upper incomplete gamma function)\n"
            "F = f0 + (1 − f0)(1 − cd)⁵ − f1 cd,  G1(θ) = 1 + Λ (1 − exp(c (θ − θ0)^k)) for θ > θ0, else 1"),
    "principled": (
        "f = (1 − metallic) base_color/π · ((1 − w(ci)/2)(1 − w(co)/2) + R (w(ci) + w(co) + w(ci) w(co)(R − 1)))\n"
        "  + sheen (1 − metallic) w(cd) · (1 + sheen_tint (base_color/lum − 1))\n"
        "  + F · D_GGX(h; αx, αy) · G1(ωi) G1(ωo) / (4 ci co)\n"
        "  + clearcoat/4 · (0.04 + 0.96 w(cd)) · D_GTR1(h; αc) · G1_GGX(ωi; 0.25) G1_GGX(ωo; 0.25)\n"
        "w(c) = (1 − c)⁵,  R = 2 roughness cd²,  lum = 0.212671 R + 0.715160 G + 0.072169 B\n"
        "αx = max(0.001, roughness²/a),  αy = max(0.001, roughness² a),  a = √(1 − 0.9 anisotropic)\n"
        "F = (1 − metallic)(1 − spec_tint) F_dielectric(cd, η) + metallic S(base_color)\n"
        "    + (1 − metallic) spec_tint S(base_color/lum · ((η − 1)/(η + 1))²),  S(f0) = f0 + (1 − f0) w(cd)\n"
        "η = 2/(1 − √(0.08 specular)) − 1,  αc = 0.1 + clearcoat_gloss (0.001 − 0.1)\n"
        "D_GTR1 = (αc² − 1) / (π ln(αc²) (1 + (αc² − 1) ch²))"
    ),
    "blender": (
        "f = metallic S(cd; base_color) · D G2/(4 ci co) + (1 − metallic) [F_dielectric(cd; ior) · D G2/(4 ci co)\n"
        "    + (1 − E(co)) base_color/π]\n"
        "E = F0 + (1 − F0) s(roughness, co, √((ior − 1)/(ior + 1))),  F0 = ((ior − 1)/(ior + 1))²,\n"
        "co = ωo·n (the view)\n"
        "S(c; f0) = f0 + (1 − f0)(1 − c)⁵,  D = GGX,  G2 = 1/(1 + Λ(ωi) + Λ(ωo)),  α = roughness²\n"
        "s: Cycles' table ggx_gen_schlick_ior_s (16³ nodes, trilinear), computed by quadrature\n"
        "coat=true: f_coat = w F_dielectric(cd; coat_ior) D_c G2_c/(4 ci co)\n"
        "    + clamp(1 − w F_dielectric(co; coat_ior), 0, 1) mix(1, coat_tint^(1/cosθt), w) f,\n"
        "w = coat_weight,  α_c = coat_roughness²,  cosθt = √(1 − (1 − co²)/coat_ior²)\n"
        "sheen=true: f_sheen = w_s t_s E(co, r_s) D_LTC(ωi)/ci + clamp(1 − max(w_s t_s) E(co, r_s), 0, 1) f,\n"
        "w_s = sheen_weight,  t_s = sheen_tint,  r_s = sheen_roughness,  E and D_LTC: Zeltner's sheen by MaterialX's "
        "fits (Cycles: its table)"
    ),
    "openpbr": (
        "f = (1 − base_metalness) [specular_color F(cd; η') D G2/(4 ci co) K(F) + (1 − E(co; F0') K(F)) f_on]\n"
        "  + base_metalness · specular_weight · F82(cd) D G2/(4 ci co) K(F82)\n"
        "η': the graph's index modulated by specular_weight: ε = √(clamp(specular_weight F0(specular_ior), 0, "
        "0.99999)), η' = (1 + ε)/(1 − ε)\n"
        "E(μ; F0) = F0 A(μ, α) + B(μ, α): MaterialX's rational fit of the GGX albedo,  K(F) = 1 + F (1 − E₁)/E₁,  "
        "E₁ = A + B\n"
        "f_on: OpenPBR's energy-preserving Oren-Nayar diffuse of base_color, roughness base_diffuse_roughness\n"
        "F82: Hoffman's F82-tinted Schlick term, F0 = base_color, F82 = specular_color,  D = GGX,  "
        "G2 height-correlated,  α = specular_roughness²\n"
        "coat=true: f_coat = w_c F(cd; coat_ior) D G2/(4 ci co) K_c(F) + (1 − w_c E_c(co) K_c(F)) T_c f,  w_c = "
        "coat_weight, α_c = coat_roughness²,\n"
        "  T_c: the coat's colour and darkening; f's roughness and index as the coat changes them (docs/export.md)\n"
        "fuzz=true: f_fuzz = fuzz_weight fuzz_color E_z(co) D_LTC(ωi)/ci + (1 − fuzz_weight E_z(co)) f,  "
        "Zeltner's sheen (MaterialX's fits of its LTC and albedo E_z, roughness fuzz_roughness)"
    ),
    "pbrt": (
        "f = (1 − amount) reflectance/π + amount · F(cd; eta + i k) · D G2/(4 ci co)\n"
        "D = 1/(π α² ch⁴ (1 + tan²θh/α²)²) (Trowbridge-Reitz = GGX),  G2 = 1/(1 + Λ(ωi) + Λ(ωo)),\n"
        "Λ(ω) = (√(1 + α² tan²θ) − 1)/2,  α = roughness (remaproughness false),  F: exact complex-index Fresnel"
    ),
    "coateddiffuse": (
        "f = F(cd; η) D G/(4 ci co) + (ρ/π) X(co) Y(ci)/η² · Σ_{k<5} (ρ R)^k,  ρ = reflectance,  η = eta\n"
        "D = GGX of width roughness,  G = 1/(1 + Λ(ωi) + Λ(ωo)),  F: exact dielectric Fresnel\n"
        "X(μ) = ∫ f_T(ω → ω') |cos ω'| Tr(ω') dω',  Tr(ω) = exp(−0.01/|cos ω|)  (the light entering the slab)\n"
        "Y(μ): the same with pbrt-v4's power-heuristic weights at the base;  R: the interface's reflection from inside\n"
        "X, Y at 64 cosines even in √μ (32 × 32 microfacet normals), cubic in √μ between;  R by 2 × 24 cosines"
    ),
    "coatedconductor": (
        "f = T(co) T(ci)/η² Tr(u0) Tr(ui) [f_c(u0, ui) + Σ_{k=1}^{4} (𝒦^k f_c(·, ui))(u0)],  η = interface_eta\n"
        "u0, ui: ωo, ωi refracted into the coat (horizontal components / η);  T = 1 − F(·; η);  Tr(u) = exp(−0.01/cos u)\n"
        "f_c = FrComplex(|u·h|; (1 + i 2√r/√(1 − r))/η) D G/(4 cos u cos v),  r = reflectance,  GGX of width "
        "conductor_roughness\n"
        "𝒦 g(u) = ∫ f_c(u, v) |cos v| Tr(v)² R(v) g(v turned by π in azimuth) dv,  R: the coat's reflection from inside\n"
        "𝒦 by cosine harmonics in Δφ (64) over 2 × 12 Gauss-Legendre cosines; the sum tabulated at 33 × 33 outside "
        "sines × 65 Δφ, cubic between"
    ),
    "roughplastic": (
        "f = specular_reflectance · F(cd; η) D G1(ωi) G1(ωo)/(4 ci co)\n"
        "  + diffuse_reflectance/(1 − R) · T(ci) T(co)/(π η²),  η = int_ior\n"
        "D = GGX of width alpha,  G1 = 2/(1 + √(1 + α² tan²θ)),  F: exact dielectric Fresnel\n"
        "T: the interface's transmittance at 64 cosines (Mitsuba's 32 × 32 visible-normal quadrature), linear between\n"
        "R: the interface's internal reflectance (42 × 73 table in √α and √(η − 1), cubic convolution)"
    ),
    "gltf": (
        "f = (1 − metallic) [(1 − specular · max_c F) base_color/π + specular F · D V]\n"
        "  + metallic (base_color + (1 − base_color) w(cd)) · D V\n"
        "F = f0 + (1 − f0) w(cd),  f0 = min(((ior − 1)/(ior + 1))² specular_color, 1),  w(c) = (1 − c)⁵\n"
        "D = α²/(π (ch² (α² − 1) + 1)²),  V = G2/(4 ci co),  G2 = 1/(1 + Λ(ωi) + Λ(ωo)) (GGX),  α = roughness²\n"
        "with a sheen: f = sheen_color · Ds Vs + f · min(1 − s E(ci), 1 − s E(co)),  s = max_c sheen_color\n"
        "Ds = (2 + 1/αs) sin^(1/αs)θh/(2π),  Vs = 1/((1 + Λs(ωi) + Λs(ωo)) 4 ci co) (Charlie),  αs = sheen_roughness²\n"
        "E: the sheen's directional albedo (32 × 32 nodes, bilinear), computed by quadrature\n"
        "with a clearcoat: f = (1 − c) f + c · D V (α = clearcoat_roughness²),  c = clearcoat (0.04 + 0.96 (1 − co)⁵)"
    ),
    "toon-diffuse": "f = (ρshade + (ρd − ρshade) · S((ci − threshold)/width)) / π,  S(u) = 1/(1 + e^(−u))",
    "toon-specular": "f = ks · S((r·ωo − threshold)/width) / π,  S(u) = 1/(1 + e^(−u))",
}

NOTES = {
    "oren-nayar": "Evaluated as (ωi,xy·ωo,xy)/max(ci, co), which equals cos(φi − φo) sinα tanβ and needs no "
                  "azimuth, so it stays finite at normal incidence.",
    "phong": "The modified (normalised) Phong lobe of Lafortune & Willems; energy conserving for ks ≤ 1.",
    "blinn-phong": "The (n + 8)/(8π) factor is an approximate normalisation (Real-Time Rendering, 3rd ed., "
                   "Eq. 7.48).",
    "ward": "With ks = 1 the albedo of Ward's √(ci co) normalisation stays below 1 up to about 89.8° of "
            "incidence (0.68 at 89.5° for α = 0.5) and exceeds 1 only beyond; see properties.md.",
    "ward-duer": "Dür's ci co normalisation is closer to energy balance than Ward's away from grazing for small "
                 "α, but its albedo grows without bound towards grazing (9.9 at 89.5° for α = 0.5, ks = 1).",
    "cook-torrance": "Walter et al.'s normalisation 1/(4 ci co) (not Cook & Torrance's 1/(π ci co)); m is the "
                     "width of the distribution (Beckmann m, GGX α). With fresnel=dielectric or conductor the "
                     "option material=NAME takes the default η (and κ) from a preset, see the tables at the end. "
                     "distribution=blinn with shadowing=smith uses Walter et al.'s Beckmann approximation of the "
                     "Blinn distribution's Smith term: against the exact G1 (by quadrature) it errs by about 5e-4 "
                     "at m = 0.05, 1.3% at m = 0.2, 10% at m = 0.5 and up to 50% at m = 0.9 near grazing. "
                     "distribution=std (Ribardière et al., CGF 2017) adds the tail exponent gamma; its Λ is exact "
                     "(the Student-t tail as an incomplete beta function, where the paper fits a rational "
                     "approximation), evaluated by its continued fraction (Numerical Recipes §6.4) to about 1e-13 "
                     "and differentiated in γ like any other expression. distribution=gtr (Burley 2012, App. B) "
                     "also has an exponent gamma; Burley gives no Smith Λ for it, so Λ is integrated numerically "
                     "from its definition, to about 1e-11 against SciPy's adaptive quadrature.",
    "ashikhmin-shirley": "The specular term only (add a diffuse lobe for the rest); F is evaluated at ωi·h.",
    "ashikhmin-shirley-aniso": "nu is the exponent along the tangent x, nv along the bitangent y; at h = n the "
                               "exponent is taken as (nu + nv)/2.",
    "lafortune": "cxy = −cz gives a specular lobe, cxy = cz a retro-reflective one, cxy = 0 an off-specular "
                 "lobe towards the normal. Because of the normalisation only the direction of (cxy, cz) matters, so cz_j "
                 "is held at 1 unless freed (fits would otherwise have a free, meaningless scale) and cxy_j spans "
                 "[−2, 2]. Fits start lobes apart, fit K lobes from K − 1 (brdffit.fit_lobes) and report them "
                 "sorted by exponent. "
                 "With lobes=K the parameters are ks_j, cxy_j (or cx_j, cy_j), cz_j, n_j for j = 1..K.",
    "burley": "The diffuse of the Disney BRDF (and of Mitsuba 3's and Blender's principled BSDFs): brighter "
              "towards grazing on the retro-reflective side for a rough surface (F_D90 up to 2.5), darker for a "
              "smooth one (F_D90 = 0.5). Reciprocal; not energy conserving at grazing for large roughness.",
    "sheen": "The Disney BRDF's sheen: a Schlick-shaped grazing term added to the diffuse (no 1/π), for cloth.",
    "charlie-sheen": "A microfacet lobe of fibres (an inverted distribution: most normals near the horizon), for "
                     "cloth, velvet and felt. Estevez & Kulla's terminator softening is a shading-normal device and "
                     "is left out, as glTF's KHR_materials_sheen and MaterialX leave it out.",
    "abc-smooth": "Löw et al.'s smooth-surface model: an ABC (K-correlation) curve of the projected deviation from "
                  "the mirror direction, no shadowing; A is unnormalised (an amplitude in 1/sr).",
    "abc-microfacet": "Löw et al.'s microfacet model: the ABC curve as an unnormalised distribution of 1 − cosθh, "
                      "with Cook & Torrance's π, V-cavity shadowing and Fresnel term, as BBM evaluates it.",
    "sgd": "Bagher et al.'s shifted gamma distribution with their Fresnel correction f1 and fitted shadowing "
           "(shadow_lambda, shadow_c, shadow_k, shadow_theta0), as BBM evaluates them, with the π of Cook & "
           "Torrance's form. The paper and BBM fit K; here it normalises D exactly, from α and p (p < 1). f1 and the "
           "shadowing parameters are held at values that switch them off (θ0 = π/2: G1 = 1) unless freed.",
    "principled": "The Disney BRDF as Mitsuba 3's principled plugin evaluates it (its reflection: no spec_trans, "
                  "flatness or eta), parameter names and ranges included, so that `brdffit export --to mitsuba` "
                  "writes it exactly; tests/test_principled.py holds it to the plugin at 2,000 random pairs. The "
                  "clearcoat has no 1/(4 ci co), as the plugin evaluates it. anisotropic, spec_tint and sheen_tint "
                  "are held at 0 unless freed. Not reciprocal only in name: every term is symmetric in ωi and ωo.",
    "blender": "Blender's Principled BSDF (4.2+) with the GGX distribution, as Cycles evaluates it "
               "(intern/cycles/kernel/svm/closure.h): the inputs Base Color, Metallic, Roughness and IOR, the others "
               "neutral; with `coat=true` also Coat Weight, Coat Roughness and Coat IOR (Coat Tint held white unless "
               "freed), the coat layered over the rest as Cycles 4.2 layers it; with `sheen=true` also Sheen Weight and "
               "Sheen Roughness (Sheen Tint held white unless freed), Zeltner's microfibre sheen over everything, "
               "whose albedo and LTC Cycles reads from a table that bpy does not ship and the model takes from "
               "MaterialX's fits: an approximation of Cycles' (docs/export.md measures it). The diffuse layer is attenuated by Cycles' estimate of the specular layer's albedo at the "
               "viewing direction, so the model is not reciprocal, as Cycles' is not; its table is computed again by "
               "quadrature and agrees with Cycles' to 1e-4. `brdffit fit --for blender`, `brdffit export --to "
               "blender`; tests/test_export_blender.py renders the export in Cycles against brdffit's render.",
    "openpbr": "OpenPBR Surface as MaterialX 1.39 evaluates an opaque one (its graph `open_pbr_surface.mtlx` and "
               "the GLSL of its BSDF nodes), without thin film, transmission, subsurface or emission, "
               "isotropic, base_weight 1: a dielectric specular layered over an energy-preserving Oren-Nayar "
               "diffuse by the layer's albedo at the view (MaterialX's rational fit), mixed by base_metalness with "
               "an F82-tinted metal; with `coat=true`, OpenPBR's coat over it (a GGX dielectric layer that "
               "roughens, darkens and tints what lies beneath; coat_color held white and coat_darkening at 1 "
               "unless freed), for lacquer and varnish; with `fuzz=true`, OpenPBR's fuzz layer over that (Zeltner "
               "et al.'s 2022 LTC microfibre sheen, the `zeltner` mode of MaterialX's sheen_bsdf), for cloth and "
               "felt. "
               "specular_weight and specular_color are held at 1 unless freed (with no metal, "
               "the graph's weight and index are one degree of freedom). Not reciprocal, as MaterialX's layering "
               "is not; tests/test_models.py holds it to a transcription of the GLSL. `brdffit fit --for openpbr`, "
               "`brdffit export --to openpbr` (a MaterialX document that MaterialX validates).",
    "pbrt": "What pbrt-v4 renders for a `mix` (amount) of a `diffuse` (reflectance) and a `conductor` (eta, k, "
            "roughness with remaproughness false): pbrt picks the conductor at a shading point with probability "
            "amount, so the expected BRDF is the convex combination. Every parameter is declared inside the range "
            "pbrt-v4 takes (roughness from 1e-3: below it pbrt's conductor is a perfect mirror; k = 0 is a "
            "dielectric's Fresnel term), so a fit is written as it is (`brdffit fit --for pbrt`, `brdffit export "
            "--to pbrt`). reflectance is a linear amplitude. Reciprocal.",
    "coatedconductor": "pbrt-v4's `coatedconductor` material with a smooth coat (interface.roughness 0, its "
                       "default; interface.eta) over a rough conductor (conductor.roughness with remaproughness "
                       "false; the conductor given by its reflectance, as pbrt-v4 accepts it), with pbrt's slab "
                       "(thickness 0.01, albedo 0, maxdepth 10). pbrt-v4's `f` estimates it by a random walk; the "
                       "lobe is that walk's expectation, by quadrature (within 1 % of rules three times finer at "
                       "any pair, 0.05 % in the cosine-weighted norm, from α = 0.05 on), checked against a "
                       "transcription of the walk (tests/test_coatedconductor.py); pbrt-v4's sampling walk "
                       "(`Sample_f`, indirect light) has the same expectation, checked against its transcription "
                       "too, so renders follow the lobe under any light. The coat's mirror reflection is "
                       "a delta that `f` does not return: pbrt renders it besides the lobe. A rough coat is not "
                       "modelled. Reciprocal: under a smooth coat the walk's two ends enter alike (no power heuristic "
                       "between them, as in coateddiffuse); the reflectance is not a linear amplitude. `brdffit fit --for pbrt`, `brdffit export --to pbrt`.",
    "coateddiffuse": "pbrt-v4's `coateddiffuse` material: a rough dielectric interface (roughness with "
                     "remaproughness false, eta) over a diffuse base (reflectance), with pbrt's slab (thickness "
                     "0.01, albedo 0, maxdepth 10). pbrt-v4's `f` estimates it by a random walk; the lobe is that "
                     "walk's expectation, by quadrature (X and Y within 1e-4 of a finer rule for θ up to 84°, 2e-3 "
                     "beyond; read between their cosines within 7e-4 of the rule from α = 0.01 on, 2 % beyond 84° "
                     "at α = 1e-3), checked against a transcription of the walk (tests/test_coateddiffuse.py). "
                     "pbrt-v4 samples the BSDF with another walk (`Sample_f`) whose expectation is 3-16 % lower at "
                     "the tests' settings (pbrt-v4 issue #187): renders follow this lobe for direct light from "
                     "point and distant lights, not for indirect light (docs/export.md). Not "
                     "reciprocal, as pbrt's `f` is not; reflectance is not a linear amplitude (it enters the "
                     "series of bounces between base and interface). `brdffit fit --for pbrt`, `brdffit export "
                     "--to pbrt`.",
    "roughplastic": "Mitsuba 3's `roughplastic` plugin (GGX, nonlinear false): a rough dielectric interface over a "
                    "diffuse base, whose light enters through the interface (T), bounces inside (1/(1 − R)) and "
                    "leaves through it again. T is computed as the plugin computes it; R is a smooth counterpart of "
                    "the plugin's, whose own value jumps by up to 6e-3 between neighbouring η, and the export "
                    "corrects the written diffuse_reflectance for the difference, so that Mitsuba renders the fit "
                    "exactly (docs/export.md, \"Mitsuba's roughplastic\"; tests/test_roughplastic.py). Every "
                    "parameter is declared in the plugin's range (`brdffit fit --for mitsuba`). diffuse_reflectance "
                    "and specular_reflectance are linear amplitudes. Reciprocal.",
    "gltf": "The BRDF a glTF 2.0 file describes: its metallic-roughness material as the specification's Appendix B "
            "writes it, with KHR_materials_ior (ior) and KHR_materials_specular (specular, specular_color). Every "
            "parameter is declared inside the range a glTF file accepts, so a fit is a material any glTF viewer "
            "takes as written (`brdffit fit --for gltf`, `brdffit export --to gltf`). base_color is a linear "
            "amplitude (the value is affine in it); specular_color is held at white, the sheen "
            "(KHR_materials_sheen: Estevez & Kulla's Charlie distribution and visibility, the base scaled by the "
            "sheen's albedo at both directions) and the clearcoat (KHR_materials_clearcoat) at 0 unless freed. Not "
            "reciprocal with a clearcoat: its Fresnel weight takes the viewing direction (the extension's "
            "layering); without one every Fresnel term is taken at the half vector and the sheen is reciprocal.",
    "toon-diffuse": "Non-photorealistic two-tone shading. width is held fixed by fits unless it is freed. Not "
                    "reciprocal: it switches on ci alone.",
    "toon-specular": "A flat highlight disc; width is held fixed by fits unless it is freed. Reciprocal, since "
                     "r·ωo is symmetric in ωi and ωo.",
}

# Option values that are not visible from the dataclass field alone.
OPTION_VALUES = {
    "distribution": ", ".join(microfacet.DISTRIBUTIONS),
    "shadowing": ", ".join(microfacet.SHADOWING),
    "fresnel": ", ".join(FRESNEL_MODES),
    "material": "a conductor (" + ", ".join(fresnel.CONDUCTORS) + ") or dielectric ("
                + ", ".join(fresnel.DIELECTRICS) + ") preset",
    "lobes": "a positive integer K",
    "anisotropic": "True, False",
}

# Option settings whose parameters differ from the default ones: their extra parameters get a table of their own.
VARIANTS = {
    "cook-torrance": [{"fresnel": "dielectric"}, {"fresnel": "conductor"}, {"anisotropic": True},
                      {"distribution": "std"}, {"distribution": "gtr"}],
    "ggx": [{"fresnel": "dielectric"}, {"fresnel": "conductor"}, {"anisotropic": True}],
    "lafortune": [{"anisotropic": True}],
    "openpbr": [{"coat": True}, {"fuzz": True}],
    "blender": [{"coat": True}, {"sheen": True}],
}


def _number(x: float) -> str:
    if math.isinf(x):
        return "∞" if x > 0 else "−∞"
    if abs(x - math.pi / 2) < 1e-12:
        return "π/2"
    return f"{x:g}"


def _param_table(specs) -> list[str]:
    lines = ["| name | kind | default | bounds | unit | meaning |", "|---|---|---|---|---|---|"]
    for s in specs:
        meaning = s.doc + (" (held fixed unless freed)" if s.fixed else "")
        lo = ("(" if math.isinf(s.lower) else "[") + _number(s.lower)
        hi = _number(s.upper) + (")" if math.isinf(s.upper) else "]")
        lines.append(f"| `{s.name}` | {s.kind} | {_number(s.default)} | {lo}, {hi} | {s.unit} | {meaning} |")
    return lines


def _lobe_section(name: str) -> list[str]:
    cls = models.lobe_class(name)
    out = [f"## `{name}`", "", f"Reference: {cls.reference}.", "", "```", EQUATIONS[name], "```", ""]
    if name in NOTES:
        out += [NOTES[name], ""]
    fields = [f for f in dataclasses.fields(cls) if f.name not in COMMON_OPTIONS]  # every lobe's, described once
    if fields:
        out += ["Options:", "", "| option | default | values |", "|---|---|---|"]
        out += [f"| `{f.name}` | `{f.default!r}` | {OPTION_VALUES.get(f.name, '')} |" for f in fields]
        out.append("")
    base = models.get(name, channels=1).param_specs
    out += ["Parameters:", ""] + _param_table(base) + [""]
    for options in VARIANTS.get(name, []):
        specs = models.get(name, channels=1, **options).param_specs
        extra = [s for s in specs if s not in base]
        label = ", ".join(f"{k}={v}" for k, v in options.items())
        out += [f"With `{label}` these parameters replace or join the ones above:", ""] + _param_table(extra) + [""]
    return out


def render() -> str:
    """The full text of docs/models.md."""
    names = models.names()
    out = [
        "# Models",
        "",
        "<!-- Generated by scripts/make_models_doc.py from the lobe declarations: edit the script, not this file. -->",
        "",
        "Every model is a lobe or a sum of lobes, built with "
        "`brdffit.models.get(spec, channels=3, **options_and_params)` and evaluated with "
        "`brdffit.evaluate(model, theta_i, phi_i, theta_o, phi_o)`. The conventions (frame, directions, f_r in 1/sr "
        "without the cosine, zero below the horizon) are in [conventions.md](conventions.md).",
        "",
        "- A spec joins lobes with `+`: `\"lambert+cook-torrance\"`. A lobe may carry its own options in brackets: "
        "`\"lambert+cook-torrance(distribution=ggx, fresnel=conductor, material=gold)\"`; options given as keywords "
        "to `get` apply to every lobe that accepts them.",
        "- When two lobes of a sum declare the same parameter, the second gets the suffix `_2`, the third `_3`: "
        "`\"lambert+ward+ward\"` has `rho_d, ks, alpha, ks_2, alpha_2`. A suffixed name that another lobe declares "
        "itself is skipped: in `\"phong+phong+lafortune(lobes=2)\"` the second Phong has `ks_3, n_3`, since `ks_2` "
        "and `n_2` are the Lafortune lobe 2's.",
        "- Every lobe takes the option `share=NAMES` (parameter names separated by spaces): the lobe has no "
        "parameter of its own under those names and reads the one of the nearest earlier lobe that declares it. "
        "`\"lambert+ggx+ggx(share=f0)\"` is two GGX lobes with one Fresnel term: `rho_d, ks, alpha, f0, ks_2, "
        "alpha_2`. The declarations must match (a dielectric's η is not a conductor's), and amplitudes cannot be "
        "shared; fits treat a shared parameter as acting through every lobe that reads it.",
        "- Every lobe takes the option `bounded=true`: each amplitude it declares without an upper bound (ks, ks_j) "
        "is bounded by 1, so that ks·F ≤ 1 where the Fresnel factor reaches 1 and the plausibility check's specular "
        "test holds by construction. `\"lambert+ggx(bounded=true)\"` is the best fit a renderer can take as "
        "plausible; on materials whose grazing rise needs ks > 1 with Schlick's Fresnel (the RGL-EPFL vinyl films) "
        "it predicts worse than the unbounded fit, which the selection's verdict then flags IMPLAUSIBLE.",
        "- A *colour* parameter has one value per channel (shape `(channels,)`); a *shape* parameter is one scalar "
        "shared by all channels. Fits keep every parameter strictly inside its bounds through smooth transforms "
        "(see `brdffit.params`).",
        "- `brdffit models` prints the same tables on the command line.",
        "",
        "Notation: ci = cosθi, co = cosθo, h = normalize(ωi + ωo), ch = n·h = cosθh, cd = ωi·h = ωo·h = cosθd, "
        "r = 2(n·ωi)n − ωi the mirror direction of ωi, x the tangent and y the bitangent.",
        "",
        "Lobes: " + ", ".join(f"`{n}`" for n in names) + ".",
        "",
    ]
    for name in names:
        out += _lobe_section(name)
    out += ["## Fresnel presets", "", "Conductors (`fresnel=conductor, material=NAME`):", "",
            "| material | η | κ | F at normal incidence |", "|---|---|---|---|"]
    for mat, (eta, k) in fresnel.CONDUCTORS.items():
        f0 = ((eta - 1) ** 2 + k**2) / ((eta + 1) ** 2 + k**2)
        out.append(f"| {mat} | {eta:g} | {k:g} | {f0:.4f} |")
    out += ["", "Dielectrics (`fresnel=dielectric, material=NAME`):", "", "| material | η | F at normal incidence |",
            "|---|---|---|"]
    for mat, eta in fresnel.DIELECTRICS.items():
        out.append(f"| {mat} | {eta:g} | {((eta - 1) / (eta + 1)) ** 2:.4g} |")
    out += [
        "",
        "## Reciprocity and energy conservation",
        "",
        "A lobe is reciprocal when f(ωi, ωo) = f(ωo, ωi) for every parameter value; `Lobe.reciprocal` records it and "
        "`Model.reciprocal` is true when every lobe of a sum is. A lobe has an offset when part of it does not scale "
        "with its linear amplitudes (`Lobe.offset`): the separable solve evaluates only such lobes, and lobes with "
        "a fixed amplitude beside a free one, at zero amplitudes (docs/fitting.md); a test holds every lobe to its "
        "declaration.",
        "",
        "| lobe | reciprocal | offset |",
        "|---|---|---|",
    ]
    out += [f"| `{n}` | {'yes' if models.lobe_class(n).reciprocal else '**no**'} | "
            f"{'yes' if models.lobe_class(n).offset else 'no'} |" for n in names]
    out += [
        "",
        "Energy conservation (whether the directional albedo stays at or below 1) depends on the parameters; the "
        "measured albedos of each lobe are in [properties.md](properties.md).",
        "",
        "## Not provided",
        "",
        "He-Torrance (He, Torrance, Sillion & Greenberg, SIGGRAPH 1991): its physical-optics term is an infinite "
        "sum over the surface's autocorrelation, with its own convergence and wavelength handling, a project of its "
        "own; the microfacet lobes above cover the geometric-optics regime it reduces to for rough surfaces.",
        "",
    ]
    return "\n".join(out)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if docs/models.md is out of date")
    args = parser.parse_args(argv)
    text = render()
    if args.check:
        current = OUTPUT.read_text(encoding="utf-8") if OUTPUT.exists() else ""
        if current != text:
            print(f"{OUTPUT} is out of date: run python scripts/make_models_doc.py", file=sys.stderr)
            return 1
        return 0
    OUTPUT.write_text(text, encoding="utf-8")
    print(f"wrote {OUTPUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
