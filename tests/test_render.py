"""Rendering (brdffit.render): radiance values, lights, tone curves and the files it writes."""

import math

import matplotlib.image
import numpy as np
import pytest

from brdffit import models, synth
from brdffit import render as R
from brdffit.io.merl import MerlTable
from brdffit.interpolation import interpolate
from brdffit.scene import Scene, scene_error

RES = 48


def _srgb(x):
    # IEC 61966-2-1 Eq. 5, written out independently of the module.
    return 1.055 * x ** (1 / 2.4) - 0.055 if x > 0.0031308 else 12.92 * x


@pytest.fixture(scope="module")
def glossy():
    return models.get("lambert+ward", alpha=0.3)


# ------------------------------------------------------------------------------------------------------ radiance
def test_lambert_sphere_under_a_frontal_light_is_rho_over_pi_nz_e():
    rho, e = np.array([0.8, 0.5, 0.2]), 2.5
    img = R.render_sphere(models.get("lambert", rho_d=rho), lights=[(0.0, 0.0, e)], resolution=RES)
    assert img.shape == (RES, RES, 3)
    centres = -1 + (np.arange(RES) + 0.5) * 2 / RES
    u, w = np.meshgrid(centres, centres[::-1])
    r2 = u * u + w * w
    nz = np.sqrt(np.clip(1 - r2, 0, None))
    expected = np.where((r2 < 1)[..., None], rho / math.pi * nz[..., None] * e, 0.0)
    np.testing.assert_allclose(img, expected, rtol=1e-12, atol=1e-15)


def test_default_lights_and_plane(glossy):
    assert len(R.DEFAULT_LIGHTS) == 3 and all(len(light) == 3 for light in R.DEFAULT_LIGHTS)
    img = R.render_sphere(glossy, resolution=32)
    assert img.shape == (32, 32, 3) and np.all(img >= 0) and img.max() > 0
    assert img[0, 0].sum() == 0  # the corner is off the sphere
    # An orthographic plane under directional lights is uniform: every pixel equals the direction-list scene.
    plane = R.render_plane(glossy, resolution=8)
    lit = [light for light in R.DEFAULT_LIGHTS if light[0] < math.pi / 2]
    wi = np.array([[math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)] for t, p, _ in lit])
    wo = np.array([math.sin(0.9), 0.0, math.cos(0.9)])
    pairs = R.render(Scene.from_directions(wi, np.tile(wo, (len(lit), 1)), [e for *_, e in lit]), glossy)
    np.testing.assert_allclose(plane, np.broadcast_to(pairs.sum(axis=0), plane.shape), rtol=1e-12)
    # A near viewer makes the swatch vary.
    assert np.ptp(R.render_plane(glossy, resolution=8, distance=2.0)[..., 0]) > 0


def test_render_rejects_unknown_sources():
    with pytest.raises(TypeError, match="Model, Measurements"):
        R.render_sphere("lambert", resolution=8)


# --------------------------------------------------------------------------------------------------- area lights
def test_area_light_of_radius_zero_is_the_point_light(glossy):
    light = (math.radians(30), math.radians(60), 1.7)
    area = R.area_light(*light, radius=0.0, samples=16)
    point = R.render_sphere(glossy, lights=[light], resolution=RES)
    np.testing.assert_allclose(R.render_sphere(glossy, lights=area, resolution=RES), point, rtol=0, atol=1e-12)


def test_area_light_samples():
    theta, phi, radius = math.radians(30), math.radians(60), math.radians(10)
    lights = R.area_light(theta, phi, 2.0, radius, samples=25, seed=3)
    assert len(lights) == 25
    assert sum(e for *_, e in lights) == pytest.approx(2.0, abs=1e-14)
    centre = np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)])
    d = np.array([[math.sin(t) * math.cos(p), math.sin(t) * math.sin(p), math.cos(t)] for t, p, _ in lights])
    cos_psi = d @ centre
    assert np.all(cos_psi >= math.cos(radius) - 1e-12)
    # Stratified in cosψ: exactly one sample per stratum of equal solid angle.
    strata = np.floor((1 - cos_psi) / (1 - math.cos(radius)) * 25).astype(int)
    assert sorted(strata) == list(range(25))
    assert lights == R.area_light(theta, phi, 2.0, radius, samples=25, seed=3)  # seeded
    assert lights != R.area_light(theta, phi, 2.0, radius, samples=25, seed=4)
    with pytest.raises(ValueError):
        R.area_light(theta, phi, 1.0, -0.1)
    with pytest.raises(ValueError):
        R.area_light(theta, phi, 1.0, 0.1, samples=0)


def test_small_area_light_is_close_to_the_point_light():
    model = models.get("lambert")
    light = (math.radians(20), 0.0, 1.0)
    point = R.render_sphere(model, lights=[light], resolution=RES)
    area = R.render_sphere(model, lights=R.area_light(*light, radius=math.radians(5), samples=64), resolution=RES)
    # Lambert: the cone average of cosθi differs from the centre's by at most about (1 - cos 5°) = 0.4 %, plus
    # the terminator, where part of the disk is already set.
    assert scene_error(area, point, "relative") < 0.01


# ------------------------------------------------------------------------------------------------- tone mapping
def test_tonemap_hand_values():
    assert _srgb(0.5) == pytest.approx(0.7353569830524495)
    grey = np.full((2, 2, 3), 0.5)
    np.testing.assert_allclose(R.tonemap(grey, "clamp"), 0.7354, atol=5e-5)
    np.testing.assert_allclose(R.srgb_oetf([0.0, 0.001, 1.0, 2.0]), [0.0, 0.01292, 1.0, 1.0], atol=1e-15)
    # Reinhard: luminance 1 -> 1 / (1 + 1) = 0.5 before the OETF; grey keeps its colour.
    np.testing.assert_allclose(R.tonemap(np.ones((1, 1, 3)), "reinhard"), _srgb(0.5), rtol=1e-14)
    np.testing.assert_allclose(R.tonemap(np.full((1, 1, 3), 0.5), "reinhard", exposure=2.0), _srgb(0.5),
                               rtol=1e-14)
    # A coloured pixel keeps its channel ratios (before the OETF): scaled by 1 / (1 + Y).
    rgb = np.array([[[0.6, 0.2, 0.1]]])
    y = 0.2126 * 0.6 + 0.7152 * 0.2 + 0.0722 * 0.1
    np.testing.assert_allclose(R.tonemap(rgb, "reinhard"), [[[_srgb(c / (1 + y)) for c in (0.6, 0.2, 0.1)]]])
    # Filmic (Narkowicz 2015 ACES fit) at x = 1: 2.54 / 3.16.
    np.testing.assert_allclose(R.tonemap(np.ones((1, 1)), "filmic"), _srgb(2.54 / 3.16), rtol=1e-14)
    assert R.tonemap(np.zeros((1, 1, 3)), "filmic").max() == pytest.approx(_srgb(0.0), abs=1e-15)
    with pytest.raises(ValueError, match="unknown tone mapping"):
        R.tonemap(grey, "gamma")
    with pytest.raises(ValueError, match="exposure"):
        R.tonemap(grey, exposure=0.0)


@pytest.mark.parametrize("method", R.TONEMAPS)
def test_tone_curves_are_monotonic_and_in_range(method):
    x = np.geomspace(1e-5, 1e3, 400)
    grey = np.repeat(x[:, None, None], 3, axis=2).reshape(400, 1, 3)
    out = R.tonemap(grey, method)[:, 0, 0]
    assert np.all(np.diff(out) >= 0) and out.min() >= 0 and out.max() <= 1
    if method != "clamp":
        assert np.all(np.diff(out[x < 5]) > 0)  # strictly increasing below saturation (ACES: x ≈ 7.2)
        assert out[-1] > 0.99


# ------------------------------------------------------------------------------------------------ other sources
def test_render_of_measurements_matches_the_model(glossy):
    data = synth.generate(glossy, pattern="uniform", n=20000, seed=0)
    scene = Scene.sphere(R.DEFAULT_LIGHTS, view=(math.radians(10), math.radians(20)), resolution=RES)
    model_img = R.render(scene, glossy)
    data_img = R.render(scene, data)
    np.testing.assert_allclose(data_img[scene.mask],
                               scene.radiance(interpolate(data, scene.wi, scene.wo, k=8)))
    # Measured: relative RMS 0.26 %, max-relative 1.3 %, ΔE 0.04 (docs/rendering.md).
    assert scene_error(data_img, model_img, "relative") < 0.01
    assert scene_error(data_img, model_img, "max-relative") < 0.04


def test_render_of_a_merl_table_matches_the_model_within_the_tabulation_error(glossy):
    table = MerlTable.from_model(glossy)
    scene = Scene.sphere(R.DEFAULT_LIGHTS, resolution=RES)
    model_img = R.render(scene, glossy)
    table_img = R.render(scene, table)
    assert np.all(np.isfinite(table_img))
    # The tabulation error at the scene's rows, and the image error it allows (triangle inequality per pixel).
    f_model = np.asarray(models.evaluate_dirs(glossy, scene.wi, scene.wo))
    th_i = np.arccos(scene.wi[:, 2])
    th_o = np.arccos(scene.wo[:, 2])
    f_table = np.nan_to_num(table.lookup(th_i, np.arctan2(scene.wi[:, 1], scene.wi[:, 0]),
                                         th_o, np.arctan2(scene.wo[:, 1], scene.wo[:, 0])))
    bound = scene.image(scene.radiance(np.abs(f_table - f_model)))
    assert np.all(np.abs(table_img - model_img) <= bound + 1e-12)
    # Measured: relative RMS 0.56 %, max-relative 1.8 %, ΔE 0.08 (docs/rendering.md).
    assert scene_error(table_img, model_img, "relative") < 0.02


# -------------------------------------------------------------------------------------------------------- files
def test_png_round_trip(tmp_path, rng):
    ldr = rng.random((5, 7, 3))
    path = tmp_path / "a.png"
    R.save_png(path, ldr)
    back = matplotlib.image.imread(path)
    assert back.shape[:2] == (5, 7) and back.shape[2] in (3, 4)
    np.testing.assert_allclose(back[..., :3], ldr, atol=0.5 / 255 + 1e-6)
    R.save_png(tmp_path / "grey.png", ldr[..., 0])
    grey = matplotlib.image.imread(tmp_path / "grey.png")
    np.testing.assert_allclose(grey[..., 0], ldr[..., 0], atol=1 / 255)


def test_npy_round_trip_is_exact(tmp_path, rng):
    hdr = (rng.random((4, 6, 3)) * 100).astype(np.float32)
    path = tmp_path / "a.npy"
    R.save_npy(path, hdr)
    back = np.load(path)
    assert back.dtype == np.float32 and np.array_equal(back, hdr)
    R.save_npy(tmp_path / "b.npy", hdr.astype(np.float64))
    assert np.load(tmp_path / "b.npy").dtype == np.float32


@pytest.mark.parametrize("save, good", [(R.save_png, np.zeros((2, 2, 3))), (R.save_npy, np.zeros((2, 2, 3)))])
def test_failed_write_leaves_an_existing_file_intact(tmp_path, save, good, monkeypatch):
    path = tmp_path / "out"
    save(path, good)
    before = path.read_bytes()
    with pytest.raises(ValueError):
        save(path, np.zeros((2, 2, 2, 2)))  # wrong dims
    assert path.read_bytes() == before
    # A writer that fails half way through: the old file survives and no temporary file is left behind.
    target = matplotlib.image if save is R.save_png else np

    def broken(file, *args, **kwargs):
        if hasattr(file, "write"):
            file.write(b"partial")
        else:
            with open(file, "wb") as handle:
                handle.write(b"partial")
        raise OSError("disk full")

    monkeypatch.setattr(target, "imsave" if save is R.save_png else "save", broken)
    with pytest.raises(OSError, match="disk full"):
        save(path, good + 1)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_difference():
    b = np.zeros((2, 2, 3))
    b[0, 0] = 1.0
    b[0, 1] = 0.5
    a = b.copy()
    a[0, 1] = 0.6
    d = R.difference(a, b)
    assert d.shape == (2, 2)
    np.testing.assert_allclose(d, [[0, 0.2], [0, 0]], atol=1e-12)
    # The floor (1 % of the brightest reference pixel) keeps dark pixels finite.
    a[1, 1] = 0.001
    assert R.difference(a, b)[1, 1] == pytest.approx(0.001 / 0.01)
    assert R.difference(a, b, floor=0.1)[1, 1] == pytest.approx(0.01)
    with pytest.raises(ValueError):
        R.difference(a, b[:1])
