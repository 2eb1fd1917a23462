"""Tests of brdffit.scene: sphere/plane/direction-list scenes checked against hand-computed radiance, the error
metrics against hand-computed values (an sRGB -> Lab conversion written out here), and the interpolation of measured
data against the model that generated it."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdffit
from brdffit import Measurements, evaluate_dirs, models, synth
from brdffit.interpolation import interpolate
from brdffit.scene import Scene, linear_srgb_to_lab, scene_error

DEG = math.pi / 180.0
RHO = np.array([0.2, 0.5, 0.8])


def lambert(rho=RHO):
    return models.get("lambert", rho_d=rho)


def unit(theta, phi):
    return np.array([math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)])


def pixel_centres(resolution, half_width):
    """(x to the right, y up) of the pixel centres, row 0 at the top, computed independently of the module."""
    step = 2.0 * half_width / resolution
    col = -half_width + (np.arange(resolution) + 0.5) * step
    x = np.tile(col, (resolution, 1))
    y = np.tile(col[::-1, None], (1, resolution))
    return x, y


# ---------------------------------------------------------------------------------------------------------------
# Sphere
# ---------------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("resolution", [33, 64])
def test_sphere_lit_from_viewer_is_lambert_cosine(resolution):
    # Light at the viewer: cosθi = n·v = n_z, so L = ρ/π n_z I at every visible pixel and 0 outside the disk.
    intensity = 2.5
    scene = Scene.sphere([(0.0, 0.0, intensity)], resolution=resolution)
    image = scene.image(scene.radiance_of(lambert()))
    x, y = pixel_centres(resolution, 1.0)
    inside = x * x + y * y < 1.0
    nz = np.sqrt(np.where(inside, 1.0 - x * x - y * y, 0.0))
    expected = (RHO / math.pi)[None, None, :] * nz[..., None] * intensity
    assert image.shape == (resolution, resolution, 3)
    np.testing.assert_allclose(image, expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(scene.mask, inside)
    # Every visible pixel is lit once; the viewer direction is the normal's z in the local frame.
    assert scene.n_rows == scene.n_pixels == int(inside.sum())
    np.testing.assert_allclose(scene.wo[:, 2], nz[inside], rtol=1e-12)


def test_sphere_pixel_count_matches_disk_area():
    for resolution in (32, 64, 128):
        scene = Scene.sphere([(0.0, 0.0, 1.0)], resolution=resolution)
        radius = resolution / 2
        # Gauss circle problem: the lattice count differs from πr² by far less than the perimeter.
        assert abs(scene.n_pixels - math.pi * radius ** 2) < 0.2 * 2 * math.pi * radius
        assert scene.shape == (resolution, resolution)


def test_sphere_light_from_behind_lights_nothing():
    scene = Scene.sphere([(math.pi, 0.0, 1.0)], resolution=32)
    assert scene.n_rows == 0
    assert scene.n_pixels > 700  # the pixels exist, black
    radiance = scene.radiance_of(lambert())
    assert radiance.shape == (scene.n_pixels, 3) and not radiance.any()


def test_sphere_side_light_lights_the_right_half():
    # A light along world +x lights exactly the pixels with n_x = u > 0, with cosθi = u.
    scene = Scene.sphere([(0.5 * math.pi, 0.0, 1.0)], resolution=40)
    x, y = pixel_centres(40, 1.0)
    inside = x * x + y * y < 1.0
    image = scene.image(scene.radiance_of(lambert()))
    expected = np.where((inside & (x > 0))[..., None], (RHO / math.pi) * np.maximum(x, 0.0)[..., None], 0.0)
    np.testing.assert_allclose(image, expected, rtol=1e-12, atol=1e-15)


def test_sphere_shading_frame():
    # At the image centre the local frame is the world frame (tangent = image right = world x).
    light = (30 * DEG, 40 * DEG, 1.0)
    scene = Scene.sphere([light], resolution=33)
    centre = np.flatnonzero(scene.mask.ravel() == 1)
    centre_pixel = int(np.searchsorted(centre, 16 * 33 + 16))
    row = int(np.flatnonzero(scene.pixel == centre_pixel)[0])
    np.testing.assert_allclose(scene.wi[row], unit(light[0], light[1]), atol=1e-12)
    np.testing.assert_allclose(scene.wo[row], [0.0, 0.0, 1.0], atol=1e-12)
    # Everywhere: unit vectors and wi·wo = l·v (the local frame is a rotation of the world frame).
    np.testing.assert_allclose(np.linalg.norm(scene.wi, axis=1), 1.0, rtol=1e-12)
    np.testing.assert_allclose(np.sum(scene.wi * scene.wo, axis=1), unit(light[0], light[1])[2], rtol=1e-12)
    # The tangent runs along the circles of latitude about the image's up axis (world y): it has no y component,
    # so a light along world y has local x = 0 at every pixel.
    up = Scene.sphere([(90 * DEG, 90 * DEG, 1.0)], resolution=33)
    np.testing.assert_allclose(up.wi[:, 0], 0.0, atol=1e-12)
    assert np.all(up.wi[:, 1] > 0)  # and the bitangent y = n × x points towards the top of the image


def test_sphere_view_rotation_keeps_the_front_lit_image():
    # Viewer and light both along an arbitrary direction: the same Lambert image as the default view.
    view = (50 * DEG, 120 * DEG)
    rotated = Scene.sphere([(*view, 1.0)], view=view, resolution=24)
    default = Scene.sphere([(0.0, 0.0, 1.0)], resolution=24)
    np.testing.assert_allclose(rotated.radiance_of(lambert()), default.radiance_of(lambert()), rtol=1e-12)
    # The wi/wo pairs match too for a specular model (the shading frame turns with the camera).
    spec = models.get("lambert+ward", alpha=0.3)
    np.testing.assert_allclose(rotated.radiance_of(spec), default.radiance_of(spec), rtol=1e-10)


def test_radiance_sums_lights():
    model = models.get("lambert+ward", alpha=0.3)
    lights = [(20 * DEG, 10 * DEG, 1.0), (70 * DEG, 200 * DEG, 0.5), (45 * DEG, 300 * DEG, 2.0)]
    both = Scene.sphere(lights, view=(10 * DEG, 30 * DEG), resolution=32)
    parts = [Scene.sphere([light], view=(10 * DEG, 30 * DEG), resolution=32) for light in lights]
    total = sum(part.radiance_of(model) for part in parts)
    np.testing.assert_allclose(both.radiance_of(model), total, rtol=1e-12)
    # Scaling a light's intensity scales its contribution.
    double = Scene.sphere([(20 * DEG, 10 * DEG, 2.0)], view=(10 * DEG, 30 * DEG), resolution=32)
    np.testing.assert_allclose(double.radiance_of(model), 2.0 * parts[0].radiance_of(model), rtol=1e-12)


def test_radiance_jax_path_matches_numpy_and_differentiates():
    scene = Scene.sphere([(0.3, 0.2, 1.0), (1.0, 2.0, 0.7)], resolution=16)
    model = models.get("lambert+ward", alpha=0.3)
    f = evaluate_dirs(model, scene.wi, scene.wo)
    np.testing.assert_allclose(np.asarray(scene.radiance(f)), scene.radiance(np.asarray(f)), rtol=1e-12)
    grad = jax.grad(lambda rho: jnp.sum(scene.radiance(evaluate_dirs(model.replace(rho_d=rho), scene.wi,
                                                                          scene.wo))))(jnp.full(3, 0.5))
    # d/dρ Σ L = Σ_rows cosθi E / π for each channel.
    expected = np.sum(scene.wi[:, 2] * scene.intensity) / math.pi
    np.testing.assert_allclose(np.asarray(grad), expected, rtol=1e-12)


# ---------------------------------------------------------------------------------------------------------------
# Direction lists and planes
# ---------------------------------------------------------------------------------------------------------------


def test_from_angles_round_trip():
    theta_i = np.array([0.0, 0.4, 1.2, 1.5])
    phi_i = np.array([0.0, 1.0, 2.0, 5.0])
    theta_o = np.array([0.3, 0.4, 0.1, 1.0])
    phi_o = np.array([3.0, 4.1, 0.0, 2.0])
    intensity = np.array([1.0, 2.0, 0.5, 3.0])
    scene = Scene.from_angles(theta_i, phi_i, theta_o, phi_o, intensity=intensity)
    wi = np.stack([unit(t, p) for t, p in zip(theta_i, phi_i)])
    wo = np.stack([unit(t, p) for t, p in zip(theta_o, phi_o)])
    np.testing.assert_allclose(scene.wi, wi, atol=1e-15)
    np.testing.assert_allclose(scene.wo, wo, atol=1e-15)
    np.testing.assert_array_equal(scene.pixel, np.arange(4))
    assert scene.n_pixels == 4 and scene.shape is None
    again = Scene.from_directions(scene.wi, scene.wo, scene.intensity)
    np.testing.assert_array_equal(again.wi, scene.wi)
    np.testing.assert_array_equal(again.wo, scene.wo)
    model = models.get("lambert+ward", alpha=0.3)
    f = np.asarray(brdffit.evaluate(model, theta_i, phi_i, theta_o, phi_o))
    np.testing.assert_allclose(scene.radiance_of(model), f * (np.cos(theta_i) * intensity)[:, None], rtol=1e-12)
    # Directions are normalised; default intensity is 1; a direction list has no image.
    scaled = Scene.from_directions(3.0 * wi, 0.5 * wo)
    np.testing.assert_allclose(scaled.wi, wi, atol=1e-15)
    np.testing.assert_array_equal(scaled.intensity, 1.0)
    with pytest.raises(ValueError, match="no image"):
        scene.image(scene.radiance_of(model))
    with pytest.raises(ValueError, match="shape"):
        scene.radiance(np.ones((3, 3)))


def test_plane_point_light_pixel_by_hand():
    light = (0.3, -0.2, 1.5, 4.0)  # point light: position, radiant intensity
    scene = Scene.plane([light], view=(30 * DEG, 60 * DEG), resolution=8, size=2.0, distance=5.0)
    model = models.get("lambert+ward", alpha=0.3)
    image = scene.image(scene.radiance_of(model))
    assert image.shape == (8, 8, 3) and scene.n_pixels == 64
    # Pixel (row 2, column 5): centre x = -1 + 5.5 * 0.25, y = 1 - 2.5 * 0.25.
    p = np.array([-1.0 + 5.5 * 0.25, 1.0 - 2.5 * 0.25, 0.0])
    to_light = np.array(light[:3]) - p
    d = np.linalg.norm(to_light)
    wi = to_light / d
    eye = 5.0 * unit(30 * DEG, 60 * DEG)
    wo = (eye - p) / np.linalg.norm(eye - p)
    f = np.asarray(evaluate_dirs(model, wi[None], wo[None]))[0]
    expected = f * wi[2] * light[3] / d ** 2  # f cosθi I/d²
    np.testing.assert_allclose(image[2, 5], expected, rtol=1e-12)
    # Lambert under the same light: ρ/π I z_L / d³.
    lam = scene.image(scene.radiance_of(lambert()))
    np.testing.assert_allclose(lam[2, 5], RHO / math.pi * light[3] * 1.5 / d ** 3, rtol=1e-12)


def test_plane_directional_light_and_viewer_at_infinity_is_uniform():
    scene = Scene.plane([(40 * DEG, 0.0, 2.0)], view=(40 * DEG, math.pi))  # viewer on the mirror direction
    model = models.get("lambert+ward", alpha=0.3)
    radiance = scene.radiance_of(model)
    f = np.asarray(evaluate_dirs(model, unit(40 * DEG, 0.0)[None], unit(40 * DEG, math.pi)[None]))[0]
    np.testing.assert_allclose(radiance, np.broadcast_to(f * math.cos(40 * DEG) * 2.0, radiance.shape), rtol=1e-12)
    # A light below the plane lights nothing; a viewer below it is refused.
    assert Scene.plane([(0.0, 0.0, -1.0, 1.0)]).n_rows == 0
    assert Scene.plane([(100 * DEG, 0.0, 1.0)]).n_rows == 0
    with pytest.raises(ValueError, match="above the plane"):
        Scene.plane([(0.0, 0.0, 1.0)], view=(100 * DEG, 0.0))
    with pytest.raises(ValueError, match="light 0"):
        Scene.plane([(1.0, 2.0)])


# ---------------------------------------------------------------------------------------------------------------
# Error metrics
# ---------------------------------------------------------------------------------------------------------------


def lab_by_hand(rgb):
    """Linear sRGB -> XYZ (IEC 61966-2-1) -> CIE L*a*b* (CIE 15), D65 white = XYZ of rgb (1, 1, 1), one colour."""
    r, g, b = rgb
    x = 0.4124 * r + 0.3576 * g + 0.1805 * b
    y = 0.2126 * r + 0.7152 * g + 0.0722 * b
    z = 0.0193 * r + 0.1192 * g + 0.9505 * b
    xn, yn, zn = 0.9505, 1.0, 1.0890

    def f(t):
        return t ** (1 / 3) if t > (6 / 29) ** 3 else t / (3 * (6 / 29) ** 2) + 4 / 29

    return np.array([116 * f(y / yn) - 16, 500 * (f(x / xn) - f(y / yn)), 200 * (f(y / yn) - f(z / zn))])


def test_lab_conversion():
    np.testing.assert_allclose(linear_srgb_to_lab([1.0, 1.0, 1.0]), [100.0, 0.0, 0.0], atol=1e-12)
    # Published value for sRGB red (Lindbloom's calculator, D65): L 53.2408, a 80.0925, b 67.2032; the 4-digit
    # IEC matrix agrees to a few hundredths.
    np.testing.assert_allclose(linear_srgb_to_lab([1.0, 0.0, 0.0]), [53.2408, 80.0925, 67.2032], atol=0.05)
    for rgb in ([1.0, 0.0, 0.0], [0.1, 0.6, 0.3], [0.001, 0.002, 0.0005]):  # the last one is on the linear branch
        np.testing.assert_allclose(linear_srgb_to_lab(rgb), lab_by_hand(rgb), rtol=1e-12, atol=1e-12)


def test_scene_error_identical_and_scaled():
    rng = np.random.default_rng(0)
    reference = rng.uniform(0.1, 1.0, size=(50, 3))
    for metric in ("relative", "delta-e", "max-relative"):
        assert scene_error(reference, reference, metric) == 0.0
    assert scene_error(1.1 * reference, reference, "relative") == pytest.approx(0.1, rel=1e-12)
    assert scene_error(1.1 * reference, reference, "max-relative") == pytest.approx(0.1, rel=1e-12)
    # Images (H, W, C) work the same.
    assert scene_error(0.9 * reference.reshape(5, 10, 3), reference.reshape(5, 10, 3)) == pytest.approx(0.1)
    # ΔE uses one exposure for both images: scaling both changes nothing.
    other = reference * rng.uniform(0.8, 1.2, size=reference.shape)
    assert scene_error(7.0 * other, 7.0 * reference, "delta-e") == pytest.approx(
        scene_error(other, reference, "delta-e"), rel=1e-12)
    with pytest.raises(ValueError, match="unknown metric"):
        scene_error(reference, reference, "psnr")
    with pytest.raises(ValueError, match="3 channels"):
        scene_error(reference[:, :2], reference[:, :2], "delta-e")


def test_delta_e_by_hand():
    # Reference: two white pixels and a black one (excluded from the mean); the 99th-percentile luminance is 1,
    # so the exposure is 1. Candidate: white and red (and something on the black pixel, which does not count).
    reference = np.array([[1.0, 1.0, 1.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]])
    candidate = np.array([[1.0, 1.0, 1.0], [1.0, 0.0, 0.0], [5.0, 5.0, 5.0]])
    delta = np.linalg.norm(lab_by_hand([1.0, 0.0, 0.0]) - np.array([100.0, 0.0, 0.0]))
    assert delta == pytest.approx(math.sqrt((100 - 53.2329) ** 2 + 80.1053 ** 2 + 67.2228 ** 2), abs=1e-3)
    assert scene_error(candidate, reference, "delta-e") == pytest.approx(delta / 2, rel=1e-12)
    # Exposure: a reference at half brightness maps back to Y = 1.
    assert scene_error(0.5 * candidate, 0.5 * reference, "delta-e") == pytest.approx(delta / 2, rel=1e-12)


def test_max_relative_ignores_dark_pixels_and_black_references():
    reference = np.array([[1.0], [0.5], [0.001]])
    candidate = np.array([[1.05], [0.4], [0.1]])  # the last pixel is below 1 % of the maximum
    assert scene_error(candidate, reference, "max-relative") == pytest.approx(0.2)
    black = np.zeros((4, 3))
    for metric in ("relative", "delta-e", "max-relative"):
        assert scene_error(black, black, metric) == 0.0
        assert scene_error(black + 0.1, black, metric) == math.inf


# ---------------------------------------------------------------------------------------------------------------
# Interpolation of measured data
# ---------------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ward_data():
    model = models.get("lambert+ward", alpha=0.3)
    return model, synth.generate(model, pattern="uniform", n=20000, seed=0)


def relative_errors(estimate, truth):
    rms = math.sqrt(float(np.sum((estimate - truth) ** 2) / np.sum(truth ** 2)))
    return rms, np.abs(estimate - truth) / truth


def test_interpolation_accuracy(ward_data):
    model, data = ward_data
    # Queries within 80° of the normal: measured relative RMS 0.74 %, 99th percentile 1.7 %, max 4.3 %.
    query = synth.generate(model, pattern="uniform", n=3000, seed=1, max_theta=80 * DEG)
    truth = np.asarray(evaluate_dirs(model, query.wi(), query.wo()))
    rms, rel = relative_errors(interpolate(data, query.wi(), query.wo()), truth)
    assert rms < 0.012
    assert np.quantile(rel, 0.99) < 0.025
    assert rel.max() < 0.07
    # The whole hemisphere: Ward's 1/√(cosθi cosθo) grows without bound at grazing angles, where no finite
    # sample interpolates it (relative RMS 9 %), but 90 % of the pairs stay within 0.5 %.
    query = synth.generate(model, pattern="uniform", n=3000, seed=2)
    truth = np.asarray(evaluate_dirs(model, query.wi(), query.wo()))
    _, rel = relative_errors(interpolate(data, query.wi(), query.wo()), truth)
    assert np.quantile(rel, 0.9) < 0.01
    # Anisotropic coordinates on the same (isotropic) data: one more dimension to fill, relative RMS 3.4 %.
    query = synth.generate(model, pattern="uniform", n=3000, seed=1, max_theta=80 * DEG)
    truth = np.asarray(evaluate_dirs(model, query.wi(), query.wo()))
    rms, _ = relative_errors(interpolate(data, query.wi(), query.wo(), isotropic=False), truth)
    assert rms < 0.05


def test_interpolated_sphere_matches_model(ward_data):
    model, data = ward_data
    scene = Scene.sphere([(30 * DEG, 0.0, 1.0), (60 * DEG, 200 * DEG, 0.5)], view=(10 * DEG, 20 * DEG),
                         resolution=48)
    reference = scene.radiance_of(model)
    measured = scene.radiance_interpolated(data)
    assert scene_error(measured, reference, "relative") < 0.01  # measured 0.4 %
    assert scene_error(measured, reference, "delta-e") < 0.2  # measured 0.04
    assert scene_error(measured, reference, "max-relative") < 0.04  # measured 1.5 %


def test_interpolation_is_reciprocal_and_isotropic(rng):
    model = models.get("lambert+ward", alpha=0.3)
    data = synth.generate(model, pattern="uniform", n=3000, seed=3)
    wi = synth.generate(model, pattern="uniform", n=500, seed=4).wi()
    wo = synth.generate(model, pattern="uniform", n=500, seed=5).wo()
    for isotropic in (True, False):
        forward = interpolate(data, wi, wo, isotropic=isotropic)
        np.testing.assert_allclose(interpolate(data, wo, wi, isotropic=isotropic), forward, rtol=1e-12)
    # Rotating both directions about the normal changes nothing in the isotropic coordinates.
    angle = rng.uniform(0, 2 * math.pi, size=(500, 1))
    c, s = np.cos(angle), np.sin(angle)

    def rotate(w):
        return np.concatenate([c * w[:, :1] - s * w[:, 1:2], s * w[:, :1] + c * w[:, 1:2], w[:, 2:]], axis=1)

    np.testing.assert_allclose(interpolate(data, rotate(wi), rotate(wo)), interpolate(data, wi, wo),
                               rtol=1e-9)
    # Reciprocity is used: a single sample at (ωi, ωo) answers a query at (ωo, ωi) exactly, even for
    # anisotropic coordinates.
    one = Measurements(0.3, 0.0, 1.1, 2.0, [[0.7, 0.2, 0.1]])
    for isotropic in (True, False):
        np.testing.assert_allclose(interpolate(one, one.wo(), one.wi(), k=1, isotropic=isotropic), one.values)


def test_interpolation_ignores_missing_values_and_the_horizon(ward_data):
    _, data = ward_data
    data = data.take(np.arange(4000))
    values = np.array(data.values)
    values[::3, 1] = np.nan  # channel G missing on every third row
    values[5::7, :] = np.nan  # whole rows missing
    holes = data.replace(values=values, sigma=None)
    query = synth.generate("lambert+ward", pattern="uniform", n=400, seed=6)
    estimate = interpolate(holes, query.wi(), query.wo())
    assert np.all(np.isfinite(estimate))
    # Each channel equals the interpolation of only its present samples.
    for channel in range(3):
        present = holes.take(np.isfinite(values[:, channel])).select_channels(channel)
        np.testing.assert_allclose(estimate[:, channel], interpolate(present, query.wi(), query.wo())[:, 0],
                                   rtol=1e-12)
    # A query at a measured sample returns its value.
    np.testing.assert_allclose(interpolate(data, data.wi()[:10], data.wo()[:10]), data.values[:10], rtol=1e-9)
    # Below the horizon: 0.
    wi = np.array([[0.0, 0.6, -0.8], [0.6, 0.0, 0.8], [0.6, 0.0, 0.8]])
    wo = np.array([[0.0, 0.0, 1.0], [0.0, -0.6, -0.8], [0.0, 0.0, 1.0]])
    below = interpolate(data, wi, wo)
    assert not below[:2].any() and np.all(below[2] > 0)
    with pytest.raises(ValueError, match="no measured value"):
        interpolate(holes.replace(values=np.where(np.arange(3) == 0, np.nan, values)), wi, wo)
