#!/usr/bin/env python3
"""Writes short_box.gltf + short_box.bin: the Cornell short box (a 1.65 m cube centred at
(3.925, 0.825, 3.825), turned -17 degrees about y) as 12 outward-wound triangles."""
import json
import math
import struct

c, h, a = (3.925, 0.825, 3.825), 0.825, math.radians(-17.0)
verts = []
for i in range(8):
    x, y, z = (h if i & 1 else -h), (h if i & 2 else -h), (h if i & 4 else -h)
    rx, rz = x * math.cos(a) + z * math.sin(a), -x * math.sin(a) + z * math.cos(a)
    verts.append((c[0] + rx, c[1] + y, c[2] + rz))
quads = [[0, 4, 6, 2], [1, 3, 7, 5], [0, 1, 5, 4], [2, 6, 7, 3], [0, 2, 3, 1], [4, 5, 7, 6]]
idx = [i for q in quads for i in (q[0], q[1], q[2], q[0], q[2], q[3])]
pos = b"".join(struct.pack("<3f", *v) for v in verts)
ind = b"".join(struct.pack("<H", i) for i in idx)
open("short_box.bin", "wb").write(pos + ind)
lo = [min(v[k] for v in verts) for k in range(3)]
hi = [max(v[k] for v in verts) for k in range(3)]
gltf = {
    "asset": {"version": "2.0", "generator": "scenes/cornell_mesh (see README)"},
    "scene": 0,
    "scenes": [{"nodes": [0]}],
    "nodes": [{"mesh": 0, "name": "short_box"}],
    "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
    "buffers": [{"uri": "short_box.bin", "byteLength": len(pos) + len(ind)}],
    "bufferViews": [
        {"buffer": 0, "byteOffset": 0, "byteLength": len(pos)},
        {"buffer": 0, "byteOffset": len(pos), "byteLength": len(ind)},
    ],
    "accessors": [
        {"bufferView": 0, "componentType": 5126, "count": 8, "type": "VEC3", "min": lo, "max": hi},
        {"bufferView": 1, "componentType": 5123, "count": 36, "type": "SCALAR"},
    ],
}
open("short_box.gltf", "w").write(json.dumps(gltf, indent=1) + "\n")
