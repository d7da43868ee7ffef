"""Headless tests of the lightfarm Blender add-on, with Blender's own Python module (``bpy``)
against a real ``lightfarm serve`` on a loopback port.

Run (what ``.ci/run`` does): ``VENV/bin/python plugins/blender/tests/test_addon.py
--lightfarm target/release/lightfarm``. The service is started once for the module with
its store in a temporary directory and stopped at the end. Bakes are small (``T`` = 6,
128 rays per texel) and take seconds.

What is checked: the exported scene JSON of a two-room level built with bpy against
``data/two_rooms.scene.json``; bake, reuse (200), Apply, the lightmap pixels against
``lightfarm eval`` of the same bundle and lights, all bounces and one (within 1/255; float
images agree to float32 rounding), texel orientation through the mesh's own ``lightmap`` UVs,
relighting after a light moved without a rebake; the evaluate answer gzip-compressed on the
wire and equal to the plain one; a rotated block and a non-manifold clutter
mesh reported by name; a 422 shown on the object it names; the service down as a message; cancel;
a mesh clutter uploaded as GLB with a ``lightmap`` UV layer made for it (``TEXCOORD_1``); mesh
clutter lightmaps (an icosphere with generated UVs, a cylinder with an artist's Lightmap Pack
UVs, kept) against ``lightfarm eval``: every texel's pixel within 1/255, its cell where the
engine's own atlas (``eval --f16``) puts it, its UV mapping to its world position; a long block
baked as pieces keeping every texel in its faces' tiles; opening another file mid-bake (the timer stops watching, no traceback); the maze round trip through
import and export.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import unittest
import urllib.request

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.abspath(os.path.join(HERE, "..", "..", ".."))
sys.path.insert(0, os.path.abspath(os.path.join(HERE, "..")))

import bpy  # noqa: E402  (first: it puts Blender's own modules on the path)
import addon_utils  # noqa: E402

from lightfarm_blender import frames, operators, scene_export  # noqa: E402
from lightfarm_blender.lightmap_layout import (  # noqa: E402
    BoxLightmap, records_by_surface, texel_value, texels_by_face, texels_per_face)
from lightfarm_blender.mesh_lightmap import MeshLightmap, bary2  # noqa: E402

LIGHTFARM = None
SERVER = None
# Bake overrides that keep every bake to seconds.
FAST = {"texels_per_face": 6, "rays_per_texel": 128}
TOLERANCE = 1.0 / 255.0


class Server:
    """``lightfarm serve`` on 127.0.0.1:0 with a temporary store."""

    def __init__(self, binary):
        self.data = tempfile.mkdtemp(prefix="lf-blender-")
        self.process = subprocess.Popen(
            [binary, "serve", "--addr", "127.0.0.1:0", "--data", self.data],
            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        line = self.process.stdout.readline().strip()
        prefix = "lightfarm: listening on "
        if not line.startswith(prefix):
            raise RuntimeError(f"lightfarm serve said {line!r}")
        self.url = line[len(prefix):]

    def stop(self):
        self.process.terminate()
        self.process.wait(timeout=30)


def setUpModule():
    global SERVER
    SERVER = Server(LIGHTFARM)
    addon_utils.enable("lightfarm_blender", default_set=True)


def tearDownModule():
    SERVER.stop()


def fresh_scene(url=None):
    """An empty Blender scene, the add-on's preferences pointing at ``url``."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    addon_utils.enable("lightfarm_blender", default_set=True)
    prefs = bpy.context.preferences.addons["lightfarm_blender"].preferences
    prefs.url = url or SERVER.url
    prefs.token = ""
    state = bpy.context.scene.lightfarm
    state.texels_per_face = FAST["texels_per_face"]
    state.rays_per_texel = FAST["rays_per_texel"]
    return bpy.context.scene


def collection(name):
    found = bpy.data.collections.get(name)
    if found is None:
        found = bpy.data.collections.new(name)
        bpy.context.scene.collection.children.link(found)
    return found


def material(name, colour):
    made = bpy.data.materials.new(name)
    made.use_nodes = True
    bsdf = made.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
    return made


def cube(name, lo, hi, where, materials=()):
    """A six-sided box from Blender-frame corners ``lo``–``hi`` (origin at its centre)."""
    centre = [(a + b) / 2 for a, b in zip(lo, hi)]
    half = [(b - a) / 2 for a, b in zip(lo, hi)]
    verts = [(sx * half[0], sy * half[1], sz * half[2])
             for sz in (-1, 1) for sy in (-1, 1) for sx in (-1, 1)]
    faces = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    for m in materials:
        mesh.materials.append(m)
    obj = bpy.data.objects.new(name, mesh)
    obj.location = centre
    collection(where).objects.link(obj)
    return obj


def point_light(name, location, watts, colour):
    data = bpy.data.lights.new(name, "POINT")
    data.energy = watts
    data.color = colour
    obj = bpy.data.objects.new(name, data)
    obj.location = location
    bpy.context.scene.collection.objects.link(obj)
    return obj


def build_two_rooms():
    """Two 4 × 4 × 3 m rooms side by side along x (Blender y = −lightfarm z) sharing the
    x = 4 wall, which therefore becomes an opening; a pillar; one point light."""
    scene = fresh_scene()
    scene.name = "two_rooms"
    grey = material("grey", (0.7, 0.7, 0.7))
    warm = material("warm", (0.75, 0.6, 0.5))
    terracotta = material("terracotta", (0.6, 0.3, 0.2))
    cube("room_a", (0, -4, 0), (4, 0, 3), scene_export.BLOCKS, [grey])
    room_b = cube("room_b", (4, -4, 0), (8, 0, 3), scene_export.BLOCKS, [warm, terracotta])
    for polygon in room_b.data.polygons:  # the floor (Blender -z) gets the second material
        if polygon.normal.z < -0.5:
            polygon.material_index = 1
    cube("pillar", (1.5, -2.0, 0.0), (2.0, -1.5, 2.5), scene_export.CLUTTER,
         [material("stone", (0.5, 0.5, 0.5))])
    point_light("lamp", (1.0, -3.0, 2.2), 10.0 * 4 * 3.141592653589793, (1.0, 0.9, 0.8))
    return scene


def run_bake(scene, timeout=300):
    """Bake through the operator, following the job as the UI timer would."""
    assert bpy.ops.lightfarm.bake() == {"FINISHED"}
    deadline = time.time() + timeout
    while operators.poll_job() is not None:
        if time.time() > deadline:
            raise AssertionError("bake did not finish")
        time.sleep(0.2)
    return scene.lightfarm


def cli_eval(bundle_hash, lights, method="drt", bounces="all", f16=False):
    """``lightfarm eval`` of the service's bundle with ``lights``: RESULT.json (and with
    ``f16``, the ``--f16`` indirect atlas as a height × width × 3 float16 array, row 0 on
    top)."""
    work = tempfile.mkdtemp(prefix="lf-eval-")
    bundle = os.path.join(work, "bundle.lfb")
    with urllib.request.urlopen(f"{SERVER.url}/v1/bundles/{bundle_hash}") as response:
        with open(bundle, "wb") as out:
            out.write(response.read())
    lights_path = os.path.join(work, "lights.json")
    with open(lights_path, "w") as out:
        json.dump(lights, out)
    result = os.path.join(work, "result.json")
    atlas = os.path.join(work, "atlas.f16")
    subprocess.run([LIGHTFARM, "eval", bundle, "--lights", lights_path, "--method", method,
                    "--bounces", bounces, "-o", result] + (["--f16", atlas] if f16 else []),
                   check=True, stdout=subprocess.DEVNULL)
    with open(result) as f:
        document = json.load(f)
    if not f16:
        return document
    import numpy as np
    with open(atlas, "rb") as f:
        data = f.read()
    width, height = np.frombuffer(data[8:16], dtype="<u4")
    pixels = np.frombuffer(data[16:], dtype="<f2").reshape(height, width, 3)
    return document, pixels


def bake_status(bake_id):
    with urllib.request.urlopen(f"{SERVER.url}/v1/bakes/{bake_id}") as response:
        return json.load(response)


def lightmap_image(obj):
    """The image the object's first material shows through its lightmap node."""
    node = obj.material_slots[0].material.node_tree.nodes["lightfarm lightmap"]
    return node.image


def uv_at(obj, polygon, point):
    """The mesh's own ``lightmap`` UV at a lightfarm-frame point on an axis-aligned quad:
    the affine map through three of its corners."""
    mesh = obj.data
    layer = mesh.uv_layers["lightmap"]
    loops = list(polygon.loop_indices)
    corners = [frames.to_lightfarm(obj.matrix_world @ mesh.vertices[mesh.loops[k].vertex_index].co)
               for k in loops]
    uvs = [tuple(layer.data[k].uv) for k in loops]
    axis = max(range(3), key=lambda a: abs(polygon.normal[a]))
    axis = {0: 0, 1: 2, 2: 1}[axis]  # Blender normal axis -> lightfarm axis
    u, v = [a for a in range(3) if a != axis]
    # Solve uv = A · (p_u, p_v, 1) from the first three corners.
    import numpy as np
    m = np.array([[c[u], c[v], 1.0] for c in corners[:3]])
    coeff = np.linalg.solve(m, np.array(uvs[:3]))
    return np.array([point[u], point[v], 1.0]) @ coeff


class LongBlock(unittest.TestCase):
    def test_a_long_block_baked_as_pieces_keeps_every_texel_in_its_faces_tiles(self):
        """A 30 x 1.2 x 4 m room is baked as 7 pieces (``bake/scene/pieces.rs``): its long
        faces have 7 grids of T x T texels under one name. T is still found, and a long face's
        tile holds all 7·T x T texels, one pixel each, in position order, with its UVs on
        them."""
        work = tempfile.mkdtemp(prefix="lf-long-")
        scene = {"format": "lightfarm.scene/1", "name": "long",
                 "settings": {"texels_per_face": 4, "rays_per_texel": 64},
                 "blocks": [{"id": "hall", "min": [0, 0, 0], "max": [30, 1.2, 4],
                             "albedo": [0.6, 0.6, 0.6]}]}
        lights = {"lights": [{"kind": "point", "position": [2, 0.6, 0.5],
                              "intensity": [5, 5, 5]}], "poses": []}
        paths = {name: os.path.join(work, name) for name in
                 ("scene.json", "lights.json", "bundle.lfb", "result.json")}
        for name, document in (("scene.json", scene), ("lights.json", lights)):
            with open(paths[name], "w") as out:
                json.dump(document, out)
        subprocess.run([LIGHTFARM, "bake", paths["scene.json"], "--out", paths["bundle.lfb"],
                        "--no-cache"], check=True, stdout=subprocess.DEVNULL)
        subprocess.run([LIGHTFARM, "eval", paths["bundle.lfb"], "--lights", paths["lights.json"],
                        "-o", paths["result.json"]], check=True, stdout=subprocess.DEVNULL)
        with open(paths["result.json"]) as f:
            result = json.load(f)
        surfaces = records_by_surface(result)
        self.assertEqual(len(surfaces["block:hall/-y"]), 7 * 16)
        self.assertEqual(len(surfaces["block:hall/-x"]), 16)
        self.assertEqual(texels_per_face(result), 4)
        faces = texels_by_face(result, 4)[("block", "hall")]
        self.assertEqual(sorted(faces), sorted(frames.FACES))
        layout = BoxLightmap.for_faces(faces, 4)
        # -x, +x: tangent axes (y, z); -y, +y: (x, z); -z, +z: (x, y).
        sizes = {"-x": (4, 4), "+x": (4, 4), "-y": (28, 4), "+y": (28, 4),
                 "-z": (28, 4), "+z": (28, 4)}
        self.assertEqual(layout.sizes, sizes)
        for face, records in faces.items():
            self.assertEqual(len(records), sizes[face][0] * sizes[face][1], face)
        # Floor (-y): texel (i, j) is the one at x = (i + 1/2)·30/28, z = j + 1/2, unchanged.
        floor = faces["-y"]
        original = {tuple(round(x, 6) for x in r["position"]): r
                    for r in surfaces["block:hall/-y"]}
        values = {face: [r["indirect"] for r in records] for face, records in faces.items()}
        pixels = layout.pixels(values)
        lo, hi = [0.0, 0.0, 0.0], [30.0, 1.2, 4.0]
        for j in range(4):
            for i in range(28):
                k = 28 * j + i
                r = floor[k]
                self.assertAlmostEqual(r["position"][0], (i + 0.5) * 30 / 28, places=5)
                self.assertAlmostEqual(r["position"][2], j + 0.5, places=5)
                self.assertEqual(r["indirect"],
                                 original[tuple(round(x, 6) for x in r["position"])]["indirect"])
                x, y = layout.texel_pixel("-y", k)
                at = 4 * (y * layout.width + x)
                self.assertEqual(pixels[at:at + 3], r["indirect"])
                # The UV of the texel's centre lands on its pixel.
                u, v = layout.uv("-y", r["position"], lo, hi)
                self.assertEqual((int(u * layout.width), int(v * layout.height)), (x, y))
        self.assertGreater(floor[0]["indirect"][0], 0.0)


    def test_a_long_block_applied_in_blender_shows_every_texel(self):
        """The same kind of room built in Blender, baked through the service and applied:
        its lightmap holds every texel of its long faces at its pixel, within 1/255 of
        ``lightfarm eval``, the UVs on them."""
        scene = fresh_scene()
        scene.name = "long_hall"
        # lightfarm (x, y, z) = (0–30, 0–1.2, 0–4): Blender y = −z, z = y.
        cube("hall", (0, -4, 0), (30, 0, 1.2), scene_export.BLOCKS,
             [material("grey", (0.6, 0.6, 0.6))])
        point_light("lamp", (2.0, -0.5, 0.6), 10.0 * 4 * 3.141592653589793, (1.0, 1.0, 1.0))
        state = run_bake(scene)
        self.assertEqual(state.state, "succeeded", state.message)
        state.mode = "emission"
        self.assertEqual(bpy.ops.lightfarm.apply(), {"FINISHED"})
        export = scene_export.export_scene(scene)
        expected = cli_eval(bake_status(state.bake_id)["bundle"], export.lights)
        t = texels_per_face(expected)
        self.assertEqual(t, FAST["texels_per_face"])
        faces = texels_by_face(expected, t)[("block", "hall")]
        layout = BoxLightmap.for_faces(faces, t)
        # Cut along x only: the faces along it are n·T texels long.
        n = layout.sizes["-y"][0] // t
        self.assertGreater(n, 1)
        for face in ("-y", "+y", "-z", "+z"):
            self.assertEqual(layout.sizes[face], (n * t, t), face)
        worst, checked = check_box_lightmap(self, bpy.data.objects["hall"], faces, layout,
                                            "emission")
        self.assertEqual(checked, (4 * n + 2) * t * t)
        self.assertLessEqual(worst, TOLERANCE)
        print(f"\n  long hall ({n} pieces): {checked} texels, max |pixel - eval| = {worst:.3g}",
              end="")


class TwoRooms(unittest.TestCase):
    def test_export_matches_expected_scene_and_lights(self):
        scene = build_two_rooms()
        export = scene_export.export_scene(scene)
        self.assertEqual(export.problems, [])
        with open(os.path.join(HERE, "data", "two_rooms.scene.json")) as f:
            self.assertEqual(export.scene, json.load(f))
        with open(os.path.join(HERE, "data", "two_rooms.lights.json")) as f:
            self.assertEqual(export.lights, json.load(f))

    def test_bake_apply_matches_cli_eval_and_relights_without_rebake(self):
        scene = build_two_rooms()
        state = run_bake(scene)
        self.assertEqual(state.state, "succeeded", state.message)
        self.assertEqual(state.progress, 1.0)
        bake_id = state.bake_id
        # The same bake again: the service's 200 answer, no new work.
        state = run_bake(scene)
        self.assertEqual((state.state, state.bake_id), ("succeeded", bake_id))
        self.assertIn("reused", state.message)
        bundle_hash = bake_status(bake_id)["bundle"]

        for mode in ("emission", "multiply"):
            state.mode = mode
            self.assertEqual(bpy.ops.lightfarm.apply(), {"FINISHED"})
            self.check_against_eval(scene, bundle_hash, mode)
        # All bounces by default; one bounce when asked (the papers' light), and less of it.
        summed_all = int(state.message.split(" bounce")[0].rsplit(" ", 1)[1])
        self.assertGreater(summed_all, 1, state.message)
        all_pixels = list(lightmap_image(bpy.data.objects["room_b"]).pixels)
        state.bounces = 1
        self.assertEqual(bpy.ops.lightfarm.apply(), {"FINISHED"})
        self.assertIn("1 bounce)", state.message)
        self.check_against_eval(scene, bundle_hash, "multiply", bounces="1")
        one_pixels = list(lightmap_image(bpy.data.objects["room_b"]).pixels)
        self.assertLess(sum(one_pixels), sum(all_pixels))
        state.bounces = 0

        # Move the light: Apply again relights from the same bake (no rebake).
        bakes_before = len(os.listdir(os.path.join(SERVER.data, "jobs")))
        before = list(lightmap_image(bpy.data.objects["room_b"]).pixels)
        bpy.data.objects["lamp"].location = (6.0, -1.0, 2.0)
        state.mode = "emission"
        self.assertEqual(bpy.ops.lightfarm.apply(), {"FINISHED"})
        after = list(lightmap_image(bpy.data.objects["room_b"]).pixels)
        self.assertGreater(max(abs(a - b) for a, b in zip(before, after)), 0.05)
        self.check_against_eval(scene, bundle_hash, "emission")
        self.assertEqual(len(os.listdir(os.path.join(SERVER.data, "jobs"))), bakes_before)

    def check_against_eval(self, scene, bundle_hash, mode, bounces="all"):
        export = scene_export.export_scene(scene)
        expected = cli_eval(bundle_hash, export.lights, bounces=bounces)
        t = texels_per_face(expected)
        self.assertEqual(t, FAST["texels_per_face"])
        by_object = texels_by_face(expected, t)
        self.assertEqual(set(by_object), {("block", "room_a"), ("block", "room_b"),
                                          ("clutter", "pillar")})
        worst, checked = 0.0, 0
        for (kind, name), faces in by_object.items():
            layout = BoxLightmap.for_faces(faces, t)
            self.assertEqual((layout.width, layout.height), BoxLightmap(t).size())
            w, n = check_box_lightmap(self, bpy.data.objects[name], faces, layout, mode)
            worst, checked = max(worst, w), checked + n
        self.assertEqual(checked, (5 + 5 + 6) * t * t)
        self.assertLessEqual(worst, TOLERANCE)
        print(f"\n  {mode}: {checked} texels, max |pixel - eval| = {worst:.3g}", end="")


def check_box_lightmap(test, obj, faces, layout, mode):
    """Checks ``obj``'s applied lightmap against ``faces`` (``texels_by_face``'s, laid out
    as ``layout``): the image's size, and for every texel the UV of its centre on the
    polygon of its face landing on its pixel. Returns (the largest |pixel − texel value|,
    texels checked)."""
    image = lightmap_image(obj)
    test.assertEqual(tuple(image.size), (layout.width, layout.height))
    test.assertEqual(obj.data.uv_layers.get("lightmap") is not None, True)
    pixels = list(image.pixels)
    polygon_of = {}
    for polygon in obj.data.polygons:
        centre = frames.to_lightfarm(obj.matrix_world @ polygon.center)
        normal_axis = {0: 0, 1: 2, 2: 1}[max(range(3), key=lambda a: abs(polygon.normal[a]))]
        for face in faces:
            lo_hi = faces[face][0]["position"][frames.face_axis(face)]
            if frames.face_axis(face) == normal_axis and abs(centre[normal_axis] - lo_hi) < 1e-4:
                polygon_of[face] = polygon
    worst, checked = 0.0, 0
    for face, records in faces.items():
        test.assertIn(face, polygon_of, f"{obj.name} {face}: no polygon")
        for k, record in enumerate(records):
            x, y = layout.texel_pixel(face, k)
            at = 4 * (y * layout.width + x)
            want = texel_value(record, mode)
            for c in range(3):
                worst = max(worst, abs(pixels[at + c] - want[c]))
            # Orientation: the mesh's UV at the texel's centre lands on that pixel.
            uv = uv_at(obj, polygon_of[face], record["position"])
            test.assertEqual((int(uv[0] * layout.width), int(uv[1] * layout.height)),
                             (x, y), f"{record['surface']} #{record['index']}")
            checked += 1
    return worst, checked


class BadInput(unittest.TestCase):
    def test_rotated_block_and_open_mesh_are_reported_by_name(self):
        scene = build_two_rooms()
        tilted = cube("tilted_room", (10, -4, 0), (14, 0, 3), scene_export.BLOCKS)
        tilted.rotation_euler = (0.0, 0.0, 0.3)
        bpy.ops.mesh.primitive_plane_add(size=1.0, location=(2, -2, 1))
        sheet = bpy.context.active_object
        sheet.name = "sheet"
        for owner in list(sheet.users_collection):
            owner.objects.unlink(sheet)
        collection(scene_export.CLUTTER).objects.link(sheet)
        sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
        scene.collection.objects.link(sun)
        bpy.context.view_layer.update()
        export = scene_export.export_scene(scene)
        names = [name for name, _ in export.problems]
        self.assertEqual(names, ["tilted_room", "sheet", "sun"], export.problems)
        self.assertIn("not an axis-aligned box", export.problems[0][1])
        self.assertIn("not closed", export.problems[1][1])
        self.assertEqual([b["id"] for b in export.scene["blocks"]], ["room_a", "room_b"])
        # The bake goes on without them, and the panel lists them.
        state = run_bake(scene)
        self.assertEqual(state.state, "succeeded", state.message)
        self.assertEqual([p.name for p in state.problems], names)

    def test_service_422_is_shown_on_the_object_it_names(self):
        scene = build_two_rooms()
        white = material("white", (1.0, 1.0, 1.0))
        bpy.data.objects["pillar"].data.materials[0] = white
        state = run_bake(scene)
        self.assertEqual(state.state, "failed")
        self.assertIn("albedo", state.message)
        self.assertEqual([p.name for p in state.problems], ["pillar"])
        self.assertIn("clutter \"pillar\"", state.problems[0].message)
        self.assertIn("albedo", bpy.data.objects["pillar"]["lightfarm_error"])
        self.assertEqual(bpy.ops.lightfarm.select(name="pillar"), {"FINISHED"})
        self.assertEqual(bpy.context.view_layer.objects.active.name, "pillar")
        # Fixed and baked again: the mark is gone.
        bpy.data.objects["pillar"].data.materials[0] = material("grey", (0.5, 0.5, 0.5))
        self.assertEqual(run_bake(scene).state, "succeeded")
        self.assertNotIn("lightfarm_error", bpy.data.objects["pillar"])

    def test_service_down_gives_a_message(self):
        scene = build_two_rooms()
        prefs = bpy.context.preferences.addons["lightfarm_blender"].preferences
        prefs.url = "http://127.0.0.1:9"  # discard port: nothing listens
        state = run_bake(scene, timeout=60)
        self.assertEqual(state.state, "failed")
        self.assertIn("not reachable", state.message)
        # Apply reports the same sentence (in the UI a message; a script gets it raised).
        state.bake_id, state.state = "0" * 64, "succeeded"
        with self.assertRaises(RuntimeError) as caught:
            bpy.ops.lightfarm.apply()
        self.assertIn("not reachable", str(caught.exception))
        self.assertNotIn("Traceback", str(caught.exception))
        self.assertIn("not reachable", state.message)


class Service(unittest.TestCase):
    def test_cancel_stops_the_bake(self):
        scene = build_two_rooms()
        scene.lightfarm.texels_per_face = 24
        scene.lightfarm.rays_per_texel = 65536
        self.assertEqual(bpy.ops.lightfarm.bake(), {"FINISHED"})
        deadline = time.time() + 60
        while operators.current_job() is not None and not scene.lightfarm.bake_id:
            operators.poll_job()
            self.assertLess(time.time(), deadline)
            time.sleep(0.1)
        self.assertEqual(bpy.ops.lightfarm.cancel(), {"FINISHED"})
        state = run_bake_wait(scene)
        self.assertEqual(state.state, "cancelled", state.message)

    def test_evaluate_is_gzip_compressed_and_gives_the_plain_answer(self):
        scene = build_two_rooms()
        state = run_bake(scene)
        self.assertEqual(state.state, "succeeded", state.message)
        lights = scene_export.export_scene(scene).lights
        service = operators.service_of(bpy.context)
        result, _ = service.evaluate(state.bake_id, lights)
        self.assertEqual(service.last_encoding, "gzip")
        # The same request without Accept-Encoding: the plain document, several times larger.
        request = urllib.request.Request(
            f"{SERVER.url}/v1/bakes/{state.bake_id}/evaluate",
            data=json.dumps(lights).encode("utf-8"),
            headers={"Content-Type": "application/json"}, method="POST")
        with urllib.request.urlopen(request) as response:
            self.assertIsNone(response.headers.get("Content-Encoding"))
            plain = response.read()
        self.assertEqual(result, json.loads(plain))
        self.assertLess(3 * service.last_wire_bytes, len(plain))

    def test_opening_another_file_during_a_bake_stops_watching_it(self):
        scene = build_two_rooms()
        self.assertEqual(bpy.ops.lightfarm.bake(), {"FINISHED"})
        bpy.ops.wm.read_factory_settings(use_empty=True)  # the baked scene is freed
        self.assertIsNone(operators.poll_job())
        self.assertIsNone(operators.current_job())
        del scene

    def test_mesh_clutter_is_uploaded_as_glb(self):
        scene = build_two_rooms()
        ball = mesh_clutter("ball", "ico_sphere", subdivisions=2, radius=0.3,
                            location=(3, -1, 0.5))
        export = scene_export.export_scene(scene)
        self.assertEqual(export.problems, [])
        self.assertIn("ball", export.meshes)
        # Export gave the ball a "lightmap" UV layer (it had none) and sent it as TEXCOORD_1.
        self.assertIn("lightmap", ball.data.uv_layers)
        self.assertEqual(glb_attributes(export.meshes["ball"]),
                         {"POSITION", "TEXCOORD_0", "TEXCOORD_1"})
        service = operators.service_of(bpy.context)
        request = urllib.request.Request(f"{SERVER.url}/v1/assets", data=export.meshes["ball"],
                                         method="POST")
        with urllib.request.urlopen(request) as response:
            created = json.load(response)
        self.assertEqual((created["format"], created["triangles"]), ("glb", 80))
        self.assertEqual(service.upload_asset(export.meshes["ball"]), created["hash"])
        state = run_bake(scene)
        self.assertEqual(state.state, "succeeded", state.message)
        self.assertEqual(bpy.ops.lightfarm.apply(), {"FINISHED"})
        self.assertEqual([p.name for p in state.problems], [])
        self.assertIn("lit 4 objects", state.message)

    def test_mesh_clutter_lightmap_matches_cli_eval(self):
        scene = build_two_rooms()
        mesh_clutter("ball", "ico_sphere", subdivisions=2, radius=0.4, location=(6, -2, 0.6))
        column = mesh_clutter("column", "cylinder", vertices=12, radius=0.25, depth=2.0,
                              location=(2.5, -3.0, 1.0))
        # An artist's own lightmap UVs are kept: the column's come from Lightmap Pack.
        from bl_operators.uvcalc_lightmap import lightmap_uvpack
        uv = column.data.uv_layers.new(name="lightmap")
        column.data.uv_layers.active = uv
        lightmap_uvpack([column.data], PREF_SEL_ONLY=False, PREF_MARGIN_DIV=50)
        before = [tuple(d.uv) for d in column.data.uv_layers["lightmap"].data]
        state = run_bake(scene)
        self.assertEqual(state.state, "succeeded", state.message)
        self.assertEqual([tuple(d.uv) for d in column.data.uv_layers["lightmap"].data], before)
        bundle_hash = bake_status(state.bake_id)["bundle"]
        for mode, bounces in (("emission", "all"), ("multiply", "all"), ("emission", "1")):
            state.mode, state.bounces = mode, int(bounces) if bounces != "all" else 0
            self.assertEqual(bpy.ops.lightfarm.apply(), {"FINISHED"})
            self.assertEqual([p.name for p in state.problems], [], state.message)
            self.assertIn("lit 5 objects", state.message)
            self.check_meshes(scene, bundle_hash, mode, bounces, ("ball", "column"))
        state.bounces = 0

    def check_meshes(self, scene, bundle_hash, mode, bounces, names):
        """Every texel of each mesh clutter object: its pixel in the applied image equals
        ``lightfarm eval``'s value (within 1/255), its cell is where the engine's own atlas
        (``eval --f16``, the bundle's surface atlas) puts it, and the object's ``lightmap`` UV at
        a texel's centre maps to that texel's world position (orientation)."""
        import numpy as np
        export = scene_export.export_scene(scene)
        expected, f16 = cli_eval(bundle_hash, export.lights, bounces=bounces, f16=True)
        t = texels_per_face(expected)
        surfaces = records_by_surface(expected)
        for name in names:
            obj = bpy.data.objects[name]
            records = surfaces[f"clutter:{name}"]
            atlas = MeshLightmap(*export.mesh_lightmaps[name], t)
            self.assertEqual(atlas.texel_count, len(records))
            image = lightmap_image(obj)
            self.assertEqual(tuple(image.size), (atlas.size, atlas.size))
            node = obj.material_slots[0].material.node_tree.nodes["lightfarm uv"]
            self.assertEqual(node.uv_map, "lightmap")
            pixels = np.array(image.pixels[:]).reshape(atlas.size, atlas.size, 4)
            worst = 0.0
            for record in records:
                x, y = atlas.texel_pixel(record["index"])
                want = texel_value(record, mode)
                worst = max(worst, max(abs(pixels[y, x, c] - want[c]) for c in range(3)))
            self.assertLessEqual(worst, TOLERANCE, name)
            # The engine's placement: eval --f16 holds the indirect light of this surface's
            # atlas as one region; exactly one offset puts every texel on its value.
            cells = np.array(atlas.cells)
            indirect = np.array([r["indirect"] for r in records], dtype=np.float16)
            height, width = f16.shape[:2]
            offsets = [(ox, oy) for oy in range(height - cells[:, 1].max())
                       for ox in range(width - cells[:, 0].max())
                       if np.array_equal(f16[oy + cells[:, 1], ox + cells[:, 0]], indirect)]
            self.assertEqual(len(offsets), 1, f"{name}: offsets {offsets[:4]}")
            # Orientation: a texel whose centre is inside a UV triangle sits at that point of
            # the triangle in the world.
            inside = 0
            for record in records:
                cx, cy = atlas.cells[record["index"]]
                for tri, tuv in zip(atlas.triangles, atlas.triangle_uv):
                    b = bary2(tuv, (cx + 0.5, cy + 0.5))
                    if b is not None and min(b) > 1e-6:
                        world = [sum(b[k] * tri[k][a] for k in range(3)) for a in range(3)]
                        self.assertLess(max(abs(w - p) for w, p in zip(world,
                                                                       record["position"])),
                                        1e-4, f"{name} #{record['index']}")
                        inside += 1
                        break
            self.assertGreater(inside, len(records) // 3, name)
            # Filtering: bilinear lookups anywhere on a triangle (corners, edge midpoints,
            # centroid) read four filled pixels, never the black outside the charts.
            # (Filled: the image's texels and the rings around them; some texels are black,
            # the column's base stands on the floor.)
            filled = np.array(atlas.pixels([(1.0, 1.0, 1.0)] * len(records))).reshape(
                atlas.size, atlas.size, 4)[:, :, 0] > 0.0
            for tuv in atlas.triangle_uv:
                for b in ((1, 0, 0), (0, 1, 0), (0, 0, 1), (.5, .5, 0), (0, .5, .5), (.5, 0, .5),
                          (1 / 3, 1 / 3, 1 / 3)):
                    u = sum(b[k] * tuv[k][0] for k in range(3))
                    v = atlas.size - sum(b[k] * tuv[k][1] for k in range(3))  # Blender rows
                    x0, y0 = int(np.floor(u - 0.5)), int(np.floor(v - 0.5))
                    for y in (y0, y0 + 1):
                        for x in (x0, x0 + 1):
                            if 0 <= x < atlas.size and 0 <= y < atlas.size:
                                self.assertTrue(filled[y, x], f"{name}: black at ({x}, {y})")
            print(f"\n  {name} {mode} bounces={bounces}: {len(records)} texels on "
                  f"{atlas.size}x{atlas.size}, max |pixel - eval| = {worst:.3g}", end="")


def mesh_clutter(name, primitive, **options):
    """A Blender primitive (``bpy.ops.mesh.primitive_<primitive>_add``) in
    ``lightfarm_clutter``, with a material."""
    getattr(bpy.ops.mesh, f"primitive_{primitive}_add")(**options)
    obj = bpy.context.active_object
    obj.name = name
    obj.data.name = name
    for owner in list(obj.users_collection):
        owner.objects.unlink(obj)
    collection(scene_export.CLUTTER).objects.link(obj)
    obj.data.materials.append(material(f"{name} paint", (0.6, 0.55, 0.4)))
    return obj


def glb_attributes(glb):
    import struct
    length = struct.unpack_from("<I", glb, 12)[0]
    document = json.loads(glb[20:20 + length])
    return set(document["meshes"][0]["primitives"][0]["attributes"])


def run_bake_wait(scene, timeout=120):
    deadline = time.time() + timeout
    while operators.poll_job() is not None:
        if time.time() > deadline:
            raise AssertionError("bake did not end")
        time.sleep(0.2)
    return scene.lightfarm


class RoundTrip(unittest.TestCase):
    def test_maze_import_then_export_is_the_same_scene(self):
        for name in ("maze", "cornell", "corridor"):
            fresh_scene()
            path = os.path.join(REPO, "scenes", name, "scene.json")
            self.assertEqual(bpy.ops.lightfarm.import_scene(filepath=path), {"FINISHED"})
            with open(path) as f:
                original = json.load(f)
            export = scene_export.export_scene(bpy.context.scene)
            self.assertEqual(export.problems, [])
            self.assertEqual(close(export.scene, original), True, name)
            with open(os.path.join(REPO, "scenes", name, "lights.json")) as f:
                self.assertEqual(close(export.lights, json.load(f)), True, name)


def close(a, b, tolerance=1e-9):
    """Equal JSON documents, numbers within ``tolerance`` (float formatting)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(close(a[k], b[k], tolerance) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(close(x, y, tolerance) for x, y in zip(a, b))
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return abs(a - b) <= tolerance * max(1.0, abs(b))
    return a == b


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--lightfarm", default=os.path.join(REPO, "target", "release",
                                                             "lightfarm"))
    args, rest = parser.parse_known_args()
    LIGHTFARM = os.path.abspath(args.lightfarm)
    unittest.main(argv=[sys.argv[0]] + rest, verbosity=2)
