"""The Blender side: make a scene render JNDS inputs with Cycles.

Runs inside Blender's Python (``bpy``, the standard library and this package's pure-Python
``errors`` and ``sampling`` only; the package's dependencies -- numpy 2, torch,
onnxruntime -- are not needed and not imported). In
Blender's Python console, or a script run by Blender, with this repository on ``sys.path``::

    import bpy
    from jnds_deploy import blender as jb
    jb.configure(bpy.context.scene, output="//jnds/raw/")   # prints every setting it changes
    bpy.ops.render.render(animation=True)                    # Blender's own render
    jb.configure_reference(bpy.context.scene, output="//jnds/ref/", spp=128)
    bpy.ops.render.render(animation=True)                    # the 2x reference (optional)

then, in the project's environment: ``jnds import cycles jnds/raw --out seq --reference
jnds/ref``. ``restore(scene, changes)`` undoes ``configure``; working on a copy of the
scene (``bpy.ops.scene.new(type='FULL_COPY')``) is just as good.

What ``configure`` sets (and nothing else of the user's look):
- the passes the import maps onto the paper's split (``PASSES``), and a value AOV
  ``Roughness`` written by an AOV Output node added to every material: Cycles has no
  roughness pass. The AOV carries Blender's (perceptual) roughness; the import squares it
  into the microfacet alpha, the convention of the format's ``roughness`` (the Mitsuba
  renderer writes alpha). Purely diffuse and emissive materials write 1;
- 1 sample per pixel, no adaptive sampling, no denoising, no path guiding, a different
  noise seed per frame, motion blur off (Blender greys out the Vector pass with it on);
- a box pixel filter of the smallest width, so a pixel's one sample sits at one point,
  and per frame a Halton (2, 3) sub-pixel jitter (``sampling.jitter``) by a keyed camera
  lens shift; the jitter of every frame goes to ``jnds.json`` beside the frames, where the
  import reads it. Cycles' Vector pass does not see the lens shift: it describes the pixel
  centre's point, as the format wants (``jnds_deploy.blender.importer``);
- Cycles' Denoising Data passes, which mark the camera rays that scattered in a volume
  before reaching any surface, and per frame the direction back to the camera in
  ``jnds.json``, the normal the import gives those pixels;
- multilayer 32-bit float EXR output (Blender 5 writes one part per pass).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

from ..errors import ConfigError
from ..sampling import jitter

# view-layer property -> pass name in the EXR (``ViewLayer.<pass>.<channel>``)
PASSES = {
    "use_pass_combined": "Combined",
    "use_pass_diffuse_direct": "Diffuse Direct",
    "use_pass_diffuse_indirect": "Diffuse Indirect",
    "use_pass_diffuse_color": "Diffuse Color",
    "use_pass_glossy_direct": "Glossy Direct",
    "use_pass_glossy_indirect": "Glossy Indirect",
    "use_pass_glossy_color": "Glossy Color",
    "use_pass_transmission_direct": "Transmission Direct",
    "use_pass_transmission_indirect": "Transmission Indirect",
    "use_pass_transmission_color": "Transmission Color",
    "use_pass_emit": "Emission",
    "use_pass_environment": "Environment",
    "use_pass_normal": "Normal",
    "use_pass_vector": "Vector",
    "use_pass_z": "Depth",
}
CYCLES_PASSES = {  # on view_layer.cycles
    "use_pass_volume_direct": "Volume Direct",
    "use_pass_volume_indirect": "Volume Indirect",
}
# view_layer.cycles.denoising_store_passes ("Denoising Data") writes these; the import takes
# from "Denoising Normal" which camera rays scattered in a volume before any surface (Cycles
# writes the view direction there, and nothing in Normal, Depth or Vector): ``jnds_deploy.blender.importer``
DENOISING_PASSES = ("Denoising Normal", "Denoising Albedo", "Denoising Depth")
ROUGHNESS_AOV = "Roughness"
AOV_NODE = "jnds_roughness"  # the name of the AOV Output node added to each material
SIDECAR = "jnds.json"  # frame range, size and jitter, beside the rendered frames
JITTER_PERIOD = 16
SHIFT_BASE = "jnds_shift_base"  # custom property: the camera's lens shift under the jitter keys
FILTER_WIDTH = 0.01  # pixels: the box filter's smallest width, a point sample


@dataclass
class Changes:
    """What ``configure`` changed: (object, attribute, old value) to restore, and what it
    added (AOV nodes, the AOV, the camera's shift animation)."""

    settings: list = field(default_factory=list)
    nodes: list = field(default_factory=list)  # (material, node name)
    aov: bool = False
    shift_keys: bool = False

    def set(self, owner, attr: str, value, where: str, log) -> None:
        old = getattr(owner, attr)
        if old != value:
            self.settings.append((owner, attr, old))
            setattr(owner, attr, value)
            log(f"jnds: {where}.{attr}: {old!r} -> {value!r}")


def _bsdf_roughness(material):
    """The (node, input socket) that gives the material's roughness, or None (diffuse,
    emissive): the first BSDF with a Roughness input that reaches the output."""
    if not material.node_tree:
        return None
    for node in material.node_tree.nodes:
        if (
            node.type
            in ("BSDF_PRINCIPLED", "BSDF_GLOSSY", "BSDF_ANISOTROPIC", "BSDF_METALLIC", "BSDF_GLASS", "BSDF_REFRACTION")
            and "Roughness" in node.inputs
        ):
            return node.inputs["Roughness"]
    return None


def _add_roughness_aov(material, changes: Changes, log) -> None:
    tree = material.node_tree
    if tree is None or AOV_NODE in tree.nodes:
        return
    node = tree.nodes.new("ShaderNodeOutputAOV")
    node.name = AOV_NODE
    node.aov_name = ROUGHNESS_AOV
    source = _bsdf_roughness(material)
    if source is None:
        node.inputs["Value"].default_value = 1.0
        what = "1 (no rough BSDF)"
    elif source.is_linked:
        tree.links.new(source.links[0].from_socket, node.inputs["Value"])
        what = f"the socket feeding {source.node.name}.Roughness"
    else:
        node.inputs["Value"].default_value = source.default_value
        what = f"{source.node.name}.Roughness = {source.default_value:.3f}"
    changes.nodes.append((material, AOV_NODE))
    log(f"jnds: material {material.name!r}: AOV Output {ROUGHNESS_AOV!r} <- {what}")


def _shift_scale(scene, camera_data) -> float:
    """Lens shift is in units of the sensor's fitted dimension: pixels per unit of shift."""
    w = scene.render.resolution_x * scene.render.resolution_percentage / 100
    h = scene.render.resolution_y * scene.render.resolution_percentage / 100
    w, h = w * scene.render.pixel_aspect_x, h * scene.render.pixel_aspect_y
    fit = camera_data.sensor_fit
    return w if fit == "HORIZONTAL" or (fit == "AUTO" and w >= h) else h


def _key_jitter(scene, changes: Changes, log) -> dict:
    """Key the camera's lens shift per frame (constant interpolation) so each frame's
    sample sits at its Halton offset; one frame beyond each end too (Cycles evaluates the
    scene at frame - 1 and + 1 for the Vector pass). Returns {frame: (jx, jy)}."""
    cam = scene.camera.data
    if (
        cam.animation_data
        and cam.animation_data.action
        and any(fc.data_path in ("shift_x", "shift_y") for fc in _fcurves(cam.animation_data.action))
    ):
        raise ConfigError(
            f"camera {scene.camera.name!r}: its lens shift is animated; jnds jitters it "
            "per frame (pass jitter=False, or remove that animation)"
        )
    unit = _shift_scale(scene, cam)
    base = (cam.shift_x, cam.shift_y)
    jitters = {}
    for f in range(scene.frame_start - 1, scene.frame_end + 2):
        jx, jy = jitter(f - scene.frame_start, JITTER_PERIOD)
        jitters[f] = (jx, jy)
        # top-down pixel offsets (y down): a positive shift_y moves the image content down
        cam.shift_x = base[0] + jx / unit
        cam.shift_y = base[1] - jy / unit
        cam.keyframe_insert("shift_x", frame=f)
        cam.keyframe_insert("shift_y", frame=f)
    cam.shift_x, cam.shift_y = base
    cam[SHIFT_BASE] = list(base)  # for _clear_shift_keys, whoever calls it
    for fc in _fcurves(cam.animation_data.action):
        if fc.data_path in ("shift_x", "shift_y"):
            for k in fc.keyframe_points:
                k.interpolation = "CONSTANT"
    changes.shift_keys = True
    log(
        f"jnds: camera {scene.camera.name!r}: lens shift keyed per frame {scene.frame_start - 1}.."
        f"{scene.frame_end + 1} (Halton 2,3 jitter, constant interpolation)"
    )
    return jitters


def _fcurves(action):
    """An action's F-curves (Blender 5 keeps them in layers, strips and channel bags)."""
    if hasattr(action, "fcurves") and action.fcurves is not None:
        try:
            return list(action.fcurves)
        except (AttributeError, TypeError):
            pass
    out = []
    for layer in getattr(action, "layers", []):
        for strip in layer.strips:
            for bag in getattr(strip, "channelbags", []):
                out += list(bag.fcurves)
    return out


def _sampling(scene, changes: Changes, spp: int, filter_width: float, log) -> None:
    c = scene.cycles
    changes.set(scene.render, "engine", "CYCLES", "render", log)
    changes.set(c, "samples", spp, "cycles", log)
    changes.set(c, "use_adaptive_sampling", False, "cycles", log)
    changes.set(c, "use_denoising", False, "cycles", log)
    changes.set(c, "use_guiding", False, "cycles", log)
    changes.set(c, "use_animated_seed", True, "cycles", log)
    changes.set(c, "pixel_filter_type", "BOX", "cycles", log)
    changes.set(c, "filter_width", filter_width, "cycles", log)
    changes.set(scene.render, "use_motion_blur", False, "render", log)


def _output(scene, changes: Changes, output: str | None, log) -> None:
    im = scene.render.image_settings
    changes.set(im, "media_type", "MULTI_LAYER_IMAGE", "image_settings", log)
    changes.set(im, "file_format", "OPEN_EXR_MULTILAYER", "image_settings", log)
    changes.set(im, "color_depth", "32", "image_settings", log)
    if output is not None:
        changes.set(scene.render, "filepath", output, "render", log)


def _passes(scene, changes: Changes, log) -> None:
    vl = _render_layer(scene) or scene.view_layers[0]
    for prop in PASSES:
        changes.set(vl, prop, True, f"view_layer[{vl.name!r}]", log)
    for prop in CYCLES_PASSES:
        changes.set(vl.cycles, prop, True, f"view_layer[{vl.name!r}].cycles", log)
    changes.set(vl.cycles, "denoising_store_passes", True, f"view_layer[{vl.name!r}].cycles", log)
    if ROUGHNESS_AOV not in [a.name for a in vl.aovs]:
        aov = vl.aovs.add()
        aov.name, aov.type = ROUGHNESS_AOV, "VALUE"
        changes.aov = True
        log(f"jnds: view_layer[{vl.name!r}]: AOV {ROUGHNESS_AOV!r} (value) added")


def _render_layer(scene):
    """The view layer that renders: the first one with use set."""
    return next((vl for vl in scene.view_layers if vl.use), None)


def _toward_camera(scene) -> dict:
    """{frame: the camera's local +Z axis in world space} (a Blender camera looks down -Z):
    the normal the import gives a pixel whose camera ray scattered in a volume, where
    Cycles' Denoising Normal is (0, 0, -1) in camera space."""
    current = scene.frame_current
    out = {}
    for f in range(scene.frame_start, scene.frame_end + 1):
        scene.frame_set(f)
        z = scene.camera.matrix_world.to_3x3().col[2].normalized()
        out[f] = [z.x, z.y, z.z]
    scene.frame_set(current)
    return out


def _sidecar(scene, jitters: dict, kind: str, scale: int = 1, toward: dict | None = None) -> None:
    import bpy

    folder = os.path.dirname(bpy.path.abspath(scene.render.filepath)) or "."
    os.makedirs(folder, exist_ok=True)
    r = scene.render
    size = [int(r.resolution_x * r.resolution_percentage / 100), int(r.resolution_y * r.resolution_percentage / 100)]
    data = {
        "kind": kind,
        "frame_start": scene.frame_start,
        "frame_end": scene.frame_end,
        "size": size,
        "scale": scale,
        "roughness": f"AOV {ROUGHNESS_AOV!r}: Blender's roughness r (alpha = r^2)",
        "jitter": {str(f): list(j) for f, j in jitters.items()},
        "blender": bpy.app.version_string,
    }
    if toward is not None:
        data["toward_camera"] = {str(f): v for f, v in toward.items()}
    with open(os.path.join(folder, SIDECAR), "w") as fh:
        json.dump(data, fh, indent=1)


def configure(scene=None, output: str | None = None, jitter_frames: bool = True, log=print) -> Changes:
    """Make ``scene`` render JNDS inputs (module docstring); every change is printed and
    returned for ``restore``. ``output``: the render's file path prefix (e.g. ``//raw/``)."""
    import bpy

    scene = scene or bpy.context.scene
    if scene.camera is None:
        raise ConfigError(f"scene {scene.name!r} has no camera")
    changes = Changes()
    _sampling(scene, changes, 1, FILTER_WIDTH, log)
    _passes(scene, changes, log)
    _output(scene, changes, output, log)
    for material in bpy.data.materials:
        _add_roughness_aov(material, changes, log)
    jitters = _key_jitter(scene, changes, log) if jitter_frames else {}
    _sidecar(
        scene,
        {f: j for f, j in jitters.items() if scene.frame_start <= f <= scene.frame_end},
        "inputs",
        toward=_toward_camera(scene),
    )
    return changes


def configure_reference(scene=None, output: str | None = None, spp: int = 128, scale: int = 2, log=print) -> Changes:
    """Make ``scene`` render the reference of the same frames: ``scale`` x the resolution,
    ``spp`` samples per target pixel box-filtered over the pixel, no jitter, the same
    passes (the import takes colour and the converged components from them). Call it on a
    scene ``configure`` set up (or ``restore``d), or on a fresh one."""
    import bpy

    scene = scene or bpy.context.scene
    changes = Changes()
    _clear_shift_keys(scene)
    _sampling(scene, changes, spp, 1.0, log)
    _passes(scene, changes, log)
    _output(scene, changes, output, log)
    for material in bpy.data.materials:
        _add_roughness_aov(material, changes, log)
    changes.set(scene.render, "resolution_percentage", scene.render.resolution_percentage * scale, "render", log)
    _sidecar(scene, {}, "reference", scale)
    return changes


def restore(scene, changes: Changes, log=print) -> None:
    """Undo ``configure``: settings back, the added nodes, AOV and shift keys removed."""
    for owner, attr, old in reversed(changes.settings):
        setattr(owner, attr, old)
    for material, name in changes.nodes:
        if material.node_tree and name in material.node_tree.nodes:
            material.node_tree.nodes.remove(material.node_tree.nodes[name])
    vl = _render_layer(scene)
    if changes.aov and vl is not None:
        for a in vl.aovs:
            if a.name == ROUGHNESS_AOV:
                vl.aovs.remove(a)
                break
    if changes.shift_keys:
        _clear_shift_keys(scene)
    log(f"jnds: scene {scene.name!r} restored")


def _clear_shift_keys(scene) -> None:
    """Remove the lens-shift keys ``configure`` added (frames frame_start - 1 .. frame_end + 1)
    and put the shift back where it was: without keys, the property keeps the value of the
    last frame evaluated, a jittered one."""
    cam = scene.camera.data
    if SHIFT_BASE not in cam:
        return
    if cam.animation_data and cam.animation_data.action:
        for f in range(scene.frame_start - 1, scene.frame_end + 2):
            for path in ("shift_x", "shift_y"):
                try:
                    cam.keyframe_delete(path, frame=f)
                except RuntimeError:  # no key there
                    pass
    cam.shift_x, cam.shift_y = cam[SHIFT_BASE]
    del cam[SHIFT_BASE]
