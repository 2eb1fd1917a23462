"""The sheen of brdffit's ``blender`` model (`brdffit.models.blender`, ``sheen=True``): the albedo its layering
assumes, and a fit that recovers a sheened fabric. tests/test_models.py holds it to a NumPy transcription of Cycles'
closure (with MaterialX's fits in place of Cycles' table) and, at weight 0, to the model without sheen; Cycles
itself renders its export in tests/test_export_blender.py, which measures what the fits cost."""

import numpy as np
import pytest
from scipy import integrate

import brdffit
from brdffit import models

FABRIC = dict(base_color=[0.45, 0.08, 0.12], metallic=0.0, roughness=0.8, ior=1.5, sheen_weight=0.9,
              sheen_roughness=0.35)


@pytest.mark.parametrize("theta_o, roughness", [(0.0, 0.5), (0.6, 0.2), (1.2, 0.8), (1.45, 1.0)])
def test_the_sheen_alone_reflects_its_albedo_at_the_view(theta_o, roughness):
    """Over a black base (no diffuse, and IOR 1: no specular) the model is the sheen alone, whose albedo at the view
    is w·E(μo): the LTC integrates to 1 over the hemisphere. The integral by adaptive quadrature against E from
    MaterialX's fit, which the layering weight uses."""
    from brdffit.models.sheen import zeltner_sheen_fit

    weight = 0.7
    model = models.get("blender(sheen=true)", base_color=[0.0] * 3, metallic=0.0, roughness=0.5, ior=1.0,
                       sheen_weight=weight, sheen_roughness=roughness)

    def row(theta_i):
        phi = np.linspace(-np.pi, np.pi, 513)
        f = np.asarray(brdffit.evaluate(model, np.full_like(phi, theta_i), phi, np.full_like(phi, theta_o),
                                        np.zeros_like(phi)))[:, 0]
        return integrate.simpson(f, x=phi) * np.cos(theta_i) * np.sin(theta_i)

    value, _ = integrate.quad(row, 0.0, np.pi / 2, epsabs=1e-10, epsrel=1e-8, limit=200)
    albedo, _, _ = zeltner_sheen_fit(np.cos(theta_o), roughness, xp=np)
    assert value == pytest.approx(weight * albedo, rel=2e-4)


def test_fit_recovers_a_synthetic_sheened_fabric():
    """A red fabric with a strong sheen and 0.1 % noise, recovered (5 %, 0.02) at the optimum that a fit from the
    truth reaches."""
    from recovery import assert_recovered

    assert_recovered("blender(sheen=true)", FABRIC, noise=0.001, seed=9)
