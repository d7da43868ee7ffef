"""Renders ``docs/maze.png``: the maze imported into Blender, baked on a real
``lightfarm serve`` (T = 8, 256 rays per texel), lit with its four lamps through
"Apply lighting" (emission mode, all bounces: the panel's default) and rendered headless with
Cycles on the CPU.

Cycles runs with zero bounces, so every pixel shows the lightmap exactly as applied (the
picture is the baked light, not Cycles' own). For the picture only, after the lighting is
applied, the ceilings (``+y`` faces) are deleted and the outside of every wall is made
transparent (the Geometry node's Backfacing), so the camera sees into the rooms.

Usage: ``VENV/bin/python plugins/blender/docs/make_screenshot.py --lightfarm
target/release/lightfarm [--out plugins/blender/docs/maze.png]``.
"""

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.abspath(os.path.join(HERE, "..", "..", ".."))
sys.path.insert(0, os.path.abspath(os.path.join(HERE, "..")))

import bpy  # noqa: E402
import addon_utils  # noqa: E402

from lightfarm_blender import operators  # noqa: E402


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--lightfarm", default=os.path.join(REPO, "target/release/lightfarm"))
    parser.add_argument("--out", default=os.path.join(HERE, "maze.png"))
    args = parser.parse_args()
    data = tempfile.mkdtemp(prefix="lf-shot-")
    server = subprocess.Popen([args.lightfarm, "serve", "--addr", "127.0.0.1:0", "--data",
                               data], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                              text=True)
    url = server.stdout.readline().strip().split()[-1]
    try:
        bpy.ops.wm.read_factory_settings(use_empty=True)
        addon_utils.enable("lightfarm_blender", default_set=True)
        bpy.context.preferences.addons["lightfarm_blender"].preferences.url = url
        scene = bpy.context.scene
        bpy.ops.lightfarm.import_scene(filepath=os.path.join(REPO, "scenes/maze/scene.json"))
        scene.lightfarm.texels_per_face = 8
        scene.lightfarm.rays_per_texel = 256
        started = time.time()
        bpy.ops.lightfarm.bake()
        while operators.poll_job() is not None:
            time.sleep(0.5)
        print(f"bake: {scene.lightfarm.state} in {time.time() - started:.1f} s "
              f"({scene.lightfarm.message})")
        scene.lightfarm.mode = "emission"
        bpy.ops.lightfarm.apply()
        print(scene.lightfarm.message)
        for obj in bpy.data.collections["lightfarm_blocks"].objects:
            mesh = obj.data
            ceilings = [p.index for p in mesh.polygons if p.normal.z < -0.5]
            import bmesh
            bm = bmesh.new()
            bm.from_mesh(mesh)
            bm.faces.ensure_lookup_table()
            bmesh.ops.delete(bm, geom=[bm.faces[i] for i in ceilings], context="FACES_ONLY")
            bm.to_mesh(mesh)
            bm.free()
        for material in bpy.data.materials:
            nodes = material.node_tree.nodes if material.node_tree else []
            if "lightfarm emission" not in nodes:
                continue
            links = material.node_tree.links
            emission = nodes["lightfarm emission"]
            output = next(n for n in nodes if n.type == "OUTPUT_MATERIAL")
            geometry = nodes.new("ShaderNodeNewGeometry")
            clear = nodes.new("ShaderNodeBsdfTransparent")
            mix = nodes.new("ShaderNodeMixShader")
            links.new(geometry.outputs["Backfacing"], mix.inputs["Fac"])
            links.new(emission.outputs["Emission"], mix.inputs[1])
            links.new(clear.outputs["BSDF"], mix.inputs[2])
            links.new(mix.outputs["Shader"], output.inputs["Surface"])
        camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
        scene.collection.objects.link(camera)
        camera.location = (9.0, -30.0, 22.0)
        camera.rotation_euler = (math.radians(42), 0.0, 0.0)
        camera.data.lens = 34
        scene.camera = camera
        scene.render.engine = "CYCLES"
        scene.cycles.device = "CPU"
        scene.cycles.samples = 16
        scene.cycles.max_bounces = 0
        scene.render.resolution_x, scene.render.resolution_y = 960, 720
        scene.view_settings.view_transform = "AgX"
        scene.view_settings.exposure = 1.5
        scene.world = bpy.data.worlds.new("black")
        scene.world.color = (0.0, 0.0, 0.0)
        scene.render.filepath = args.out
        scene.render.image_settings.file_format = "PNG"
        bpy.ops.render.render(write_still=True)
        print("wrote", args.out)
    finally:
        server.terminate()
        server.wait()


if __name__ == "__main__":
    main()
