"""The coat of brdffit's ``blender`` model (`brdffit.models.blender`, ``coat=True``): its limit at weight 0 and a fit
that recovers a coated material. tests/test_models.py holds it to a transcription of Cycles 4.2's kernel source, and
Cycles itself renders the coat's export in tests/test_export_blender.py."""

import numpy as np

import brdffit
from brdffit import models
from recovery import assert_recovered

COATED = dict(base_color=[0.6, 0.12, 0.08], metallic=0.0, roughness=0.6, ior=1.5, coat_weight=0.8,
              coat_roughness=0.25, coat_ior=1.6)


def test_coat_of_weight_zero_is_the_model_without_coat():
    rng = np.random.default_rng(4)
    angles = (rng.uniform(0, 1.5, 200), rng.uniform(-3, 3, 200), rng.uniform(0, 1.5, 200), rng.uniform(-3, 3, 200))
    plain = {k: v for k, v in COATED.items() if not k.startswith("coat")}
    np.testing.assert_allclose(
        np.asarray(brdffit.evaluate(models.get("blender(coat=true)", **dict(COATED, coat_weight=0.0)), *angles)),
        np.asarray(brdffit.evaluate(models.get("blender", **plain), *angles)), rtol=1e-15, atol=0.0)


def test_fit_recovers_a_synthetic_coated_material():
    """A lacquered red with 0.1 % noise, recovered (5 %, 0.02) at the optimum that a fit from the truth reaches. The
    base's specular shows only through the coat: at 1 % noise the optimum puts its index at 1.30 and its roughness
    at 0.545 (against 1.5 and 0.6), hence the lower noise."""
    assert_recovered("blender(coat=true)", COATED, noise=0.001, seed=8)
