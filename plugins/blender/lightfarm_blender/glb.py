"""A minimal binary glTF 2.0 (GLB) writer for mesh clutter uploads.

One mesh, one primitive: ``POSITION`` (float32 VEC3, lightfarm frame, metres, y up) and
``uint32`` indices, triangles wound counter-clockwise seen from outside (the lit side for
lightfarm). No materials: the scene's ``albedo`` gives the colour.

Invariant: the output is a valid GLB (12-byte header, a JSON chunk padded with spaces and a
BIN chunk padded with zeros to 4 bytes); accessors carry the ``min``/``max`` glTF requires.
"""

import json
import struct


def write_glb(positions, triangles):
    """``positions``: list of (x, y, z); ``triangles``: list of (a, b, c) vertex indices.
    Returns the GLB bytes."""
    vertex_bytes = b"".join(struct.pack("<3f", *p) for p in positions)
    index_bytes = b"".join(struct.pack("<3I", *t) for t in triangles)
    binary = vertex_bytes + index_bytes
    binary += b"\0" * (-len(binary) % 4)
    lo = [min(p[k] for p in positions) for k in range(3)]
    hi = [max(p[k] for p in positions) for k in range(3)]
    document = {
        "asset": {"version": "2.0", "generator": "lightfarm_blender"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [{"byteLength": len(binary)}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": len(vertex_bytes), "target": 34962},
            {"buffer": 0, "byteOffset": len(vertex_bytes), "byteLength": len(index_bytes),
             "target": 34963},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": len(positions), "type": "VEC3",
             "min": lo, "max": hi},
            {"bufferView": 1, "componentType": 5125, "count": 3 * len(triangles),
             "type": "SCALAR"},
        ],
    }
    text = json.dumps(document, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return (struct.pack("<4sII", b"glTF", 2, total)
            + struct.pack("<I4s", len(text), b"JSON") + text
            + struct.pack("<I4s", len(binary), b"BIN\0") + binary)
