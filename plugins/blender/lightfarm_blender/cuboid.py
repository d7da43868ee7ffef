"""Is a mesh an axis-aligned box, and which of its six faces does each polygon cover?

Pure Python on points already in the lightfarm frame (metres, y up; see ``frames``), so the
rules are testable without Blender. A mesh is an axis-aligned cuboid when its bounding box
has positive extents, every vertex sits on a corner of that box, and every polygon lies in
one of the box's six face planes and covers that whole face (its four corners). A face of the
box with no polygon on it is *missing* (for a block: an opening).

Invariant: coordinates are compared within ``EPSILON`` metres, and the box returned is the
bounding box rounded to ``DIGITS`` decimals, so two blocks drawn to the same grid give
identical numbers (openings must coincide exactly).
"""

from .frames import FACES, face_axis, face_is_max

# Metres: vertices closer than this to a corner plane count as on it.
EPSILON = 1e-4
# Decimals kept in exported coordinates (10 µm).
DIGITS = 5


class Cuboid:
    """An axis-aligned box: ``min``/``max`` (lightfarm frame, rounded) and, per face name,
    the indices of the polygons covering it."""

    def __init__(self, lo, hi, polygons_by_face):
        self.min = lo
        self.max = hi
        self.polygons_by_face = polygons_by_face

    def present_faces(self):
        """Faces with at least one polygon, in canonical order."""
        return [f for f in FACES if self.polygons_by_face.get(f)]

    def face_rect(self, face):
        """(plane coordinate, (min, max) of the two tangent axes) of one face."""
        axis = face_axis(face)
        plane = self.max[axis] if face_is_max(face) else self.min[axis]
        rest = [k for k in range(3) if k != axis]
        return plane, tuple((self.min[k], self.max[k]) for k in rest)


def rounded(values):
    """Coordinates as exported (``DIGITS`` decimals, no negative zero)."""
    return [round(v, DIGITS) + 0.0 for v in values]


def analyse(points, polygons):
    """``points``: vertex positions (lightfarm frame); ``polygons``: vertex index lists.
    Returns ``(Cuboid, None)`` or ``(None, why)`` with a sentence saying what is wrong."""
    if not points:
        return None, "has no vertices"
    lo = [min(p[k] for p in points) for k in range(3)]
    hi = [max(p[k] for p in points) for k in range(3)]
    for k, axis in enumerate("xyz"):
        if hi[k] - lo[k] <= EPSILON:
            return None, f"is flat along {axis} (extent {hi[k] - lo[k]:.6g} m)"

    def side(value, k):
        if abs(value - lo[k]) <= EPSILON:
            return 0
        if abs(value - hi[k]) <= EPSILON:
            return 1
        return None

    for p in points:
        if any(side(p[k], k) is None for k in range(3)):
            return None, ("is not an axis-aligned box (a vertex is off the corners of its "
                          "bounding box: rotated, sheared or not a box)")
    by_face = {f: [] for f in FACES}
    for index, polygon in enumerate(polygons):
        face = None
        for k in range(3):
            sides = {side(points[v][k], k) for v in polygon}
            if len(sides) == 1:
                face = FACES[2 * k + sides.pop()]
                break
        if face is None:
            return None, f"is not an axis-aligned box (polygon {index} cuts through it)"
        axis = face_axis(face)
        corners = {tuple(side(points[v][k], k) for k in range(3) if k != axis) for v in polygon}
        if len(corners) != 4:
            return None, (f"is not an axis-aligned box (polygon {index} covers part of its "
                          f"{face} face only)")
        by_face[face].append(index)
    return Cuboid(rounded(lo), rounded(hi), by_face), None


def coincide(a, face_a, b, face_b, epsilon=EPSILON):
    """Whether face ``face_a`` of cuboid ``a`` and ``face_b`` of ``b`` are the same rectangle."""
    plane_a, rect_a = a.face_rect(face_a)
    plane_b, rect_b = b.face_rect(face_b)
    if face_axis(face_a) != face_axis(face_b) or abs(plane_a - plane_b) > epsilon:
        return False
    return all(abs(x - y) <= epsilon for ra, rb in zip(rect_a, rect_b) for x, y in zip(ra, rb))
