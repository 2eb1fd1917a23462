"""The coat of brdffit's ``blender`` model (`brdffit.models.blender`, ``coat=True``): a fit that recovers a coated
material. tests/test_models.py holds it to a transcription of Cycles 4.2's kernel source and, at weight 0, to the
model without coat; Cycles itself renders the coat's export in tests/test_export_blender.py."""

from recovery import assert_recovered

COATED = dict(base_color=[0.6, 0.12, 0.08], metallic=0.0, roughness=0.6, ior=1.5, coat_weight=0.8,
              coat_roughness=0.25, coat_ior=1.6)


def test_fit_recovers_a_synthetic_coated_material():
    """A lacquered red with 0.1 % noise, recovered (5 %, 0.02) at the optimum that a fit from the truth reaches. The
    base's specular shows only through the coat: at 1 % noise the optimum puts its index at 1.30 and its roughness
    at 0.545 (against 1.5 and 0.6), hence the lower noise."""
    assert_recovered("blender(coat=true)", COATED, noise=0.001, seed=8)
