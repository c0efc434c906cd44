"""Procedural Cycles scenes for training and test data, built with ``bpy`` (Blender side:
bpy, the standard library and this package's pure-Python modules), and the driver that renders one sequence.

Deliberately unlike the Mitsuba scenes (``render.scene``): rooms lit by a sun and sky
through a window, dark rooms lit by small emissive objects, collections of metals and
glossy dielectrics, walls and floors with brick, checker, noise and voronoi textures,
thin geometry, and objects that move on their own (not only the camera). Deterministic
per seed: one ``random.Random(seed)``, emitters are icospheres (Cycles' light sampling
varied from run to run with UV spheres), path guiding off, a fixed noise seed.

Run by ``jnds render --engine cycles`` (``blender.render``) in Blender's environment::

    python -m jnds_deploy.blender.scenes CONFIG_JSON RAW_DIR [REF_DIR]

It renders frame by frame into RAW_DIR (inputs, ``blender.configure``) and REF_DIR (the
reference, ``blender.configure_reference``), skipping frames already there (each file is
written under a temporary name and renamed), and prints one ``jnds-frame`` line per frame.
"""

from __future__ import annotations

import json
import math
import os
import random
import sys
import time

from ..errors import ConfigError

# the kinds the training and validation sets are made of
CYCLES_TRAIN_KINDS = ("sunroom", "darkroom", "metals", "textures")
# training-only kinds, added on request (``jnds dataset --mixed-sequences``): ``mixed``
# draws each ingredient of the training kinds at random and combines them (world, room or
# open ground, light rig, materials), for variety rather than another fixed layout; ``lights``
# (``--lights-sequences``) does the same with every sort of light Blender has: spot lights,
# area lights of each shape and emissive meshes other than small spheres besides mixed's;
# ``interior`` (``--interior-sequences``) is a closed room lit mostly by bounced light;
# ``detail`` (``--detail-sequences``) bump-mapped surfaces and dense, curved shapes;
# ``layers`` (``--layers-sequences``) the Principled BSDF's other layers (sheen, coat,
# subsurface, anisotropy, thin film, transmission) mixed on smooth shapes, and meshes of struts;
# ``glass`` (``--glass-sequences``) thin-walled, solid, frosted and tinted glass and
# water, caustics; ``print`` (``--print-sequences``) lettering and signs of every size;
# ``media`` (``--media-sequences``) participating media: haze, drifting mist, smoke, glow
CYCLES_EXTRA_KINDS = ("mixed", "lights", "interior", "detail", "layers", "glass", "print", "media")
# kinds only the test set is made of (render.dataset): built apart from the training kinds,
# so that the test measures scenes the model never saw the like of. gallery: a long hall
# under strip lights, a polished floor, finely textured panels, sculptures; night: an
# outdoor ground under a dark sky, spot lights and small very bright neon tubes
CYCLES_TEST_KINDS = ("gallery", "night")
# the held-out splits (render.dataset), {split: its kinds}, in the order they were written.
# Each split's kinds were built apart from every kind above and every split before it, with
# what none of them has, after the split before it had been looked at to choose something:
# - holdout, after the light sorts of the lights kind had been read off the test set's
#   failures. atrium: a tall court lit by the sun and sky through a skylight, rings of
#   columns and a thin railing, a still pool; workshop: a dark room under shaded pendant
#   lamps, a bench of many small props, a spinning fan;
# - street-studio, after holdout had been looked at (the firefly clamp's idea came from it).
#   street: a wet road at dusk between lit facades, street lamps, cars whose headlights move
#   with them; studio: a cyclorama under large softboxes, a turntable, materials no other
#   kind uses (subsurface, sheen, coat, anisotropic metal, thin-film) and a wire mesh;
# - grove-haze, after street-studio's studio had been looked at to choose training data (the
#   ``layers`` kind). grove: trees of leaf cards in a translucent material, grass of thin
#   blades, dappled sun through swaying crowns; haze: a closed hall filled with a scattering
#   volume, spot lights and daylight drawing beams through it;
# - bathroom-fur, after grove-haze's haze had been seen failing and the ``media`` training
#   kind written for it. bathroom: a small tiled room of large plane mirrors (facing, on some
#   draws), chrome, ceramic, a sliding frosted screen; fur: shapes and a rug coated in hair
#   strands (Principled Hair BSDF, curves a fraction of a pixel thick)
CYCLES_HOLDOUT_KINDS = {
    "holdout": ("atrium", "workshop"),
    "street-studio": ("street", "studio"),
    "grove-haze": ("grove", "haze"),
    "bathroom-fur": ("bathroom", "fur"),
}
# kinds of the ghosting sets (docs/ghosting.md): what provokes a history-reusing denoiser to
# ghost. plain: a user's first scene, default Principled cubes and spheres on a plain or
# checkered floor under one area light, a near-mirror white cube, a ball rolling fast across
# the view, a sliding cube, a thin pole and, on some draws, a moving lamp; the camera moves
# twice as fast as in the other kinds
CYCLES_GHOST_KINDS = ("plain",)
CYCLES_SCENE_KINDS = (
    CYCLES_TRAIN_KINDS
    + CYCLES_EXTRA_KINDS
    + CYCLES_TEST_KINDS
    + sum(CYCLES_HOLDOUT_KINDS.values(), ())
    + CYCLES_GHOST_KINDS
)
TEXTURES = ("brick", "checker", "noise", "voronoi")


def _material(name, rng, *, metal=False, rough=None, color=None, texture=None, emission=0.0, glass=False):
    import bpy

    m = bpy.data.materials.new(name)
    m.use_nodes = True
    nodes, links = m.node_tree.nodes, m.node_tree.links
    bsdf = nodes["Principled BSDF"]
    base = color or [rng.uniform(0.05, 0.9) for _ in range(3)]
    bsdf.inputs["Base Color"].default_value = (*base, 1.0)
    bsdf.inputs["Roughness"].default_value = rng.uniform(0.02, 0.9) if rough is None else rough
    bsdf.inputs["Metallic"].default_value = 1.0 if metal else 0.0
    if glass:
        bsdf.inputs["Transmission Weight"].default_value = 1.0
    if texture:
        tex = _texture(nodes, texture, rng)
        ramp = nodes.new("ShaderNodeMix")
        ramp.data_type = "RGBA"
        ramp.inputs[6].default_value = (*[rng.uniform(0.05, 0.9) for _ in range(3)], 1.0)
        ramp.inputs[7].default_value = (*base, 1.0)
        links.new(tex.outputs["Fac"] if "Fac" in tex.outputs else tex.outputs[0], ramp.inputs[0])
        links.new(ramp.outputs[2], bsdf.inputs["Base Color"])
        if rng.random() < 0.5:  # roughness varying with the texture too
            rmap = nodes.new("ShaderNodeMapRange")
            rmap.inputs["To Min"].default_value = rng.uniform(0.05, 0.4)
            rmap.inputs["To Max"].default_value = rng.uniform(0.5, 1.0)
            links.new(tex.outputs["Fac"] if "Fac" in tex.outputs else tex.outputs[0], rmap.inputs["Value"])
            links.new(rmap.outputs["Result"], bsdf.inputs["Roughness"])
    if emission:
        bsdf.inputs["Emission Color"].default_value = (*[rng.uniform(0.6, 1.0) for _ in range(3)], 1.0)
        bsdf.inputs["Emission Strength"].default_value = emission
    return m


def _texture(nodes, kind, rng):
    scale = rng.uniform(4.0, 30.0)
    if kind == "brick":
        t = nodes.new("ShaderNodeTexBrick")
        t.inputs["Scale"].default_value = scale / 4
        t.inputs["Mortar Size"].default_value = rng.uniform(0.005, 0.03)
    elif kind == "checker":
        t = nodes.new("ShaderNodeTexChecker")
        t.inputs["Scale"].default_value = scale
    elif kind == "noise":
        t = nodes.new("ShaderNodeTexNoise")
        t.inputs["Scale"].default_value = scale
        t.inputs["Detail"].default_value = rng.uniform(2, 12)
    elif kind == "wave":  # bands or rings, distorted: wood grain, ripples, corrugation
        t = nodes.new("ShaderNodeTexWave")
        t.wave_type = rng.choice(("BANDS", "RINGS"))
        t.inputs["Scale"].default_value = scale / 2
        t.inputs["Distortion"].default_value = rng.uniform(0.0, 8.0)
    else:
        t = nodes.new("ShaderNodeTexVoronoi")
        t.inputs["Scale"].default_value = scale
        return t  # outputs Distance first
    return t


def _box(name, size, location, material, rotation=(0, 0, 0)):
    import bpy

    bpy.ops.mesh.primitive_cube_add(size=1, location=location, rotation=rotation)
    obj = bpy.context.object
    obj.name = name
    obj.scale = size
    obj.data.materials.append(material)
    return obj


def _emitter(name, radius, location, material):
    """An icosphere emitter: Cycles' light sampling is deterministic with these."""
    import bpy

    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=2, radius=radius, location=location)
    obj = bpy.context.object
    obj.name = name
    obj.data.materials.append(material)
    return obj


def _objects(rng, n, extent, metal_share, textured_share, frames):
    """Props on the floor, some of them moving (location and rotation keyed linearly)."""
    import bpy

    moving = []
    for i in range(n):
        kind = rng.choice(("cube", "sphere", "cylinder", "torus", "cone", "thin"))
        loc = (rng.uniform(-extent, extent), rng.uniform(-extent, extent), 0.0)
        s = rng.uniform(0.3, 1.1)
        if kind == "cube":
            bpy.ops.mesh.primitive_cube_add(size=s, location=(loc[0], loc[1], s / 2))
        elif kind == "sphere":
            bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=4, radius=s / 2, location=(loc[0], loc[1], s / 2))
            bpy.ops.object.shade_smooth()
        elif kind == "cylinder":
            bpy.ops.mesh.primitive_cylinder_add(radius=s / 3, depth=s * 1.5, location=(loc[0], loc[1], s * 0.75))
        elif kind == "torus":
            bpy.ops.mesh.primitive_torus_add(
                major_radius=s / 2,
                minor_radius=s / 8,
                location=(loc[0], loc[1], s / 2),
                rotation=(rng.uniform(0, 3), 0, 0),
            )
            bpy.ops.object.shade_smooth()
        elif kind == "cone":
            bpy.ops.mesh.primitive_cone_add(radius1=s / 2, depth=s, location=(loc[0], loc[1], s / 2))
        else:  # thin geometry: a pole or a wire frame a pixel or two wide
            bpy.ops.mesh.primitive_cylinder_add(
                radius=rng.uniform(0.01, 0.03),
                depth=rng.uniform(1.0, 3.0),
                location=(loc[0], loc[1], 1.0),
                rotation=(rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), 0),
            )
        obj = bpy.context.object
        r = rng.random()
        mat = _material(
            f"m{i}",
            rng,
            metal=r < metal_share,
            texture=rng.choice(TEXTURES) if rng.random() < textured_share else None,
            glass=metal_share <= r < metal_share + 0.1,
        )
        obj.data.materials.append(mat)
        if rng.random() < 0.4:  # moves on its own
            d = (rng.uniform(-1.5, 1.5), rng.uniform(-1.5, 1.5))
            spin = rng.uniform(-1.5, 1.5)
            for f, t in ((0, 0.0), (frames + 1, 1.0)):
                obj.location = (obj.location[0] + d[0] * t, obj.location[1] + d[1] * t, obj.location[2])
                obj.rotation_euler[2] = spin * t
                obj.keyframe_insert("location", frame=f)
                obj.keyframe_insert("rotation_euler", frame=f)
                obj.location = (obj.location[0] - d[0] * t, obj.location[1] - d[1] * t, obj.location[2])
            moving.append(obj)
    return moving


def _room(rng, half, height, window: bool, texture_walls: bool):
    walls = _material(
        "walls", rng, rough=rng.uniform(0.5, 1.0), texture=rng.choice(TEXTURES) if texture_walls else None
    )
    floor = _material("floor", rng, rough=rng.uniform(0.2, 0.9), texture=rng.choice(TEXTURES))
    t = 0.1
    _box("floor", (2 * half, 2 * half, t), (0, 0, -t / 2), floor)
    _box("ceiling", (2 * half, 2 * half, t), (0, 0, height + t / 2), walls)
    _box("wall_w", (t, 2 * half, height), (-half, 0, height / 2), walls)
    _box("wall_e", (t, 2 * half, height), (half, 0, height / 2), walls)
    _box("wall_s", (2 * half, t, height), (0, -half - 1.0, height / 2), walls)
    if not window:
        _box("wall_n", (2 * half, t, height), (0, half, height / 2), walls)
        return
    # the north wall with a window: four boxes around the opening
    w0, w1, z0, z1 = -half * 0.5, half * 0.4, height * 0.3, height * 0.85
    _box("wall_n_l", (w0 + half, t, height), ((-half + w0) / 2, half, height / 2), walls)
    _box("wall_n_r", (half - w1, t, height), ((w1 + half) / 2, half, height / 2), walls)
    _box("wall_n_b", (w1 - w0, t, z0), ((w0 + w1) / 2, half, z0 / 2), walls)
    _box("wall_n_t", (w1 - w0, t, height - z1), ((w0 + w1) / 2, half, (z1 + height) / 2), walls)
    # thin geometry: window bars
    bar = _material("bars", rng, metal=True, rough=0.3)
    for k in range(1, 4):
        x = w0 + (w1 - w0) * k / 4
        _box(f"bar{k}", (0.03, 0.03, z1 - z0), (x, half, (z0 + z1) / 2), bar)


def _world(scene, rng, kind):
    import bpy

    world = bpy.data.worlds.new("world")
    scene.world = world
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    if kind in ("sky", "dusk"):  # dusk: the sun just below the horizon, dim
        sky = world.node_tree.nodes.new("ShaderNodeTexSky")
        sky.sky_type = "PREETHAM"
        sky.sun_direction = (
            (rng.uniform(-0.3, 0.3), 0.8, rng.uniform(0.3, 0.7))
            if kind == "sky"
            else (rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(0.0, 0.08))
        )
        world.node_tree.links.new(sky.outputs["Color"], bg.inputs["Color"])
        bg.inputs["Strength"].default_value = rng.uniform(0.3, 1.0) if kind == "sky" else rng.uniform(0.02, 0.15)
    elif kind == "dark":
        bg.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
        bg.inputs["Strength"].default_value = 0.0
    elif kind == "night":  # a deep blue sky, dim
        bg.inputs["Color"].default_value = (0.02, 0.03, rng.uniform(0.06, 0.12), 1.0)
        bg.inputs["Strength"].default_value = rng.uniform(0.3, 1.0)
    else:
        bg.inputs["Color"].default_value = (*[rng.uniform(0.3, 0.8) for _ in range(3)], 1.0)
        bg.inputs["Strength"].default_value = rng.uniform(0.5, 1.5)
    world.cycles.sampling_method = "MANUAL"  # the automatic importance map costs seconds a render
    world.cycles.sample_map_resolution = 512


def _camera(scene, rng, path, frames, target, radius, height, speed=1.0):
    """Keyed camera: static, dolly, orbit, pan or cut, ``speed`` times the usual motion;
    returns the frames that are cuts."""
    import bpy

    bpy.ops.object.camera_add()
    cam = bpy.context.object
    scene.camera = cam
    cam.data.lens = rng.uniform(24, 40)
    track = cam.constraints.new("TRACK_TO")
    empty = bpy.data.objects.new("target", None)
    scene.collection.objects.link(empty)
    empty.location = target
    track.target = empty
    a0 = rng.uniform(0, 2 * math.pi)
    cuts = []
    for f in range(0, frames + 2):
        t = speed * f / max(frames, 1)
        a, r, aim = a0, radius, list(target)
        if path == "orbit":
            a = a0 + 0.5 * t
        elif path == "dolly":
            r = radius * (1.0 - 0.35 * t)
        elif path == "pan":
            aim = [
                target[0] + 2.0 * math.cos(a0 + math.pi / 2) * (t - 0.5),
                target[1] + 2.0 * math.sin(a0 + math.pi / 2) * (t - 0.5),
                target[2],
            ]
        elif path == "cut" and f > frames // 2:
            a = a0 + 2.2
        cam.location = (target[0] + r * math.cos(a), target[1] + r * math.sin(a), height)
        empty.location = aim
        cam.keyframe_insert("location", frame=f)
        empty.keyframe_insert("location", frame=f)
    if path == "cut":
        cuts.append(frames // 2 + 1)  # scene frame numbers start at 1
    return cuts


def build(cfg: dict):
    """A new scene for ``cfg`` (kind, seed, camera, frames, size); returns (scene, cuts)."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    rng = random.Random(cfg["seed"])
    kind, frames = cfg["scene"], cfg["frames"]
    speed = 1.0  # the camera path's speed (``_camera``)
    w, h = cfg["size"]
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = w, h, 100
    scene.frame_start, scene.frame_end = 1, frames
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.seed = cfg["seed"]
    scene.cycles.blur_glossy = 0.0  # no "filter glossy": references stay sharp
    scene.cycles.sample_clamp_indirect = 0.0
    scene.cycles.max_bounces = 6
    if kind == "sunroom":
        _world(scene, rng, "sky")
        _room(rng, 5.0, 3.2, window=True, texture_walls=rng.random() < 0.5)
        bpy.ops.object.light_add(
            type="SUN", rotation=(math.radians(rng.uniform(35, 60)), 0, math.radians(rng.uniform(160, 200)))
        )
        bpy.context.object.data.energy = rng.uniform(3.0, 8.0)
        bpy.context.object.data.angle = math.radians(rng.uniform(0.5, 3))
        moving = _objects(rng, rng.randint(4, 8), 3.5, 0.25, 0.4, frames)
        target, radius, height = (0, 0, 0.8), rng.uniform(3.5, 4.5), rng.uniform(1.2, 2.4)
    elif kind == "darkroom":
        _world(scene, rng, "dark")
        _room(rng, 5.0, 3.0, window=False, texture_walls=rng.random() < 0.5)
        for i in range(rng.randint(2, 5)):
            em = _material(f"em{i}", rng, emission=rng.uniform(10.0, 50.0), rough=0.5)
            _emitter(
                f"lamp{i}",
                rng.uniform(0.05, 0.15),
                (rng.uniform(-3.5, 3.5), rng.uniform(-3.5, 3.5), rng.uniform(0.1, 2.5)),
                em,
            )
        moving = _objects(rng, rng.randint(4, 8), 3.5, 0.3, 0.4, frames)
        target, radius, height = (0, 0, 0.8), rng.uniform(3.5, 4.5), rng.uniform(1.0, 2.2)
    elif kind == "metals":
        _world(scene, rng, "color")
        floor = _material("floor", rng, rough=rng.uniform(0.05, 0.6), texture=rng.choice(TEXTURES))
        _box("floor", (40, 40, 0.1), (0, 0, -0.05), floor)
        for i in range(2):
            em = _material(f"em{i}", rng, emission=rng.uniform(5.0, 20.0), rough=0.5)
            _emitter(f"lamp{i}", rng.uniform(0.3, 0.8), (rng.uniform(-6, 6), rng.uniform(-6, 6), rng.uniform(3, 6)), em)
        moving = _objects(rng, rng.randint(6, 10), 3.0, 0.6, 0.2, frames)
        target, radius, height = (0, 0, 0.5), rng.uniform(5.0, 7.0), rng.uniform(1.5, 3.5)
    elif kind == "textures":
        _world(scene, rng, "sky")
        _room(rng, 6.0, 3.5, window=True, texture_walls=True)
        bpy.ops.object.light_add(type="AREA", location=(0, 0, 3.3))
        bpy.context.object.data.energy = rng.uniform(200, 600)
        bpy.context.object.data.size = rng.uniform(1.0, 2.5)
        moving = _objects(rng, rng.randint(5, 9), 4.0, 0.2, 0.9, frames)
        target, radius, height = (0, 0, 0.8), rng.uniform(3.5, 5.0), rng.uniform(1.2, 2.6)
    elif kind == "mixed":
        moving, target, radius, height = _mixed(scene, rng, frames)
    elif kind == "lights":
        moving, target, radius, height = _mixed(scene, rng, frames, RIGS + LIGHTS_RIGS, (2, 4))
    elif kind == "interior":
        moving, target, radius, height = _interior(scene, rng, frames)
    elif kind == "detail":
        moving, target, radius, height = _detail(scene, rng, frames)
    elif kind == "layers":
        moving, target, radius, height = _layers(scene, rng, frames)
    elif kind == "glass":
        moving, target, radius, height = _glass(scene, rng, frames)
    elif kind == "print":
        moving, target, radius, height = _print(scene, rng, frames)
    elif kind == "media":
        moving, target, radius, height = _media(scene, rng, frames)
    elif kind == "gallery":
        _world(scene, rng, "dark")
        _room(rng, 6.0, 4.0, window=False, texture_walls=False)
        floor = _material("polished", rng, rough=rng.uniform(0.02, 0.12), texture="checker")
        _box("polished_floor", (12, 12, 0.02), (0, 0, 0.01), floor)
        for i in range(rng.randint(3, 5)):  # strip lights along the ceiling
            strip = _material(f"strip{i}", rng, emission=rng.uniform(8.0, 25.0), rough=0.5, color=(1, 1, 1))
            _box(f"strip{i}", (0.15, 9.0, 0.04), (-4.0 + 8.0 * i / 4, 0, 3.9), strip)
        for i in range(rng.randint(3, 6)):  # panels of fine texture on the walls
            x = rng.choice((-5.9, 5.9))
            panel = _material(f"panel{i}", rng, rough=rng.uniform(0.3, 0.9), texture=rng.choice(TEXTURES))
            _box(
                f"panel{i}",
                (0.02, rng.uniform(1.0, 2.5), rng.uniform(0.8, 1.8)),
                (x, rng.uniform(-4.5, 4.5), rng.uniform(1.4, 2.4)),
                panel,
            )
        moving = _objects(rng, rng.randint(5, 8), 3.5, 0.5, 0.3, frames)
        target, radius, height = (0, 0, 1.0), rng.uniform(3.5, 5.0), rng.uniform(1.4, 2.6)
    elif kind == "night":
        _world(scene, rng, "night")
        ground = _material("ground", rng, rough=rng.uniform(0.05, 0.4), texture=rng.choice(("brick", "noise")))
        _box("ground", (40, 40, 0.1), (0, 0, -0.05), ground)
        for i in range(rng.randint(2, 3)):
            bpy.ops.object.light_add(type="SPOT", location=(rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(3, 5)))
            light = bpy.context.object
            light.data.energy = rng.uniform(300, 1500)
            light.data.spot_size = math.radians(rng.uniform(30, 70))
            light.data.spot_blend = rng.uniform(0.1, 0.5)
        for i in range(rng.randint(2, 4)):  # neon tubes: thin and far brighter than anything lit
            neon = _material(f"neon{i}", rng, emission=rng.uniform(20.0, 80.0), rough=0.5)
            bpy.ops.mesh.primitive_cylinder_add(
                radius=rng.uniform(0.02, 0.05),
                depth=rng.uniform(0.8, 2.0),
                location=(rng.uniform(-4, 4), rng.uniform(-4, 4), rng.uniform(0.5, 2.5)),
                rotation=(rng.uniform(0, 3), rng.uniform(0, 3), 0),
            )
            bpy.context.object.data.materials.append(neon)
        moving = _objects(rng, rng.randint(6, 10), 4.0, 0.4, 0.4, frames)
        target, radius, height = (0, 0, 0.6), rng.uniform(4.5, 6.5), rng.uniform(1.2, 2.8)
    elif kind == "atrium":
        moving, target, radius, height = _atrium(scene, rng, frames)
    elif kind == "workshop":
        moving, target, radius, height = _workshop(scene, rng, frames)
    elif kind == "street":
        moving, target, radius, height = _street(scene, rng, frames)
    elif kind == "studio":
        moving, target, radius, height = _studio(scene, rng, frames)
    elif kind == "grove":
        moving, target, radius, height = _grove(scene, rng, frames)
    elif kind == "haze":
        moving, target, radius, height = _haze(scene, rng, frames)
    elif kind == "bathroom":
        moving, target, radius, height = _bathroom(scene, rng, frames)
    elif kind == "fur":
        moving, target, radius, height = _fur(scene, rng, frames)
    elif kind == "plain":
        moving, target, radius, height = _plain(scene, rng, frames)
        speed = 2.0
    else:
        raise ConfigError(f"unknown Cycles scene {kind!r}, expected one of {', '.join(CYCLES_SCENE_KINDS)}")
    for obj in moving:
        for fc in _all_fcurves(obj):
            for k in fc.keyframe_points:
                k.interpolation = "LINEAR"
    cuts = _camera(scene, rng, cfg["camera"], frames, target, radius, height, speed)
    # close-ups and wide views both (drawn last: the other kinds' draws are unchanged)
    if kind in ("detail", "layers", "glass", "print", "media"):
        scene.camera.data.lens = rng.uniform(18, 55)
    return scene, cuts


def _slide(obj, frames, delta, spin=(0.0, 0.0, 0.0)):
    """Keys ``obj`` moving by ``delta`` (world units) and turning by ``spin`` (radians)
    between frame 0 and frame ``frames`` + 1, linearly (one frame beyond each end: Cycles'
    Vector pass reads the neighbouring frames)."""
    start, rot = tuple(obj.location), tuple(obj.rotation_euler)
    for f, t in ((0, 0.0), (frames + 1, 1.0)):
        obj.location = tuple(a + d * t for a, d in zip(start, delta))
        obj.rotation_euler = tuple(a + d * t for a, d in zip(rot, spin))
        obj.keyframe_insert("location", frame=f)
        obj.keyframe_insert("rotation_euler", frame=f)


def _plain(scene, rng, frames):
    """The ``plain`` kind (CYCLES_GHOST_KINDS). Returns (moving objects, camera target,
    radius, height)."""
    import bpy

    _world(scene, rng, "dark")
    floor = _material(
        "floor", rng, rough=0.5, color=[rng.uniform(0.3, 0.8)] * 3, texture="checker" if rng.random() < 0.5 else None
    )
    _box("floor", (40, 40, 0.1), (0, 0, -0.05), floor)
    bpy.ops.object.light_add(type="AREA", location=(rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(3.5, 5)))
    bpy.context.object.data.energy = rng.uniform(400, 900)
    bpy.context.object.data.size = rng.uniform(1.5, 3.0)
    for i in range(rng.randint(3, 5)):  # still props, default Principled with a colour
        s = rng.uniform(0.5, 1.0)
        x, y = rng.uniform(-2.5, 2.5), rng.uniform(-2.5, 2.5)
        if rng.random() < 0.5:
            bpy.ops.mesh.primitive_cube_add(size=s, location=(x, y, s / 2), rotation=(0, 0, rng.uniform(0, 1.5)))
        else:
            bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=4, radius=s / 2, location=(x, y, s / 2))
            bpy.ops.object.shade_smooth()
        bpy.context.object.data.materials.append(_material(f"prop{i}", rng, rough=0.5))
    mirror = _material("mirror", rng, metal=True, rough=rng.uniform(0.02, 0.08), color=(0.9, 0.9, 0.9))
    _box(
        "mirror_cube",
        (1.0, 1.0, 1.0),
        (rng.uniform(-2, 2), rng.uniform(-2, 2), 0.5),
        mirror,
        rotation=(0, 0, rng.uniform(0, 1.5)),
    )
    moving = []
    a = rng.uniform(0, 2 * math.pi)  # the ball rolls through the centre, fast
    r = rng.uniform(0.3, 0.5)
    d = rng.uniform(4.0, 6.0)
    bpy.ops.mesh.primitive_ico_sphere_add(
        subdivisions=4, radius=r, location=(-d / 2 * math.cos(a), -d / 2 * math.sin(a), r)
    )
    bpy.ops.object.shade_smooth()
    ball = bpy.context.object
    ball.data.materials.append(_material("ball", rng, rough=0.5, texture="checker"))
    _slide(ball, frames, (d * math.cos(a), d * math.sin(a), 0.0), (-d / r * math.sin(a), d / r * math.cos(a), 0.0))
    moving.append(ball)
    b = a + rng.uniform(1.0, 2.0)  # a cube sliding and turning
    bpy.ops.mesh.primitive_cube_add(size=0.6, location=(rng.uniform(-1.5, 1.5), rng.uniform(-1.5, 1.5), 0.3))
    cube = bpy.context.object
    cube.data.materials.append(_material("slider", rng, rough=0.5))
    _slide(cube, frames, (2.5 * math.cos(b), 2.5 * math.sin(b), 0.0), (0.0, 0.0, rng.uniform(-1.5, 1.5)))
    moving.append(cube)
    bpy.ops.mesh.primitive_cylinder_add(
        radius=0.025, depth=2.0, location=(rng.uniform(-1.5, 1.5), rng.uniform(-1.5, 1.5), 1.0)
    )
    pole = bpy.context.object  # thin geometry, moving
    pole.data.materials.append(_material("pole", rng, rough=0.5))
    _slide(pole, frames, (rng.uniform(-2, 2), rng.uniform(-2, 2), 0.0))
    moving.append(pole)
    if rng.random() < 0.5:  # a lamp moving through the scene
        lamp = _emitter(
            "lamp",
            0.12,
            (rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(0.3, 1.2)),
            _material("lamp", rng, emission=rng.uniform(20.0, 40.0), rough=0.5),
        )
        _slide(lamp, frames, (rng.uniform(-3, 3), rng.uniform(-3, 3), 0.0))
        moving.append(lamp)
    return moving, (0, 0, 0.5), rng.uniform(4.5, 6.0), rng.uniform(1.5, 2.8)


# light rigs: those of the training kinds (mixed), and the further sorts of the lights kind
RIGS = ("sun", "area", "points", "emitters")
LIGHTS_RIGS = ("spots", "shaped_area", "bars")


def _mixed(scene, rng, frames, rigs=RIGS, count=(1, 3)):
    """The ``mixed`` kind: a world, a room (with or without a window) or open ground,
    ``count`` light rigs drawn from ``rigs`` (mixed: the training kinds' sorts, a sun, an
    area light, point lights, small emissive icospheres), props with random shares of metal
    and texture. Returns (moving props, camera target, radius, height)."""
    world = rng.choice(("sky", "dark", "color"))
    _world(scene, rng, world)
    half = rng.uniform(4.0, 7.0)
    room = rng.random() < 0.6
    if room:
        _room(rng, half, rng.uniform(2.6, 4.0), window=rng.random() < 0.5, texture_walls=rng.random() < 0.6)
    else:
        ground = _material("ground", rng, rough=rng.uniform(0.05, 0.9), texture=rng.choice(TEXTURES))
        _box("ground", (40, 40, 0.1), (0, 0, -0.05), ground)
    rigs = rng.sample(rigs, rng.randint(*count))
    if world == "dark" and rigs == ["sun"]:
        rigs.append("emitters")  # a sun alone in a closed dark room may light nothing seen
    for rig in rigs:
        _mixed_rig(rig, rng)
    moving = _objects(rng, rng.randint(4, 10), 3.5, rng.uniform(0.1, 0.7), rng.uniform(0.2, 0.9), frames)
    target, radius, height = (0, 0, rng.uniform(0.4, 1.0)), rng.uniform(3.5, 6.0), rng.uniform(1.0, 3.0)
    if room:
        # The camera circles the room's centre: with a radius beyond the walls (x = +-half,
        # y = half) it leaves the room, and three training seeds' frames went black or looked in
        # from outside (docs/dataset.md). Clamped rather than redrawn, so that the random draws,
        # and every scene whose camera stayed inside, are as rendered before.
        radius = min(radius, half - 0.15)
    return moving, target, radius, height


def _mixed_rig(rig, rng):
    """One light rig of the ``mixed`` kind (``RIGS``) or of the ``lights`` kind (``LIGHTS_RIGS``)."""
    import bpy

    if rig == "sun":
        bpy.ops.object.light_add(
            type="SUN", rotation=(math.radians(rng.uniform(20, 70)), 0, math.radians(rng.uniform(0, 360)))
        )
        bpy.context.object.data.energy = rng.uniform(2.0, 8.0)
        bpy.context.object.data.angle = math.radians(rng.uniform(0.5, 5))
    elif rig == "area":
        bpy.ops.object.light_add(type="AREA", location=(rng.uniform(-2, 2), rng.uniform(-2, 2), 2.5))
        bpy.context.object.data.energy = rng.uniform(100, 600)
        bpy.context.object.data.size = rng.uniform(0.3, 2.5)
    elif rig == "points":
        for i in range(rng.randint(1, 3)):
            bpy.ops.object.light_add(
                type="POINT", location=(rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(0.5, 2.5))
            )
            bpy.context.object.data.energy = rng.uniform(50, 400)
            bpy.context.object.data.shadow_soft_size = rng.uniform(0.02, 0.5)
    elif rig == "emitters":
        for i in range(rng.randint(1, 4)):
            em = _material(f"em{i}", rng, emission=rng.uniform(5.0, 60.0), rough=0.5)
            _emitter(
                f"lamp{i}",
                rng.uniform(0.05, 0.4),
                (rng.uniform(-3.5, 3.5), rng.uniform(-3.5, 3.5), rng.uniform(0.1, 2.5)),
                em,
            )
    else:
        _lights_rig(rig, rng)


def _lights_rig(rig, rng):
    """The further light sorts of the ``lights`` kind: spot lights (cones of light with
    sharp or soft edges), an area light of a random shape, emissive bars and tubes (long
    thin meshes, bright against what they light)."""
    import bpy

    if rig == "spots":
        for i in range(rng.randint(1, 3)):
            bpy.ops.object.light_add(
                type="SPOT",
                location=(rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(2.0, 4.5)),
                rotation=(rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), 0),
            )
            light = bpy.context.object.data
            light.energy = rng.uniform(150, 1500)
            light.spot_size = math.radians(rng.uniform(20, 90))
            light.spot_blend = rng.uniform(0.0, 0.6)
            light.shadow_soft_size = rng.uniform(0.02, 0.4)
            light.color = [rng.uniform(0.6, 1.0) for _ in range(3)]
    elif rig == "shaped_area":
        bpy.ops.object.light_add(
            type="AREA",
            location=(rng.uniform(-2.5, 2.5), rng.uniform(-2.5, 2.5), rng.uniform(1.5, 3.0)),
            rotation=(rng.uniform(-0.8, 0.8), rng.uniform(-0.8, 0.8), 0),
        )
        light = bpy.context.object.data
        light.shape = rng.choice(("SQUARE", "RECTANGLE", "DISK", "ELLIPSE"))
        light.size, light.size_y = rng.uniform(0.2, 2.0), rng.uniform(0.05, 2.0)
        light.energy = rng.uniform(50, 500)
    else:  # emissive bars and tubes, lying, standing or overhead
        for i in range(rng.randint(1, 4)):
            em = _material(f"bar{i}", rng, emission=rng.uniform(5.0, 80.0), rough=0.5)
            length, width = rng.uniform(0.5, 3.0), rng.uniform(0.02, 0.12)
            loc = (rng.uniform(-3.5, 3.5), rng.uniform(-3.5, 3.5), rng.uniform(0.1, 3.0))
            rot = (rng.uniform(0, math.pi), rng.uniform(0, math.pi), rng.uniform(0, math.pi))
            if rng.random() < 0.5:
                _box(f"bar{i}", (width, length, width), loc, em, rot)
            else:
                bpy.ops.mesh.primitive_cylinder_add(radius=width / 2, depth=length, location=loc, rotation=rot)
                bpy.context.object.data.materials.append(em)


INTERIOR_RIGS = ("uplight", "cove", "lamps", "wallwash")


def _interior(scene, rng, frames):
    """The ``interior`` training kind: a closed room lit mostly by light that has bounced
    once or more, the usual case in real interiors and the one that leaves the most
    low-frequency noise at 1 spp. Lamps hidden from the camera or aimed at the ceiling and
    walls (``INTERIOR_RIGS``), daylight through a door or a hatch in the roof, walls of one
    tint (colour bleeding); shelves along the walls and tables carrying clusters of small
    props, lamps hanging on thin cords; a few props moving on the floor.
    Returns (moving props, camera target, radius, height)."""
    import bpy

    world = rng.choice(("sky", "dusk", "dark"))
    _world(scene, rng, world)
    half, height, t = rng.uniform(3.0, 6.0), rng.uniform(2.4, 4.0), 0.1
    # the camera circles inside the walls, clear of the shelves (0.4 m deep at most); hanging
    # lamps stay inside its circle
    radius = min(rng.uniform(2.5, 4.5), half - 0.6)
    tint = [rng.uniform(0.3, 0.9) for _ in range(3)]
    walls = _material(
        "walls",
        rng,
        rough=rng.uniform(0.5, 1.0),
        color=tint,
        texture=rng.choice(TEXTURES) if rng.random() < 0.4 else None,
    )
    floor = _material("floor", rng, rough=rng.uniform(0.05, 0.8), texture=rng.choice(TEXTURES))
    _box("floor", (2 * half, 2 * half, t), (0, 0, -t / 2), floor)
    _box("wall_w", (t, 2 * half, height), (-half, 0, height / 2), walls)
    _box("wall_e", (t, 2 * half, height), (half, 0, height / 2), walls)
    _box("wall_s", (2 * half, t, height), (0, -half, height / 2), walls)
    daylight = world != "dark"
    door = daylight and rng.random() < 0.6  # else a hatch in the roof
    if door:  # a doorway in the north wall, 0.9-2.0 m wide and 2.0-2.3 m tall
        w, top, x0 = rng.uniform(0.9, 2.0), min(rng.uniform(2.0, 2.3), height - 0.2), rng.uniform(-0.5, 0.5) * half
        _box("wall_n_l", (x0 - w / 2 + half, t, height), ((-half + x0 - w / 2) / 2, half, height / 2), walls)
        _box("wall_n_r", (half - x0 - w / 2, t, height), ((x0 + w / 2 + half) / 2, half, height / 2), walls)
        _box("wall_n_t", (w, t, height - top), (x0, half, (top + height) / 2), walls)
    else:
        _box("wall_n", (2 * half, t, height), (0, half, height / 2), walls)
    if daylight and not door:  # the roof around a hatch of 0.6-1.5 m, off centre
        hx, hy, o = rng.uniform(-0.5, 0.5) * half, rng.uniform(-0.5, 0.5) * half, rng.uniform(0.3, 0.75)
        z = height + t / 2
        _box("roof_n", (2 * half, half - hy - o, t), (0, (hy + o + half) / 2, z), walls)
        _box("roof_s", (2 * half, hy - o + half, t), (0, (hy - o - half) / 2, z), walls)
        _box("roof_e", (half - hx - o, 2 * o, t), ((hx + o + half) / 2, hy, z), walls)
        _box("roof_w", (hx - o + half, 2 * o, t), ((hx - o - half) / 2, hy, z), walls)
    else:
        _box("ceiling", (2 * half, 2 * half, t), (0, 0, height + t / 2), walls)
    if daylight:  # the sun low through the door (from the north), or steep through the hatch
        rot = (
            (math.radians(rng.uniform(45, 75)), 0, math.radians(rng.uniform(150, 210)))
            if door
            else (math.radians(rng.uniform(5, 35)), 0, math.radians(rng.uniform(0, 360)))
        )
        bpy.ops.object.light_add(type="SUN", rotation=rot)
        bpy.context.object.data.energy = rng.uniform(2.0, 8.0)
        bpy.context.object.data.angle = math.radians(rng.uniform(0.5, 3))
    rigs = rng.sample(INTERIOR_RIGS, rng.randint(1 if daylight else 2, 3))
    for rig in rigs:
        _interior_rig(rig, rng, half, height, radius - 0.5)
    wood = _material("furniture", rng, rough=rng.uniform(0.3, 0.8), texture=rng.choice(("noise", None)))
    for i in range(rng.randint(1, 3)):  # shelves against the west, east or south wall
        side = rng.choice(("w", "e", "s"))
        along, depth, shelf_h, levels = rng.uniform(-0.5, 0.5) * half, 0.35, rng.uniform(1.2, 2.2), rng.randint(2, 4)
        width = rng.uniform(0.8, 1.8)
        cx, cy = {"w": (-half + 0.25, along), "e": (half - 0.25, along), "s": (along, -half + 0.25)}[side]
        sx, sy = (depth, width) if side in ("w", "e") else (width, depth)
        for k in range(levels):
            z = 0.15 + (shelf_h - 0.15) * k / (levels - 1)
            _box(f"shelf{i}_{k}", (sx, sy, 0.03), (cx, cy, z), wood)
            _props(f"s{i}_{k}", rng, rng.randint(3, 8), (cx, cy, z + 0.015), (sx * 0.4, sy * 0.45), 0.03, 0.18)
        for e in (-1, 1):  # the two uprights
            off = (0, e * sy / 2) if side in ("w", "e") else (e * sx / 2, 0)
            _box(
                f"upright{i}{e}",
                (sx if side in ("w", "e") else 0.03, 0.03 if side in ("w", "e") else sy, shelf_h),
                (cx + off[0], cy + off[1], shelf_h / 2),
                wood,
            )
    for i in range(rng.randint(1, 2)):  # tables in the middle of the room
        tx, ty = rng.uniform(-0.35, 0.35) * half, rng.uniform(-0.35, 0.35) * half
        tw, td, th = rng.uniform(0.8, 1.8), rng.uniform(0.6, 1.0), rng.uniform(0.7, 0.8)
        _box(f"table{i}", (tw, td, 0.04), (tx, ty, th), wood)
        for lx in (-1, 1):
            for ly in (-1, 1):
                _box(
                    f"table{i}leg{lx}{ly}",
                    (0.04, 0.04, th),
                    (tx + lx * (tw / 2 - 0.05), ty + ly * (td / 2 - 0.05), th / 2),
                    wood,
                )
        _props(f"t{i}", rng, rng.randint(4, 12), (tx, ty, th + 0.02), (tw * 0.45, td * 0.45), 0.03, 0.2)
    moving = _objects(rng, rng.randint(2, 5), 0.5 * half, rng.uniform(0.1, 0.5), rng.uniform(0.2, 0.7), frames)
    return moving, (0, 0, rng.uniform(0.6, 1.1)), radius, rng.uniform(1.2, min(2.2, height - 0.3))


# the ``detail`` kind's textures (``wave`` is drawn by no other kind) and shapes
DETAIL_TEXTURES = TEXTURES + ("wave",)
DETAIL_SHAPES = ("monkey", "rock", "slats", "stairs", "pebbles", "terrain")


def _relief(name, rng, world_coords=False, **kwargs):
    """``_material`` with, on most draws, a relief: a Bump node on the shading normal driven by
    a texture of its own, as nearly every surface of a real asset has (a normal or bump map).
    It changes the shading per pixel, and the normal pass with it, where the geometry is flat.
    ``world_coords``: textures follow world position at 0.3 x their scale in metres (a large
    still surface: the ground, walls), instead of the object's own box."""
    m = _material(name, rng, **kwargs)
    nodes, links = m.node_tree.nodes, m.node_tree.links
    if rng.random() < 0.75:
        tex = _texture(nodes, rng.choice(DETAIL_TEXTURES), rng)
        bump = nodes.new("ShaderNodeBump")
        bump.inputs["Strength"].default_value = rng.uniform(0.1, 1.0)
        bump.inputs["Distance"].default_value = rng.uniform(0.005, 0.05)
        links.new(tex.outputs["Fac"] if "Fac" in tex.outputs else tex.outputs[0], bump.inputs["Height"])
        links.new(bump.outputs["Normal"], nodes["Principled BSDF"].inputs["Normal"])
    if world_coords:
        where = nodes.new("ShaderNodeNewGeometry")
        scale = nodes.new("ShaderNodeVectorMath")
        scale.operation = "SCALE"
        scale.inputs["Scale"].default_value = 0.3
        links.new(where.outputs["Position"], scale.inputs[0])
        for node in list(nodes):
            if node.bl_idname.startswith("ShaderNodeTex"):
                links.new(scale.outputs["Vector"], node.inputs["Vector"])
    return m


def _displace(name, noise_scale, strength):
    """The selected mesh displaced along its normals by a clouds (noise) texture, smooth-shaded."""
    import bpy

    tex = bpy.data.textures.new(name, type="CLOUDS")
    tex.noise_scale = noise_scale
    bpy.ops.object.modifier_add(type="DISPLACE")
    bpy.context.object.modifiers[-1].texture = tex
    bpy.context.object.modifiers[-1].strength = strength
    bpy.ops.object.shade_smooth()


def _detail(scene, rng, frames):
    """The ``detail`` training kind: the surface and geometric detail of real assets,
    which the other kinds' flat primitives lack. Surfaces with bump-mapped relief (``_relief``)
    and a wave texture besides the others; curved and dense shapes (``DETAIL_SHAPES``): a
    subdivided monkey head, rocks (icospheres displaced by noise), rows of slats a few pixels
    apart (blinds, fences, radiators), stairs, beds of pebbles a pixel or two across, a patch of
    displaced terrain; a close camera with a wide range of focal lengths; the light rigs of
    ``mixed`` and ``lights``; some shapes turning, the usual props moving.
    Returns (moving objects, camera target, radius, height)."""
    import bpy

    world = rng.choice(("sky", "dusk", "dark", "color"))
    _world(scene, rng, world)
    # the camera circles the centre at ``radius``; the shapes stand within 1.6 m of it, the
    # walls beyond the camera's circle
    radius, metal, textured = rng.uniform(2.4, 3.8), rng.uniform(0.1, 0.5), rng.uniform(0.3, 0.9)
    ground = _relief(
        "ground", rng, world_coords=True, rough=rng.uniform(0.05, 0.9), texture=rng.choice(DETAIL_TEXTURES)
    )
    _box("ground", (40, 40, 0.1), (0, 0, -0.05), ground)
    if rng.random() < 0.6:  # a corner of two walls, open to the world on the other sides
        wall = _relief(
            "wall",
            rng,
            world_coords=True,
            rough=rng.uniform(0.3, 1.0),
            texture=rng.choice(DETAIL_TEXTURES) if rng.random() < 0.7 else None,
        )
        h, d = rng.uniform(2.0, 4.0), radius + rng.uniform(0.4, 1.5)
        _box("wall_a", (0.1, 2 * d, h), (-d, 0, h / 2), wall)
        _box("wall_b", (2 * d, 0.1, h), (0, -d, h / 2), wall)
    rigs = rng.sample(RIGS + LIGHTS_RIGS, rng.randint(1, 3))
    if world == "dark" and rigs == ["sun"]:
        rigs.append("emitters")
    for rig in rigs:
        _mixed_rig(rig, rng)

    def material(i):
        r = rng.random()
        return _relief(
            f"d{i}",
            rng,
            metal=r < metal,
            glass=metal <= r < metal + 0.08,
            texture=rng.choice(DETAIL_TEXTURES) if rng.random() < textured else None,
        )

    moving = []
    for i in range(rng.randint(4, 8)):
        shape = rng.choice(DETAIL_SHAPES)
        a, r = rng.uniform(0, 2 * math.pi), rng.uniform(0, 1.6)
        x, y, s = r * math.cos(a), r * math.sin(a), rng.uniform(0.25, 0.8)
        if shape == "monkey":
            bpy.ops.mesh.primitive_monkey_add(
                size=s, location=(x, y, s / 2), rotation=(rng.uniform(-0.3, 0.3), 0, rng.uniform(0, 2 * math.pi))
            )
            bpy.ops.object.modifier_add(type="SUBSURF")
            bpy.context.object.modifiers[-1].render_levels = 2
            bpy.ops.object.shade_smooth()
        elif shape == "rock":
            bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=5, radius=s / 2, location=(x, y, s * 0.35))
            _displace(f"rock{i}", rng.uniform(0.1, 0.5), rng.uniform(0.1, 0.4) * s)
        elif shape == "slats":  # n slats 0.5-3 cm thick, 2-12 cm apart, upright or lying
            n, gap, t, span = (
                rng.randint(8, 24),
                rng.uniform(0.02, 0.12),
                rng.uniform(0.005, 0.03),
                rng.uniform(0.5, 1.5),
            )
            mat, a = material(i), rng.uniform(0, math.pi)
            upright = rng.random() < 0.5
            for k in range(n):
                o = (k - n / 2) * gap
                if upright:
                    _box(
                        f"slat{i}_{k}",
                        (t, t * 3, span),
                        (x + o * math.cos(a), y + o * math.sin(a), span / 2),
                        mat,
                        (0, 0, a),
                    )
                else:
                    _box(f"slat{i}_{k}", (span, t * 3, t), (x, y, 0.1 + k * gap), mat, (0, 0, a))
            continue
        elif shape == "stairs":
            n, rise, run, width = (
                rng.randint(3, 7),
                rng.uniform(0.08, 0.18),
                rng.uniform(0.15, 0.3),
                rng.uniform(0.5, 1.2),
            )
            mat, a = material(i), rng.uniform(0, 2 * math.pi)
            for k in range(n):
                r = k * run
                _box(
                    f"step{i}_{k}",
                    (run, width, rise * (k + 1)),
                    (x + r * math.cos(a), y + r * math.sin(a), rise * (k + 1) / 2),
                    mat,
                    (0, 0, a),
                )
            continue
        elif shape == "pebbles":  # a bed of 60-200 stones 1-5 cm across
            mat = material(i)
            for k in range(rng.randint(60, 200)):
                r = rng.uniform(0.005, 0.025)
                bpy.ops.mesh.primitive_ico_sphere_add(
                    subdivisions=1, radius=r, location=(x + rng.gauss(0, 0.25), y + rng.gauss(0, 0.25), r * 0.6)
                )
                bpy.context.object.data.materials.append(mat)
            continue
        else:  # terrain: a patch of ground displaced by noise
            bpy.ops.mesh.primitive_grid_add(
                x_subdivisions=96, y_subdivisions=96, size=rng.uniform(1.5, 3.0), location=(x, y, 0.01)
            )
            _displace(f"terrain{i}", rng.uniform(0.1, 0.4), rng.uniform(0.05, 0.3))
        obj = bpy.context.object
        obj.data.materials.append(material(i))
        if rng.random() < 0.3:  # turns on the spot
            spin = rng.uniform(-1.5, 1.5)
            for f, t in ((0, 0.0), (frames + 1, 1.0)):
                obj.rotation_euler[2] = spin * t
                obj.keyframe_insert("rotation_euler", frame=f)
            moving.append(obj)
    moving += _objects(rng, rng.randint(2, 4), 1.5, metal, textured, frames)
    return moving, (0, 0, rng.uniform(0.2, 0.6)), radius, rng.uniform(0.7, 2.0)


def _slides(obj, rng, frames, p, reach):
    """With probability ``p``, ``obj`` slides up to ``reach`` metres along x and y and turns up to
    1.5 radians about its vertical axis over the sequence, keyed at its two ends (made linear by
    ``build``); returns whether it moves."""
    if rng.random() >= p:
        return False
    d, spin = (rng.uniform(-reach, reach), rng.uniform(-reach, reach)), rng.uniform(-1.5, 1.5)
    x0, y0, z0 = obj.location[0], obj.location[1], obj.rotation_euler[2]
    for f, t in ((0, 0.0), (frames + 1, 1.0)):
        obj.location[0], obj.location[1] = x0 + d[0] * t, y0 + d[1] * t
        obj.rotation_euler[2] = z0 + spin * t
        obj.keyframe_insert("location", frame=f)
        obj.keyframe_insert("rotation_euler", frame=f)
    return True


def _layered_material(name, rng):
    """A Principled BSDF with its other layers drawn independently, each on in some draws and
    at any weight when on: sheen (cloth), coat (lacquer, car paint), subsurface (wax, skin,
    marble), anisotropy (brushed metal), thin film (oil, soap), transmission (frosted glass);
    base roughness and specular level over their whole range. Real assets mix them; every
    other training kind's materials are base colour, roughness, metal or clear glass."""
    m = _material(
        name,
        rng,
        metal=rng.random() < 0.3,
        rough=rng.uniform(0.0, 1.0),
        texture=rng.choice(DETAIL_TEXTURES) if rng.random() < 0.35 else None,
    )
    b = m.node_tree.nodes["Principled BSDF"].inputs
    b["Specular IOR Level"].default_value = rng.uniform(0.2, 1.0)
    if rng.random() < 0.45:
        b["Sheen Weight"].default_value = rng.uniform(0.3, 1.0)
        b["Sheen Roughness"].default_value = rng.uniform(0.1, 1.0)
        b["Sheen Tint"].default_value = (*[rng.uniform(0.5, 1.0) for _ in range(3)], 1.0)
    if rng.random() < 0.4:
        b["Coat Weight"].default_value = rng.uniform(0.3, 1.0)
        b["Coat Roughness"].default_value = rng.uniform(0.0, 0.3)
        b["Coat Tint"].default_value = (*[rng.uniform(0.6, 1.0) for _ in range(3)], 1.0)
    if rng.random() < 0.3:
        b["Subsurface Weight"].default_value = rng.uniform(0.5, 1.0)
        b["Subsurface Radius"].default_value = [rng.uniform(0.1, 1.0) for _ in range(3)]
        b["Subsurface Scale"].default_value = rng.uniform(0.01, 0.3)
    if rng.random() < 0.3:
        b["Anisotropic"].default_value = rng.uniform(0.3, 1.0)
        b["Anisotropic Rotation"].default_value = rng.uniform(0.0, 1.0)
    if rng.random() < 0.25:
        b["Thin Film Thickness"].default_value = rng.uniform(100, 1000)
        b["Thin Film IOR"].default_value = rng.uniform(1.2, 1.8)
    if rng.random() < 0.12:
        b["Transmission Weight"].default_value = 1.0
        b["IOR"].default_value = rng.uniform(1.1, 1.8)
    return m


def _struts(name, rng, location, size, cells, thickness, rotation):
    """A mesh of struts: a grid turned into wire by Blender's wireframe modifier (a fence, a
    screen, a grille; ``cells`` (x, y) may be 1 along one side: parallel bars)."""
    import bpy

    bpy.ops.mesh.primitive_grid_add(
        x_subdivisions=cells[0], y_subdivisions=cells[1], size=size, location=location, rotation=rotation
    )
    bpy.ops.object.modifier_add(type="WIREFRAME")
    bpy.context.object.modifiers[-1].thickness = thickness
    bpy.context.object.data.materials.append(
        _material(name, rng, metal=rng.random() < 0.6, rough=rng.uniform(0.05, 0.8))
    )
    return bpy.context.object


LAYERS_SHAPES = ("torus", "sphere", "monkey", "capsule", "cloth")


def _layers(scene, rng, frames):
    """The ``layers`` training kind: smooth curved shapes in layered materials
    (``_layered_material``) and one to three meshes of struts 1-8 cm apart, a tenth to a third of that thick,
    standing, tilted or hanging, some moving; ground with relief, sometimes a corner of walls;
    the light rigs of ``mixed`` and ``lights``. Returns (moving objects, camera target, radius,
    height)."""
    import bpy

    _world(scene, rng, rng.choice(("sky", "dusk", "dark", "color")))
    radius = rng.uniform(2.4, 4.0)
    ground = _relief(
        "ground",
        rng,
        world_coords=True,
        rough=rng.uniform(0.05, 0.9),
        texture=rng.choice(DETAIL_TEXTURES) if rng.random() < 0.7 else None,
    )
    _box("ground", (40, 40, 0.1), (0, 0, -0.05), ground)
    if rng.random() < 0.5:
        wall = _relief("wall", rng, world_coords=True, rough=rng.uniform(0.3, 1.0))
        h, d = rng.uniform(2.0, 4.0), radius + rng.uniform(0.4, 1.5)
        _box("wall_a", (0.1, 2 * d, h), (-d, 0, h / 2), wall)
        _box("wall_b", (2 * d, 0.1, h), (0, -d, h / 2), wall)
    for rig in rng.sample(RIGS + LIGHTS_RIGS, rng.randint(1, 3)):
        _mixed_rig(rig, rng)
    moving = []

    def moves(obj, p):
        if _slides(obj, rng, frames, p, 0.8):
            moving.append(obj)

    for i in range(rng.randint(4, 8)):
        shape, a, r, s = (
            rng.choice(LAYERS_SHAPES),
            rng.uniform(0, 2 * math.pi),
            rng.uniform(0, 1.6),
            rng.uniform(0.25, 0.8),
        )
        x, y = r * math.cos(a), r * math.sin(a)
        if shape == "torus":
            bpy.ops.mesh.primitive_torus_add(
                major_radius=s / 2,
                minor_radius=s * rng.uniform(0.08, 0.25),
                major_segments=64,
                minor_segments=24,
                location=(x, y, s / 2),
                rotation=(rng.uniform(0, math.pi), 0, rng.uniform(0, math.pi)),
            )
        elif shape == "sphere":
            bpy.ops.mesh.primitive_uv_sphere_add(radius=s / 2, segments=64, ring_count=32, location=(x, y, s / 2))
        elif shape == "monkey":
            bpy.ops.mesh.primitive_monkey_add(
                size=s, location=(x, y, s / 2), rotation=(0, 0, rng.uniform(0, 2 * math.pi))
            )
            bpy.ops.object.modifier_add(type="SUBSURF")
            bpy.context.object.modifiers[-1].render_levels = 2
        elif shape == "capsule":  # a cylinder with rounded ends: bottles, handles, limbs
            bpy.ops.mesh.primitive_cylinder_add(
                vertices=48,
                radius=s / 4,
                depth=s,
                location=(x, y, s / 2),
                rotation=(rng.uniform(0, 1.5), 0, rng.uniform(0, math.pi)),
            )
            bpy.ops.object.modifier_add(type="BEVEL")
            bpy.context.object.modifiers[-1].width, bpy.context.object.modifiers[-1].segments = s / 8, 6
        else:  # cloth: a plane folded by noise, draped near the ground
            bpy.ops.mesh.primitive_grid_add(
                x_subdivisions=64,
                y_subdivisions=64,
                size=s * 2,
                location=(x, y, s / 3),
                rotation=(rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4), 0),
            )
            _displace(f"cloth{i}", rng.uniform(0.2, 0.6), rng.uniform(0.05, 0.25))
        bpy.ops.object.shade_smooth()
        bpy.context.object.data.materials.append(_layered_material(f"l{i}", rng))
        moves(bpy.context.object, 0.35)
    for i in range(rng.randint(1, 3)):
        a, r, size = rng.uniform(0, 2 * math.pi), rng.uniform(0.3, 2.0), rng.uniform(0.6, 2.2)
        pitch = rng.uniform(0.01, 0.08)
        cells = max(2, int(size / pitch))
        cells = (cells, 1) if rng.random() < 0.25 else (cells, max(2, int(cells * rng.uniform(0.5, 1.5))))
        tilt = rng.choice((math.pi / 2, math.pi / 2 + rng.uniform(-0.6, 0.6), rng.uniform(0, 0.3)))
        z = size / 2 if tilt > 0.5 else rng.uniform(1.2, 2.5)  # standing, or hanging overhead
        # struts a tenth to a third of the pitch thick: thicker, a fine mesh reads as a panel
        thickness = max(0.0015, pitch * rng.uniform(0.1, 0.35))
        moves(
            _struts(
                f"struts{i}",
                rng,
                (r * math.cos(a), r * math.sin(a), z),
                size,
                cells,
                thickness,
                (tilt, 0, rng.uniform(0, math.pi)),
            ),
            0.3,
        )
    return moving, (0, 0, rng.uniform(0.3, 0.8)), radius, rng.uniform(0.7, 2.0)


def _glass_material(name, rng):
    """Glass or water: clear, frosted (rough transmission) or tinted, IOR 1.2-1.8."""
    tint = [rng.uniform(0.3, 1.0) for _ in range(3)] if rng.random() < 0.4 else [1.0, 1.0, 1.0]
    m = _material(name, rng, glass=True, color=tint, rough=rng.choice((0.0, 0.0, rng.uniform(0.02, 0.4))))
    m.node_tree.nodes["Principled BSDF"].inputs["IOR"].default_value = rng.uniform(1.2, 1.8)
    return m


GLASS_SHAPES = ("tumbler", "bottle", "ball", "pane", "tank")


def _glass(scene, rng, frames):
    """The ``glass`` training kind: glassware on a table or the ground: thin-walled
    tumblers and bottles (open cylinders given a wall by Blender's solidify modifier), solid
    balls, upright panes, a tank of water; clear, frosted or tinted; a sun, spot or area lights
    casting caustics; some pieces sliding or turning. Returns (moving objects, camera target,
    radius, height)."""
    import bpy

    _world(scene, rng, rng.choice(("sky", "dusk", "color", "dark")))
    radius = rng.uniform(2.2, 3.6)
    ground = _relief(
        "ground",
        rng,
        world_coords=True,
        rough=rng.uniform(0.1, 0.9),
        texture=rng.choice(DETAIL_TEXTURES) if rng.random() < 0.7 else None,
    )
    _box("ground", (40, 40, 0.1), (0, 0, -0.05), ground)
    top = 0.0
    if rng.random() < 0.5:  # a table under the glassware
        top = rng.uniform(0.4, 0.8)
        _box(
            "table",
            (rng.uniform(1.6, 2.6), rng.uniform(1.0, 1.8), 0.05),
            (0, 0, top - 0.025),
            _material("table", rng, rough=rng.uniform(0.05, 0.6), texture=rng.choice(TEXTURES)),
        )
    rigs = rng.sample(("sun", "spots", "area", "shaped_area", "points"), rng.randint(1, 2))
    if "sun" not in rigs and rng.random() < 0.5:
        rigs.append("sun")
    for rig in rigs:
        _mixed_rig(rig, rng)
    moving = []
    for i in range(rng.randint(5, 10)):
        shape, s = rng.choice(GLASS_SHAPES), rng.uniform(0.08, 0.35)
        x, y = rng.uniform(-0.8, 0.8), rng.uniform(-0.5, 0.5)
        mat = _glass_material(f"g{i}", rng)
        if shape in ("tumbler", "bottle"):
            h = s * (1.2 if shape == "tumbler" else 2.5)
            bpy.ops.mesh.primitive_cylinder_add(
                vertices=48,
                radius=s / 2 if shape == "tumbler" else s / 3,
                depth=h,
                end_fill_type="NOTHING",
                location=(x, y, top + h / 2),
            )
            bpy.ops.object.modifier_add(type="SOLIDIFY")
            bpy.context.object.modifiers[-1].thickness = rng.uniform(0.002, 0.008)
            bpy.ops.object.shade_smooth()
        elif shape == "ball":
            bpy.ops.mesh.primitive_uv_sphere_add(segments=48, ring_count=24, radius=s / 2, location=(x, y, top + s / 2))
            bpy.ops.object.shade_smooth()
        elif shape == "pane":
            _box(f"pane{i}", (s * 3, 0.006, s * 2.5), (x, y, top + s * 1.25), mat, (0, 0, rng.uniform(0, math.pi)))
        else:  # a glass tank holding water
            w = s * 2
            _box(f"tank{i}", (w, w * 0.6, w * 0.8), (x, y, top + w * 0.4), mat)
            water = _material(f"water{i}", rng, glass=True, rough=0.0, color=[0.85, 0.95, 1.0])
            water.node_tree.nodes["Principled BSDF"].inputs["IOR"].default_value = 1.33
            _box(f"water{i}", (w * 0.97, w * 0.57, w * 0.55), (x, y, top + w * 0.29), water)
            continue
        obj = bpy.context.object
        if shape != "pane":
            obj.data.materials.append(mat)
        if _slides(obj, rng, frames, 0.3, 0.4):
            moving.append(obj)
    moving += _objects(rng, rng.randint(1, 3), 2.0, 0.3, 0.5, frames)
    return moving, (0, 0, top + rng.uniform(0.1, 0.3)), radius, top + rng.uniform(0.4, 1.5)


PRINT_CHARS = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789 .,:-/#&"


def _print(scene, rng, frames):
    """The ``print`` training kind: lettering, the fine high-contrast detail of signs,
    labels, posters and screens: 16-40 lines of random text 3-40 cm tall (strokes of under a pixel
    to a few pixels at the camera's distance) on panels, walls and boxes, extruded or flat, some glowing
    (signs, screens), some on moving boxes; Blender's magic texture (fine interference patterns)
    on some panels. Returns (moving objects, camera target, radius, height)."""
    import bpy

    world = rng.choice(("sky", "dusk", "dark", "color"))
    _world(scene, rng, world)
    radius = rng.uniform(2.2, 3.8)
    ground = _relief(
        "ground",
        rng,
        world_coords=True,
        rough=rng.uniform(0.1, 0.9),
        texture=rng.choice(DETAIL_TEXTURES) if rng.random() < 0.5 else None,
    )
    _box("ground", (40, 40, 0.1), (0, 0, -0.05), ground)
    d = radius + rng.uniform(0.3, 1.2)
    walls = rng.random() < 0.6
    if walls:
        wall = _material("wall", rng, rough=rng.uniform(0.3, 1.0))
        _box("wall_a", (0.1, 2 * d, 3.0), (-d, 0, 1.5), wall)
        _box("wall_b", (2 * d, 0.1, 3.0), (0, -d, 1.5), wall)
    rigs = rng.sample(RIGS + LIGHTS_RIGS, rng.randint(1, 3))
    if world == "dark" and rigs == ["sun"]:
        rigs.append("emitters")
    for rig in rigs:
        _mixed_rig(rig, rng)
    moving, holders = [], []
    for i in range(rng.randint(2, 5)):  # panels (signs, posters, screens) and boxes facing the centre
        a, r = rng.uniform(0, 2 * math.pi), rng.uniform(0.4, 1.6)
        w, h = rng.uniform(0.4, 1.4), rng.uniform(0.3, 1.0)
        face = _material(f"panel{i}", rng, rough=rng.uniform(0.1, 0.9))
        if rng.random() < 0.3:  # fine interference patterns
            nodes, links = face.node_tree.nodes, face.node_tree.links
            magic = nodes.new("ShaderNodeTexMagic")
            magic.inputs["Scale"].default_value = rng.uniform(5, 40)
            magic.turbulence_depth = rng.randint(2, 5)
            links.new(magic.outputs["Color"], nodes["Principled BSDF"].inputs["Base Color"])
        z = rng.uniform(0.2, 1.2) + h / 2
        holders.append(
            _box(
                f"panel{i}",
                (w, 0.04, h),
                (r * math.cos(a), r * math.sin(a), z),
                face,
                (0, 0, a + math.pi / 2 + rng.uniform(-0.5, 0.5)),
            )
        )
    for i in range(rng.randint(16, 40)):
        text = "".join(rng.choice(PRINT_CHARS) for _ in range(rng.randint(3, 16)))
        size = math.exp(rng.uniform(math.log(0.03), math.log(0.4)))
        glow = rng.random() < 0.25
        mat = (
            _material(f"ink{i}", rng, emission=rng.uniform(2.0, 30.0), rough=0.5)
            if glow
            else _material(f"ink{i}", rng, metal=rng.random() < 0.2, rough=rng.uniform(0.05, 0.9))
        )
        bpy.ops.object.text_add()
        obj = bpy.context.object
        obj.data.body, obj.data.size = text, size
        obj.data.extrude = rng.choice((0.0, size * rng.uniform(0.02, 0.2)))
        obj.data.align_x = "CENTER"
        obj.data.materials.append(mat)
        if holders and rng.random() < 0.7:  # on a panel's face (its local front, -y), parented to it
            p = rng.choice(holders)
            obj.parent = p
            obj.location = (rng.uniform(-0.4, 0.4), -0.6, rng.uniform(-0.4, 0.4))  # in the panel's scaled frame
            obj.rotation_euler = (math.pi / 2, 0, 0)
            # undoes the panel's scale as seen through the 90-degree turn (local y is the panel's z)
            obj.scale = (1 / p.scale[0], 1 / p.scale[2], 1 / p.scale[1])
        else:  # standing free or lying on the ground
            a, r = rng.uniform(0, 2 * math.pi), rng.uniform(0, 1.8)
            standing = rng.random() < 0.5
            obj.location = (r * math.cos(a), r * math.sin(a), rng.uniform(0.05, 1.5) if standing else 0.002)
            obj.rotation_euler = (math.pi / 2 if standing else 0, 0, a + math.pi / 2)
    for p in holders:
        if rng.random() < 0.25:  # a sign that turns on its post (its lettering with it)
            for f, t in ((0, 0.0), (frames + 1, 1.0)):
                p.rotation_euler[2] += rng.uniform(-0.6, 0.6) * t
                p.keyframe_insert("rotation_euler", frame=f)
            moving.append(p)
    moving += _objects(rng, rng.randint(1, 3), 2.0, 0.3, 0.5, frames)
    return moving, (0, 0, rng.uniform(0.4, 1.0)), radius, rng.uniform(0.6, 1.8)


def _props(name, rng, n, base, extent, smallest, largest):
    """``n`` small props standing on a surface centred at ``base`` (x, y, top z)."""
    import bpy

    for i in range(n):
        s = rng.uniform(smallest, largest)
        loc = (
            base[0] + rng.uniform(-extent[0], extent[0]),
            base[1] + rng.uniform(-extent[1], extent[1]),
            base[2] + s / 2,
        )
        shape = rng.choice(("cube", "sphere", "cylinder", "cone"))
        if shape == "cube":
            bpy.ops.mesh.primitive_cube_add(size=s, location=loc, rotation=(0, 0, rng.uniform(0, 3)))
        elif shape == "sphere":
            bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=3, radius=s / 2, location=loc)
            bpy.ops.object.shade_smooth()
        elif shape == "cylinder":
            bpy.ops.mesh.primitive_cylinder_add(radius=s / 3, depth=s, location=loc)
        else:
            bpy.ops.mesh.primitive_cone_add(radius1=s / 2.5, depth=s, location=loc)
        r = rng.random()
        bpy.context.object.data.materials.append(
            _material(
                f"{name}p{i}",
                rng,
                metal=r < 0.25,
                glass=0.25 <= r < 0.35,
                texture=rng.choice(TEXTURES) if rng.random() < 0.4 else None,
            )
        )


def _interior_rig(rig, rng, half, height, reach):
    """One of the ``interior`` kind's light sorts, each lighting the room mostly by bounce:
    uplight (area lights facing the ceiling), cove (an emissive strip hidden on top of a
    ledge near the ceiling), lamps (point lights in shades open at both ends, hanging on thin
    cords, within ``reach`` of the room's vertical axis), wallwash (an area light close to a wall, facing it)."""
    import bpy

    if rig == "uplight":
        for i in range(rng.randint(1, 2)):
            bpy.ops.object.light_add(
                type="AREA",
                location=(rng.uniform(-0.7, 0.7) * half, rng.uniform(-0.7, 0.7) * half, rng.uniform(0.3, height - 0.8)),
                rotation=(math.pi + rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), 0),
            )
            bpy.context.object.data.size = rng.uniform(0.1, 0.6)
            bpy.context.object.data.energy = rng.uniform(100, 600)
            bpy.context.object.data.color = (1.0, rng.uniform(0.75, 1.0), rng.uniform(0.55, 1.0))
    elif rig == "cove":
        side = rng.choice((-1, 1))
        x, z = side * (half - 0.3), height - rng.uniform(0.3, 0.6)
        ledge = _material("ledge", rng, rough=0.8, color=[rng.uniform(0.5, 0.9)] * 3)
        _box("ledge", (0.3, 2 * half - 0.4, 0.05), (x, 0, z), ledge)
        _box("ledge_lip", (0.03, 2 * half - 0.4, 0.12), (x - side * 0.15, 0, z + 0.06), ledge)
        strip = _material("cove", rng, emission=rng.uniform(5.0, 30.0), rough=0.5)
        _box("cove_strip", (0.04, 2 * half - 0.6, 0.03), (x, 0, z + 0.04), strip)
    elif rig == "lamps":
        shade = _material("lampshade", rng, rough=rng.uniform(0.3, 0.9), metal=rng.random() < 0.4)
        cord = _material("cord", rng, rough=0.6, color=(0.02, 0.02, 0.02))
        for i in range(rng.randint(1, 3)):
            a, r = rng.uniform(0, 2 * math.pi), rng.uniform(0, reach)
            x, y = r * math.cos(a), r * math.sin(a)
            z = height - rng.uniform(0.6, 1.2)
            bpy.ops.object.light_add(type="POINT", location=(x, y, z))
            bpy.context.object.data.energy = rng.uniform(40, 250)
            bpy.context.object.data.shadow_soft_size = rng.uniform(0.02, 0.06)
            bpy.context.object.data.color = (1.0, rng.uniform(0.7, 0.95), rng.uniform(0.45, 0.8))
            bpy.ops.mesh.primitive_cylinder_add(
                vertices=32,
                radius=rng.uniform(0.12, 0.25),
                depth=rng.uniform(0.2, 0.35),
                end_fill_type="NOTHING",
                location=(x, y, z),
            )
            bpy.context.object.data.materials.append(shade)
            bpy.ops.mesh.primitive_cylinder_add(radius=0.004, depth=height - z, location=(x, y, (height + z) / 2))
            bpy.context.object.data.materials.append(cord)
    else:  # wallwash
        side = rng.choice(("w", "e", "s"))
        d = half - rng.uniform(0.3, 0.8)
        # an area light shines along its local -z: turned to face the wall, tilted up a little
        loc, rot = {
            "w": ((-d, rng.uniform(-0.5, 0.5) * half, height * 0.6), (0, math.pi / 2 + 0.3, 0)),
            "e": ((d, rng.uniform(-0.5, 0.5) * half, height * 0.6), (0, -math.pi / 2 - 0.3, 0)),
            "s": ((rng.uniform(-0.5, 0.5) * half, -d, height * 0.6), (-math.pi / 2 - 0.3, 0, 0)),
        }[side]
        bpy.ops.object.light_add(type="AREA", location=loc, rotation=rot)
        bpy.context.object.data.size = rng.uniform(0.2, 1.0)
        bpy.context.object.data.energy = rng.uniform(150, 700)


MEDIA_SORTS = ("air", "mist", "smoke", "glow")


def _volume_material(name, rng, density, noise=0.0, emission=0.0, drift=None, frames=0):
    """A Principled Volume of ``density`` per metre: homogeneous, or where ``noise`` (cycles
    per metre) is given shaped by a noise texture in object space, thresholded so that it
    comes in clouds with clear air between them, drifting by ``drift`` (x, y, z metres over
    the sequence, keyed; a volume gives no motion vectors, as in any engine); emissive
    (``emission``, blackbody or a colour) where asked."""
    import bpy

    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.remove(nodes["Principled BSDF"])
    vol = nodes.new("ShaderNodeVolumePrincipled")
    vol.inputs["Color"].default_value = (*[rng.uniform(0.6, 1.0) for _ in range(3)], 1.0)
    vol.inputs["Anisotropy"].default_value = rng.uniform(-0.3, 0.8)
    if noise:
        coords = nodes.new("ShaderNodeTexCoord")
        mapping = nodes.new("ShaderNodeMapping")
        tex = nodes.new("ShaderNodeTexNoise")
        tex.inputs["Scale"].default_value = noise
        tex.inputs["Detail"].default_value = rng.uniform(1.0, 6.0)
        ramp = nodes.new("ShaderNodeMapRange")
        low = rng.uniform(0.4, 0.55)
        ramp.inputs["From Min"].default_value, ramp.inputs["From Max"].default_value = low, low + rng.uniform(0.1, 0.3)
        ramp.inputs["To Max"].default_value = density
        links.new(coords.outputs["Object"], mapping.inputs["Vector"])
        links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
        links.new(tex.outputs["Fac"], ramp.inputs["Value"])
        links.new(ramp.outputs["Result"], vol.inputs["Density"])
        if drift:
            loc = mapping.inputs["Location"]
            for f, t in ((0, 0.0), (frames + 1, 1.0)):
                loc.default_value = [-d * t for d in drift]
                loc.keyframe_insert("default_value", frame=f)
    else:
        vol.inputs["Density"].default_value = density
    if emission:
        if rng.random() < 0.5:
            vol.inputs["Blackbody Intensity"].default_value = emission
            vol.inputs["Temperature"].default_value = rng.uniform(1200, 3500)
        else:
            vol.inputs["Emission Strength"].default_value = emission
            vol.inputs["Emission Color"].default_value = (*[rng.uniform(0.2, 1.0) for _ in range(3)], 1.0)
    links.new(vol.outputs[0], nodes["Material Output"].inputs["Volume"])
    return mat


def _media(scene, rng, frames):
    """The ``media`` training kind: a ``lights`` scene (any world, a room or open ground,
    two to four light rigs of every sort) in participating media of one or two sorts
    (``MEDIA_SORTS``): air, a homogeneous haze filling the scene (0.005-0.08 per metre); mist,
    clouds of noise up to 0.03-0.4 per metre drifting through it; smoke, dense noisy blobs (1-12 per metre)
    hanging or sliding among the props; glow, an emissive blob (blackbody or a colour).
    Written after the held-out ``haze`` had been seen failing (docs/dataset.md, "Splits"), so
    that the grove-haze split no longer measures unseen volumes. Returns (moving objects,
    camera target, radius, height)."""
    import bpy

    moving, target, radius, height = _mixed(scene, rng, frames, RIGS + LIGHTS_RIGS, (2, 4))
    sorts = rng.sample(MEDIA_SORTS, rng.randint(1, 2))
    reach = max(radius + 1.0, 4.0)
    for sort in sorts:
        if sort in ("air", "mist"):  # a box holding the whole scene, the camera inside it
            top = rng.uniform(2.5, 4.0) if sort == "air" else rng.uniform(1.0, 3.0)
            noise = 0.0 if sort == "air" else rng.uniform(0.3, 1.5)
            drift = [rng.uniform(-1.5, 1.5), rng.uniform(-1.5, 1.5), rng.uniform(-0.3, 0.3)]
            mat = _volume_material(
                sort,
                rng,
                rng.uniform(0.005, 0.08) if sort == "air" else rng.uniform(0.03, 0.4),
                noise,
                drift=drift if rng.random() < 0.5 else None,
                frames=frames,
            )
            bpy.ops.mesh.primitive_cube_add(size=1, location=(0, 0, top / 2 + 0.01))
            bpy.context.object.scale = (2 * reach, 2 * reach, top)
            bpy.context.object.data.materials.append(mat)
            continue
        for i in range(rng.randint(1, 4) if sort == "smoke" else rng.randint(1, 2)):
            s = rng.uniform(0.4, 2.0)
            loc = (
                rng.uniform(-2.0, 2.0),
                rng.uniform(-2.0, 2.0),
                rng.uniform(s / 3, 2.0),
            )  # inside the camera's circle
            if rng.random() < 0.5:
                bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=3, radius=s / 2, location=loc)
            else:
                bpy.ops.mesh.primitive_cube_add(size=s, location=loc, rotation=(0, 0, rng.uniform(0, 3)))
            obj = bpy.context.object
            obj.data.materials.append(
                _volume_material(
                    f"{sort}{i}",
                    rng,
                    rng.uniform(1.0, 12.0) if sort == "smoke" else rng.uniform(0.5, 5.0),
                    rng.uniform(0.8, 4.0) / s,
                    emission=rng.uniform(1.0, 20.0) if sort == "glow" else 0.0,
                )
            )
            if _slides(obj, rng, frames, 0.4, 1.0):
                moving.append(obj)
    return moving, target, radius, height


def _atrium(scene, rng, frames):
    """The ``atrium`` kind of the holdout split: a tall court roofed but for a skylight, the sun and sky
    coming in through it; a ring of columns, a thin metal railing, a still glossy pool."""
    import bpy

    _world(scene, rng, "sky")
    half, height, t = rng.uniform(5.0, 7.0), rng.uniform(5.0, 7.0), 0.2
    walls = _material(
        "walls",
        rng,
        rough=rng.uniform(0.4, 0.9),
        texture=rng.choice(("brick", "noise")) if rng.random() < 0.6 else None,
    )
    stone = _material("stone", rng, rough=rng.uniform(0.1, 0.5), texture=rng.choice(TEXTURES))
    _box("floor", (2 * half, 2 * half, t), (0, 0, -t / 2), stone)
    for name, size, loc in (
        ("w", (t, 2 * half, height), (-half, 0, height / 2)),
        ("e", (t, 2 * half, height), (half, 0, height / 2)),
        ("s", (2 * half, t, height), (0, -half, height / 2)),
        ("n", (2 * half, t, height), (0, half, height / 2)),
    ):
        _box(f"wall_{name}", size, loc, walls)
    o = rng.uniform(1.2, 2.5)  # half the skylight's side: the roof is four slabs around it
    side = half - o
    _box("roof_n", (2 * half, side, t), (0, (half + o) / 2, height + t / 2), walls)
    _box("roof_s", (2 * half, side, t), (0, -(half + o) / 2, height + t / 2), walls)
    _box("roof_e", (side, 2 * o, t), ((half + o) / 2, 0, height + t / 2), walls)
    _box("roof_w", (side, 2 * o, t), (-(half + o) / 2, 0, height + t / 2), walls)
    bpy.ops.object.light_add(
        type="SUN", rotation=(math.radians(rng.uniform(5, 30)), 0, math.radians(rng.uniform(0, 360)))
    )
    bpy.context.object.data.energy = rng.uniform(3.0, 8.0)
    bpy.context.object.data.angle = math.radians(rng.uniform(0.5, 2.0))
    ring, n = rng.uniform(0.55, 0.8) * half, rng.randint(6, 10)
    column = _material("column", rng, rough=rng.uniform(0.3, 0.8), color=[rng.uniform(0.6, 0.9)] * 3)
    for i in range(n):
        a = 2 * math.pi * i / n
        bpy.ops.mesh.primitive_cylinder_add(
            radius=rng.uniform(0.05, 0.12), depth=height, location=(ring * math.cos(a), ring * math.sin(a), height / 2)
        )
        bpy.context.object.data.materials.append(column)
    rail = _material("rail", rng, metal=True, rough=rng.uniform(0.1, 0.4))
    bpy.ops.mesh.primitive_torus_add(
        major_radius=ring,
        minor_radius=rng.uniform(0.01, 0.02),
        location=(0, 0, rng.uniform(0.9, 1.1)),
        major_segments=96,
    )
    bpy.context.object.data.materials.append(rail)
    pool = _material("pool", rng, rough=rng.uniform(0.0, 0.05), color=(0.02, 0.05, rng.uniform(0.08, 0.2)))
    _box("pool", (rng.uniform(1.5, 3.0), rng.uniform(1.5, 3.0), 0.02), (0, 0, 0.01), pool)
    moving = _objects(rng, rng.randint(4, 8), 0.45 * half, 0.3, 0.4, frames)
    return moving, (0, 0, 1.0), rng.uniform(0.3, 0.5) * half, rng.uniform(1.2, 2.5)


def _workshop(scene, rng, frames):
    """The ``workshop`` kind of the holdout split: a closed room lit only by one or two pendant lamps in
    open metal shades (hard-edged pools of light), a bench crowded with small props, and a
    fan whose thin blades spin about a vertical axis."""
    import bpy

    _world(scene, rng, "dark")
    _room(rng, 4.0, 2.6, window=False, texture_walls=True)
    shade = _material("shade", rng, metal=True, rough=rng.uniform(0.2, 0.5))
    for i in range(rng.randint(1, 2)):
        x, y, z = rng.uniform(-1.5, 1.5), rng.uniform(-1.0, 1.0), rng.uniform(1.7, 2.2)
        bpy.ops.object.light_add(type="POINT", location=(x, y, z))
        light = bpy.context.object.data
        light.energy = rng.uniform(100, 400)
        light.shadow_soft_size = rng.uniform(0.02, 0.08)
        light.color = (1.0, rng.uniform(0.7, 0.9), rng.uniform(0.5, 0.7))
        # the shade: a cone open at the bottom around the lamp (its apex up)
        bpy.ops.mesh.primitive_cone_add(
            vertices=32, radius1=rng.uniform(0.15, 0.3), depth=0.3, end_fill_type="NOTHING", location=(x, y, z + 0.08)
        )
        bpy.context.object.data.materials.append(shade)
    wood = _material("bench", rng, rough=rng.uniform(0.3, 0.7), texture="noise")
    bx, by = rng.uniform(-0.8, 0.8), rng.uniform(-0.5, 0.5)
    _box("bench", (2.4, 1.0, 0.06), (bx, by, 0.9), wood)
    for sx in (-1, 1):
        for sy in (-1, 1):
            _box(f"leg{sx}{sy}", (0.06, 0.06, 0.87), (bx + 1.1 * sx, by + 0.42 * sy, 0.435), wood)
    for i in range(rng.randint(12, 25)):  # small props on the bench, a few pixels to a few dozen wide
        s = rng.uniform(0.03, 0.15)
        loc = (bx + rng.uniform(-1.1, 1.1), by + rng.uniform(-0.45, 0.45), 0.93 + s / 2)
        shape = rng.choice(("cube", "sphere", "cylinder"))
        if shape == "cube":
            bpy.ops.mesh.primitive_cube_add(size=s, location=loc, rotation=(0, 0, rng.uniform(0, 3)))
        elif shape == "sphere":
            bpy.ops.mesh.primitive_uv_sphere_add(radius=s / 2, location=loc)
            bpy.ops.object.shade_smooth()
        else:
            bpy.ops.mesh.primitive_cylinder_add(radius=s / 3, depth=s, location=loc)
        r = rng.random()
        bpy.context.object.data.materials.append(
            _material(f"prop{i}", rng, metal=r < 0.3, texture=rng.choice(TEXTURES) if rng.random() < 0.5 else None)
        )
    # the fan: blades parented to a hub that turns at a constant rate
    fx, fy, fz = rng.choice((-2.5, 2.5)), rng.uniform(-2.0, 2.0), rng.uniform(1.0, 1.6)
    metal = _material("fan", rng, metal=True, rough=rng.uniform(0.2, 0.5))
    bpy.ops.mesh.primitive_cylinder_add(radius=0.015, depth=fz, location=(fx, fy, fz / 2))
    bpy.context.object.data.materials.append(metal)
    hub = bpy.data.objects.new("fan_hub", None)
    scene.collection.objects.link(hub)
    hub.location = (fx, fy, fz)
    blades, length = rng.randint(3, 5), rng.uniform(0.25, 0.45)
    for k in range(blades):
        a = 2 * math.pi * k / blades
        blade = _box(
            f"blade{k}",
            (length, 0.07, 0.006),
            (0.55 * length * math.cos(a), 0.55 * length * math.sin(a), 0),
            metal,
            (0.25, 0, a),
        )
        blade.parent = hub
    turn = rng.uniform(0.05, 0.25) * rng.choice((-1, 1))  # radians a frame
    for f in (0, frames + 1):
        hub.rotation_euler[2] = turn * f
        hub.keyframe_insert("rotation_euler", frame=f)
    moving = _objects(rng, rng.randint(2, 4), 2.5, 0.3, 0.5, frames) + [hub]
    return moving, (bx, by, 1.0), rng.uniform(2.2, 3.0), rng.uniform(1.3, 2.0)


def _key_path(obj, frames, start, step):
    """Key ``obj`` moving by ``step`` (x, y, z) a frame from ``start``, one frame beyond each
    end (Cycles evaluates frame - 1 and frame + 1 for the Vector pass)."""
    for f in (0, frames + 1):
        obj.location = tuple(a + b * f for a, b in zip(start, step))
        obj.keyframe_insert("location", frame=f)


def _street(scene, rng, frames):
    """The ``street`` kind of the street-studio held-out split: a wet road at dusk between two rows of facades
    with lit windows, street lamps on thin poles, and one to three cars driving along it
    whose headlights (emissive discs and spot lights) move with them."""
    import bpy

    _world(scene, rng, "dusk")
    road_half = rng.uniform(3.0, 4.5)
    road = _material(
        "asphalt", rng, rough=rng.uniform(0.03, 0.25), color=[rng.uniform(0.03, 0.08)] * 3, texture="noise"
    )
    _box("road", (60, 2 * road_half, 0.1), (0, 0, -0.05), road)
    kerb = _material("pavement", rng, rough=rng.uniform(0.4, 0.9), texture=rng.choice(("brick", "checker")))
    for side in (-1, 1):
        _box(f"pavement{side}", (60, 2.5, 0.25), (0, side * (road_half + 1.25), 0.075), kerb)
        x = -20.0
        while x < 20.0:  # facades of random widths and heights, windows lit at random
            width, tall, depth = rng.uniform(4, 9), rng.uniform(6, 18), 4.0
            y = side * (road_half + 2.5 + depth / 2)
            _box(
                f"house{side}_{x:.0f}",
                (width, depth, tall),
                (x + width / 2, y, tall / 2),
                _material(
                    f"facade{side}_{x:.0f}",
                    rng,
                    rough=rng.uniform(0.5, 0.95),
                    texture=rng.choice(("brick", "noise", None)),
                ),
            )
            lit = _material(
                f"window{side}_{x:.0f}",
                rng,
                emission=rng.uniform(1.0, 12.0),
                rough=0.3,
                color=(1.0, rng.uniform(0.6, 0.95), rng.uniform(0.3, 0.8)),
            )
            dark = _material(f"glass{side}_{x:.0f}", rng, rough=0.05, color=(0.02, 0.02, 0.03))
            for fx in range(int(width // 1.5)):
                for fz in range(int((tall - 1.0) // 2.5)):
                    wx = x + 0.75 + 1.5 * fx
                    _box(
                        f"w{side}_{wx:.1f}_{fz}",
                        (0.8, 0.05, 1.2),
                        (wx, y - side * (depth / 2 + 0.03), 1.8 + 2.5 * fz),
                        lit if rng.random() < 0.4 else dark,
                    )
            x += width + rng.uniform(0.0, 1.0)
    pole = _material("pole", rng, metal=True, rough=rng.uniform(0.3, 0.6), color=(0.3, 0.3, 0.32))
    lamp = _material("lamp", rng, emission=rng.uniform(20.0, 60.0), rough=0.5, color=(1.0, 0.85, 0.6))
    x0 = rng.uniform(-12, -6)
    for k in range(rng.randint(3, 5)):
        side = 1 if k % 2 else -1
        x, y, h = x0 + k * rng.uniform(5, 8), side * (road_half + 0.4), rng.uniform(4.0, 6.0)
        bpy.ops.mesh.primitive_cylinder_add(radius=0.06, depth=h, location=(x, y, h / 2))
        bpy.context.object.data.materials.append(pole)
        _emitter(f"globe{k}", 0.18, (x, y, h + 0.1), lamp)
        bpy.ops.object.light_add(type="SPOT", location=(x, y, h - 0.1))
        light = bpy.context.object.data
        light.energy = rng.uniform(800, 2500)
        light.spot_size = math.radians(rng.uniform(70, 110))
        light.spot_blend = rng.uniform(0.2, 0.6)
        light.color = (1.0, 0.8, 0.55)
    moving = []
    for c in range(rng.randint(1, 3)):
        lane = rng.choice((-1, 1)) * road_half / 2
        speed = rng.uniform(0.25, 0.8) * (1 if lane < 0 else -1)  # metres a frame, driving on the right
        start = (rng.uniform(-4, 4) - speed * frames / 2, lane, 0.0)
        car = bpy.data.objects.new(f"car{c}", None)
        scene.collection.objects.link(car)
        paint = _material(f"paint{c}", rng, metal=rng.random() < 0.5, rough=rng.uniform(0.1, 0.4))
        body = _box(f"body{c}", (4.2, 1.8, 0.8), (0, 0, 0.65), paint)
        cabin = _box(
            f"cabin{c}",
            (2.2, 1.6, 0.6),
            (-0.3, 0, 1.35),
            _material(f"cabin{c}", rng, rough=0.05, color=(0.05, 0.06, 0.08)),
        )
        parts = [body, cabin]
        front = 2.1 if speed > 0 else -2.1
        head = _material(f"head{c}", rng, emission=rng.uniform(30.0, 80.0), rough=0.5, color=(1.0, 0.95, 0.85))
        tail = _material(f"tail{c}", rng, emission=rng.uniform(5.0, 20.0), rough=0.5, color=(1.0, 0.05, 0.02))
        for sy in (-0.65, 0.65):
            parts.append(_emitter(f"head{c}{sy}", 0.1, (front * 1.01, sy, 0.7), head))
            parts.append(_box(f"tail{c}{sy}", (0.04, 0.3, 0.12), (-front * 1.0, sy, 0.8), tail))
            # a spot shines along its -Z: -84 degrees about Y aims it ahead (+X) and a little down
            bpy.ops.object.light_add(
                type="SPOT", location=(front * 1.05, sy, 0.7), rotation=(0, math.radians(-84 if speed > 0 else 84), 0)
            )
            light = bpy.context.object
            light.data.energy = rng.uniform(300, 900)
            light.data.spot_size = math.radians(rng.uniform(40, 60))
            light.data.spot_blend = 0.3
            parts.append(light)
        for obj in parts:
            obj.parent = car
        _key_path(car, frames, start, (speed, 0.0, 0.0))
        moving.append(car)
    # the camera stays off the facades: at most 2 m from the road's edge (its path's radius)
    return moving, (rng.uniform(-2, 2), 0, 1.2), rng.uniform(3.5, road_half + 2.0), rng.uniform(1.5, 4.0)


def _studio_material(name, rng, sort):
    """A Principled BSDF of one of the sorts no other kind uses."""
    m = _material(name, rng, rough=rng.uniform(0.2, 0.6))
    bsdf = m.node_tree.nodes["Principled BSDF"]
    if sort == "subsurface":  # wax, skin, marble
        bsdf.inputs["Subsurface Weight"].default_value = 1.0
        bsdf.inputs["Subsurface Radius"].default_value = [rng.uniform(0.2, 1.0) for _ in range(3)]
        bsdf.inputs["Subsurface Scale"].default_value = rng.uniform(0.02, 0.2)
    elif sort == "sheen":  # cloth, velvet
        bsdf.inputs["Sheen Weight"].default_value = 1.0
        bsdf.inputs["Sheen Roughness"].default_value = rng.uniform(0.2, 0.8)
        bsdf.inputs["Roughness"].default_value = 0.9
    elif sort == "coat":  # car paint, lacquer
        bsdf.inputs["Coat Weight"].default_value = 1.0
        bsdf.inputs["Coat Roughness"].default_value = rng.uniform(0.0, 0.1)
        bsdf.inputs["Metallic"].default_value = rng.choice((0.0, 1.0))
    elif sort == "anisotropic":  # brushed metal
        bsdf.inputs["Metallic"].default_value = 1.0
        bsdf.inputs["Anisotropic"].default_value = rng.uniform(0.5, 1.0)
        bsdf.inputs["Anisotropic Rotation"].default_value = rng.uniform(0.0, 1.0)
        bsdf.inputs["Roughness"].default_value = rng.uniform(0.15, 0.5)
    else:  # thin film over a dark dielectric: soap bubble, oil slick colours
        bsdf.inputs["Thin Film Thickness"].default_value = rng.uniform(200, 800)
        bsdf.inputs["Roughness"].default_value = rng.uniform(0.02, 0.2)
        bsdf.inputs["Base Color"].default_value = (0.05, 0.05, 0.05, 1.0)
    return m


STUDIO_SORTS = ("subsurface", "sheen", "coat", "anisotropic", "thin_film")


def _studio(scene, rng, frames):
    """The ``studio`` kind of the street-studio held-out split: a seamless backdrop curving from floor to wall
    under two or three large softboxes, a turntable carrying a smooth hero object, props of
    materials no other kind uses, and a fine wire mesh."""
    import bpy

    _world(scene, rng, "dark")
    backdrop = _material("backdrop", rng, rough=rng.uniform(0.6, 1.0), color=[rng.uniform(0.3, 0.85)] * 3)
    # floor (up to y = 4), a cove (the inside of a quarter cylinder of radius r) and a wall
    r = rng.uniform(1.0, 2.0)
    _box("floor", (20, 14, 0.1), (0, -3.0, -0.05), backdrop)
    profile = [
        (4.0 + r * math.cos(a), r + r * math.sin(a)) for a in (-math.pi / 2 + math.pi / 2 * k / 24 for k in range(25))
    ]
    verts = [(x, y, z) for x in (-10.0, 10.0) for y, z in profile]
    faces = [(k, k + 1, 26 + k, 25 + k) for k in range(24)]
    mesh = bpy.data.meshes.new("cove")
    mesh.from_pydata(verts, [], faces)
    mesh.materials.append(backdrop)
    for poly in mesh.polygons:
        poly.use_smooth = True
    cove = bpy.data.objects.new("cove", mesh)
    scene.collection.objects.link(cove)
    _box("wall", (20, 0.1, 10), (0, 4.0 + r + 0.05, r + 5), backdrop)
    for k in range(rng.randint(2, 3)):  # large softboxes around the set
        a = rng.uniform(-2.4, 2.4) if k else rng.uniform(-0.6, 0.6)
        d, h = rng.uniform(3.0, 5.0), rng.uniform(2.0, 4.0)
        bpy.ops.object.light_add(type="AREA", location=(d * math.sin(a), -d * math.cos(a), h))
        light = bpy.context.object
        light.data.shape = "RECTANGLE"
        light.data.size, light.data.size_y = rng.uniform(1.0, 2.5), rng.uniform(1.0, 2.5)
        light.data.energy = rng.uniform(300, 1500) / (k + 1)
        light.data.color = (1.0, rng.uniform(0.85, 1.0), rng.uniform(0.75, 1.0))
        track = light.constraints.new("TRACK_TO")
        aim = bpy.data.objects.new(f"aim{k}", None)
        scene.collection.objects.link(aim)
        aim.location = (0, 0, 0.6)
        track.target = aim
    table = _material("turntable", rng, rough=0.3, color=(0.05, 0.05, 0.05))
    bpy.ops.mesh.primitive_cylinder_add(vertices=64, radius=0.9, depth=0.1, location=(0, 0, 0.05))
    bpy.context.object.data.materials.append(table)
    spin = bpy.data.objects.new("turntable_hub", None)
    scene.collection.objects.link(spin)
    hero = rng.choice(("monkey", "torus_knot", "sphere"))
    if hero == "monkey":
        bpy.ops.mesh.primitive_monkey_add(size=0.9, location=(0, 0, 0.6))
        bpy.ops.object.modifier_add(type="SUBSURF")
        bpy.context.object.modifiers[-1].levels = 2
    elif hero == "torus_knot":
        bpy.ops.mesh.primitive_torus_add(
            major_radius=0.4,
            minor_radius=0.12,
            location=(0, 0, 0.6),
            rotation=(rng.uniform(0.3, 1.2), 0, 0),
            major_segments=96,
        )
    else:
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.45, location=(0, 0, 0.55), segments=64, ring_count=32)
    bpy.ops.object.shade_smooth()
    obj = bpy.context.object
    obj.data.materials.append(_studio_material("hero", rng, rng.choice(STUDIO_SORTS)))
    obj.parent = spin
    turn = rng.uniform(0.04, 0.15) * rng.choice((-1, 1))  # radians a frame
    for f in (0, frames + 1):
        spin.rotation_euler[2] = turn * f
        spin.keyframe_insert("rotation_euler", frame=f)
    for i in range(rng.randint(4, 7)):  # props on the backdrop, one material sort each
        a, d = rng.uniform(0, 2 * math.pi), rng.uniform(1.3, 2.8)
        x, y, s = d * math.cos(a), min(d * math.sin(a), 3.0), rng.uniform(0.2, 0.6)
        shape = rng.choice(("cube", "sphere", "cylinder", "cone"))
        if shape == "cube":
            bpy.ops.mesh.primitive_cube_add(size=s, location=(x, y, s / 2), rotation=(0, 0, rng.uniform(0, 3)))
            bpy.ops.object.modifier_add(type="BEVEL")
            bpy.context.object.modifiers[-1].width = s * 0.1
            bpy.context.object.modifiers[-1].segments = 3
        elif shape == "sphere":
            bpy.ops.mesh.primitive_uv_sphere_add(radius=s / 2, location=(x, y, s / 2), segments=48, ring_count=24)
            bpy.ops.object.shade_smooth()
        elif shape == "cylinder":
            bpy.ops.mesh.primitive_cylinder_add(vertices=48, radius=s / 3, depth=s * 1.4, location=(x, y, s * 0.7))
            bpy.ops.object.shade_smooth()
        else:
            bpy.ops.mesh.primitive_cone_add(vertices=48, radius1=s / 2, depth=s, location=(x, y, s / 2))
            bpy.ops.object.shade_smooth()
        bpy.context.object.data.materials.append(_studio_material(f"prop{i}", rng, rng.choice(STUDIO_SORTS)))
    # a fine wire mesh standing behind the set: a grid turned into thin struts
    cells = rng.randint(12, 30)
    bpy.ops.mesh.primitive_grid_add(
        x_subdivisions=cells,
        y_subdivisions=cells,
        size=rng.uniform(1.2, 2.0),
        location=(rng.uniform(-1.5, 1.5), rng.uniform(1.5, 2.5), 1.0),
        rotation=(math.pi / 2, 0, rng.uniform(-0.5, 0.5)),
    )
    bpy.ops.object.modifier_add(type="WIREFRAME")
    bpy.context.object.modifiers[-1].thickness = rng.uniform(0.004, 0.012)
    bpy.context.object.data.materials.append(_material("wire", rng, metal=True, rough=rng.uniform(0.2, 0.5)))
    return [spin], (0, 0, 0.6), rng.uniform(2.6, 4.0), rng.uniform(1.0, 2.2)


def _cards(name, rng, n, centre, extent, size, material):
    """One mesh of ``n`` small quads (leaf cards) at random points of an ellipsoid
    (``extent``: its half axes) about ``centre``, each at a random angle."""
    import bpy

    verts, faces = [], []
    for k in range(n):
        while True:
            u = [rng.uniform(-1, 1) for _ in range(3)]
            if sum(x * x for x in u) <= 1:
                break
        c = [centre[j] + u[j] * extent[j] for j in range(3)]
        a, b = rng.uniform(0, 2 * math.pi), rng.uniform(0, math.pi)
        # two unit vectors spanning the card: one in the horizontal plane, one tilted by b
        e1 = (math.cos(a), math.sin(a), 0.0)
        e2 = (-math.sin(a) * math.cos(b), math.cos(a) * math.cos(b), math.sin(b))
        s1, s2 = size * rng.uniform(0.6, 1.4), size * rng.uniform(0.3, 0.7)
        base = len(verts)
        for p, q in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            verts.append(tuple(c[j] + p * s1 / 2 * e1[j] + q * s2 / 2 * e2[j] for j in range(3)))
        faces.append((base, base + 1, base + 2, base + 3))
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _leaf_material(name, rng):
    """Foliage: a diffuse-glossy leaf mixed with a translucent closure (light through the leaf)."""
    import bpy

    m = bpy.data.materials.new(name)
    m.use_nodes = True
    nodes, links = m.node_tree.nodes, m.node_tree.links
    green = (rng.uniform(0.03, 0.25), rng.uniform(0.15, 0.5), rng.uniform(0.02, 0.12), 1.0)
    bsdf = nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = green
    bsdf.inputs["Roughness"].default_value = rng.uniform(0.3, 0.7)
    tl = nodes.new("ShaderNodeBsdfTranslucent")
    tl.inputs["Color"].default_value = (green[0] * 1.5, green[1] * 1.5, green[2], 1.0)
    mix = nodes.new("ShaderNodeMixShader")
    mix.inputs["Fac"].default_value = rng.uniform(0.2, 0.5)
    links.new(bsdf.outputs[0], mix.inputs[1])
    links.new(tl.outputs[0], mix.inputs[2])
    links.new(mix.outputs[0], nodes["Material Output"].inputs["Surface"])
    return m


def _grove(scene, rng, frames):
    """The ``grove`` kind of the grove-haze held-out split: three to six trees (a tapering trunk, a few branches,
    one or two crowns of 300-900 leaf cards that sway), grass of thin blades, a low sun through
    the crowns casting dappled light, a sky. Returns (moving objects, camera target, radius,
    height)."""
    import bpy

    _world(scene, rng, "sky")
    bpy.ops.object.light_add(
        type="SUN", rotation=(math.radians(rng.uniform(30, 65)), 0, math.radians(rng.uniform(0, 360)))
    )
    bpy.context.object.data.energy = rng.uniform(3.0, 6.0)
    bpy.context.object.data.angle = math.radians(rng.uniform(0.3, 1.5))
    soil = _material(
        "soil", rng, rough=0.9, color=(rng.uniform(0.1, 0.25), rng.uniform(0.08, 0.18), 0.05), texture="noise"
    )
    _box("soil", (40, 40, 0.1), (0, 0, -0.05), soil)
    bark = _material(
        "bark", rng, rough=0.8, color=(rng.uniform(0.1, 0.3), rng.uniform(0.07, 0.2), 0.05), texture="voronoi"
    )
    moving = []
    for i in range(rng.randint(3, 6)):
        a, r = rng.uniform(0, 2 * math.pi), rng.uniform(1.0, 3.5)
        x, y, h = r * math.cos(a), r * math.sin(a), rng.uniform(2.0, 4.0)
        bpy.ops.mesh.primitive_cone_add(
            vertices=24, radius1=rng.uniform(0.06, 0.15), radius2=0.02, depth=h, location=(x, y, h / 2)
        )
        bpy.context.object.data.materials.append(bark)
        for k in range(rng.randint(2, 5)):  # branches: thin cylinders leaning out of the trunk
            z, ang, ln = rng.uniform(0.4, 0.85) * h, rng.uniform(0, 2 * math.pi), rng.uniform(0.4, 1.2)
            bpy.ops.mesh.primitive_cylinder_add(
                vertices=12,
                radius=rng.uniform(0.01, 0.03),
                depth=ln,
                location=(x + 0.4 * ln * math.cos(ang), y + 0.4 * ln * math.sin(ang), z + 0.2 * ln),
                rotation=(0, rng.uniform(0.6, 1.2), ang),
            )
            bpy.context.object.data.materials.append(bark)
        leaves = _leaf_material(f"leaf{i}", rng)
        for k in range(rng.randint(1, 2)):
            e = (rng.uniform(0.6, 1.3), rng.uniform(0.6, 1.3), rng.uniform(0.5, 1.0))
            crown = _cards(
                f"crown{i}_{k}",
                rng,
                rng.randint(300, 900),
                (x + rng.uniform(-0.3, 0.3), y + rng.uniform(-0.3, 0.3), h * rng.uniform(0.75, 0.95)),
                e,
                rng.uniform(0.05, 0.14),
                leaves,
            )
            # swaying in the wind: a small tilt back and forth about the crown's own centre
            bpy.context.view_layer.objects.active = crown
            crown.select_set(True)
            bpy.ops.object.origin_set(type="ORIGIN_GEOMETRY", center="BOUNDS")
            crown.select_set(False)
            amp, period = rng.uniform(0.01, 0.05), rng.uniform(4, 10)
            for f in range(0, frames + 2):
                crown.rotation_euler[0] = amp * math.sin(2 * math.pi * f / period)
                crown.rotation_euler[1] = amp * math.cos(2 * math.pi * f / period)
                crown.keyframe_insert("rotation_euler", frame=f)
            moving.append(crown)
    blades = _leaf_material("grass", rng)
    for k in range(rng.randint(3, 6)):  # tufts of grass: thin upright cards
        gx, gy = rng.uniform(-3, 3), rng.uniform(-3, 3)
        verts, faces = [], []
        for j in range(rng.randint(150, 400)):
            px, py = gx + rng.gauss(0, 0.4), gy + rng.gauss(0, 0.4)
            ht, wd, a = rng.uniform(0.1, 0.4), 0.006, rng.uniform(0, math.pi)
            lean = (rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1))
            b = len(verts)
            verts += [
                (px - wd * math.cos(a), py - wd * math.sin(a), 0),
                (px + wd * math.cos(a), py + wd * math.sin(a), 0),
                (px + lean[0], py + lean[1], ht),
            ]
            faces.append((b, b + 1, b + 2))
        mesh = bpy.data.meshes.new(f"tuft{k}")
        mesh.from_pydata(verts, [], faces)
        mesh.materials.append(blades)
        scene.collection.objects.link(bpy.data.objects.new(f"tuft{k}", mesh))
    return moving, (0, 0, rng.uniform(0.8, 1.8)), rng.uniform(4.0, 6.0), rng.uniform(1.0, 2.2)


def _haze(scene, rng, frames):
    """The ``haze`` kind of the grove-haze held-out split: a closed hall filled with a homogeneous scattering volume
    (density 0.02-0.12 per metre, forward scattering), lit by spot lights hung high and aimed down
    and by the sun through one or two openings in the roof, so that beams stand in the air; two
    rows of columns along the walls, crates in the middle, a few of them sliding. Returns (moving
    objects, camera target, radius, height)."""
    import bpy

    _world(scene, rng, "sky")
    half, height = rng.uniform(4.0, 6.0), rng.uniform(4.0, 6.0)
    wall = _material("hall", rng, rough=rng.uniform(0.6, 1.0), color=[rng.uniform(0.3, 0.7)] * 3)
    floor = _material("hall_floor", rng, rough=rng.uniform(0.3, 0.9), texture=rng.choice(("brick", "noise")))
    t = 0.2
    _box("floor", (2 * half, 2 * half, t), (0, 0, -t / 2), floor)
    _box("wall_w", (t, 2 * half, height), (-half, 0, height / 2), wall)
    _box("wall_e", (t, 2 * half, height), (half, 0, height / 2), wall)
    _box("wall_s", (2 * half, t, height), (0, -half, height / 2), wall)
    _box("wall_n", (2 * half, t, height), (0, half, height / 2), wall)
    # a roof with one or two openings along x: the sun comes in through them
    gaps = sorted(rng.sample([-0.5, -0.1, 0.3], rng.randint(1, 2)))
    edges = [-half] + [e for g in gaps for e in (g * half, g * half + 0.8)] + [half]
    for k in range(0, len(edges), 2):
        _box(
            f"roof{k}", (2 * half, edges[k + 1] - edges[k], t), (0, (edges[k] + edges[k + 1]) / 2, height + t / 2), wall
        )
    bpy.ops.object.light_add(
        type="SUN", rotation=(math.radians(rng.uniform(10, 35)), 0, math.radians(rng.uniform(-30, 30)))
    )
    bpy.context.object.data.energy = rng.uniform(8.0, 16.0)
    bpy.context.object.data.angle = math.radians(0.5)
    for i in range(rng.randint(1, 3)):
        bpy.ops.object.light_add(
            type="SPOT",
            location=(rng.uniform(-half + 1, half - 1), rng.uniform(-half + 1, half - 1), height - 0.3),
            rotation=(rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4), 0),
        )
        light = bpy.context.object.data
        light.energy, light.spot_size = rng.uniform(2000, 8000), math.radians(rng.uniform(15, 40))
        light.spot_blend, light.shadow_soft_size = rng.uniform(0.05, 0.3), rng.uniform(0.02, 0.1)
        light.color = [rng.uniform(0.7, 1.0) for _ in range(3)]
    # the air: a box just inside the hall with a Principled Volume
    air = bpy.data.materials.new("air")
    air.use_nodes = True
    nodes = air.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    vol = nodes.new("ShaderNodeVolumePrincipled")
    vol.inputs["Density"].default_value = rng.uniform(0.02, 0.12)
    vol.inputs["Anisotropy"].default_value = rng.uniform(0.2, 0.7)
    vol.inputs["Color"].default_value = (*[rng.uniform(0.8, 1.0) for _ in range(3)], 1.0)
    air.node_tree.links.new(vol.outputs[0], nodes["Material Output"].inputs["Volume"])
    bpy.ops.mesh.primitive_cube_add(size=1, location=(0, 0, height / 2))
    bpy.context.object.scale = (2 * half - 0.25, 2 * half - 0.25, height - 0.05)
    bpy.context.object.data.materials.append(air)
    col = _material("column", rng, rough=rng.uniform(0.3, 0.8))
    n = rng.randint(2, 4)
    for i in range(2 * n):  # two rows of columns along the long walls, the middle left clear
        x, y = -half + (i // 2 + 0.5) * 2 * half / n, (half - 0.7) * (1 if i % 2 else -1)
        bpy.ops.mesh.primitive_cylinder_add(
            vertices=32, radius=rng.uniform(0.15, 0.3), depth=height, location=(x, y, height / 2)
        )
        bpy.context.object.data.materials.append(col)
    moving = []
    for i in range(rng.randint(4, 9)):
        s = rng.uniform(0.3, 0.9)
        x, y = rng.uniform(-1.6, 1.6), rng.uniform(-1.6, 1.6)  # inside the camera's circle
        crate = _box(
            f"crate{i}",
            (s, s * rng.uniform(0.7, 1.4), s),
            (x, y, s / 2),
            _material(f"crate{i}", rng, metal=rng.random() < 0.3, texture=rng.choice(TEXTURES)),
            (0, 0, rng.uniform(0, math.pi)),
        )
        if rng.random() < 0.35:
            d = (rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0))
            for f, tt in ((0, 0.0), (frames + 1, 1.0)):
                crate.location = (x + d[0] * tt, y + d[1] * tt, s / 2)
                crate.keyframe_insert("location", frame=f)
            moving.append(crate)
    # the camera circles between the crates and the rows of columns
    return moving, (0, 0, rng.uniform(1.0, 2.0)), min(rng.uniform(2.6, 3.6), half - 1.3), rng.uniform(1.2, 2.5)


def _bathroom(scene, rng, frames):
    """The ``bathroom`` kind of the bathroom-fur held-out split: a small tiled room with one or two large plane mirrors
    (facing mirrors repeat the room into the distance), chrome rails and taps, a ceramic basin and
    tub, a frosted glass screen sliding along the tub, lit by strip lamps beside the mirror, a
    ceiling lamp, and on some draws daylight through a frosted window. Mirrors show the whole room
    in the specular layer, which no other kind has at this size. Returns (moving objects, camera
    target, radius, height)."""
    import bpy

    daylight = rng.random() < 0.5
    _world(scene, rng, "sky" if daylight else "dark")
    half, height = rng.uniform(1.6, 2.4), rng.uniform(2.4, 2.8)
    tile_colour = [rng.uniform(0.6, 0.95)] * 3 if rng.random() < 0.6 else [rng.uniform(0.1, 0.8) for _ in range(3)]
    wall = _material("tiles", rng, rough=rng.uniform(0.05, 0.3), color=tile_colour, texture="brick")
    floor = _material("floor_tiles", rng, rough=rng.uniform(0.1, 0.5), texture="checker")
    t = 0.1
    _box("floor", (2 * half, 2 * half, t), (0, 0, -t / 2), floor)
    _box(
        "ceiling",
        (2 * half, 2 * half, t),
        (0, 0, height + t / 2),
        _material("ceiling", rng, rough=0.8, color=[0.85, 0.85, 0.85]),
    )
    _box("wall_n", (2 * half, t, height), (0, half, height / 2), wall)
    _box("wall_s", (2 * half, t, height), (0, -half, height / 2), wall)
    _box("wall_w", (t, 2 * half, height), (-half, 0, height / 2), wall)
    if daylight:  # the east wall around a window of frosted glass, the sun through it
        z0, z1, y0, y1 = 1.2, 2.1, -0.5, 0.5
        _box("wall_e_s", (t, half + y0, height), (half, (-half + y0) / 2, height / 2), wall)
        _box("wall_e_n", (t, half - y1, height), (half, (half + y1) / 2, height / 2), wall)
        _box("wall_e_b", (t, y1 - y0, z0), (half, 0, z0 / 2), wall)
        _box("wall_e_t", (t, y1 - y0, height - z1), (half, 0, (z1 + height) / 2), wall)
        _box(
            "window",
            (0.01, y1 - y0, z1 - z0),
            (half, 0, (z0 + z1) / 2),
            _material("frosted", rng, glass=True, rough=rng.uniform(0.1, 0.4), color=[0.95, 0.95, 0.95]),
        )
        bpy.ops.object.light_add(
            type="SUN", rotation=(math.radians(rng.uniform(40, 65)), 0, math.radians(rng.uniform(60, 120)))
        )
        bpy.context.object.data.energy = rng.uniform(3.0, 7.0)
    else:
        _box("wall_e", (t, 2 * half, height), (half, 0, height / 2), wall)
    mirror = _material("mirror", rng, metal=True, rough=rng.uniform(0.0, 0.02), color=[0.92, 0.92, 0.92])
    w, h = rng.uniform(0.9, 1.8), rng.uniform(0.8, 1.2)
    _box("mirror_n", (w, 0.01, h), (rng.uniform(-0.3, 0.3), half - 0.06, 1.0 + h / 2), mirror)
    if rng.random() < 0.5:  # facing mirrors
        _box("mirror_s", (rng.uniform(0.8, 1.6), 0.01, h), (rng.uniform(-0.3, 0.3), -half + 0.06, 1.0 + h / 2), mirror)
    for side in (-1, 1):  # strip lamps either side of the north mirror
        _box(
            f"strip{side}",
            (0.05, 0.03, h),
            (side * (w / 2 + 0.12), half - 0.07, 1.0 + h / 2),
            _material(f"strip{side}", rng, emission=rng.uniform(4.0, 15.0), rough=0.5),
        )
    bpy.ops.object.light_add(type="AREA", location=(0, 0, height - 0.05))
    bpy.context.object.data.energy = rng.uniform(30, 150)
    bpy.context.object.data.size = rng.uniform(0.2, 0.5)
    ceramic = _material("ceramic", rng, rough=rng.uniform(0.03, 0.15), color=[0.92, 0.92, 0.9])
    chrome = _material("chrome", rng, metal=True, rough=rng.uniform(0.05, 0.2), color=[0.85, 0.86, 0.88])
    _box("basin", (0.6, 0.4, 0.15), (0, half - 0.3, 0.85), ceramic)
    _box(
        "cabinet",
        (0.7, 0.45, 0.78),
        (0, half - 0.3, 0.39),
        _material("cabinet", rng, rough=rng.uniform(0.2, 0.7), texture=rng.choice(("wave", "noise"))),
    )
    bpy.ops.mesh.primitive_cylinder_add(
        vertices=32, radius=0.015, depth=0.25, location=(0, half - 0.12, 1.0), rotation=(math.pi / 2.5, 0, 0)
    )
    bpy.context.object.data.materials.append(chrome)
    tub_x = -half + 0.45
    _box("tub", (0.75, 1.6, 0.55), (tub_x, -0.2, 0.275), ceramic)
    for _ in range(rng.randint(1, 3)):  # towel rails
        bpy.ops.mesh.primitive_cylinder_add(
            vertices=24,
            radius=0.012,
            depth=rng.uniform(0.5, 0.9),
            location=(
                half - 0.08 if not daylight else rng.uniform(-0.8, 0.8),
                -half + 0.08 if daylight else rng.uniform(-1.0, 1.0),
                rng.uniform(0.9, 1.6),
            ),
            rotation=(0, math.pi / 2, 0) if daylight else (math.pi / 2, 0, 0),
        )
        bpy.context.object.data.materials.append(chrome)
    screen = _box(
        "screen",
        (0.01, 0.8, 1.6),
        (tub_x + 0.38, -0.6, 0.55 + 0.8),
        _material("screen", rng, glass=True, rough=rng.uniform(0.0, 0.4), color=[0.9, 0.95, 0.95]),
    )
    moving = []
    d = rng.uniform(0.4, 0.8) * rng.choice((-1, 1))
    for f, tt in ((0, 0.0), (frames + 1, 1.0)):
        screen.location[1] = -0.6 + d * tt
        screen.keyframe_insert("location", frame=f)
    moving.append(screen)
    for i in range(rng.randint(2, 5)):  # bottles and jars on the basin and the tub's rim
        s = rng.uniform(0.04, 0.09)
        x, y, z = (rng.uniform(-0.3, 0.3), half - 0.2, 0.93) if i % 2 else (tub_x + rng.uniform(-0.3, 0.3), -0.95, 0.55)
        bpy.ops.mesh.primitive_cylinder_add(
            vertices=32, radius=s / 2, depth=s * rng.uniform(1.5, 3.0), location=(x, y, z + s)
        )
        bpy.ops.object.shade_smooth()
        bpy.context.object.data.materials.append(_material(f"bottle{i}", rng, glass=rng.random() < 0.4))
    return (
        moving,
        (rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(0.9, 1.3)),
        half - 0.45,
        rng.uniform(1.3, 1.8),
    )


def _hair_material(name, rng):
    """Principled Hair BSDF (Chiang), melanin-coloured or dyed."""
    import bpy

    m = bpy.data.materials.new(name)
    m.use_nodes = True
    nodes = m.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    hair = nodes.new("ShaderNodeBsdfHairPrincipled")
    if rng.random() < 0.6:
        hair.parametrization = "MELANIN"
        hair.inputs["Melanin"].default_value = rng.uniform(0.1, 0.95)
        hair.inputs["Melanin Redness"].default_value = rng.uniform(0.0, 1.0)
    else:
        hair.parametrization = "COLOR"
        hair.inputs["Color"].default_value = (*[rng.uniform(0.05, 0.9) for _ in range(3)], 1.0)
    hair.inputs["Roughness"].default_value = rng.uniform(0.15, 0.5)
    hair.inputs["Radial Roughness"].default_value = rng.uniform(0.2, 0.6)
    m.node_tree.links.new(hair.outputs[0], nodes["Material Output"].inputs["Surface"])
    return m


def _grow_hair(obj, rng, count, length, radius):
    """A hair particle system on ``obj``: ``count`` strands ``length`` metres long, ``radius``
    metres thick at the root, tapering, drawn in the object's second material slot."""
    obj.data.materials.append(_hair_material(f"{obj.name}_hair", rng))
    mod = obj.modifiers.new("fur", type="PARTICLE_SYSTEM")
    ps = mod.particle_system.settings
    ps.type = "HAIR"
    ps.count, ps.hair_length = count, length
    ps.material = 2
    ps.use_advanced_hair = True
    ps.brownian_factor = rng.uniform(0.0, 0.3) * length
    ps.factor_random = rng.uniform(0.0, 0.2) * length
    ps.display_step, ps.render_step = 3, 4
    ps.radius_scale, ps.root_radius, ps.tip_radius = radius, 1.0, 0.0
    mod.particle_system.seed = rng.randint(0, 10000)


def _fur(scene, rng, frames):
    """The ``fur`` kind of the bathroom-fur held-out split: furry shapes and a shaggy rug in the Principled Hair BSDF,
    strands a fraction of a pixel thick (Cycles' curves), which no other kind has: balls, a
    cushion and a torus coated in fur 1-12 cm long, some rolling or turning, on a rug of longer
    strands, under a sun and sky or area lights. Returns (moving objects, camera target, radius,
    height)."""
    import bpy

    scene.cycles_curves.shape = "THICK"
    outdoor = rng.random() < 0.5
    _world(scene, rng, "sky" if outdoor else "color")
    ground = _material("ground", rng, rough=rng.uniform(0.3, 0.9), texture=rng.choice(TEXTURES))
    _box("ground", (30, 30, 0.1), (0, 0, -0.05), ground)
    if outdoor:
        bpy.ops.object.light_add(
            type="SUN", rotation=(math.radians(rng.uniform(25, 60)), 0, math.radians(rng.uniform(0, 360)))
        )
        bpy.context.object.data.energy = rng.uniform(2.0, 6.0)
    for i in range(1 if outdoor else rng.randint(2, 3)):
        bpy.ops.object.light_add(
            type="AREA",
            location=(rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(1.5, 3.0)),
            rotation=(rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), 0),
        )
        bpy.context.object.data.energy = rng.uniform(50, 300)
        bpy.context.object.data.size = rng.uniform(0.3, 1.5)
    bpy.ops.mesh.primitive_plane_add(size=rng.uniform(1.5, 2.5), location=(0, 0, 0.005))
    rug = bpy.context.object
    rug.name = "rug"
    rug.data.materials.append(_material("rug_base", rng, rough=0.9))
    _grow_hair(rug, rng, rng.randint(8000, 20000), rng.uniform(0.04, 0.12), rng.uniform(0.0015, 0.004))
    moving = []
    for i in range(rng.randint(2, 5)):
        shape = rng.choice(("ball", "ball", "cushion", "torus"))
        s = rng.uniform(0.15, 0.45)
        loc = (rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), s / 2 + 0.02)
        if shape == "ball":
            bpy.ops.mesh.primitive_uv_sphere_add(radius=s / 2, location=loc, segments=32, ring_count=16)
        elif shape == "cushion":
            bpy.ops.mesh.primitive_cube_add(size=s, location=loc, rotation=(0, 0, rng.uniform(0, 3)))
            bpy.context.object.scale = (1.0, rng.uniform(0.6, 1.0), 0.4)
            bpy.ops.object.modifier_add(type="SUBSURF")
            bpy.context.object.modifiers[-1].levels = bpy.context.object.modifiers[-1].render_levels = 2
        else:
            bpy.ops.mesh.primitive_torus_add(
                major_radius=s / 2, minor_radius=s / 6, location=loc, rotation=(rng.uniform(0, 1.2), 0, 0)
            )
        bpy.ops.object.shade_smooth()
        obj = bpy.context.object
        obj.data.materials.append(_material(f"skin{i}", rng, rough=0.7))
        _grow_hair(obj, rng, rng.randint(3000, 12000), rng.uniform(0.01, 0.12), rng.uniform(0.0008, 0.003))
        if _slides(obj, rng, frames, 0.5, 0.6):
            moving.append(obj)
    return moving, (0, 0, rng.uniform(0.1, 0.3)), rng.uniform(1.6, 2.6), rng.uniform(0.5, 1.4)


def _all_fcurves(obj):
    from . import _fcurves

    if not (obj.animation_data and obj.animation_data.action):
        return []
    return _fcurves(obj.animation_data.action)


def _render_frames(scene, folder: str, frames, label: str) -> None:
    """Render each frame not yet in ``folder`` (written under a temporary name, renamed)."""
    import bpy

    os.makedirs(folder, exist_ok=True)
    for f in frames:
        final = os.path.join(folder, f"{f:04d}.exr")
        if os.path.exists(final):
            print(f"jnds-frame {label} {f} skipped", flush=True)
            continue
        scene.frame_set(f)
        scene.render.filepath = os.path.join(folder, f".tmp{f:04d}")
        t0 = time.perf_counter()
        bpy.ops.render.render(write_still=True)
        written = bpy.path.abspath(scene.render.frame_path(frame=f))
        if not os.path.exists(written):
            written = scene.render.filepath + ".exr"
        os.replace(written, final)
        print(f"jnds-frame {label} {f} {time.perf_counter() - t0:.3f}", flush=True)


def render_sequence(cfg: dict, raw: str, ref: str | None) -> None:
    from .. import blender as jb

    scene, cuts = build(cfg)
    frames = range(scene.frame_start, scene.frame_end + 1)
    changes = jb.configure(scene, output=os.path.join(raw, ""), log=lambda m: None)
    _add_cuts(raw, cuts)
    _render_frames(scene, raw, frames, "inputs")
    if ref:
        jb.restore(scene, changes, log=lambda m: None)
        scene.cycles.seed = cfg["seed"] + 7919  # reference noise independent of the inputs'
        jb.configure_reference(
            scene, output=os.path.join(ref, ""), spp=cfg["spp"], scale=cfg["scale"], log=lambda m: None
        )
        _render_frames(scene, ref, frames, "reference")


def _add_cuts(raw: str, cuts: list[int]) -> None:
    from . import SIDECAR

    path = os.path.join(raw, SIDECAR)
    with open(path) as fh:
        data = json.load(fh)
    data["cuts"] = cuts
    with open(path, "w") as fh:
        json.dump(data, fh, indent=1)


if __name__ == "__main__":
    cfg_json, raw_dir = sys.argv[1], sys.argv[2]
    render_sequence(json.loads(cfg_json), raw_dir, sys.argv[3] if len(sys.argv) > 3 else None)
