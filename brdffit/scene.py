r"""Scenes in which a material is judged and the radiance a BRDF gives in them.

A `Scene` is a flat list of (shading point, light) rows: for each row the direction to the light ``wi`` and to the
viewer ``wo`` in the local shading frame of the point (docs/conventions.md: z = normal, x = tangent), the
irradiance the light delivers at normal incidence (``intensity``) and the pixel the row contributes to. Under
directional or point lights the reflected radiance of a pixel is the sum over its rows (the reflection equation,
docs/conventions.md, with the incident radiance a delta in direction):

.. math::  L_o(p) = \sum_{\text{rows } r \text{ of } p} f_r(\omega_{i,r}, \omega_{o,r}) \, \cos\theta_{i,r} \, E_r

Constructors: `Scene.from_directions` / `Scene.from_angles` (a list of light/view pairs, one pixel each),
`Scene.sphere` (an orthographic view of a unit sphere under directional lights) and `Scene.plane` (a flat square
under directional or point lights). `scene_error` compares two radiance images (relative RMS, CIE76 ΔE*ab after
a common exposure, maximum relative error); `Scene.radiance_interpolated` shows a measurement in a scene through
`brdffit.interpolation.interpolate`, so that a fitted model can be compared with it there (docs/scenes.md).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import numpy as np

from .interpolation import _normalise_rows, interpolate
from .measurements import Measurements
from .models import Model, evaluate_dirs

__all__ = [
    "Scene",
    "scene_error",
    "linear_srgb_to_lab",
    "METRICS",
]

# Metrics understood by `scene_error`.
METRICS = ("relative", "delta-e", "max-relative")

# Rows of a scene evaluated at once by `Scene.radiance_of` (bounds the memory of large scenes).
_CHUNK = 1 << 18

# A pixel of the `max-relative` metric counts only where the reference exceeds this fraction of its maximum.
_MAX_RELATIVE_FLOOR = 0.01


def _unit_vectors(theta, phi) -> np.ndarray:
    theta, phi = np.broadcast_arrays(np.asarray(theta, dtype=float), np.asarray(phi, dtype=float))
    s = np.sin(theta)
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)], axis=-1)


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a)  # own copy
    a.flags.writeable = False
    return a


def _parse_lights(lights, allow_points: bool) -> list[tuple[str, np.ndarray, float]]:
    """Turn ``lights`` into ``[(kind, vector, intensity)]`` with kind ``"directional"`` or ``"point"``."""
    if isinstance(lights, tuple) and lights and not isinstance(lights[0], (tuple, list, np.ndarray)):
        lights = [lights]  # a single light given bare
    parsed = []
    for number, light in enumerate(lights):
        light = tuple(float(x) for x in light)
        if len(light) == 3:
            theta, phi, intensity = light
            parsed.append(("directional", _unit_vectors(theta, phi), intensity))
        elif len(light) == 4 and allow_points:
            parsed.append(("point", np.array(light[:3]), light[3]))
        else:
            what = "(theta, phi, intensity) or (x, y, z, intensity)" if allow_points else "(theta, phi, intensity)"
            raise ValueError(f"light {number}: expected {what}, got {light!r}")
        if not all(math.isfinite(x) for x in light) or light[-1] < 0:
            raise ValueError(f"light {number}: needs finite numbers and an intensity >= 0, got {light!r}")
    if not parsed:
        raise ValueError("a scene needs at least one light")
    return parsed


def _pixel_grid(resolution: int, half_width: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates (u to the right, v up) of a square image covering [-half_width, half_width]²."""
    resolution = int(resolution)
    if resolution < 1:
        raise ValueError(f"resolution must be a positive integer, got {resolution}")
    step = 2.0 * half_width / resolution
    centres = -half_width + (np.arange(resolution) + 0.5) * step
    u, v = np.meshgrid(centres, centres[::-1])  # row 0 is the top of the image (largest v)
    return u, v


@dataclasses.dataclass(frozen=True, eq=False)
class Scene:
    """Rows of (shading point, light) pairs, each adding f_r cosθi E to one pixel.

    Attributes:
        wi: ``(M, 3)`` unit directions to the light, in the local frame of the row's shading point.
        wo: ``(M, 3)`` unit directions to the viewer, local frame.
        intensity: ``(M,)`` irradiance the light delivers at normal incidence (E; radiance = f_r cosθi E).
        pixel: ``(M,)`` index in ``[0, n_pixels)`` of the pixel/sample each row contributes to; the rows of one
            pixel are summed (several lights).
        n_pixels: number of pixels; a pixel without rows (no light above its horizon) has radiance 0.
        shape: image shape ``(H, W)`` of sphere and plane scenes, None for direction lists.
        name: a short description for reports.
        mask: ``(H, W)`` bool, True at the image positions of the pixels, which are numbered in row-major order
            of the True entries; None for direction lists.
    """

    wi: np.ndarray
    wo: np.ndarray
    intensity: np.ndarray
    pixel: np.ndarray
    n_pixels: int
    shape: tuple | None
    name: str
    mask: np.ndarray | None = None

    def __post_init__(self):
        wi = np.asarray(self.wi, dtype=float).reshape(-1, 3)
        wo = np.asarray(self.wo, dtype=float).reshape(-1, 3)
        m = wi.shape[0]
        intensity = np.asarray(self.intensity, dtype=float).reshape(-1)
        pixel = np.asarray(self.pixel).reshape(-1)
        if wo.shape[0] != m or intensity.shape[0] != m or pixel.shape[0] != m:
            raise ValueError(f"scene rows disagree: wi {wi.shape}, wo {wo.shape}, intensity {intensity.shape}, "
                             f"pixel {pixel.shape}")
        n_pixels = int(self.n_pixels)
        if m and (not np.issubdtype(pixel.dtype, np.integer) or pixel.min() < 0 or pixel.max() >= n_pixels):
            raise ValueError(f"pixel indices must be integers in [0, {n_pixels})")
        shape, mask = self.shape, self.mask
        if shape is not None:
            shape = tuple(int(s) for s in shape)
            mask = np.ones(shape, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
            if mask.shape != shape or int(mask.sum()) != n_pixels:
                raise ValueError(f"mask must have shape {shape} and {n_pixels} True entries")
        elif mask is not None:
            raise ValueError("a mask needs an image shape")
        for name, value in (("wi", _readonly(wi)), ("wo", _readonly(wo)), ("intensity", _readonly(intensity)),
                            ("pixel", _readonly(pixel.astype(np.intp))), ("n_pixels", n_pixels), ("shape", shape),
                            ("mask", None if mask is None else _readonly(mask))):
            object.__setattr__(self, name, value)

    @property
    def n_rows(self) -> int:
        """The number of (point, light) rows M."""
        return int(self.wi.shape[0])

    def __repr__(self) -> str:
        image = "" if self.shape is None else f", shape={self.shape}"
        return f"Scene({self.name!r}, rows={self.n_rows}, pixels={self.n_pixels}{image})"

    # ---------------------------------------------------------------------------------------------- constructors
    @classmethod
    def from_directions(cls, wi, wo, intensity=None, name: str = "directions") -> "Scene":
        """A list of light/view pairs, each its own pixel (a gonio-reflectometer's view of the material).

        Arguments:
            wi: ``(M, 3)`` directions to the light, local frame (normalised here).
            wo: ``(M, 3)`` directions to the viewer.
            intensity: irradiance at normal incidence, scalar or ``(M,)``; default 1.
            name: a label.

        Returns:
            A `Scene` with ``pixel = arange(M)``, ``shape = None``.
        """
        wi, wo = _normalise_rows("wi", wi), _normalise_rows("wo", wo)
        if wi.shape != wo.shape:
            raise ValueError(f"wi and wo must have the same shape, got {wi.shape} and {wo.shape}")
        m = wi.shape[0]
        intensity = np.broadcast_to(np.asarray(1.0 if intensity is None else intensity, dtype=float), (m,))
        return cls(wi, wo, intensity, np.arange(m), m, None, name)

    @classmethod
    def from_angles(cls, theta_i, phi_i, theta_o, phi_o, intensity=None, name: str = "directions") -> "Scene":
        """`from_directions` with spherical angles (radians, broadcast against each other, flattened).

        Arguments:
            theta_i, phi_i: polar angle and azimuth of the direction to the light.
            theta_o, phi_o: the same for the viewer.
            intensity: irradiance at normal incidence, scalar or one per pair; default 1.
            name: a label.

        Returns:
            A `Scene` with one pixel per pair.
        """
        ti, pi_, to, po = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (theta_i, phi_i, theta_o, phi_o)))
        wi = _unit_vectors(ti.reshape(-1), pi_.reshape(-1))
        wo = _unit_vectors(to.reshape(-1), po.reshape(-1))
        if intensity is not None:
            intensity = np.broadcast_to(np.asarray(intensity, dtype=float), ti.shape).reshape(-1)
        return cls.from_directions(wi, wo, intensity, name=name)

    @classmethod
    def sphere(cls, lights, view=(0.0, 0.0), resolution: int = 64) -> "Scene":
        """An orthographic view of a unit sphere under directional lights (a material preview).

        The camera looks at the sphere from the world direction ``v = (sinθv cosφv, sinθv sinφv, cosθv)``; its
        image axes are ``right = Rz(φv) Ry(θv) x`` and ``up = Rz(φv) Ry(θv) y``, so with ``view=(0, 0)`` the viewer
        is on world +z, image right is world +x and image up is world +y. Pixel centres ``(u, w)`` of a
        ``resolution``² grid over [−1, 1]² are visible where u² + w² < 1; there the normal is
        ``n = u right + w up + √(1 − u² − w²) v``.

        Shading frame of a pixel: z = n, tangent x = normalise(up × n), y = n × x. The tangent runs along the
        circles of latitude of a globe whose north pole is at the top of the image (eastwards, i.e. to the right at
        the image centre); it is defined at every visible pixel (the poles lie on the silhouette).

        Arguments:
            lights: list of directional lights ``(theta, phi, intensity)``: the world direction towards the light
                (radians) and its irradiance at normal incidence.
            view: ``(theta_v, phi_v)``, the world direction towards the viewer (radians).
            resolution: image width and height in pixels.

        Returns:
            A `Scene` with ``shape = (resolution, resolution)``, one pixel per visible point of the sphere (``mask``
            is the disk) and one row per (pixel, light) with the light above the pixel's horizon (n·l > 0).
        """
        parsed = _parse_lights(lights, allow_points=False)
        theta_v, phi_v = (float(a) for a in view)
        ct, st, cp, sp = math.cos(theta_v), math.sin(theta_v), math.cos(phi_v), math.sin(phi_v)
        right = np.array([ct * cp, ct * sp, -st])  # Rz(φv) Ry(θv) x
        up = np.array([-sp, cp, 0.0])  # Rz(φv) Ry(θv) y
        toward_viewer = np.array([st * cp, st * sp, ct])  # Rz(φv) Ry(θv) z = right × up
        u, w = _pixel_grid(resolution, 1.0)
        r2 = u * u + w * w
        mask = r2 < 1.0
        u, w = u[mask], w[mask]
        nz = np.sqrt(1.0 - r2[mask])
        normal = u[:, None] * right + w[:, None] * up + nz[:, None] * toward_viewer
        tangent = np.cross(up, normal)
        tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)  # |up × n| = √(1 − w²) > 0 inside the disk
        bitangent = np.cross(normal, tangent)
        frame = np.stack([tangent, bitangent, normal], axis=1)  # (P, 3, 3): rows are the local axes in world
        wo_local = frame @ toward_viewer
        n_pix = normal.shape[0]
        rows_wi, rows_wo, rows_e, rows_pix = [], [], [], []
        for _, direction, intensity in parsed:
            wi_local = frame @ direction
            lit = wi_local[:, 2] > 0.0
            rows_wi.append(wi_local[lit])
            rows_wo.append(wo_local[lit])
            rows_e.append(np.full(int(lit.sum()), intensity))
            rows_pix.append(np.flatnonzero(lit))
        name = (f"sphere {int(resolution)}x{int(resolution)}, {len(parsed)} light(s), view "
                f"({math.degrees(theta_v):.4g}°, {math.degrees(phi_v):.4g}°)")
        return cls(np.concatenate(rows_wi), np.concatenate(rows_wo), np.concatenate(rows_e),
                   np.concatenate(rows_pix), n_pix, mask.shape, name, mask)

    @classmethod
    def plane(cls, lights, view=(0.0, 0.0), resolution: int = 64, size: float = 2.0,
              distance: float | None = None) -> "Scene":
        """A flat square of side ``size`` centred at the origin of the world xy plane (a material swatch).

        The world frame is the shading frame of every point (z = normal, x = tangent). The image is the square
        itself, sampled at ``resolution``² pixel centres ``(x, y, 0)`` (column 0 at x = −size/2, row 0 at
        y = +size/2): every pixel is a surface point of equal area, whatever the view, so the error metrics weigh
        the surface evenly (a camera would foreshorten it; this is its texture-space image).

        Viewer: ``view = (theta_v, phi_v)`` is the direction from the centre of the square towards the viewer.
        With ``distance=None`` the viewer is at infinity (orthographic: the same ωo at every point); with a
        distance it is a point at ``distance · v`` and ωo = normalise(eye − p) varies over the square, which
        shows a highlight moving across it.

        Lights: ``(theta, phi, intensity)`` is a directional light (world direction towards it, irradiance E at
        normal incidence); ``(x, y, z, intensity)`` is a point light of radiant intensity I (W/sr) at that
        position, which gives ωi = normalise(L − p) and E = I / |L − p|² (inverse-square law).

        Arguments:
            lights: list of lights as above.
            view: direction towards the viewer (radians); θv < π/2.
            resolution: image width and height in pixels.
            size: side of the square (same length unit as light positions and ``distance``).
            distance: distance of a point viewer from the centre, or None for a viewer at infinity.

        Returns:
            A `Scene` with ``shape = (resolution, resolution)``, every pixel part of the square, and one row per
            (pixel, light) with the light above the horizon.
        """
        parsed = _parse_lights(lights, allow_points=True)
        theta_v, phi_v = (float(a) for a in view)
        if not 0.0 <= theta_v < 0.5 * math.pi:
            raise ValueError(f"the viewer must be above the plane: theta_v in [0, π/2), got {theta_v!r}")
        size = float(size)
        if not size > 0.0:
            raise ValueError(f"size must be > 0, got {size!r}")
        x, y = _pixel_grid(resolution, 0.5 * size)
        points = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
        toward_viewer = _unit_vectors(theta_v, phi_v)
        if distance is None:
            wo = np.broadcast_to(toward_viewer, points.shape)
        else:
            distance = float(distance)
            if not distance > 0.0:
                raise ValueError(f"distance must be > 0 or None, got {distance!r}")
            to_eye = distance * toward_viewer - points
            wo = to_eye / np.linalg.norm(to_eye, axis=1, keepdims=True)
        rows_wi, rows_wo, rows_e, rows_pix = [], [], [], []
        for kind, vector, intensity in parsed:
            if kind == "directional":
                wi = np.broadcast_to(vector, points.shape)
                e = np.full(points.shape[0], intensity)
            else:
                to_light = vector - points
                d2 = np.sum(to_light * to_light, axis=1)
                with np.errstate(divide="ignore", invalid="ignore"):
                    wi = to_light / np.sqrt(d2)[:, None]
                    e = intensity / d2
            lit = (wi[:, 2] > 0.0) & (wo[:, 2] > 0.0)
            rows_wi.append(wi[lit])
            rows_wo.append(wo[lit])
            rows_e.append(e[lit])
            rows_pix.append(np.flatnonzero(lit))
        res = int(resolution)
        viewer = "at infinity" if distance is None else f"at distance {distance:.4g}"
        name = (f"plane {res}x{res} of size {size:.4g}, {len(parsed)} light(s), viewer {viewer} towards "
                f"({math.degrees(theta_v):.4g}°, {math.degrees(phi_v):.4g}°)")
        return cls(np.concatenate(rows_wi), np.concatenate(rows_wo), np.concatenate(rows_e),
                   np.concatenate(rows_pix), res * res, (res, res), name, np.ones((res, res), dtype=bool))

    # ------------------------------------------------------------------------------------------------- radiance
    def _row_weight(self) -> np.ndarray:
        # cosθi E of each row; the cosine is clamped at 0 so that a direction list with a light below the horizon
        # adds nothing even for values that are not zero there.
        return np.maximum(self.wi[:, 2], 0.0) * self.intensity

    def radiance(self, f):
        r"""Radiance of every pixel: L_p = Σ_{rows r of p} f_r cosθi,r E_r (reflection equation for delta lights).

        Arguments:
            f: BRDF values (1/sr, without the cosine) at the rows, shape ``(M, C)`` or ``(M,)``. A JAX array gives
                a JAX result (differentiable, summed with `jax.ops.segment_sum`); anything else gives NumPy.

        Returns:
            ``(n_pixels, C)`` radiance (in the unit of ``intensity`` per sr); pixels without rows are 0.
        """
        weight = self._row_weight()
        if isinstance(f, jax.Array):
            f2 = f[:, None] if f.ndim == 1 else f
            self._check_rows(f2.shape)
            return jax.ops.segment_sum(f2 * weight[:, None].astype(f2.dtype), self.pixel,
                                       num_segments=self.n_pixels)
        f2 = np.asarray(f, dtype=float)
        f2 = f2[:, None] if f2.ndim == 1 else f2
        self._check_rows(f2.shape)
        contrib = f2 * weight[:, None]
        out = np.empty((self.n_pixels, f2.shape[1]))
        for c in range(f2.shape[1]):
            out[:, c] = np.bincount(self.pixel, weights=contrib[:, c], minlength=self.n_pixels)
        return out

    def _check_rows(self, shape):
        if len(shape) != 2 or shape[0] != self.n_rows:
            raise ValueError(f"BRDF values must have shape ({self.n_rows}, C) for this scene, got {tuple(shape)}")

    def radiance_of(self, model: Model) -> np.ndarray:
        """Radiance of a model in this scene: `radiance` of `brdffit.evaluate_dirs` at the rows.

        Arguments:
            model: a `brdffit.Model`.

        Returns:
            ``(n_pixels, model.channels)`` NumPy radiance.
        """
        parts = [np.asarray(evaluate_dirs(model, self.wi[s:s + _CHUNK], self.wo[s:s + _CHUNK]))
                 for s in range(0, self.n_rows, _CHUNK)]
        f = np.concatenate(parts) if parts else np.zeros((0, model.channels))
        return self.radiance(f)

    def radiance_interpolated(self, measurements: Measurements, k: int = 8, isotropic: bool = True) -> np.ndarray:
        """Radiance of measured data in this scene: `radiance` of `brdffit.interpolation.interpolate` at the rows.

        Arguments:
            measurements: the measured BRDF.
            k, isotropic: as for `brdffit.interpolation.interpolate`.

        Returns:
            ``(n_pixels, C)`` radiance.
        """
        return self.radiance(interpolate(measurements, self.wi, self.wo, k=k, isotropic=isotropic))

    def image(self, radiance) -> np.ndarray:
        """Place per-pixel radiance into the image of a sphere or plane scene.

        Arguments:
            radiance: ``(n_pixels, C)`` (or ``(n_pixels,)``) from `radiance` / `radiance_of`.

        Returns:
            ``(H, W, C)`` (or ``(H, W)``) array, 0 outside the object.

        Raises:
            ValueError: for a direction-list scene (it has no image) or radiance of the wrong length.
        """
        if self.shape is None:
            raise ValueError(f"scene {self.name!r} is a list of directions and has no image")
        radiance = np.asarray(radiance)
        if radiance.shape[:1] != (self.n_pixels,):
            raise ValueError(f"radiance must have {self.n_pixels} rows (one per pixel), got shape {radiance.shape}")
        out = np.zeros(self.shape + radiance.shape[1:], dtype=radiance.dtype)
        out[self.mask] = radiance
        return out


# ---------------------------------------------------------------------------------------------------------------
# Error metrics
# ---------------------------------------------------------------------------------------------------------------

# Linear sRGB -> CIE XYZ, IEC 61966-2-1:1999 Eq. 7 (primaries of ITU-R BT.709, white D65).
_SRGB_TO_XYZ = np.array([
    [0.4124, 0.3576, 0.1805],
    [0.2126, 0.7152, 0.0722],
    [0.0193, 0.1192, 0.9505],
])
# Reference white: XYZ of linear sRGB (1, 1, 1), i.e. D65 as the 4-digit matrix reproduces it
# (0.9505, 1.0000, 1.0890; CIE 15:2004 Table T.3 gives 0.95047, 1, 1.08883). Using the matrix's own white maps
# sRGB white exactly to L* = 100, a* = b* = 0.
_WHITE = _SRGB_TO_XYZ.sum(axis=1)
# Luminance Y of linear sRGB: the middle row of the matrix.
_LUMINANCE = _SRGB_TO_XYZ[1]


def _lab_f(t):
    # CIE 15:2004 Eq. 8.3-8.5: f(t) = t^(1/3) for t > (6/29)³, else t / (3 (6/29)²) + 4/29.
    delta = 6.0 / 29.0
    return np.where(t > delta ** 3, np.cbrt(t), t / (3.0 * delta * delta) + 4.0 / 29.0)


def linear_srgb_to_lab(rgb) -> np.ndarray:
    r"""CIE 1976 L*a*b* of linear sRGB values (D65 white).

    XYZ = M rgb with the IEC 61966-2-1 matrix; then (CIE 15:2004, Sec. 8.2.1)
    L* = 116 f(Y/Yn) − 16, a* = 500 (f(X/Xn) − f(Y/Yn)), b* = 200 (f(Y/Yn) − f(Z/Zn)), with (Xn, Yn, Zn) the XYZ
    of rgb = (1, 1, 1). The input is linear (no sRGB transfer curve); values above 1 give L* > 100.

    Arguments:
        rgb: linear sRGB, shape ``(..., 3)``.

    Returns:
        ``(..., 3)`` array of (L*, a*, b*).
    """
    rgb = np.asarray(rgb, dtype=float)
    if rgb.shape[-1:] != (3,):
        raise ValueError(f"linear sRGB needs a last axis of 3 channels, got shape {rgb.shape}")
    fx, fy, fz = (_lab_f((rgb @ _SRGB_TO_XYZ.T)[..., k] / _WHITE[k]) for k in range(3))
    return np.stack([116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)], axis=-1)


def _zero_reference(radiance) -> float:
    return 0.0 if not np.any(radiance) else math.inf


def scene_error(radiance, reference, metric: str = "relative") -> float:
    r"""How far a radiance image is from a reference image of the same scene.

    Metrics:

    - ``"relative"``: relative RMS radiance error √(Σ (L − L_ref)² / Σ L_ref²) over all pixels and channels.
    - ``"delta-e"``: mean CIE76 colour difference ΔE*ab = |Lab − Lab_ref| over the pixels where the reference is
      not zero (any channel), treating radiance as linear sRGB (3 channels required). Both images are first
      multiplied by the same exposure 1 / Y99, where Y99 is the 99th percentile (NumPy's linear interpolation) of
      the reference luminance Y = 0.2126 R + 0.7152 G + 0.0722 B over those pixels, so that the reference's
      99th-percentile pixel has Y = 1 (L* = 100). Nothing is clipped: brighter highlights get L* > 100 and their
      differences still count. ΔE ≈ 1 is a just-noticeable difference, ΔE ≈ 2-3 noticeable side by side.
    - ``"max-relative"``: max over pixels and channels of |L − L_ref| / L_ref, over the entries where the reference
      exceeds 1 % of its maximum (so dark pixels do not dominate).

    An all-zero reference gives 0 when the radiance is zero too and inf otherwise.

    Arguments:
        radiance: radiance of the candidate, ``(n_pixels, C)`` or an image ``(H, W, C)``.
        reference: the reference, the same shape.
        metric: one of `METRICS`.

    Returns:
        The error as a float (a fraction for the relative metrics, ΔE*ab units for ``"delta-e"``).
    """
    radiance = np.asarray(radiance, dtype=float)
    reference = np.asarray(reference, dtype=float)
    if radiance.shape != reference.shape:
        raise ValueError(f"radiance and reference must have the same shape, got {radiance.shape} and "
                         f"{reference.shape}")
    if metric == "relative":
        denom = float(np.sum(reference * reference))
        if denom == 0.0:
            return _zero_reference(radiance)
        return math.sqrt(float(np.sum((radiance - reference) ** 2)) / denom)
    if metric == "max-relative":
        top = float(np.max(reference)) if reference.size else 0.0
        if top <= 0.0:
            return _zero_reference(radiance)
        keep = reference > _MAX_RELATIVE_FLOOR * top
        return float(np.max(np.abs(radiance[keep] - reference[keep]) / reference[keep]))
    if metric == "delta-e":
        if radiance.shape[-1:] != (3,):
            raise ValueError(f"the delta-e metric needs 3 channels (linear sRGB), got shape {radiance.shape}")
        rad = radiance.reshape(-1, 3)
        ref = reference.reshape(-1, 3)
        lit = np.any(ref != 0.0, axis=1)
        if not lit.any():
            return _zero_reference(rad)
        luminance = ref[lit] @ _LUMINANCE
        y99 = float(np.percentile(luminance, 99.0))
        if not y99 > 0.0:
            y99 = float(np.max(np.abs(luminance)))
        if not y99 > 0.0:
            raise ValueError("the reference has no positive luminance; the delta-e exposure is undefined")
        lab = linear_srgb_to_lab(rad[lit] / y99)
        lab_ref = linear_srgb_to_lab(ref[lit] / y99)
        return float(np.mean(np.linalg.norm(lab - lab_ref, axis=1)))
    raise ValueError(f"unknown metric {metric!r}; use one of {', '.join(METRICS)}")
