"""lightfarm for Blender: build a level from boxes, bake its indirect light on a lightfarm
service and see it in the viewport.

# Layout
- ``frames``: Blender (z up) <-> lightfarm (y up) coordinates, watts <-> W/sr.
- ``cuboid``: is a mesh an axis-aligned box, which polygons cover which face.
- ``glb``: mesh clutter as GLB for ``POST /v1/assets``.
- ``scene_export`` / ``scene_import``: Blender data <-> ``lightfarm.scene/1`` and LIGHTS.json.
- ``service``: the HTTP client (urllib); ``bake_job``: one bake on a background thread.
- ``lightmap_layout``: texel ordering and the lightmap image layout (no bpy);
  ``apply``: images, the ``lightmap`` UV layer and materials from RESULT.json.
- ``props``: preferences and per-scene state; ``operators``; ``panel``.
No module imports one that depends on it (``scene_import`` uses ``scene_export``'s names).
"""

bl_info = {
    "name": "lightfarm",
    "author": "lightfarm",
    "version": (0, 1, 0),
    "blender": (4, 2, 0),
    "location": "3D Viewport > Sidebar > lightfarm",
    "description": "Bake precomputed indirect light on a lightfarm service and apply it",
    "category": "Lighting",
}

import bpy  # noqa: E402

from . import operators, panel, props  # noqa: E402

_CLASSES = props.CLASSES + operators.CLASSES + panel.CLASSES


def register():
    for cls in _CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.lightfarm = bpy.props.PointerProperty(type=props.LightfarmSceneState)


def unregister():
    del bpy.types.Scene.lightfarm
    for cls in reversed(_CLASSES):
        bpy.utils.unregister_class(cls)
