"""The add-on's stored settings: preferences (service URL, team token) and per-scene state
(bake overrides, the last bake, the apply method, bounces and mode, problems found) shown by
the panel.

Invariant: only the UI thread writes these (the bake thread's status is copied in by the
operators' timer).
"""

import bpy

ADDON = __package__


class LightfarmPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON

    url: bpy.props.StringProperty(name="Service URL", default="http://127.0.0.1:8080",
                                  description="Base URL of `lightfarm serve`")
    token: bpy.props.StringProperty(name="Team token", default="", subtype="PASSWORD",
                                    description="Bearer token of your team (empty for an "
                                    "open local service)")

    def draw(self, context):
        self.layout.prop(self, "url")
        self.layout.prop(self, "token")


class LightfarmProblem(bpy.types.PropertyGroup):
    """One object that did not map or that the service refused (``name`` is the object)."""
    message: bpy.props.StringProperty()


class LightfarmSceneState(bpy.types.PropertyGroup):
    texels_per_face: bpy.props.IntProperty(
        name="Texels per face", default=0, min=0, max=128,
        description="Bake override (0: the scene's own setting)")
    rays_per_texel: bpy.props.IntProperty(
        name="Rays per texel", default=0, min=0, max=65536,
        description="Bake override (0: the scene's own setting)")
    method: bpy.props.EnumProperty(
        name="Method", default="drt",
        items=[("drt", "DRT", "Blocks and clutter (clutter operators)"),
               ("mrt", "MRT", "Blocks only; clutter shaded from the probe volume")])
    bounces: bpy.props.IntProperty(
        name="Bounces", default=0, min=0, max=1000,
        description="Bounces of indirect light Apply sums (0: all of them, until the rest is "
        "below 0.1%; 1: the papers' one-bounce light)")
    mode: bpy.props.EnumProperty(
        name="Lightmap", default="emission",
        items=[("emission", "Emission", "The map holds outgoing radiance, shown as emission"),
               ("multiply", "Multiply", "The map holds radiance / albedo, multiplied by the "
                "base colour")])
    bake_id: bpy.props.StringProperty(name="Bake")
    state: bpy.props.StringProperty(name="State", default="")
    stage: bpy.props.StringProperty(name="Stage", default="")
    progress: bpy.props.FloatProperty(name="Progress", default=0.0, min=0.0, max=1.0)
    message: bpy.props.StringProperty(name="Message", default="")
    problems: bpy.props.CollectionProperty(type=LightfarmProblem)


CLASSES = (LightfarmPreferences, LightfarmProblem, LightfarmSceneState)


def preferences(context):
    """The add-on's preferences, or None when it is not enabled through the add-on system."""
    addon = context.preferences.addons.get(ADDON)
    return addon.preferences if addon is not None else None


def set_problems(state, problems):
    """Replaces the panel's problem list with ``(object name, message)`` pairs."""
    state.problems.clear()
    for name, message in problems:
        item = state.problems.add()
        item.name = name
        item.message = message
