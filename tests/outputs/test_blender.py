"""``material.glb`` in Blender: its glTF importer builds the material we mean, and it renders.

Needs Blender's Python module ``bpy``, a wheel of about 500 MB that is deliberately not a test
extra; without it the test skips and says so.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image

from freqbrdf.capture.mesh import uv_sphere_mesh
from freqbrdf.model.materials import MaterialMaps
from freqbrdf.outputs import gltf


def linked_from(socket):
    """The (node, output socket) feeding an input socket; fails when nothing is linked."""
    assert socket.is_linked, f"nothing is linked to {socket.name!r}"
    link = socket.links[0]
    return link.from_node, link.from_socket


def image_node_behind(socket):
    """The image texture node feeding a socket, through at most one Separate Color node."""
    node, output = linked_from(socket)
    if node.type in ("SEPARATE_COLOR", "SEPRGB"):
        node, _ = linked_from(node.inputs[0])
    assert node.type == "TEX_IMAGE", node.type
    return node


def test_material_glb_round_trips_through_blender(tmp_path):
    bpy = pytest.importorskip(
        "bpy", reason="needs Blender's Python module bpy (a ~500 MB wheel, not a test extra: pip install bpy)"
    )
    size = 16
    maps = MaterialMaps(
        base_color=np.full((size, size, 3), 0.5, np.float32),
        roughness=np.full((size, size), 0.4, np.float32),
        metallic=np.full((size, size), 0.2, np.float32),
    )
    glb = tmp_path / "material.glb"
    gltf.write_gltf(glb, uv_sphere_mesh(32, 16), maps)

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=str(glb))
    material = bpy.data.materials["freqbrdf"]
    assert material.use_nodes
    principled = [node for node in material.node_tree.nodes if node.type == "BSDF_PRINCIPLED"]
    assert len(principled) == 1
    bsdf = principled[0]

    # Base colour: the sRGB-encoded texture, straight into Base Color.
    base = image_node_behind(bsdf.inputs["Base Color"])
    assert base.image.colorspace_settings.name == "sRGB"
    # Metallic-roughness: one Non-Color texture through Separate Color, G -> Roughness, B -> Metallic.
    roughness_node, roughness_output = linked_from(bsdf.inputs["Roughness"])
    metallic_node, metallic_output = linked_from(bsdf.inputs["Metallic"])
    assert roughness_node.type in ("SEPARATE_COLOR", "SEPRGB") and roughness_node == metallic_node
    assert roughness_output.name in ("Green", "G") and metallic_output.name in ("Blue", "B")
    packed = image_node_behind(bsdf.inputs["Roughness"])
    assert packed.image.colorspace_settings.name == "Non-Color"
    assert packed.image != base.image

    # A small render under a white world: the object is there and not black.
    scene = bpy.context.scene
    world = bpy.data.worlds.new("white")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    scene.world = world
    camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    camera.location = (0.0, -4.0, 0.0)
    camera.rotation_euler = (math.pi / 2, 0.0, 0.0)  # looks along +y, at the origin
    scene.collection.objects.link(camera)
    scene.camera = camera
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 8
    scene.render.resolution_x = scene.render.resolution_y = 64
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = True  # alpha marks the object
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGBA"
    scene.render.filepath = str(tmp_path / "render.png")
    bpy.ops.render.render(write_still=True)

    pixels = np.asarray(Image.open(tmp_path / "render.png").convert("RGBA"), np.float32) / 255.0
    covered = pixels[..., 3] > 0.5
    assert covered.mean() > 0.05, "the object is not in the picture"
    assert pixels[covered, :3].mean() > 0.1, "the object renders black"
