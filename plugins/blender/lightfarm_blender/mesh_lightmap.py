"""Where each lightfarm texel of a mesh clutter object lands in its lightmap image. Pure
Python (no bpy), so the mapping is testable on its own.

The add-on uploads mesh clutter with its ``lightmap`` UV layer as glTF ``TEXCOORD_1``
(``glb.write_glb``); the bake then lays the mesh's texels on those UVs instead of generating a
chart atlas. RESULT.json numbers a mesh's texels (surface ``clutter:<id>``, ``index``) but does
not say where they sit, so this module repeats the bake's rule (``server/src/bake/scene/mesh_atlas.rs``,
``MeshAtlas::build`` with ``TEXCOORD_1`` and ``rasterise``; ``server/src/bake/scene/geometry.rs`` for
``h``), on the same float32 numbers the GLB carries:

- ``h`` = the mesh's largest bounding-box extent / ``texels_per_face`` (metres per texel);
- the atlas is ``N × N`` texels, ``N = ⌈√(world area / UV area) / h⌉`` (at least 1);
- texel coordinates are ``uv · N`` (glTF UVs: ``v`` down, so row 0 is the top), each UV
  clamped to [0, 1];
- a cell ``(x, y)`` is a texel when some triangle overlaps its square ``[x, x+1] × [y, y+1]``
  with positive area (separating axes, overlap > 1e-9), or holds the centroid of a triangle that
  overlaps none; zero-area triangles (in the world) are dropped first;
- texels are numbered row-major (``y`` then ``x``): texel ``k`` is the ``k``-th such cell.

Image layout (Blender images: row 0 at the bottom): the image is ``N × N``, texel ``(x, y)``
at pixel ``(x, N − 1 − y)``, so the object's own ``lightmap`` UVs (Blender's ``v`` = 1 − glTF
``v``) address it directly. Empty pixels next to texels repeat their neighbours' mean (two
rings), so bilinear filtering at a chart's edge does not pull in black.

Invariant: texel ``k`` of the surface is exactly one pixel, holding exactly its value; the
caller checks that the number of cells equals the number of texels in the result (a mismatch
means the rule above and the bake's differ, and the object is reported, not lit wrongly).
"""

import math
import struct

# Separating-axis overlap a cell needs (``rasterise`` in mesh_atlas.rs).
OVERLAP_EPS = 1e-9
# Rings of empty pixels filled around the texels.
DILATE = 2


def f32(x):
    """``x`` rounded to float32 (what the GLB stores and the bake reads)."""
    return struct.unpack("<f", struct.pack("<f", x))[0]


def _sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _triangle_area(t):
    e1, e2 = _sub(t[1], t[0]), _sub(t[2], t[0])
    c = (e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
         e1[0] * e2[1] - e1[1] * e2[0])
    return 0.5 * math.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2])


def _area2(a, b, c):
    return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])


def _overlaps_square(t, x, y, eps):
    square = ((x, y), (x + 1.0, y), (x + 1.0, y + 1.0), (x, y + 1.0))
    axes = [(1.0, 0.0), (0.0, 1.0)]
    for i, j in ((0, 1), (1, 2), (2, 0)):
        e = (t[j][0] - t[i][0], t[j][1] - t[i][1])
        length = math.sqrt(e[0] * e[0] + e[1] * e[1])
        if length > 0.0:
            axes.append((-e[1] / length, e[0] / length))
    for a in axes:
        tp = [p[0] * a[0] + p[1] * a[1] for p in t]
        sp = [p[0] * a[0] + p[1] * a[1] for p in square]
        if not min(max(tp), max(sp)) - max(min(tp), min(sp)) > eps:
            return False
    return True


def bary2(t, p):
    """Barycentric coordinates of ``p`` in the 2D triangle ``t`` (None if degenerate)."""
    a = _area2(t[0], t[1], t[2])
    if abs(a) < 1e-300:
        return None
    b0 = _area2(p, t[1], t[2]) / a
    b1 = _area2(t[0], p, t[2]) / a
    return (b0, b1, 1.0 - b0 - b1)


def uv_area(uvs):
    """Summed area of UV triangles (three (u, v) each)."""
    total = 0.0
    for t in uvs:
        total += 0.5 * abs(_area2(*t))
    return total


class MeshLightmap:
    """The atlas of one mesh: ``triangles`` (three (x, y, z) each, lightfarm frame, the GLB's
    float32 values) with ``uvs`` (three glTF (u, v) each, float32 values), at
    ``texels_per_face``."""

    def __init__(self, triangles, uvs, texels_per_face):
        kept = [(t, uv) for t, uv in zip(triangles, uvs) if _triangle_area(t) > 0.0]
        self.triangles = [t for t, _ in kept]
        points = [p for t in self.triangles for p in t]
        extent = 0.0
        for k in range(3):
            extent = max(extent, max(p[k] for p in points) - min(p[k] for p in points))
        h = extent / texels_per_face
        world = 0.0
        for t in self.triangles:
            world += _triangle_area(t)
        area = uv_area([uv for _, uv in kept])
        if not area > 1e-12:
            raise ValueError("the lightmap UVs cover no area")
        n = max(int(math.ceil(math.sqrt(world / area) / h)), 1)
        self.size = n
        # Per triangle, its UVs in texel units.
        self.triangle_uv = [tuple((min(max(u, 0.0), 1.0) * n, min(max(v, 0.0), 1.0) * n)
                                  for u, v in uv) for _, uv in kept]
        cells = set()
        for t in self.triangle_uv:
            xs, ys = [p[0] for p in t], [p[1] for p in t]
            x0, x1 = max(math.floor(min(xs)), 0), min(math.ceil(max(xs)), n)
            y0, y1 = max(math.floor(min(ys)), 0), min(math.ceil(max(ys)), n)
            found = False
            for y in range(y0, y1):
                for x in range(x0, x1):
                    if _overlaps_square(t, float(x), float(y), OVERLAP_EPS):
                        cells.add((y, x))
                        found = True
            if not found:  # a zero-area UV triangle: the cell holding its centroid
                c = [(t[0][a] + t[1][a] + t[2][a]) / 3.0 for a in (0, 1)]
                cells.add((min(max(math.floor(c[1]), 0), n - 1),
                           min(max(math.floor(c[0]), 0), n - 1)))
        # Texel k -> cell (x, y), row-major.
        self.cells = [(x, y) for y, x in sorted(cells)]

    @property
    def texel_count(self):
        return len(self.cells)

    def texel_pixel(self, index):
        """Blender pixel (x, y) (row 0 at the bottom) of texel ``index``."""
        x, y = self.cells[index]
        return x, self.size - 1 - y

    def pixels(self, values):
        """RGBA floats (``N·N·4``, rows bottom to top) from ``values``: one RGB per texel, in
        index order. Texel pixels hold their value; up to ``DILATE`` rings of empty pixels
        around them the mean of their filled neighbours; the rest is black."""
        n = self.size
        rgb = [None] * (n * n)
        for index, value in enumerate(values):
            x, y = self.texel_pixel(index)
            rgb[y * n + x] = tuple(value)
        for _ in range(DILATE):
            fill = {}
            for y in range(n):
                for x in range(n):
                    if rgb[y * n + x] is not None:
                        continue
                    near = [rgb[b * n + a] for b in (y - 1, y, y + 1) for a in (x - 1, x, x + 1)
                            if 0 <= a < n and 0 <= b < n and rgb[b * n + a] is not None]
                    if near:
                        fill[y * n + x] = tuple(sum(c[k] for c in near) / len(near)
                                                for k in range(3))
            if not fill:
                break
            for at, value in fill.items():
                rgb[at] = value
        out = [0.0] * (n * n * 4)
        for at, value in enumerate(rgb):
            if value is not None:
                out[4 * at:4 * at + 3] = value
            out[4 * at + 3] = 1.0
        return out
