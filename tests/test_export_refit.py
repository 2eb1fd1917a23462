"""The export's fit option (`brdffit.export.refit`): the lobes that stand in for each source lobe, declared on the
lobe (`Lobe.stand_in`), keep a renderer material's diffuse base."""

import pytest

from brdffit import models
from brdffit.export import export_details
from brdffit.export.refit import exportable_specs

BASE = dict(base_color=[0.6, 0.3, 0.2], roughness=0.4)


@pytest.mark.parametrize("spec", ["gltf", "blender"])
def test_a_materials_diffuse_base_is_fitted_beside_its_specular_lobe(spec):
    """A dielectric glTF or Blender material is mostly its diffuse base: Mitsuba's fit option fits it a lambert
    and a GGX lobe, and ends within 0.15 relative RMS of it (with the GGX lobe alone, as when the lobe declared
    nothing, 0.34 and 0.33: the diffuse part lost)."""
    model = models.get(spec, **BASE)
    assert exportable_specs(model) == ["lambert+ggx(fresnel=dielectric)", "lambert"]
    details = export_details(model, "mitsuba", fit=True)
    assert details.mapped.spec == "lambert+ggx(fresnel=dielectric)"
    assert details.deviation.rms < 0.15
    assert 'type="diffuse"' in details.text


def test_each_lobe_declares_its_stand_in_once():
    """Diffuse lobes stand in as one lambert, a conductor lobe as a conductor GGX lobe, pbrt-v4's mix as a lambert
    and a conductor GGX lobe; lamberts are merged and come first."""
    assert exportable_specs(models.get("oren-nayar+ward")) == ["lambert+ggx(fresnel=dielectric)", "lambert"]
    assert exportable_specs(models.get("toon-diffuse+lambert+cook-torrance(fresnel=conductor)"))[0] == \
        "lambert+ggx(fresnel=conductor)"
    assert exportable_specs(models.get("pbrt")) == ["lambert+ggx(fresnel=conductor)", "lambert"]
    assert exportable_specs(models.get("ggx")) == ["ggx(fresnel=dielectric)"]
