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

Usage (the same arguments as lfgt.py, with its Python; see README's "Checking the reference"):
  gt_check.py check SCENE.json LIGHTS.json RESULT.json [lfgt.py check options]
  gt_check.py convert SCENE.json LIGHTS.json -o GTSCENE.json
  gt_check.py coincident SCENE.json     # closed faces of different blocks in one plane
`coincident` needs no Mitsuba: it lists the pairs the stock check is exposed to (how many,
their area, how many differ in albedo). lfgt.py is found in `$LF_GROUNDTRUTH` or
`../shared/groundtruth` beside the repository.
"""

import json
import os
import sys
from pathlib import Path

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
    sys.argv = ["lfgt.py"] + argv[1:]
    lfgt.main()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
