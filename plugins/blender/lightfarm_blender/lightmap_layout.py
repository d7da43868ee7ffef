"""Where each lightfarm texel of a box lands in the object's lightmap image, and the UV of
any point on the box. Pure Python (no bpy), so the ordering is testable on its own.

Texel ordering (``proto/src/face.rs``, ``server/src/bake/scene/geometry.rs``): texel ``(i, j)`` of a
``T×T`` face has index ``j·T + i``, ``i`` along the face's first tangent axis and ``j`` along
the second (both ascending lightfarm world axes; ``frames.tangent_axes``), its centre at
``min + (i + ½, j + ½)·extent/T``. A block face is the surface ``block:<id>/<face>`` (indices
``0 … T²−1``); a clutter box is one surface ``clutter:<id>`` holding its six faces in canonical
order (``-x +x -y +y -z +z``), face ``f`` at indices ``f·T² + j·T + i``. A long block the
engine baked as pieces (``server/src/bake/scene/pieces.rs``) has ``n_u·n_v`` grids of ``T×T``
on a face (``n_u·T`` texel centres along its first tangent axis, ``n_v·T`` along the
second): its image tile is ``n_u·T × n_v·T``, one pixel per texel, so the lightmap keeps the
resolution the bake gave it (the grid is found from the texels' positions).

Image layout (Blender images: pixel row 0 at the bottom, UV (0, 0) the bottom-left corner):
the six faces are tiles on a 3 × 2 grid (face ``f`` in column ``f mod 3``, row ``f div 3``;
a column as wide and a row as tall as its largest tile), each with a one-pixel border
repeating its edge texels, so bilinear filtering never mixes faces; texel ``(i, j)`` of a face
``w`` texels wide is its ``j·w + i``-th and pixel ``(tile x + i, tile y + j)``, the face's
first tangent axis running along image x. One extra row at the top stays black: polygons with
no texels (open faces) are mapped there.

Invariant: every texel of a face maps to exactly one interior pixel of its tile, and the UV of
a texel's centre is that pixel's centre.
"""

import math

from . import frames


class BoxLightmap:
    """The image layout of one box: ``T×T`` texels per face, or ``sizes[face]`` = (texels along
    the first tangent axis, along the second) for the faces given."""

    def __init__(self, texels_per_face, sizes=None):
        self.t = texels_per_face
        self.sizes = {face: (texels_per_face, texels_per_face) for face in frames.FACES}
        self.sizes.update(sizes or {})
        # Face f (its slot in frames.FACES) sits in column f mod 3, row f div 3.
        columns = [max(self.sizes[f][0] for k, f in enumerate(frames.FACES) if k % 3 == c) + 2
                   for c in range(3)]
        rows = [max(self.sizes[f][1] for k, f in enumerate(frames.FACES) if k // 3 == r) + 2
                for r in range(2)]
        self.column_x = [1 + sum(columns[:c]) for c in range(3)]
        self.row_y = [1 + sum(rows[:r]) for r in range(2)]
        self.width = sum(columns)
        self.height = sum(rows) + 1

    def size(self):
        """(width, height) of the image in pixels."""
        return self.width, self.height

    @classmethod
    def for_faces(cls, faces, texels_per_face):
        """The layout of a box's ``faces`` (``box_faces``): each face's tile as large as its
        texel grid."""
        sizes = {face: face_size(face, records, texels_per_face)
                 for face, records in faces.items()}
        return cls(texels_per_face, sizes)

    def tile_origin(self, face):
        """Pixel (x, y) of texel (0, 0) of ``face``."""
        slot = frames.FACES.index(face)
        return self.column_x[slot % 3], self.row_y[slot // 3]

    def texel_pixel(self, face, index):
        """Pixel (x, y) of texel ``index`` (``j·w + i``, ``w`` the face's width) of ``face``."""
        x0, y0 = self.tile_origin(face)
        w = self.sizes[face][0]
        return x0 + index % w, y0 + index // w

    def uv(self, face, point, lo, hi):
        """UV of a lightfarm-frame point on ``face`` of the box ``lo``–``hi``."""
        u, v = frames.tangent_axes(face)
        s = (point[u] - lo[u]) / (hi[u] - lo[u])
        t = (point[v] - lo[v]) / (hi[v] - lo[v])
        x0, y0 = self.tile_origin(face)
        w, h = self.sizes[face]
        return (x0 + s * w) / self.width, (y0 + t * h) / self.height

    def unlit_uv(self):
        """UV of the black row, for polygons without texels."""
        return 0.5 / self.width, (self.height - 0.5) / self.height

    def pixels(self, faces):
        """RGBA floats (``width·height·4``, rows bottom to top) from ``faces``: face name ->
        list of the face's ``w·h`` RGB values in texel index order. Borders repeat the edge
        texels; missing faces, the rest of a tile larger than its face and the top row are
        black."""
        out = [0.0] * (self.width * self.height * 4)
        for k in range(self.width * self.height):
            out[4 * k + 3] = 1.0
        for face, values in faces.items():
            x0, y0 = self.tile_origin(face)
            w, h = self.sizes[face]
            for y in range(-1, h + 1):
                for x in range(-1, w + 1):
                    i, j = min(max(x, 0), w - 1), min(max(y, 0), h - 1)
                    rgb = values[j * w + i]
                    at = 4 * ((y0 + y) * self.width + x0 + x)
                    out[at:at + 3] = rgb
        return out


def records_by_surface(result):
    """RESULT.json texels -> {surface name: [texel records in index order]}."""
    surfaces = {}
    for record in result["texels"]:
        surfaces.setdefault(record["surface"], []).append(record)
    for records in surfaces.values():
        records.sort(key=lambda r: r["index"])
    return surfaces


def _face_grid(face, records):
    """The distinct texel-centre coordinates of a block face's records along its two tangent
    axes, ascending (rounded to 1e-6 of the largest, so one grid line is one value)."""
    u, v = frames.tangent_axes(face)
    scale = max((abs(x) for r in records for x in r["position"]), default=1.0) or 1.0

    def key(x):
        return round(x / scale, 6)
    return (sorted({key(r["position"][u]) for r in records}),
            sorted({key(r["position"][v]) for r in records}), key)


def _gridded(face, records, t):
    """A block face's records (``n_u·n_v`` grids of ``T×T``: a long block baked as pieces)
    as one grid of ``n_u·T × n_v·T`` records in its index order (``j·n_u·T + i``, ``i`` along
    the face's first tangent axis), each record's ``index`` its place there; None when they do
    not form such a grid."""
    us, vs, key = _face_grid(face, records)
    if len(us) % t or len(vs) % t or len(us) * len(vs) != len(records):
        return None
    u, v = frames.tangent_axes(face)
    rank_u = {x: k for k, x in enumerate(us)}
    rank_v = {x: k for k, x in enumerate(vs)}
    grid = [None] * len(records)
    for r in records:
        k = rank_v[key(r["position"][v])] * len(us) + rank_u[key(r["position"][u])]
        if grid[k] is not None:
            return None
        grid[k] = dict(r, index=k)
    return grid


def face_size(face, records, t):
    """(texels along ``face``'s first tangent axis, along its second) of a box face's records
    (``box_faces``): ``T × T``, or a long block's pieces' grid."""
    if len(records) == t * t:
        return t, t
    us, vs, _ = _face_grid(face, records)
    return len(us), len(vs)


def box_faces(key, surfaces, texels_per_face):
    """{face: [texel records in index order]} of the block or clutter box ``key``
    (``("block" | "clutter", id)``) from ``records_by_surface``: a block's faces
    ``block:<id>/<face>`` with ``T²`` texels (a face of a long block baked as pieces: its
    whole grid, module doc), a clutter box's surface ``clutter:<id>`` cut into six faces of
    ``T²`` texels. None when the result has none."""
    t2 = texels_per_face * texels_per_face
    kind, object_id = key
    if kind == "block":
        faces = {}
        for face in frames.FACES:
            records = surfaces.get(f"block:{object_id}/{face}", ())
            if len(records) == t2:
                faces[face] = records
            elif records and len(records) % t2 == 0:
                grid = _gridded(face, records, texels_per_face)
                if grid is not None:
                    faces[face] = grid
        return faces or None
    records = surfaces.get(f"clutter:{object_id}", ())
    if len(records) != 6 * t2:
        return None
    return {face: records[f * t2:(f + 1) * t2] for f, face in enumerate(frames.FACES)}


def texels_by_face(result, texels_per_face, meshes=()):
    """RESULT.json texels -> {(kind, id): {face: [texel records in index order]}} for blocks
    (``block:<id>/<face>``) and clutter boxes (``clutter:<id>``, six faces of ``T²`` texels).
    Mesh clutter (ids in ``meshes``, and any surface without ``6·T²`` texels) is left out."""
    surfaces = records_by_surface(result)
    keys = set()
    for name in surfaces:
        kind, _, rest = name.partition(":")
        if kind == "block":
            keys.add(("block", rest.rpartition("/")[0]))
        elif kind == "clutter" and rest not in meshes:
            keys.add(("clutter", rest))
    out = {}
    for key in keys:
        faces = box_faces(key, surfaces, texels_per_face)
        if faces is not None:
            out[key] = faces
    return out


def texels_per_face(result):
    """T, from the block faces' texel grids: the greatest common divisor of the texel
    centres along every block face's tangent axes (a face has ``T`` along each, or ``n·T``
    along an axis a long block was cut on, module doc; a block cut on all three axes by its
    neighbours has no side of ``T``, the rest of the level does)."""
    faces = {}
    for record in result["texels"]:
        name = record["surface"]
        if name.startswith("block:"):
            faces.setdefault(name, []).append(record)
    t = 0
    for name, records in faces.items():
        face = name.rpartition("/")[2]
        if face in frames.FACES:
            us, vs, _ = _face_grid(face, records)
            t = math.gcd(t, len(us), len(vs))
    return t


def texel_value(record, mode):
    """The RGB a lightmap pixel holds: ``emission``: outgoing radiance (direct + indirect,
    W/(sr·m²)); ``multiply``: that radiance divided by the albedo (what base colour × map
    gives back; 0 where the albedo is 0)."""
    lit = [d + i for d, i in zip(record["direct"], record["indirect"])]
    if mode == "multiply":
        return [v / a if a > 0.0 else 0.0 for v, a in zip(lit, record["albedo"])]
    return lit
