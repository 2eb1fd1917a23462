r"""Rendering: sphere and plane previews of a model, of measured data or of a MERL table, tone mapping and files.

All geometry comes from `brdffit.scene.Scene` (a sphere or a flat swatch under directional or point lights); this
module only chooses how to get the BRDF at the scene's rows and turns the radiance into pictures. Under delta
lights the reflection equation (docs/conventions.md) becomes a sum over the lights (docs/scenes.md):

.. math::  L(p) = \sum_{\text{lights } l} f_r(\omega_{i,l}, \omega_o) \, \cos\theta_{i,l} \, E_l

An area light is sampled as a few directional lights (`area_light`), a small environment is `DEFAULT_LIGHTS`
(key, fill and rim). `tonemap` maps HDR radiance to display values (Reinhard, a filmic curve or plain clamping,
then the sRGB transfer function); `save_png` / `save_npy` write them atomically; `difference` makes the relative
error image of two renders. docs/rendering.md has the formulas and their sources.
"""

from __future__ import annotations

import math

import numpy as np

from .colour import srgb_encode
from .io._common import atomic_path
from .io.merl import MerlTable
from .measurements import Measurements
from .models import Model
from .interpolation import interpolate
from .scene import Scene

__all__ = [
    "render",
    "render_sphere",
    "render_plane",
    "PLANE_VIEW_DISTANCE",
    "DEFAULT_LIGHTS",
    "area_light",
    "tonemap",
    "TONEMAPS",
    "srgb_oetf",
    "luminance",
    "save_png",
    "save_npy",
    "difference",
]

# A small "environment of a few lights": directional lights (theta, phi, intensity) in world coordinates, i.e.
# the direction towards each light (radians) and the irradiance E it delivers at normal incidence. With the
# default sphere view (the viewer on world +z, image right = +x, image up = +y, docs/scenes.md):
#   key  — 40° from the view axis, from the upper left (φ = 135°), E = π: the main light and main highlight.
#          E = π makes a white Lambertian surface (f_r = 1/π) facing the key light exactly 1 in radiance, so
#          exposure 1 is a sensible default for `tonemap`;
#   fill — 55° from the view axis, from the lower right (φ = −30°), E = π/4: lifts the shadow side
#          (key : fill = 4 : 1, a common ratio in three-point lighting);
#   rim  — 110° from the view axis, i.e. behind the sphere, from the upper right (φ = 45°), E = π/2: a bright
#          crescent along the upper-right silhouette that separates the object from the black background.
DEFAULT_LIGHTS = (
    (math.radians(40.0), math.radians(135.0), math.pi),  # key
    (math.radians(55.0), math.radians(-30.0), math.pi / 4),  # fill
    (math.radians(110.0), math.radians(45.0), math.pi / 2),  # rim
)

# Tone curves understood by `tonemap`.
TONEMAPS = ("reinhard", "filmic", "clamp")

# Luminance of linear sRGB / Rec. 709 primaries: Y = 0.2126 R + 0.7152 G + 0.0722 B (ITU-R BT.709-6, item 3.2;
# the middle row of the IEC 61966-2-1 RGB -> XYZ matrix).
_LUMA = np.array([0.2126, 0.7152, 0.0722])

# ACES filmic curve fitted by K. Narkowicz, "ACES Filmic Tone Mapping Curve" (blog, 2015):
#   f(x) = x (a x + b) / (x (c x + d) + e),  a = 2.51, b = 0.03, c = 2.43, d = 0.59, e = 0.14,
# applied per channel to the exposed linear value and clamped to [0, 1]. (Narkowicz pre-multiplies by 0.6 to match
# the ACES reference rendering transform at exposure 1; here that is left to ``exposure``.)
_ACES = (2.51, 0.03, 2.43, 0.59, 0.14)


# ---------------------------------------------------------------------------------------------------- rendering
def _local_angles(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Polar angle and azimuth of unit vectors in the local frame (docs/conventions.md)."""
    return np.arccos(np.clip(w[:, 2], -1.0, 1.0)), np.arctan2(w[:, 1], w[:, 0])


def _brdf_at_rows(scene: Scene, source, k: int, isotropic: bool) -> np.ndarray:
    """f_r of ``source`` at the (ωi, ωo) rows of ``scene``, shape ``(M, C)`` (used for Measurements and MERL)."""
    if isinstance(source, Measurements):
        return interpolate(source, scene.wi, scene.wo, k=k, isotropic=isotropic)
    if isinstance(source, MerlTable):
        theta_i, phi_i = _local_angles(scene.wi)
        theta_o, phi_o = _local_angles(scene.wo)
        f = source.lookup(theta_i, phi_i, theta_o, phi_o)
        # A missing cell (NaN: no measurement there, e.g. a cell whose centre is below the horizon although the
        # query is just above it) reflects nothing in the image rather than poisoning the pixel.
        return np.nan_to_num(f, nan=0.0)
    raise TypeError(f"cannot render a {type(source).__name__}: give a brdffit Model, Measurements or a "
                    "brdffit.io.merl.MerlTable")


def render(scene: Scene, source, *, k: int = 8, isotropic: bool = True) -> np.ndarray:
    """HDR radiance of a material in a scene.

    Arguments:
        scene: a `brdffit.scene.Scene` (`Scene.sphere`, `Scene.plane`, or a direction list).
        source: what reflects: a `brdffit.Model` (evaluated exactly), `Measurements` (interpolated at the scene's
            directions with `brdffit.interpolation.interpolate`, k nearest samples) or a
            `brdffit.io.merl.MerlTable` (`MerlTable.lookup`, the value of the cell holding each direction pair;
            missing cells reflect nothing).
        k: neighbours of the interpolation of `Measurements` (ignored otherwise).
        isotropic: interpolate `Measurements` in isotropic coordinates (False for anisotropic data, e.g. brushed
            metal; see `brdffit.interpolation.interpolate`).

    Returns:
        The linear radiance image ``(H, W, C)`` (float64, black outside the object) for sphere and plane scenes, or
        ``(n_pixels, C)`` for a direction list. Its unit is that of the lights' irradiance per steradian.
    """
    if isinstance(source, Model):
        radiance = scene.radiance_of(source)
    else:
        radiance = scene.radiance(_brdf_at_rows(scene, source, k, isotropic))
    return radiance if scene.shape is None else scene.image(radiance)


def render_sphere(source, lights=None, view=(0.0, 0.0), resolution: int = 128, *, k: int = 8,
                  isotropic: bool = True) -> np.ndarray:
    """A material preview: an orthographic view of a unit sphere (`Scene.sphere`) shaded per pixel.

    Arguments:
        source: a `brdffit.Model`, `Measurements` or `MerlTable` (see `render`).
        lights: directional lights ``(theta, phi, intensity)`` in world coordinates (radians, irradiance at normal
            incidence); area lights are lists from `area_light` concatenated in. None uses `DEFAULT_LIGHTS`.
        view: world direction ``(theta_v, phi_v)`` towards the viewer (radians); ``(0, 0)`` puts the viewer on +z
            with image right = +x, image up = +y.
        resolution: image width and height in pixels.
        k, isotropic: how to interpolate `Measurements` (see `render`).

    Returns:
        ``(resolution, resolution, C)`` HDR radiance, 0 off the sphere.
    """
    scene = Scene.sphere(DEFAULT_LIGHTS if lights is None else list(lights), view=view, resolution=resolution)
    return render(scene, source, k=k, isotropic=isotropic)


# The viewer distance of `brdffit render --plane` (the swatch's side is 2): close enough that the directions, and so
# the shading, change across the swatch; a viewer at infinity sees it as one flat colour under directional lights.
PLANE_VIEW_DISTANCE = 3.0


def render_plane(source, lights=None, view=(0.9, 0.0), resolution: int = 128, *, size: float = 2.0,
                 distance: float | None = None, k: int = 8, isotropic: bool = True) -> np.ndarray:
    """A material swatch: a flat square in the world xy plane (`Scene.plane`), seen in texture space.

    With the viewer at infinity (``distance=None``) and directional lights every point looks the same; give a
    ``distance`` or point lights ``(x, y, z, intensity)`` to see the highlight move across the swatch.

    Arguments:
        source: a `brdffit.Model`, `Measurements` or `MerlTable` (see `render`).
        lights: directional ``(theta, phi, intensity)`` or point ``(x, y, z, intensity)`` lights; None uses
            `DEFAULT_LIGHTS` (the rim light is below the plane and adds nothing).
        view: direction ``(theta_v, phi_v)`` from the centre of the square towards the viewer (radians).
        resolution: image width and height in pixels.
        size: side of the square.
        distance: viewer distance from the centre (None: at infinity).
        k, isotropic: how to interpolate `Measurements` (see `render`).

    Returns:
        ``(resolution, resolution, C)`` HDR radiance.
    """
    scene = Scene.plane(DEFAULT_LIGHTS if lights is None else list(lights), view=view, resolution=resolution,
                        size=size, distance=distance)
    return render(scene, source, k=k, isotropic=isotropic)


# -------------------------------------------------------------------------------------------------- area lights
def area_light(theta: float, phi: float, intensity: float, radius: float, samples: int = 16,
               seed: int = 0) -> list:
    r"""A disk (cone) light of angular radius ``radius`` as ``samples`` directional lights.

    The directions are distributed uniformly in solid angle over the cone around (θ, φ): with u1, u2 in [0, 1),
    cosψ = 1 − u1 (1 − cos radius) and azimuth 2π u2 about the centre direction (uniform cone sampling, Pharr,
    Jakob & Humphreys, *Physically Based Rendering*, 4th ed., Sec. A.5, ``SampleUniformCone``). The samples are
    stratified: u1 = (j + ξ_j) / n takes one value per stratum j (rings of equal solid angle), and
    u2 = frac(j φ_g + ξ') follows the golden-ratio sequence (φ_g = (√5 − 1)/2) with one jitter ξ' for all, so
    the azimuths of neighbouring strata are far apart; the jitters come from ``numpy.random.default_rng(seed)``.
    Each sample carries ``intensity / samples``: the Monte Carlo estimate of ∫_cone f_r L_e cosθi dω with
    E = L_e Ω the irradiance of the whole light at normal incidence. Samples that
    fall below a shading point's horizon are dropped by the scene, so a partly set light is handled per pixel.

    Arguments:
        theta, phi: world direction of the centre of the light (radians).
        intensity: total irradiance E the light delivers at normal incidence (>= 0).
        radius: angular radius of the disk (radians, 0 to π/2); 0 gives ``samples`` copies of the point light.
        samples: number of directional lights (>= 1).
        seed: seed of the jitter.

    Returns:
        A list of ``samples`` tuples ``(theta, phi, intensity / samples)``, usable wherever lights are.
    """
    theta, phi, intensity, radius = float(theta), float(phi), float(intensity), float(radius)
    samples = int(samples)
    if samples < 1:
        raise ValueError(f"an area light needs at least one sample, got {samples}")
    if not (0.0 <= radius <= math.pi / 2):
        raise ValueError(f"radius must be between 0 and pi/2 radians, got {radius!r}")
    if not (math.isfinite(intensity) and intensity >= 0.0 and math.isfinite(theta) and math.isfinite(phi)):
        raise ValueError(f"an area light needs a finite direction and an intensity >= 0, got "
                         f"({theta!r}, {phi!r}, {intensity!r})")
    rng = np.random.default_rng(seed)
    j = np.arange(samples)
    u1 = (j + rng.random(samples)) / samples
    u2 = np.mod(j * (math.sqrt(5.0) - 1.0) / 2.0 + rng.random(), 1.0)
    cos_psi = 1.0 - u1 * (1.0 - math.cos(radius))
    sin_psi = np.sqrt(np.maximum(0.0, 1.0 - cos_psi * cos_psi))
    azimuth = 2.0 * math.pi * u2
    # Frame around the centre direction c: (t, b, c) = Rz(φ) Ry(θ) (x, y, z), the same rotation as the sphere's
    # camera (docs/scenes.md), which is defined for every θ (also at the poles).
    ct, st, cp, sp = math.cos(theta), math.sin(theta), math.cos(phi), math.sin(phi)
    t = np.array([ct * cp, ct * sp, -st])
    b = np.array([-sp, cp, 0.0])
    c = np.array([st * cp, st * sp, ct])
    d = (sin_psi * np.cos(azimuth))[:, None] * t + (sin_psi * np.sin(azimuth))[:, None] * b + cos_psi[:, None] * c
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    thetas = np.arccos(np.clip(d[:, 2], -1.0, 1.0))
    phis = np.arctan2(d[:, 1], d[:, 0])
    if radius == 0.0:  # exactly the point light (no round-off from the rotation)
        thetas, phis = np.full(samples, theta), np.full(samples, phi)
    share = intensity / samples
    return [(float(a), float(p), share) for a, p in zip(thetas, phis)]


# ------------------------------------------------------------------------------------------------- tone mapping
def srgb_oetf(linear) -> np.ndarray:
    r"""The sRGB transfer function (IEC 61966-2-1:1999, Eq. 5): linear [0, 1] -> encoded [0, 1]
    (`brdffit.colour.srgb_encode`).

    V = 12.92 L for L <= 0.0031308, else 1.055 L^(1/2.4) − 0.055. Inputs are clipped to [0, 1] first.

    Arguments:
        linear: linear values, any shape.

    Returns:
        Encoded values in [0, 1], same shape.
    """
    return srgb_encode(linear)


def luminance(image) -> np.ndarray:
    """Luminance of an image: Y = 0.2126 R + 0.7152 G + 0.0722 B for 3 channels (BT.709), the channel itself for
    ``(H, W)`` or one channel, the mean over channels otherwise (spectral renders).

    Arguments:
        image: ``(..., C)`` or ``(H, W)``.

    Returns:
        ``(H, W)`` (the shape without the channel axis).
    """
    image = np.asarray(image, dtype=float)
    if image.ndim == 2:
        return image
    if image.shape[-1] == 3:
        return image @ _LUMA
    return image.mean(axis=-1)


def tonemap(hdr, method: str = "reinhard", exposure: float = 1.0) -> np.ndarray:
    r"""Map HDR radiance to display values in [0, 1] (sRGB-encoded).

    The radiance is first multiplied by ``exposure``. Then:

    - ``"reinhard"``: the global operator of Reinhard, Stark, Shirley & Ferwerda, "Photographic tone reproduction
      for digital images", SIGGRAPH 2002, Eq. 3: L_d = L / (1 + L) on the luminance L (`luminance`); each pixel's
      channels are scaled by L_d / L, which keeps the hue. Channels that end above 1 (saturated colours) are
      clipped.
    - ``"filmic"``: the ACES filmic curve fitted by K. Narkowicz (2015), per channel:
      f(x) = x (2.51 x + 0.03) / (x (2.43 x + 0.59) + 0.14), clipped to [0, 1].
    - ``"clamp"``: min(max(x, 0), 1).

    Finally the sRGB OETF (`srgb_oetf`, IEC 61966-2-1) encodes the values for display. Negative radiance is 0.

    Arguments:
        hdr: linear radiance, ``(H, W, C)`` or ``(H, W)``.
        method: one of `TONEMAPS`.
        exposure: multiplier applied before the curve (> 0).

    Returns:
        float64 array of the same shape with values in [0, 1].
    """
    if not float(exposure) > 0.0:
        raise ValueError(f"exposure must be > 0, got {exposure!r}")
    x = np.maximum(np.asarray(hdr, dtype=float) * float(exposure), 0.0)
    if method == "clamp":
        mapped = x
    elif method == "reinhard":
        lum = luminance(x)
        scale = np.where(lum > 0.0, 1.0 / (1.0 + lum), 1.0)  # L_d / L = 1 / (1 + L)
        mapped = x * (scale if x.ndim == 2 else scale[..., None])
    elif method == "filmic":
        a, b, c, d, e = _ACES
        mapped = x * (a * x + b) / (x * (c * x + d) + e)
    else:
        raise ValueError(f"unknown tone mapping {method!r}; use one of {', '.join(TONEMAPS)}")
    return srgb_oetf(mapped)


# ------------------------------------------------------------------------------------------------------- files
def _check_image(name: str, image, channels=(1, 3, 4)) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in channels) or image.size == 0:
        raise ValueError(f"{name} must be an image of shape (H, W) or (H, W, C) with C in {channels}, got shape "
                         f"{image.shape}")
    return image


def save_png(path, ldr) -> None:
    """Write a display image as an 8-bit PNG, atomically (a temporary file beside ``path``, then a rename).

    Arguments:
        path: the file to write (replaced only when the whole file was written).
        ldr: values in [0, 1] (e.g. from `tonemap`), ``(H, W)`` (grey), ``(H, W, 3)`` or ``(H, W, 4)``; values are
            clipped and rounded to the nearest of 256 levels.
    """
    ldr = _check_image("ldr", ldr, channels=(1, 3, 4))
    ldr = np.asarray(ldr, dtype=float)
    if not np.all(np.isfinite(ldr)):
        raise ValueError("ldr has values that are not finite")
    if ldr.ndim == 3 and ldr.shape[2] == 1:
        ldr = ldr[..., 0]
    if ldr.ndim == 2:
        ldr = np.repeat(ldr[..., None], 3, axis=2)
    pixels = np.round(np.clip(ldr, 0.0, 1.0) * 255.0).astype(np.uint8)
    import matplotlib.image  # a declared dependency; imported here so that rendering works without a display

    with atomic_path(path, suffix=".png") as tmp:
        matplotlib.image.imsave(tmp, pixels, format="png")


def save_npy(path, hdr) -> None:
    """Write an HDR image as a float32 ``.npy`` array (``numpy.save``), atomically.

    Arguments:
        path: the file to write (used as given: no ``.npy`` is appended).
        hdr: ``(H, W)`` or ``(H, W, C)`` linear radiance.
    """
    hdr = np.asarray(hdr)
    if hdr.ndim not in (2, 3) or hdr.size == 0:
        raise ValueError(f"hdr must be an image of shape (H, W) or (H, W, C), got shape {hdr.shape}")
    data = hdr.astype(np.float32)
    with atomic_path(path, suffix=".npy") as tmp:
        with open(tmp, "wb") as handle:
            np.save(handle, data, allow_pickle=False)


def difference(a, b, floor: float | None = None) -> np.ndarray:
    """Relative difference image of two renders: |Y(a) − Y(b)| / max(Y(b), floor) per pixel, on luminance.

    Arguments:
        a: a render, ``(H, W, C)`` or ``(H, W)``.
        b: the reference render, same shape.
        floor: the smallest denominator; default 1 % of the largest reference luminance (so the black background
            and dark pixels do not blow up). With an all-black reference the floor is 1.

    Returns:
        ``(H, W)`` relative difference (0 where both are black).
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape:
        raise ValueError(f"the two images must have the same shape, got {a.shape} and {b.shape}")
    ya, yb = luminance(a), luminance(b)
    if floor is None:
        top = float(np.max(np.abs(yb))) if yb.size else 0.0
        floor = 0.01 * top if top > 0.0 else 1.0
    if not float(floor) > 0.0:
        raise ValueError(f"floor must be > 0, got {floor!r}")
    return np.abs(ya - yb) / np.maximum(np.abs(yb), float(floor))
