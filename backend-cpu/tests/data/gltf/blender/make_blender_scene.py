# Builds a small animated scene in Blender and exports it with Blender's own glTF exporter,
# together with Blender's world matrices of every object at a few frames, for
# backend-cpu/src/gltf/tests/blender.rs to compare against.
#
# Run from this folder (Blender 3.4, Debian's package `blender`):
#
#     blender -b --factory-startup --python make_blender_scene.py
#
# It writes, beside itself:
# - blender_sampled.glb: the default export (y-up, animations sampled every frame: LINEAR,
#   and STEP for the object whose keys are all CONSTANT);
# - blender_keys.gltf + blender_keys.bin: the same scene with sampling off, so the keys go out
#   as they are: CUBICSPLINE (Bezier), LINEAR and STEP (CONSTANT);
# - blender_frames.json: for each object, its world matrix at a list of frames (whole and
#   half frames), converted from Blender's z-up to glTF's y-up the way the exporter converts
#   (a point (x, y, z) becomes (x, z, -y)): M_gltf = C M_blender C^-1. A frame f is the glTF
#   time f / fps, as the exporter writes key times.

import json
import math
import os

import bpy
from mathutils import Matrix, Quaternion, Vector

HERE = os.path.dirname(os.path.abspath(__file__))
FPS = 24

scene = bpy.context.scene
for obj in list(bpy.data.objects):
    bpy.data.objects.remove(obj, do_unlink=True)
for mesh in list(bpy.data.meshes):
    bpy.data.meshes.remove(mesh)
scene.render.fps = FPS
scene.render.fps_base = 1.0
scene.frame_start = 1
scene.frame_end = 49

# Keys every 12 frames.
KEYS = [1, 13, 25, 37, 49]


def new_object(name, mesh):
    obj = bpy.data.objects.new(name, mesh)
    scene.collection.objects.link(obj)
    obj.rotation_mode = "QUATERNION"
    return obj


def primitive(op, name, **kw):
    op(**kw)
    obj = bpy.context.active_object
    mesh = obj.data
    mesh.name = name
    bpy.data.objects.remove(obj, do_unlink=True)
    return mesh


box = primitive(bpy.ops.mesh.primitive_cube_add, "Box", size=1.0)
cone = primitive(bpy.ops.mesh.primitive_cone_add, "Cone", vertices=8, radius1=0.5, depth=1.0)
ico = primitive(bpy.ops.mesh.primitive_ico_sphere_add, "SharedIco", subdivisions=1, radius=0.5)


def third_handles(fc, flat=False):
    """Free Bezier handles a third of the way to each neighbouring key, along Catmull-Rom
    slopes (flat at the ends, or everywhere with `flat`). With handles at thirds in time,
    Blender's Bezier segment is a cubic in time with those slopes at its ends: exactly glTF's
    CUBICSPLINE, which the exporter writes from the slopes. (Blender's automatic handles are
    not at thirds, and then no cubic in time is the curve Blender evaluates.)

    Rotations get flat handles: the exporter converts a quaternion's tangent by converting
    the point `key + slope` as a rotation, which normalizes it, so only a zero slope goes
    out exactly. Blender then blends the quaternion's components and normalizes, as glTF's
    CUBICSPLINE does."""
    keys = fc.keyframe_points
    n = len(keys)
    for i, k in enumerate(keys):
        x, y = k.co
        if 0 < i < n - 1 and not flat:
            slope = (keys[i + 1].co[1] - keys[i - 1].co[1]) / (keys[i + 1].co[0] - keys[i - 1].co[0])
        else:
            slope = 0.0
        k.handle_left_type = "FREE"
        k.handle_right_type = "FREE"
        dl = (x - keys[i - 1].co[0]) / 3 if i > 0 else 1.0
        dr = (keys[i + 1].co[0] - x) / 3 if i < n - 1 else 1.0
        k.handle_left = (x - dl, y - slope * dl)
        k.handle_right = (x + dr, y + slope * dr)


def key_location(obj, frames_values, interpolation):
    for f, v in frames_values:
        obj.location = v
        obj.keyframe_insert("location", frame=f)
    for fc in obj.animation_data.action.fcurves:
        if fc.data_path == "location":
            for k in fc.keyframe_points:
                k.interpolation = interpolation
            if interpolation == "BEZIER":
                third_handles(fc)


def key_rotation(obj, frames_values, interpolation):
    for f, (axis, degrees) in frames_values:
        obj.rotation_quaternion = Quaternion(axis, math.radians(degrees))
        obj.keyframe_insert("rotation_quaternion", frame=f)
    for fc in obj.animation_data.action.fcurves:
        if fc.data_path == "rotation_quaternion":
            for k in fc.keyframe_points:
                k.interpolation = interpolation
            if interpolation == "BEZIER":
                third_handles(fc, flat=True)


# A parent box, uniformly scaled, moving (Bezier) and turning (Bezier) about z.
parent = new_object("Parent", box)
parent.scale = (1.5, 1.5, 1.5)
key_location(parent, [(1, (0, 0, 0)), (13, (2, 0, 1)), (25, (2, 3, 1)), (37, (0, 3, 0)), (49, (0, 0, 0))], "BEZIER")
key_rotation(parent, [(f, ((0, 0, 1), a)) for f, a in zip(KEYS, [0, 40, 90, 150, 200])], "BEZIER")

# Its child cone, offset along the parent's x, turning about its own x (Bezier).
child = new_object("Child", cone)
child.parent = parent
child.location = (1.5, 0, 0)
key_rotation(child, [(f, ((1, 0, 0), a)) for f, a in zip(KEYS, [0, 60, 0, -60, 0])], "BEZIER")

# One mesh shared by three objects (linked duplicates).
dup_a = new_object("DupStill", ico)
dup_a.location = (-3, 1, 0.5)
dup_a.rotation_quaternion = Quaternion((1, 1, 0), math.radians(35))
dup_a.scale = (0.75, 0.75, 0.75)

# Moving in steps: every key CONSTANT, which goes out as STEP.
dup_b = new_object("DupStep", ico)
key_location(dup_b, [(1, (-3, -2, 0)), (13, (-2, -2, 0)), (25, (-1, -2, 1)), (37, (0, -2, 1)), (49, (1, -2, 0))], "CONSTANT")

# Moving in straight lines (LINEAR location) while turning (Bezier rotation about y).
dup_c = new_object("DupLinear", ico)
key_location(dup_c, [(1, (4, 0, 0)), (13, (4, 2, 0)), (25, (5, 2, 2)), (37, (4, 0, 2)), (49, (4, 0, 0))], "LINEAR")
key_rotation(dup_c, [(f, ((0, 1, 0), a)) for f, a in zip(KEYS, [0, 30, 100, 45, 0])], "BEZIER")

common = dict(
    export_yup=True,
    export_animations=True,
    export_materials="NONE",
    export_normals=False,
    export_texcoords=False,
    export_colors=False,
    export_cameras=False,
    export_lights=False,
    export_extras=False,
)
bpy.ops.export_scene.gltf(
    filepath=os.path.join(HERE, "blender_sampled.glb"), export_format="GLB", export_force_sampling=True, **common
)
bpy.ops.export_scene.gltf(
    filepath=os.path.join(HERE, "blender_keys.gltf"), export_format="GLTF_SEPARATE", export_force_sampling=False, **common
)

# Blender's z-up world to glTF's y-up: a point (x, y, z) becomes (x, z, -y).
C = Matrix(((1, 0, 0, 0), (0, 0, 1, 0), (0, -1, 0, 0), (0, 0, 0, 1)))
C_INV = C.inverted()

frames = [1, 2, 4.5, 7, 12, 13, 13.5, 19, 24.25, 25, 30, 36.5, 37, 44, 48.75, 49]
out = {"fps": FPS, "blender": bpy.app.version_string, "objects": {}}
for obj in scene.objects:
    samples = []
    for f in frames:
        whole = int(math.floor(f))
        scene.frame_set(whole, subframe=f - whole)
        m = C @ obj.matrix_world @ C_INV
        samples.append({"frame": f, "time": f / FPS, "matrix": [m[r][c] for r in range(4) for c in range(4)]})
    out["objects"][obj.name] = samples
with open(os.path.join(HERE, "blender_frames.json"), "w") as fh:
    json.dump(out, fh, indent=1)
print("wrote", HERE)
