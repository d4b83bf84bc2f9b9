"""Run inside Blender: import one BVH or glb and dump the armature's animated bone head positions as JSON.

    blender -b --factory-startup --python blender_dump_joints.py -- KIND INPUT OUTPUT FPS
KIND is bvh or glb. Positions are in Blender world space (Z up, metres); OUTPUT holds
{"first_frame": f, "frames": [f, ...], "bones": {name: [[x, y, z] per frame]}, "meshes": [...], ...}, one entry
per key of the imported action, so the caller can compare frame k with its own frame k.
"""
import json
import sys

import bpy
import numpy

# Debian's Blender 3.4 glTF importer uses numpy.bool, which numpy 1.24 (Debian's python3-numpy) removed and 2.0
# brought back; give it the builtin it meant.
if not hasattr(numpy, "bool"):
    numpy.bool = bool

kind, source, target, fps = sys.argv[sys.argv.index("--") + 1:][:4]
fps = int(fps)
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.fps = fps  # glTF keys are seconds: at the motion's fps, key k lands on a whole frame
scene.render.fps_base = 1.0
if kind == "bvh":
    import builtins

    from io_anim_bvh import import_bvh

    # Debian's Blender 3.4 runs its bundled BVH importer on Python 3.11, where open(path, "rU") raises ValueError
    # (mode "U" was removed); map it to "r" for this importer only. Blender's own builds ship an older Python.
    def _open(file, mode="r", *args, **kwargs):
        return builtins.open(file, mode.replace("U", ""), *args, **kwargs)

    import_bvh.open = _open
    # our BVH is in centimetres: scale 0.01 gives metres; Y up / -Z forward is the importer's default conversion
    bpy.ops.import_anim.bvh(filepath=source, global_scale=0.01, frame_start=1, use_fps_scale=False,
                            update_scene_fps=True, update_scene_duration=True, rotate_mode="NATIVE",
                            axis_forward="-Z", axis_up="Y")
elif kind == "glb":
    bpy.ops.import_scene.gltf(filepath=source)
else:
    raise SystemExit(f"unknown kind {kind!r}")

armatures = [o for o in scene.objects if o.type == "ARMATURE"]
if len(armatures) != 1:
    raise SystemExit(f"expected one armature after import, found {len(armatures)}")
armature = armatures[0]
action = armature.animation_data.action if armature.animation_data else None
if action is None:
    raise SystemExit("the imported armature has no action")
start, end = (round(v) for v in action.frame_range)
frames = list(range(start, end + 1))
bones = {bone.name: [] for bone in armature.pose.bones}
for frame in frames:
    scene.frame_set(frame)
    for bone in armature.pose.bones:
        bones[bone.name].append(list(armature.matrix_world @ bone.head))
meshes = [{"name": o.name, "vertices": len(o.data.vertices), "vertex_groups": len(o.vertex_groups),
           "bound_to_armature": any(m.type == "ARMATURE" and m.object == armature for m in o.modifiers)}
          for o in scene.objects if o.type == "MESH"]
with open(target, "w") as handle:
    json.dump({"first_frame": start, "frames": frames, "bones": bones, "version": bpy.app.version_string,
               "scene_fps": scene.render.fps, "meshes": meshes}, handle)
