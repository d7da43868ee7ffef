"""The add-on's operators: export to files, import a scene file, bake (background thread +
timer), cancel, apply lighting (the service's evaluation of the current lights).

Apply uses ``POST /v1/bakes/{id}/evaluate`` rather than the C ABI: an add-on zip cannot ship
``liblightfarm`` for every platform, and the service already holds the bundle, so moving a
light and pressing Apply again relights without a rebake and without a download.

Invariant: no operator raises into Blender: service failures end as a report and the panel's
message, and objects the scene format cannot hold are listed in the panel by name.
"""

import json
import os

import bpy

from . import apply, scene_export, scene_import
from .bake_job import BakeJob
from .props import preferences, set_problems
from .service import Service, ServiceError

# Custom property holding the service's complaint about an object, until the next bake.
ERROR_PROPERTY = "lightfarm_error"

# The running bake (one per Blender session) and the scene it belongs to.
_job = None
_job_scene = None


def service_of(context):
    prefs = preferences(context)
    if prefs is None:
        return Service("http://127.0.0.1:8080")
    return Service(prefs.url, prefs.token)


def lights_path_beside(scene_path):
    """``…/scene.json`` -> ``…/lights.json``; ``…/x.json`` -> ``…/x.lights.json``."""
    folder, name = os.path.split(scene_path)
    if name == "scene.json":
        return os.path.join(folder, "lights.json")
    return os.path.join(folder, os.path.splitext(name)[0] + ".lights.json")


def current_job():
    return _job


def _windows():
    manager = getattr(bpy.context, "window_manager", None)
    return list(manager.windows) if manager is not None else []


def _status_text(text):
    """The status bar of every window (None clears it). Timers have no window in their
    context, so the windows are reached through the window manager."""
    for window in _windows():
        try:
            window.workspace.status_text_set(text)
        except (RuntimeError, AttributeError):
            pass


def _redraw():
    for window in _windows():
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()


def poll_job():
    """Copies the bake thread's status into the scene state; returns the seconds until the
    next call (a ``bpy.app.timers`` callback), or None once the bake is final."""
    global _job
    if _job is None or _job_scene is None:
        return None
    status = _job.snapshot()
    try:
        state = _job_scene.lightfarm
    except ReferenceError:  # another file was opened: the service bakes on, unwatched here
        _job = None
        return None
    state.state = status["state"]
    state.stage = status["stage"] or ""
    state.progress = status["progress"]
    state.message = status["message"] or ""
    if status["bake_id"]:
        state.bake_id = status["bake_id"]
    if status["object_errors"]:
        # Object ids are object names; keep what export found, add what the service refused,
        # and mark the objects themselves (Object properties > Custom Properties).
        found = [(p.name, p.message) for p in state.problems]
        set_problems(state, found + [e for e in status["object_errors"] if e not in found])
        for name, message in status["object_errors"]:
            obj = bpy.data.objects.get(name)
            if obj is not None:
                obj[ERROR_PROPERTY] = message
    _redraw()
    if status["state"] in ("succeeded", "failed", "cancelled"):
        _status_text(None)
        _job = None
        return None
    _status_text(f"lightfarm: {status['stage']} {100 * status['progress']:.0f}%")
    return 0.5


class LIGHTFARM_OT_export(bpy.types.Operator):
    """Write the scene (lightfarm.scene/1) and its point lights (LIGHTS.json) to files"""
    bl_idname = "lightfarm.export"
    bl_label = "Export scene JSON"

    filepath: bpy.props.StringProperty(subtype="FILE_PATH")

    def invoke(self, context, event):
        self.filepath = bpy.path.abspath("//scene.json") if bpy.data.filepath else "scene.json"
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        export = scene_export.export_scene(context.scene)
        set_problems(context.scene.lightfarm, export.problems)
        if export.meshes:
            names = ", ".join(sorted(export.meshes))
            self.report({"WARNING"}, f"mesh clutter ({names}) is written with \"mesh\": null: "
                        "meshes are uploaded by Bake")
        with open(self.filepath, "w", encoding="utf-8") as out:
            json.dump(export.scene, out, indent=2)
        lights_path = lights_path_beside(self.filepath)
        with open(lights_path, "w", encoding="utf-8") as out:
            json.dump(export.lights, out, indent=2)
        self.report({"INFO"}, f"wrote {self.filepath} and {lights_path}")
        return {"FINISHED"}


class LIGHTFARM_OT_import(bpy.types.Operator):
    """Open a lightfarm.scene/1 file (and a LIGHTS.json beside it) as Blender objects"""
    bl_idname = "lightfarm.import_scene"
    bl_label = "Import scene JSON"

    filepath: bpy.props.StringProperty(subtype="FILE_PATH")
    lights_path: bpy.props.StringProperty(subtype="FILE_PATH", default="")

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        try:
            with open(self.filepath, encoding="utf-8") as f:
                document = json.load(f)
        except (OSError, ValueError) as error:
            self.report({"ERROR"}, f"{self.filepath}: {error}")
            return {"CANCELLED"}
        if document.get("format") != "lightfarm.scene/1":
            self.report({"ERROR"}, f"{self.filepath}: format is {document.get('format')!r}, "
                        "not \"lightfarm.scene/1\"")
            return {"CANCELLED"}
        _, problems = scene_import.import_scene(document, context.scene)
        lights_path = self.lights_path or lights_path_beside(self.filepath)
        if os.path.exists(lights_path):
            try:
                with open(lights_path, encoding="utf-8") as f:
                    scene_import.import_lights(json.load(f), context.scene)
            except (OSError, ValueError) as error:
                problems.append(("lights", f"{lights_path}: {error}"))
        set_problems(context.scene.lightfarm, problems)
        return {"FINISHED"}


class LIGHTFARM_OT_bake(bpy.types.Operator):
    """Export the scene, submit it to the lightfarm service and follow the bake"""
    bl_idname = "lightfarm.bake"
    bl_label = "Bake"

    @classmethod
    def poll(cls, context):
        return _job is None

    def execute(self, context):
        global _job, _job_scene
        state = context.scene.lightfarm
        for obj in context.scene.objects:
            if ERROR_PROPERTY in obj:
                del obj[ERROR_PROPERTY]
        export = scene_export.export_scene(context.scene)
        set_problems(state, export.problems)
        if not export.scene["blocks"]:
            self.report({"ERROR"}, "no blocks: put axis-aligned boxes in the collection "
                        f"\"{scene_export.BLOCKS}\"")
            return {"CANCELLED"}
        settings = {}
        if state.texels_per_face:
            settings["texels_per_face"] = state.texels_per_face
        if state.rays_per_texel:
            settings["rays_per_texel"] = state.rays_per_texel
        state.bake_id = ""
        state.state, state.stage, state.progress, state.message = "starting", "", 0.0, ""
        _job = BakeJob(service_of(context), export.scene, export.meshes, settings).start()
        _job_scene = context.scene
        if not bpy.app.background:
            bpy.app.timers.register(poll_job, first_interval=0.2)
        return {"FINISHED"}


class LIGHTFARM_OT_cancel(bpy.types.Operator):
    """Cancel the running bake"""
    bl_idname = "lightfarm.cancel"
    bl_label = "Cancel"

    @classmethod
    def poll(cls, context):
        return _job is not None

    def execute(self, context):
        _job.cancel()
        return {"FINISHED"}


class LIGHTFARM_OT_apply(bpy.types.Operator):
    """Evaluate the last bake for the current point lights and show the lightmaps"""
    bl_idname = "lightfarm.apply"
    bl_label = "Apply lighting"

    def execute(self, context):
        state = context.scene.lightfarm
        if not state.bake_id or state.state != "succeeded":
            self.report({"ERROR"}, "no finished bake: press Bake first")
            return {"CANCELLED"}
        export = scene_export.export_scene(context.scene)
        try:
            result, summed = service_of(context).evaluate(
                state.bake_id, export.lights, state.method, state.bounces or "all")
        except ServiceError as error:
            state.message = error.message
            self.report({"ERROR"}, error.message)
            return {"CANCELLED"}
        lit, problems = apply.apply_result(result, export.objects, state.mode, context.scene,
                                           export.mesh_lightmaps)
        set_problems(state, export.problems + problems)
        bounces = f", {summed} bounce{'' if summed == 1 else 's'}" if summed else ""
        state.message = (f"lit {len(lit)} objects from {len(export.lights['lights'])} "
                         f"point lights ({state.mode}{bounces})")
        self.report({"INFO"}, state.message)
        return {"FINISHED"}


class LIGHTFARM_OT_select(bpy.types.Operator):
    """Select the object a problem names and make it active"""
    bl_idname = "lightfarm.select"
    bl_label = "Select object"

    name: bpy.props.StringProperty()

    def execute(self, context):
        obj = bpy.data.objects.get(self.name)
        if obj is None or obj.name not in context.view_layer.objects:
            self.report({"WARNING"}, f"no object \"{self.name}\" in this view layer")
            return {"CANCELLED"}
        for other in context.view_layer.objects:
            other.select_set(False)
        obj.select_set(True)
        context.view_layer.objects.active = obj
        return {"FINISHED"}


CLASSES = (LIGHTFARM_OT_select, LIGHTFARM_OT_export, LIGHTFARM_OT_import, LIGHTFARM_OT_bake, LIGHTFARM_OT_cancel,
           LIGHTFARM_OT_apply)
