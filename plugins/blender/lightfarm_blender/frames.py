"""Frames and units between Blender and lightfarm; nothing else.

Blender is z-up, lightfarm is y-up (both right-handed, metres). A Blender point
``(bx, by, bz)`` is the lightfarm point ``(bx, bz, -by)``, the convention of
Blender's glTF exporter. Lengths are scaled by the scene's ``unit_settings.scale_length``
so one Blender unit may be any number of metres.

Light: Blender's point light ``power`` P (watts) is the flux it emits, spread evenly over
the sphere (Cycles and EEVEE), so its radiant intensity is ``I = P · colour / (4π)`` W/sr
per channel, what LIGHTS.json holds. The inverse takes the brightest channel as the power
and the ratios as the colour.

Invariant: ``to_blender(to_lightfarm(p)) == p`` exactly (only sign changes and swaps).
"""

import math

# lightfarm face name -> (lightfarm axis, is the max side).
FACES = ("-x", "+x", "-y", "+y", "-z", "+z")


def to_lightfarm(p, scale=1.0):
    """Blender world point (x, y, z) -> lightfarm point, in metres."""
    return (p[0] * scale, p[2] * scale, -p[1] * scale)


def to_blender(p, scale=1.0):
    """lightfarm point -> Blender world point, in Blender units."""
    return (p[0] / scale, -p[2] / scale, p[1] / scale)


def face_axis(face):
    """The lightfarm axis (0 x, 1 y, 2 z) a face name is perpendicular to."""
    return FACES.index(face) // 2


def face_is_max(face):
    """True for a ``+`` face."""
    return FACES.index(face) % 2 == 1


def tangent_axes(face):
    """The face's two tangent axes, ascending (``proto::Face::tangent_axes``): texel (i, j)
    has i along the first, j along the second, index ``j·T + i``."""
    return {0: (1, 2), 1: (0, 2), 2: (0, 1)}[face_axis(face)]


def opposite(face):
    """``+x`` <-> ``-x``."""
    return FACES[FACES.index(face) ^ 1]


def watts_to_intensity(power, colour):
    """Blender point light power (W) and colour -> radiant intensity per channel (W/sr)."""
    return [power * c / (4.0 * math.pi) for c in colour]


def intensity_to_watts(intensity):
    """Radiant intensity per channel (W/sr) -> (power in W, colour with max channel 1)."""
    peak = max(intensity)
    if peak <= 0.0:
        return 0.0, (1.0, 1.0, 1.0)
    return peak * 4.0 * math.pi, tuple(c / peak for c in intensity)
