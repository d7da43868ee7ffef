#!/usr/bin/env python3
"""The Mitsuba check (`../shared/groundtruth/lfgt.py`) without its coincident faces.

lfgt.py's converter gives Mitsuba every closed face of every block as a two-sided quad at the
block's bounds. Where two blocks touch without an opening (a shared wall, a floor on the
ceiling below) their faces lie in one plane, and Mitsuba's ray hits either of the two at
random (equal distances): a ray inside room A takes room B's face, and with it B's albedo, for
part of A's wall. The scene format means A's side (our tracer: of coincident faces the one
whose lit side faces the ray). On levels whose rooms differ in albedo the reference is then
off by up to about half the albedo difference on those faces, and so is every error measured
against it: on a generated two-storey level (`gen_level.py --blocks 40 --seed 21 --storeys 2
--stairs 0.3 --pillars 0.4 --dynamic 0`) our path tracer (`lightfarm reference --bounces 1`)
was 1.14x Mitsuba's one-bounce light on the floor of the room whose ceiling is a darker room's
floor (albedo 0.73 below, 0.53-0.61 above); 0.99x with the room above given the same albedo,
2.07x with it given 0.1; with the faces moved as here, 0.98x (its albedos) and 0.99x (0.1).

Here each closed block face is moved into its own block by `OFFSET` metres before Mitsuba sees
it (extents unchanged, so corners stay closed: faces overlap by `OFFSET` at the edges), which
keeps each room's faces in front of its neighbours' by far more than f32's rounding at level
scale; the query points (1 mm off the texel, lfgt.py's) stay inside. Clutter, dynamic objects
and lights are lfgt.py's, untouched.

lfgt.py reads clutter and dynamic-object meshes from OBJ files only; here glTF and GLB meshes
are read too (`gltf_triangles`: the default scene's node hierarchy, triangle primitives, as
the bake reads them), so mesh levels such as `scenes/cornell_mesh` can be checked. A glTF
whose primitives carry colours of their own (a base colour factor other than white,
`COLOR_0`, a base-colour texture) is refused: the converter gives a mesh one albedo, the
object's `albedo` setting, which is what the bake gives uncoloured primitives.

Usage (the same arguments as lfgt.py, with its Python; see README's "Checking the reference"):
  gt_check.py check SCENE.json LIGHTS.json RESULT.json [lfgt.py check options]
  gt_check.py convert SCENE.json LIGHTS.json -o GTSCENE.json
  gt_check.py coincident SCENE.json     # closed faces of different blocks in one plane
`coincident` needs no Mitsuba: it lists the pairs the stock check is exposed to (how many,
their area, how many differ in albedo). lfgt.py is found in `$LF_GROUNDTRUTH` or
`../shared/groundtruth` beside the repository.
"""

import base64
import json
import os
import struct
import sys
from pathlib import Path
from urllib.parse import unquote

ROOT = Path(__file__).resolve().parent.parent
# Metres each closed block face moves into its block: 0.2 mm, a fifth of lfgt.py's 1 mm query
# lift, and about ten f32 steps at 1 km.
OFFSET = 2e-4
# Coordinates closer than this are one (metres): a face's plane in lfgt.convert's output, and
# an overlap's extent.
SAME = 1e-9
FACES = {"-x": (0, 0), "+x": (0, 1), "-y": (1, 0), "+y": (1, 1), "-z": (2, 0), "+z": (2, 1)}


def groundtruth_dir():
    return Path(os.environ.get("LF_GROUNDTRUTH", ROOT.parent / "shared" / "groundtruth"))


def closed_faces(scene):
    """Every closed face of every block: (block id, face name, axis, plane, lo, hi, albedo)
    with lo/hi the face's bounds on the other two axes, in scene and FACES order."""
    out = []
    for b in scene["blocks"]:
        for name, (ax, side) in FACES.items():
            if name in b.get("open", []):
                continue
            u, v = [a for a in range(3) if a != ax]
            plane = b["max"][ax] if side else b["min"][ax]
            lo = (b["min"][u], b["min"][v])
            hi = (b["max"][u], b["max"][v])
            albedo = b.get("face_albedo", {}).get(name, b["albedo"])
            out.append((b["id"], name, ax, plane, lo, hi, albedo))
    return out


def coincident(scene):
    """Pairs of closed faces of different blocks in one plane with facing normals (back to
    back) that overlap with positive area: (face, face, area)."""
    faces = closed_faces(scene)
    by_plane = {}
    for f in faces:
        # Coincident faces come from the same coordinate in the scene: one key, exactly.
        by_plane.setdefault((f[2], f[3]), []).append(f)
    pairs = []
    for group in by_plane.values():
        for i, a in enumerate(group):
            for b in group[i + 1:]:
                if a[0] == b[0] or a[1] == b[1]:
                    continue  # one block, or both facing the same way (not back to back)
                w = min(a[5][0], b[5][0]) - max(a[4][0], b[4][0])
                h = min(a[5][1], b[5][1]) - max(a[4][1], b[4][1])
                if w > SAME and h > SAME:
                    pairs.append((a, b, w * h))
    return pairs


def separated(lfgt):
    """lfgt.convert with each closed block face moved `OFFSET` into its block."""
    original = lfgt.convert

    def convert(scene_path, lights_path):
        out = original(scene_path, lights_path)
        scene = json.load(open(scene_path))
        faces = closed_faces(scene)
        # lfgt.convert lists the blocks' closed faces first, block by block in FACES order
        # (checked: each quad lies in the face's plane with the face's albedo).
        for mesh, (bid, name, ax, plane, _, _, albedo) in zip(out["meshes"], faces):
            side = FACES[name][1]
            if any(abs(p[ax] - plane) > SAME for p in mesh["vertices"]) or mesh["albedo"] != albedo:
                raise SystemExit(f"gt_check: lfgt.convert's mesh order changed at {bid} {name}")
            inward = -OFFSET if side else OFFSET
            for p in mesh["vertices"]:
                p[ax] = plane + inward
        return out

    return convert


GLTF_COMPONENTS = {5121: ("B", 1), 5123: ("H", 2), 5125: ("I", 4), 5126: ("f", 4)}
GLTF_WIDTHS = {"SCALAR": 1, "VEC3": 3}


def gltf_document(path):
    """(json, [buffer bytes]) of a .gltf (buffers from files beside it or data URIs) or .glb."""
    raw = Path(path).read_bytes()
    bin_chunk = None
    if raw[:4] == b"glTF":
        length, at = struct.unpack_from("<I", raw, 8)[0], 12
        doc = None
        while at + 8 <= length:
            size, kind = struct.unpack_from("<II", raw, at)
            chunk = raw[at + 8 : at + 8 + size]
            if kind == 0x4E4F534A:
                doc = json.loads(chunk)
            elif kind == 0x004E4942:
                bin_chunk = chunk
            at += 8 + size
        if doc is None:
            raise SystemExit(f"gt_check: {path}: GLB without a JSON chunk")
    else:
        doc = json.loads(raw)
    buffers = []
    for i, b in enumerate(doc.get("buffers", [])):
        uri = b.get("uri")
        if uri is None:
            if bin_chunk is None:
                raise SystemExit(f"gt_check: {path}: buffer {i} has no uri and no GLB chunk")
            buffers.append(bin_chunk)
        elif uri.startswith("data:"):
            buffers.append(base64.b64decode(uri.split(",", 1)[1]))
        else:
            buffers.append((Path(path).parent / unquote(uri)).read_bytes())
    return doc, buffers


def gltf_accessor(doc, buffers, index):
    """Accessor `index` as a list of tuples (or of numbers for SCALAR)."""
    acc = doc["accessors"][index]
    if (
        "sparse" in acc
        or acc.get("normalized")
        or "bufferView" not in acc
        or acc["componentType"] not in GLTF_COMPONENTS
        or acc["type"] not in GLTF_WIDTHS
    ):
        raise SystemExit(
            f"gt_check: glTF accessor {index} ({acc.get('type')}, component type "
            f"{acc.get('componentType')}) is not read: float positions and unsigned indices "
            "in buffer views only"
        )
    fmt, size = GLTF_COMPONENTS[acc["componentType"]]
    width = GLTF_WIDTHS[acc["type"]]
    view = doc["bufferViews"][acc["bufferView"]]
    data = buffers[view["buffer"]]
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    stride = view.get("byteStride") or size * width
    out = []
    for k in range(acc["count"]):
        v = struct.unpack_from("<" + fmt * width, data, start + k * stride)
        out.append(v[0] if width == 1 else v)
    return out


def node_matrix(node):
    """A node's local matrix, row-major 4 × 4 (glTF stores `matrix` column-major)."""
    if "matrix" in node:
        m = node["matrix"]
        return [[m[c * 4 + r] for c in range(4)] for r in range(4)]
    t = node.get("translation", [0, 0, 0])
    x, y, z, w = node.get("rotation", [0, 0, 0, 1])
    s = node.get("scale", [1, 1, 1])
    r = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    return [[r[i][j] * s[j] for j in range(3)] + [t[i]] for i in range(3)] + [[0, 0, 0, 1]]


def mat_mul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def gltf_triangles(path):
    """(vertices, faces) of a glTF/GLB in its own frame: every triangle primitive of the
    default scene (else the first), node transforms applied down the hierarchy, as
    `server/src/bake/scene/mesh.rs` reads it. Coloured primitives are refused (module doc)."""
    doc, buffers = gltf_document(path)
    scenes = doc.get("scenes", [])
    if not scenes:
        raise SystemExit(f"gt_check: {path}: glTF has no scene")
    scene = scenes[doc.get("scene", 0)]
    identity = [[float(i == j) for j in range(4)] for i in range(4)]
    stack = [(n, identity) for n in scene.get("nodes", [])]
    vs, fs = [], []
    while stack:
        n, parent = stack.pop()
        node = doc["nodes"][n]
        world = mat_mul(parent, node_matrix(node))
        if "mesh" in node:
            for prim in doc["meshes"][node["mesh"]]["primitives"]:
                if prim.get("mode", 4) != 4 or "POSITION" not in prim["attributes"]:
                    continue
                material = doc.get("materials", [])[prim["material"]] if "material" in prim else {}
                pbr = material.get("pbrMetallicRoughness", {})
                if (
                    "COLOR_0" in prim["attributes"]
                    or "baseColorTexture" in pbr
                    or any(x != 1 for x in pbr.get("baseColorFactor", [1, 1, 1, 1])[:3])
                ):
                    raise SystemExit(
                        f"gt_check: {path}: a primitive has colours of its own; "
                        "the converter gives a mesh one albedo"
                    )
                pos = gltf_accessor(doc, buffers, prim["attributes"]["POSITION"])
                first = len(vs)
                for p in pos:
                    vs.append([sum(world[i][k] * (list(p) + [1])[k] for k in range(4)) for i in range(3)])
                idx = (
                    gltf_accessor(doc, buffers, prim["indices"])
                    if "indices" in prim
                    else list(range(len(pos)))
                )
                if any(i >= len(pos) for i in idx):
                    raise SystemExit(f"gt_check: {path}: a glTF index is out of range")
                for k in range(0, len(idx) - 2, 3):
                    fs.append([first + idx[k], first + idx[k + 1], first + idx[k + 2]])
        stack.extend((c, world) for c in node.get("children", []))
    return vs, fs


def with_gltf(load_obj):
    """lfgt.load_obj, reading `.gltf` and `.glb` files through `gltf_triangles`."""

    def load(path):
        if str(path).lower().endswith((".gltf", ".glb")):
            return gltf_triangles(path)
        return load_obj(path)

    return load


def main(argv):
    if len(argv) >= 3 and argv[1] == "coincident":
        scene = json.load(open(argv[2]))
        pairs = coincident(scene)
        differ = [p for p in pairs if p[0][6] != p[1][6]]
        print(
            "coincident_pairs=%d differing_albedo=%d area_m2=%.2f differing_area_m2=%.2f"
            % (len(pairs), len(differ), sum(p[2] for p in pairs), sum(p[2] for p in differ))
        )
        return 0
    sys.path.insert(0, str(groundtruth_dir()))
    import lfgt  # noqa: E402 (found at run time)

    lfgt.convert = separated(lfgt)
    lfgt.load_obj = with_gltf(lfgt.load_obj)
    sys.argv = ["lfgt.py"] + argv[1:]
    lfgt.main()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
