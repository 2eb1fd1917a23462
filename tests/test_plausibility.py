"""Plausibility of fitted models in every summary and report (brdffit.plausibility.plausibility)."""

import numpy as np
import pytest

import brdffit
from brdffit import properties as P
from brdffit.plausibility import plausibility


def _ward_fit(ks: float, alpha: float, seed: int):
    """A Lambert + Ward truth (ρd = 0.3, one channel) and the fit of its 600 half-diff samples to θ ≤ 80°."""
    truth = brdffit.models.get("lambert+ward", channels=1, rho_d=0.3, ks=ks, alpha=alpha)
    data = brdffit.synth.generate(truth, pattern="half-diff", n=600, noise="relative:0.01", seed=seed,
                                  max_theta=np.deg2rad(80.0), channels=["c0"])
    return truth, brdffit.fit(data, "lambert+ward")


@pytest.fixture(scope="module")
def implausible():
    # ks = 2 with a wide Ward lobe: the fitted albedo is about 1.5 at normal incidence.
    return _ward_fit(ks=2.0, alpha=0.5, seed=1)


@pytest.fixture(scope="module")
def plausible():
    return _ward_fit(ks=0.3, alpha=0.15, seed=2)


def test_scan_albedo_is_the_albedo_quadrature():
    model = brdffit.models.get("lambert+cook-torrance", channels=3, rho_d=0.5, ks=1.0, m=0.02)
    fast = P.scan_albedo(model)[:, 0, :]
    exact = np.asarray(P.directional_albedo(model, P.PLAUSIBILITY_THETA_I))
    np.testing.assert_allclose(fast, exact, atol=3e-4)  # resolution 64 against 128, the sharpest lobe


def test_implausible_fit_is_flagged_with_its_albedo(implausible):
    truth, result = implausible
    check = result.plausibility()
    albedo = float(np.max(P.directional_albedo(result.model, P.PLAUSIBILITY_THETA_I)))
    assert albedo > 1.3
    energy = check["energy"]
    assert energy.level == "implausible" and energy.value == pytest.approx(albedo, abs=1e-3)
    assert f"max albedo {energy.value:.4g}" in energy.message and energy.advice
    specular = check["specular"]
    assert specular.level == "implausible" and specular.value == pytest.approx(float(result.params["ks"][0]))
    assert specular.value == pytest.approx(2.0, rel=0.02) and "ks" in specular.message
    assert not check.ok
    summary = result.summary()
    assert f"IMPLAUSIBLE energy: max albedo {energy.value:.4g}" in summary
    assert "IMPLAUSIBLE specular: largest ks·F" in summary and "what to do:" in summary


def test_plausible_fit_is_not_flagged(plausible):
    _, result = plausible
    check = result.plausibility()
    assert check.ok and [c.level for c in check.checks] == ["ok", "ok", "ok"]
    assert check["energy"].value < 1.0 and check["specular"].value == pytest.approx(0.3, rel=0.05)
    summary = result.summary()
    assert "IMPLAUSIBLE" not in summary and "CAUTION" not in summary and "plausible energy: max albedo" in summary


def test_albedo_above_one_only_beyond_the_data_is_a_caution():
    # Lambert + a Fresnel lobe is not energy-coupled: towards grazing F -> 1 and the sum passes 1.
    model = brdffit.models.get("lambert+cook-torrance", channels=1, rho_d=0.55, ks=1.0, m=0.15, f0=0.04)
    check = plausibility(model, theta_max=np.deg2rad(70.0))
    assert check["energy"].level == "caution" and check["energy"].value > 1.1
    assert "beyond them" in check["energy"].message
    assert plausibility(model)["energy"].level == "implausible"  # when every θi counts as measured


def test_ks_above_one_within_its_errors_is_plausible():
    model = brdffit.models.get("lambert+ward", channels=1, rho_d=0.3, ks=1.004, alpha=0.5)
    assert plausibility(model, stderr={"ks": np.array([0.003])})["specular"].level == "ok"
    assert plausibility(model, stderr={"ks": np.array([0.001])})["specular"].level == "implausible"


def test_parameters_at_bounds_get_advice():
    model = brdffit.models.get("lambert+cook-torrance", channels=3, rho_d=[1.0, 0.5, 0.5], ks=[0.0, 0.3, 0.3],
                               m=0.001, f0=1.0)
    check = plausibility(model, bounds_hit=["rho_d[0]", "ks[0]", "m", "f0"])["bounds"]
    assert check.level == "caution" and check.value == 4
    assert "rho_d[0] = 1 at 1" in check.advice and "ks[0] = 0: its lobe adds nothing" in check.advice
    assert "m = 0.001 at its lower bound" in check.advice and "f0 = 1 on its bound" in check.advice


def test_report_shows_noise_model_and_plausibility(implausible, tmp_path):
    from brdffit.report import write_report

    truth, result = implausible
    data = brdffit.synth.generate(truth, pattern="half-diff", n=600, noise="relative:0.01", seed=1,
                                  max_theta=np.deg2rad(80.0), channels=["c0"])
    paths = write_report(tmp_path, data, result)
    md = open(paths["md"], encoding="utf-8").read()
    assert "## Noise model" in md and "**relative (chosen)**" in md and "stderr noise-model" in md
    assert "## Plausibility" in md and "| energy | **IMPLAUSIBLE** | max albedo" in md
    assert "± stderr (noise-model)" in md and "± sandwich" in md


def test_a_layered_renderer_model_is_judged_by_its_albedo_at_each_view():
    """Cycles' Principled BSDF (brdffit's `blender` model) weights its diffuse by 1 − E(view): a white base reflects
    more than 1 of grazing light (1.33 at θi = 89°) while its albedo at every view stays within 1 (1.000), the
    energy that a renderer tracing from the camera carries. The check reads the view's, and names θo."""
    model = brdffit.models.get("blender", base_color=1.0, roughness=0.3)
    assert not model.reciprocal
    assert P.scan_albedo(model).max() > 1.3
    assert P.scan_albedo(model, view=True).max() <= 1.0 + 1e-3
    (energy,) = [c for c in plausibility([model]).checks if c.name == "energy"]
    assert energy.level == "ok" and "θo = " in energy.message, energy.message
    # Brighter than 1 at some view: implausible, at that view.
    brighter = brdffit.models.get("openpbr", base_color=1.0, base_diffuse_roughness=1.0)
    (energy,) = [c for c in plausibility([brighter]).checks if c.name == "energy"]
    assert energy.level == "implausible" and "θo = " in energy.message, energy.message
