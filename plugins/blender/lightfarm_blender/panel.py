"""The sidebar panel (3D viewport, N panel, tab "lightfarm"): export/import, bake settings,
Bake/Cancel with stage and progress, Apply lighting with its mode, and the problems list
(every object that did not map or that the service refused, by name; clicking the name
selects the object).
"""

import bpy

from .operators import current_job


class LIGHTFARM_PT_panel(bpy.types.Panel):
    bl_label = "lightfarm"
    bl_idname = "LIGHTFARM_PT_panel"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "lightfarm"

    def draw(self, context):
        layout = self.layout
        state = context.scene.lightfarm
        row = layout.row(align=True)
        row.operator("lightfarm.import_scene", text="Import", icon="IMPORT")
        row.operator("lightfarm.export", text="Export", icon="EXPORT")

        box = layout.box()
        box.label(text="Bake", icon="LIGHT")
        box.prop(state, "texels_per_face")
        box.prop(state, "rays_per_texel")
        row = box.row(align=True)
        row.operator("lightfarm.bake", icon="RENDER_STILL")
        row.operator("lightfarm.cancel", icon="CANCEL")
        if state.state:
            if current_job() is not None and hasattr(box, "progress"):
                box.progress(factor=state.progress, type="BAR",
                             text=f"{state.stage} {100 * state.progress:.0f}%")
            else:
                box.label(text=f"{state.state}: {state.stage}")
        if state.message:
            box.label(text=state.message)

        box = layout.box()
        box.label(text="Lighting", icon="SHADING_RENDERED")
        box.prop(state, "method")
        box.prop(state, "bounces", text="Bounces (0: all)")
        box.prop(state, "mode")
        box.operator("lightfarm.apply", icon="CHECKMARK")

        if len(state.problems):
            box = layout.box()
            box.label(text=f"{len(state.problems)} problems", icon="ERROR")
            for problem in state.problems:
                row = box.row()
                select = row.operator("lightfarm.select", text=problem.name,
                                      icon="RESTRICT_SELECT_OFF")
                select.name = problem.name
                row.label(text=problem.message)


CLASSES = (LIGHTFARM_PT_panel,)
