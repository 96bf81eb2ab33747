"""Import a motion's glTF and BVH files in Blender and render the glTF at a few frames: docs/figures/step_blender.png.

Usage, in a Python with Blender as a module (``pip install "bpy>=4.1,<4.6"``, a separate venv: it is not one of
reach's dependencies)::

    reach motion ATLAS X Y Z --effector right_hand -o step.glb
    reach motion ATLAS X Y Z --effector right_hand -o step.bvh
    python docs/blender.py step.glb step.bvh OUT_PREFIX 0,11,17,49

Renders ``OUT_PREFIX_<frame>.png`` with the Workbench engine from the body's left (x forward to the right, z up),
and prints, from the BVH imported as an armature, where each bone's head lies at those frames (Blender's frame:
the atlas's y, -x, z), so that the two files' readings can be set side by side. The scene's rate is set to the
motion's 30 Hz before the glTF is imported: its importer keys the animation's times at the scene's frame rate
(at Blender's default 24 Hz, frame 11 was the motion's 0.46 s, not 0.37 s).
"""

from __future__ import annotations

import math
import sys

import bpy  # type: ignore[import-not-found]

RATE = 30  # [Hz] reach motion's default rate
SCALE = 2.6  # [m] the orthographic camera's width


def main(glb: str, bvh: str, out: str, frames: list[int]) -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps = RATE
    bpy.ops.import_scene.gltf(filepath=glb)
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_x, scene.render.resolution_y = 640, 520
    scene.display.shading.light = "STUDIO"
    camera = bpy.data.cameras.new("camera")
    camera.type, camera.ortho_scale = "ORTHO", SCALE
    view = bpy.data.objects.new("camera", camera)
    scene.collection.objects.link(view)
    scene.camera = view
    # glTF is y-up; the importer turns it z-up with the atlas's x along Blender's -y: the camera on the body's left
    view.location, view.rotation_euler = (-6.0, -0.6, 0.95), (math.radians(90), 0.0, math.radians(-90))
    for f in frames:
        scene.frame_set(f)
        scene.render.filepath = f"{out}_{f:03d}.png"
        bpy.ops.render.render(write_still=True)
    bpy.ops.import_anim.bvh(filepath=bvh, axis_forward="-Z", axis_up="Y", update_scene_fps=True)
    armature = next(o for o in bpy.data.objects if o.type == "ARMATURE")
    for f in frames:
        scene.frame_set(f)
        heads = {b.name: [round(v, 4) for v in armature.matrix_world @ b.head] for b in armature.pose.bones}
        print(f"frame {f}: {heads}")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], sys.argv[3], [int(f) for f in sys.argv[4].split(",")])
