"""Render a brdffit Blender export in Blender's Cycles, as `brdffit.render.render_sphere` renders the model.

Usage: python render_blender.py MATERIAL.py SETTINGS.json OUT.npy   (the Python of an environment with bpy)

SETTINGS: ``resolution`` (pixels a side), ``samples`` (per pixel), ``lights`` (brdffit's directional lights: the
world direction towards each light ``(theta, phi)`` in radians and its irradiance E). The scene is brdffit's sphere
preview: a unit sphere (a smooth UV sphere of 256 × 128 segments), an orthographic camera on +z looking down −z
(image right +x, up +y) framing [−1, 1]², each light a sun of strength E and angle 0 (a delta light: irradiance E
at normal incidence), no world light, direct lighting only (``max_bounces`` 0). Cycles runs on the CPU with a box
pixel filter (each pixel the mean over its square), no denoising and a fixed seed. The linear radiance of each
pixel, top row first, is saved as a ``(resolution, resolution, 3)`` float array.
"""

import importlib.util
import json
import math
import sys
import tempfile
from pathlib import Path

import bpy
import mathutils
import numpy as np


def main(material_script: str, settings_path: str, out: str) -> None:
    settings = json.loads(Path(settings_path).read_text())
    resolution = int(settings["resolution"])
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = int(settings["samples"])
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.cycles.max_bounces = 0
    scene.cycles.seed = 0
    scene.cycles.pixel_filter_type = "BOX"
    scene.render.resolution_x = scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    scene.world = None

    bpy.ops.mesh.primitive_uv_sphere_add(segments=256, ring_count=128, radius=1.0)
    sphere = bpy.context.active_object
    bpy.ops.object.shade_smooth()
    sphere.cycles.shadow_terminator_geometry_offset = 0.0  # no shadow-ray origin offset on smooth faces

    spec = importlib.util.spec_from_file_location("brdffit_material", material_script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    sphere.data.materials.append(module.build_material())

    camera = bpy.data.cameras.new("camera")
    camera.type = "ORTHO"
    camera.ortho_scale = 2.0
    camera_object = bpy.data.objects.new("camera", camera)
    camera_object.location = (0.0, 0.0, 10.0)
    scene.collection.objects.link(camera_object)
    scene.camera = camera_object

    for k, (theta, phi, irradiance) in enumerate(settings["lights"]):
        sun = bpy.data.lights.new(f"sun{k}", "SUN")
        sun.energy = float(irradiance)
        sun.angle = 0.0
        towards = mathutils.Vector((math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)))
        sun_object = bpy.data.objects.new(f"sun{k}", sun)
        sun_object.rotation_euler = towards.to_track_quat("Z", "Y").to_euler()  # the sun shines along its −z
        scene.collection.objects.link(sun_object)

    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    with tempfile.TemporaryDirectory() as folder:
        scene.render.filepath = str(Path(folder) / "render.exr")
        bpy.ops.render.render(write_still=True)
        image = bpy.data.images.load(scene.render.filepath)
        pixels = np.array(image.pixels[:], dtype=np.float64).reshape(resolution, resolution, 4)
    np.save(out, pixels[::-1, :, :3])  # Blender's rows start at the bottom


if __name__ == "__main__":
    main(*sys.argv[1:4])
