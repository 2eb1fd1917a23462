"""Cycles' render of a Blender export against brdffit's render of the model, the comparison that
tests/test_export_blender.py asserts and scripts/renderer_gallery.py reports.

Cycles (tests/clients/render_blender.py, run by the Python that has `bpy`) averages each pixel over its square (a
box filter, `SAMPLES` samples a pixel); brdffit evaluates pixel centres, so its side is rendered at `SUPERSAMPLE`²
points a pixel and averaged the same way. The difference is the mean relative difference over the lit pixels
(luminance above 1% of the brightest) inside 0.9 of the sphere's radius, where the UV sphere's facets and the
silhouette's pixel coverage do not enter.
"""

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from brdffit.render import DEFAULT_LIGHTS, render_sphere

RESOLUTION, SAMPLES, SUPERSAMPLE = 96, 256, 4
CLIENT = Path(__file__).resolve().parent / "render_blender.py"


def cycles_render(script_text: str) -> np.ndarray:
    """Cycles' render of an exported material, ``(RESOLUTION, RESOLUTION, 3)`` linear radiance, top row first.

    Raises:
        RuntimeError: the client failed (its stderr's end in the message).
    """
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        (folder / "material.py").write_text(script_text)
        (folder / "settings.json").write_text(json.dumps({"resolution": RESOLUTION, "samples": SAMPLES,
                                                          "lights": [list(light) for light in DEFAULT_LIGHTS]}))
        run = subprocess.run([sys.executable, str(CLIENT), str(folder / "material.py"), str(folder / "settings.json"),
                              str(folder / "cycles.npy")], capture_output=True, text=True, timeout=300)
        if run.returncode != 0:
            raise RuntimeError(run.stderr[-3000:])
        return np.load(folder / "cycles.npy")


def brdffit_render(model) -> np.ndarray:
    """brdffit's render of ``model``, box-filtered as Cycles' pixels are."""
    fine = render_sphere(model, resolution=RESOLUTION * SUPERSAMPLE)
    return fine.reshape(RESOLUTION, SUPERSAMPLE, RESOLUTION, SUPERSAMPLE, -1).mean(axis=(1, 3))


def difference(cycles: np.ndarray, ours: np.ndarray) -> float:
    """The mean relative difference over the lit pixels inside 0.9 of the radius (module doc)."""
    centres = (np.arange(RESOLUTION) + 0.5) / RESOLUTION * 2.0 - 1.0
    u, w = np.meshgrid(centres, -centres)
    luminance = ours.mean(axis=-1)
    lit = (u * u + w * w < 0.81) & (luminance > 0.01 * luminance.max())
    return float(np.mean(np.abs(cycles - ours)[lit] / ours[lit]))
