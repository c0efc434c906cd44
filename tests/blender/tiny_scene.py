"""A tiny Blender scene for the tests, run in Blender's environment:

    python tiny_scene.py OUT_DIR inputs|plain|nojitter|reference|reference-after-inputs|volume

A checker floor, a metal cube that moves on its own, a sun, a world colour, a camera that
dollies and trucks: set up by ``jnds_deploy.blender.configure`` (``plain``: not at all) and rendered
by Blender's own ``render(animation=True)``; ``volume``: as ``inputs``, with a block of scattering
medium in front of the cube."""

import math
import sys

import bpy

from jnds_deploy import blender as jb

W, H, FRAMES = 64, 40, 4


def build():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    s = bpy.context.scene
    s.render.engine = "CYCLES"
    s.render.resolution_x, s.render.resolution_y, s.render.resolution_percentage = W, H, 100
    s.frame_start, s.frame_end = 1, FRAMES
    s.cycles.seed = 3
    world = bpy.data.worlds.new("w")
    s.world = world
    world.color = (0.3, 0.4, 0.6)
    bpy.ops.mesh.primitive_plane_add(size=20)
    floor = bpy.data.materials.new("floor")
    floor.use_nodes = True
    bsdf = floor.node_tree.nodes["Principled BSDF"]
    tex = floor.node_tree.nodes.new("ShaderNodeTexChecker")
    tex.inputs["Scale"].default_value = 6
    floor.node_tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = 0.6
    bpy.context.object.data.materials.append(floor)
    bpy.ops.mesh.primitive_cube_add(size=1.5, location=(0, 0, 0.75))
    cube = bpy.context.object
    metal = bpy.data.materials.new("metal")
    metal.use_nodes = True
    mb = metal.node_tree.nodes["Principled BSDF"]
    mb.inputs["Metallic"].default_value = 1.0
    mb.inputs["Roughness"].default_value = 0.3
    cube.data.materials.append(metal)
    for f, x in ((0, -1.0), (FRAMES + 1, 1.0)):
        cube.location.x = x
        cube.keyframe_insert("location", frame=f)
    bpy.ops.object.light_add(type="SUN", rotation=(0.6, 0.2, 0.3))
    bpy.context.object.data.energy = 3
    bpy.ops.object.camera_add(location=(0, -8, 4), rotation=(math.radians(65), 0, 0))
    cam = bpy.context.object
    s.camera = cam
    for f, x, y in ((0, -1.0, -8.0), (FRAMES + 1, 1.5, -7.0)):  # dolly and truck
        cam.location.x, cam.location.y = x, y
        cam.keyframe_insert("location", frame=f)
    for obj in (cube, cam):
        for fc in jb._fcurves(obj.animation_data.action):
            for k in fc.keyframe_points:
                k.interpolation = "LINEAR"
    return s


def add_volume():
    """A cube of Principled Volume (density 3 per metre) over the left half of the view."""
    bpy.ops.mesh.primitive_cube_add(size=2, location=(-1.5, -4, 2))
    fog = bpy.data.materials.new("fog")
    fog.use_nodes = True
    nodes = fog.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    vol = nodes.new("ShaderNodeVolumePrincipled")
    vol.inputs["Density"].default_value = 3.0
    fog.node_tree.links.new(vol.outputs[0], nodes["Material Output"].inputs["Volume"])
    bpy.context.object.data.materials.append(fog)


if __name__ == "__main__":
    out, mode = sys.argv[1], sys.argv[2]
    scene = build()
    if mode == "plain":
        scene.render.image_settings.media_type = "MULTI_LAYER_IMAGE"
        scene.render.image_settings.file_format = "OPEN_EXR_MULTILAYER"
        scene.render.filepath = out + "/"
    elif mode == "reference":
        jb.configure_reference(scene, output=out + "/", spp=4)
    elif mode == "reference-after-inputs":  # as the README shows: no restore in between
        jb.configure(scene, output=out + "/")
        scene.frame_set(3)  # leaves a jittered lens shift evaluated
        jb.configure_reference(scene, output=out + "/", spp=4)
    else:
        if mode == "volume":
            add_volume()
        changes = jb.configure(scene, output=out + "/", jitter_frames=mode in ("inputs", "volume"))
        assert changes.settings and changes.nodes and changes.aov
    bpy.ops.render.render(animation=True)
