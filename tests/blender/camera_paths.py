"""Where the cameras of procedural Cycles scenes go, run in Blender's environment:

    python camera_paths.py JOBS_JSON

Builds each job's scene with ``blender.scenes.build`` (nothing is rendered) and prints one JSON
line per job: its seed, the room's half-size (null without a room) and the frames (1-based)
whose camera is outside the room's walls."""

import json
import sys

import bpy

from jnds_deploy.blender import scenes as blender_scene

for job in json.loads(sys.argv[1]):
    scene, _ = blender_scene.build({**job, "size": tuple(job["size"])})
    walls = bpy.data.objects.get("wall_e")
    half = walls.location.x if walls is not None else None
    outside = []
    for f in range(1, job["frames"] + 1):
        scene.frame_set(f)
        p = scene.camera.matrix_world.translation
        if half is not None and not (-half < p.x < half and -half - 1.0 < p.y < half):
            outside.append(f)
    print("CAMERA " + json.dumps({"seed": job["seed"], "half": half, "outside": outside}), flush=True)
