"""A minimal binary glTF 2.0 (GLB) writer for mesh clutter uploads.

One mesh, one primitive: ``POSITION`` (float32 VEC3, lightfarm frame, metres, y up) and
``uint32`` indices, triangles wound counter-clockwise seen from outside (the lit side for
lightfarm). With lightmap UVs, ``TEXCOORD_1`` (float32 VEC2, glTF's ``v`` down) carries them,
the lightfarm bake's lightmap UVs, and ``TEXCOORD_0`` names the same accessor (glTF wants
texture-coordinate sets numbered from 0); a vertex is then one per (position, UV) pair, so UV
seams split it. No materials: the scene's ``albedo`` gives the colour.

Invariant: the output is a valid GLB (12-byte header, a JSON chunk padded with spaces and a
BIN chunk padded with zeros to 4 bytes); accessors carry the ``min``/``max`` glTF requires.
"""

import json
import struct


def write_glb(positions, triangles, uvs=None):
    """``positions``: list of (x, y, z); ``triangles``: list of (a, b, c) vertex indices;
    ``uvs``: None, or per triangle three (u, v) (glTF convention) for ``TEXCOORD_1``.
    Returns the GLB bytes."""
    texcoords = None
    if uvs is not None:
        vertex_of, split, texcoords, corners = {}, [], [], []
        for triangle, corner_uvs in zip(triangles, uvs):
            for vertex, uv in zip(triangle, corner_uvs):
                key = (vertex, tuple(uv))
                if key not in vertex_of:
                    vertex_of[key] = len(split)
                    split.append(positions[vertex])
                    texcoords.append(tuple(uv))
                corners.append(vertex_of[key])
        positions = split
        triangles = [tuple(corners[k:k + 3]) for k in range(0, len(corners), 3)]
    vertex_bytes = b"".join(struct.pack("<3f", *p) for p in positions)
    uv_bytes = b"".join(struct.pack("<2f", *uv) for uv in texcoords) if texcoords else b""
    index_bytes = b"".join(struct.pack("<3I", *t) for t in triangles)
    binary = vertex_bytes + uv_bytes + index_bytes
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
            {"buffer": 0, "byteOffset": len(vertex_bytes) + len(uv_bytes),
             "byteLength": len(index_bytes), "target": 34963},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": len(positions), "type": "VEC3",
             "min": lo, "max": hi},
            {"bufferView": 1, "componentType": 5125, "count": 3 * len(triangles),
             "type": "SCALAR"},
        ],
    }
    if texcoords:
        document["bufferViews"].append({"buffer": 0, "byteOffset": len(vertex_bytes),
                                        "byteLength": len(uv_bytes), "target": 34962})
        document["accessors"].append({"bufferView": 2, "componentType": 5126,
                                      "count": len(texcoords), "type": "VEC2"})
        document["meshes"][0]["primitives"][0]["attributes"].update(
            {"TEXCOORD_0": 2, "TEXCOORD_1": 2})
    text = json.dumps(document, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return (struct.pack("<4sII", b"glTF", 2, total)
            + struct.pack("<I4s", len(text), b"JSON") + text
            + struct.pack("<I4s", len(binary), b"BIN\0") + binary)
