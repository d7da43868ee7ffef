#!/usr/bin/env python3
"""Writes a seeded, game-sized test level: N blocks on a grid, clutter, lights and poses.

The level is a grid of rooms. Every column of the grid has its own width and every row its own
depth (2-6 m, in 0.5 m steps), all rooms 3 m high, so two neighbouring rooms always share a
whole wall and an opening between them is the same face on both sides (the scene format's rule).
Openings: a random spanning tree over the rooms (every room reachable), plus loops (a further
fraction of the remaining walls between rooms). About a fifth of the large rooms (both sides
at least 4 m) hold a pillar (a 0.5 m box, 2.8 m high, away from the walls); about 15% of the
rooms hold a point light (at least one in the level); `--dynamic K` adds K moving balls with a
pose each in the lights file and its room as the region it moves in (the probe volume is baked
over those rooms only). The same arguments always write the same bytes.

`--storeys K` stacks K storeys of the same grid (the level's N blocks split among them, storey s
from y = 3s): each storey's rooms are joined by their own spanning tree and loops, and a fraction
`--stairs` of the rooms (at least one per pair of storeys) open their ceiling into the room above,
so light and every path between storeys go through those shafts. Pillars, lights and balls are
placed on every storey as on the ground floor; with one storey (the default) the level is the
same bytes as without the option.

`--tile B` writes N / B copies of the B-block level side by side along x instead (N a multiple
of B), each joined to the next through one opening (between the last room of the copy's first
row and the first room of the next copy's), with the tile's lights in every copy, listed copy by
copy; dynamic objects stay in the first copy. A light of the first copy then has the same
neighbourhood in every level of two copies or more, so its relighting cost can be read against
the level's size alone (`lightfarm bench --scale ... --tile B`).

Usage:
    scripts/gen_level.py OUT_DIR [--blocks 1000] [--seed 1] [--texels 8] [--rays 1024]
        [--tolerance 0.001] [--pillars 0.2] [--lights 0.15] [--loops 0.1] [--dynamic 1]
        [--storeys 1] [--stairs 0.05] [--tile B]

Writes OUT_DIR/scene.json, OUT_DIR/lights.json and (with dynamic objects) OUT_DIR/ball.obj, and
prints one line of counts.
"""

import argparse
import json
import math
import random
from pathlib import Path

HEIGHT = 3.0
PILLAR = 0.5  # pillar side, metres
PILLAR_HEIGHT = 2.8
WALL_GAP = 0.6  # metres between a pillar and the walls of its room
LIGHT_GAP = 0.4  # metres between a light and every wall, pillar or ball


def sizes(rng, n):
    """n extents in 2..6 m, 0.5 m steps."""
    return [2.0 + 0.5 * rng.randrange(9) for _ in range(n)]


def prefix(extents):
    out, at = [], 0.0
    for e in extents:
        out.append(at)
        at += e
    return out


def spanning_edges(rng, cells, loops):
    """A random spanning tree over the cells (randomised Kruskal) plus a fraction of the rest:
    one tree per storey when cells are (i, j, storey), as walls join rooms of one storey."""
    present = set(cells)
    walls = []
    for c in cells:
        for along in (0, 1):
            n = tuple(v + (k == along) for k, v in enumerate(c))
            if n in present:
                walls.append((c, n))
    rng.shuffle(walls)
    parent = {c: c for c in cells}

    def root(c):
        while parent[c] != c:
            parent[c] = parent[parent[c]]
            c = parent[c]
        return c

    tree, rest = [], []
    for a, b in walls:
        ra, rb = root(a), root(b)
        if ra != rb:
            parent[ra] = rb
            tree.append((a, b))
        else:
            rest.append((a, b))
    extra = rest[: int(round(loops * len(rest)))]
    return tree + extra


def icosphere_obj(radius, subdivisions=1):
    """A small icosphere as OBJ text (the dynamic objects' mesh)."""
    t = (1.0 + math.sqrt(5.0)) / 2.0
    verts = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
             (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
             (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
             (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    verts = [tuple(c / math.sqrt(sum(x * x for x in v)) for c in v) for v in verts]
    for _ in range(subdivisions):
        cache, new_faces = {}, []

        def middle(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = [(verts[a][k] + verts[b][k]) / 2 for k in range(3)]
                n = math.sqrt(sum(x * x for x in m))
                verts.append(tuple(x / n for x in m))
                cache[key] = len(verts) - 1
            return cache[key]

        for a, b, c in faces:
            ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
            new_faces += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new_faces
    lines = ["# icosphere written by scripts/gen_level.py"]
    lines += [f"v {radius * x:.6f} {radius * y:.6f} {radius * z:.6f}" for x, y, z in verts]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    return "\n".join(lines) + "\n"


def stair_edges(rng, cells, fraction):
    """Openings between a room and the room above it: a fraction of the stacked pairs, at
    least one between every two storeys (so every room is reachable)."""
    present = set(cells)
    storeys = max(c[2] for c in cells) + 1
    edges = []
    for s in range(storeys - 1):
        pairs = [(c, (c[0], c[1], s + 1)) for c in cells
                 if c[2] == s and (c[0], c[1], s + 1) in present]
        rng.shuffle(pairs)
        edges += pairs[:max(1, int(round(fraction * len(pairs))))]
    return edges


def generate(blocks, seed, texels, rays, tolerance, pillar_fraction, light_fraction, loops,
             dynamic, storeys=1, stairs=0.05):
    rng = random.Random(seed)
    per_storey = math.ceil(blocks / storeys)
    cols = max(1, math.ceil(math.sqrt(per_storey)))
    rows = math.ceil(per_storey / cols)
    widths, depths = sizes(rng, cols), sizes(rng, rows)
    xs, zs = prefix(widths), prefix(depths)
    if storeys == 1:
        cells = [(i, j) for j in range(rows) for i in range(cols)][:blocks]
        name = lambda c: f"room_{c[0]}_{c[1]}"  # noqa: E731
    else:
        cells = [(i, j, s) for s in range(storeys) for j in range(rows)
                 for i in range(cols)][:blocks]
        name = lambda c: f"room_{c[0]}_{c[1]}_{c[2]}"  # noqa: E731
    openings = {c: set() for c in cells}
    edges = spanning_edges(rng, cells, loops)
    if storeys > 1:
        edges += stair_edges(rng, cells, stairs)
    for a, b in edges:
        axis = next(k for k in range(len(a)) if a[k] != b[k])
        face = ["x", "z", "y"][axis]  # (i, j, storey) run along x, z and y
        openings[a].add("+" + face)
        openings[b].add("-" + face)
    face_order = ["-x", "+x", "-y", "+y", "-z", "+z"]
    scene_blocks, clutter, lights, free_cells = [], [], [], []

    def room_box(c):
        y0 = HEIGHT * (c[2] if len(c) > 2 else 0)
        return ([xs[c[0]], y0, zs[c[1]]],
                [xs[c[0]] + widths[c[0]], y0 + HEIGHT, zs[c[1]] + depths[c[1]]])

    for c in cells:
        i, j = c[:2]
        lo, hi = room_box(c)
        y0 = lo[1]
        grey = round(rng.uniform(0.55, 0.75), 2)
        tint = [round(grey + rng.uniform(-0.04, 0.04), 2) for _ in range(3)]
        scene_blocks.append({
            "id": name(c), "min": lo, "max": hi,
            "open": [f for f in face_order if f in openings[c]], "albedo": tint,
        })
        keep_out = []
        if widths[i] >= 4.0 and depths[j] >= 4.0 and rng.random() < pillar_fraction:
            px = rng.uniform(lo[0] + WALL_GAP, hi[0] - WALL_GAP - PILLAR)
            pz = rng.uniform(lo[2] + WALL_GAP, hi[2] - WALL_GAP - PILLAR)
            box = {"min": [round(px, 3), y0, round(pz, 3)],
                   "max": [round(px + PILLAR, 3), y0 + PILLAR_HEIGHT, round(pz + PILLAR, 3)]}
            clutter.append({"id": name(c).replace("room_", "pillar_", 1), "box": box,
                            "albedo": [0.55, 0.53, 0.5]})
            keep_out.append(box)
        else:
            free_cells.append(c)
        if rng.random() < light_fraction:
            lights.append(light_in(rng, lo, hi, keep_out))
    if not lights:
        c = cells[rng.randrange(len(cells))]
        lo, hi = room_box(c)
        boxes = [o["box"] for o in clutter if o["id"] == name(c).replace("room_", "pillar_", 1)]
        lights.append(light_in(rng, lo, hi, boxes))
    scene = {
        "format": "lightfarm.scene/1",
        "name": f"grid_level_{blocks}",
        "settings": {"texels_per_face": texels, "rays_per_texel": rays, "tolerance": tolerance},
        "blocks": scene_blocks,
    }
    if clutter:
        scene["clutter"] = clutter
    poses = []
    if dynamic:
        scene["dynamic"] = [{"id": f"ball_{k}", "mesh": "ball.obj",
                             "albedo": [0.8, 0.15, 0.1] if k % 2 == 0 else [0.1, 0.3, 0.8]}
                            for k in range(dynamic)]
        for k in range(dynamic):
            c = free_cells[rng.randrange(len(free_cells))] if free_cells else cells[0]
            lo, hi = room_box(c)
            x, z = (lo[0] + hi[0]) / 2, (lo[2] + hi[2]) / 2
            poses.append({"id": f"ball_{k}",
                          "translation": [round(x, 3), lo[1] + 0.5, round(z, 3)]})
            # The ball rolls about its room: the probe volume is baked there only.
            scene["dynamic"][k]["regions"] = [{"min": lo, "max": hi}]
    light_set = {"lights": lights}
    if poses:
        light_set["poses"] = poses
    return scene, light_set


def tiled(scene, light_set, copies):
    """`copies` copies of the level side by side along x (module doc)."""
    blocks = scene["blocks"]
    width = max(b["max"][0] for b in blocks) - min(b["min"][0] for b in blocks)
    # The first row's rooms (z from 0) at the low and high x ends: the joins.
    row0 = [b for b in blocks if b["min"][2] == 0.0]
    first = min(row0, key=lambda b: b["min"][0])["id"]
    last = max(row0, key=lambda b: b["max"][0])["id"]
    face_order = ["-x", "+x", "-y", "+y", "-z", "+z"]

    def shifted(box, dx):
        return {"min": [round(box["min"][0] + dx, 3)] + box["min"][1:],
                "max": [round(box["max"][0] + dx, 3)] + box["max"][1:]}

    out_blocks, out_clutter, out_lights = [], [], []
    for c in range(copies):
        dx = c * width
        tag = "" if c == 0 else f"_c{c}"
        for b in blocks:
            faces = set(b["open"])
            if b["id"] == last and c + 1 < copies:
                faces.add("+x")
            if b["id"] == first and c > 0:
                faces.add("-x")
            out_blocks.append({"id": b["id"] + tag, **shifted(b, dx),
                               "open": [f for f in face_order if f in faces],
                               "albedo": b["albedo"]})
        for o in scene.get("clutter", []):
            out_clutter.append({"id": o["id"] + tag, "box": shifted(o["box"], dx),
                                "albedo": o["albedo"]})
        for light in light_set["lights"]:
            p = light["position"]
            out_lights.append({**light, "position": [round(p[0] + dx, 3), p[1], p[2]]})
    scene = {**scene, "name": f"{scene['name']}_x{copies}", "blocks": out_blocks}
    if out_clutter:
        scene["clutter"] = out_clutter
    return scene, {**light_set, "lights": out_lights}


def light_in(rng, lo, hi, keep_out):
    """A point light inside the room [lo, hi], clear of walls and of the boxes in keep_out."""
    for _ in range(100):
        p = [rng.uniform(lo[0] + LIGHT_GAP, hi[0] - LIGHT_GAP), lo[1] + rng.uniform(1.5, 2.5),
             rng.uniform(lo[2] + LIGHT_GAP, hi[2] - LIGHT_GAP)]
        clear = all(not all(b["min"][k] - LIGHT_GAP <= p[k] <= b["max"][k] + LIGHT_GAP
                            for k in range(3)) for b in keep_out)
        if clear:
            break
    warm = rng.uniform(0.0, 1.0)
    power = rng.uniform(6.0, 18.0)
    intensity = [power, power * (0.85 + 0.1 * warm), power * (0.65 + 0.3 * (1 - warm))]
    return {"kind": "point", "position": [round(v, 3) for v in p],
            "intensity": [round(v, 2) for v in intensity]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--blocks", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--texels", type=int, default=8)
    ap.add_argument("--rays", type=int, default=1024)
    ap.add_argument("--tolerance", type=float, default=0.001)
    ap.add_argument("--pillars", type=float, default=0.2, help="fraction of large rooms")
    ap.add_argument("--lights", type=float, default=0.15, help="fraction of rooms")
    ap.add_argument("--loops", type=float, default=0.1,
                    help="fraction of the walls outside the spanning tree that open")
    ap.add_argument("--dynamic", type=int, default=1, help="moving balls")
    ap.add_argument("--storeys", type=int, default=1, help="storeys of the grid (module doc)")
    ap.add_argument("--stairs", type=float, default=0.05,
                    help="fraction of stacked rooms open to the room above")
    ap.add_argument("--tile", type=int, default=None,
                    help="copies of a level of this many blocks (module doc)")
    a = ap.parse_args()
    if a.blocks < 1:
        ap.error("--blocks must be at least 1")
    if a.storeys < 1 or a.storeys > a.blocks:
        ap.error(f"--storeys {a.storeys}: between 1 and --blocks ({a.blocks})")
    if a.storeys > 1 and a.tile is not None:
        ap.error("--storeys and --tile do not combine")
    if a.tile is not None and (a.tile < 1 or a.blocks % a.tile != 0):
        ap.error(f"--tile {a.tile}: --blocks {a.blocks} must be a positive multiple of it")
    tile = a.tile or a.blocks
    scene, light_set = generate(tile, a.seed, a.texels, a.rays, a.tolerance, a.pillars,
                                a.lights, a.loops, a.dynamic, a.storeys, a.stairs)
    if a.blocks > tile:
        scene, light_set = tiled(scene, light_set, a.blocks // tile)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "scene.json").write_text(json.dumps(scene, indent=1) + "\n")
    (a.out / "lights.json").write_text(json.dumps(light_set, indent=1) + "\n")
    if a.dynamic:
        (a.out / "ball.obj").write_text(icosphere_obj(0.4))
    print(f"{a.out}: {len(scene['blocks'])} blocks, {len(scene.get('clutter', []))} pillars, "
          f"{len(light_set['lights'])} lights, {a.dynamic} dynamic objects")


if __name__ == "__main__":
    main()
