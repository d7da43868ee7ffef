"""RESULT.json (the service's evaluation) -> lightmap images on the Blender objects.

For every block and clutter box the result has texels for: a float image
``lightmap <object>`` (linear, ``lightmap_layout.BoxLightmap``), a UV layer ``lightmap`` on
its mesh placing every polygon on its face's tile, and its materials wired to show it:
each material slot gets a per-object copy (``<material> [lightmap <object>]``) whose output is
an Emission shader fed by the lightmap (``emission``: the map holds outgoing radiance) or by
base colour × lightmap (``multiply``: the map holds radiance / albedo). The copy keeps the
original's Principled BSDF (disconnected), so its base colour still exports as the albedo.

Mesh clutter (``clutter:<id>`` texels on the mesh's own ``lightmap`` UVs, which export sent
as ``TEXCOORD_1``): an ``N × N`` image laid out by ``mesh_lightmap.MeshLightmap``, shown through
that same UV layer (Apply does not touch it), materials wired as above. A mesh whose texel
count differs from what its UVs give (UVs edited since the bake) is reported, not lit.

Invariant: pixel ``(x, y)`` of a texel holds exactly ``texel_value`` of that texel's record
(float32), so the image equals ``lightfarm eval`` up to float32 rounding.
"""

import bpy

from . import frames
from .cuboid import analyse
from .lightmap_layout import (BoxLightmap, box_faces, records_by_surface, texel_value,
                              texels_per_face)
from .mesh_lightmap import MeshLightmap

UV_LAYER = "lightmap"
MODES = ("emission", "multiply")


def _image(name, width, height):
    image = bpy.data.images.get(name)
    if image is not None and (tuple(image.size) != (width, height) or not image.is_float):
        bpy.data.images.remove(image)
        image = None
    if image is None:
        image = bpy.data.images.new(name, width, height, alpha=False, float_buffer=True)
    return image


def _lightmap_material(source, obj, image, mode):
    """The per-object copy of ``source`` showing ``image``."""
    if source is not None and source.get("lightfarm_lightmap_of") == obj.name:
        material = source
    else:
        material = source.copy() if source is not None else bpy.data.materials.new("lightfarm")
        material.name = f"{source.name if source else 'lightfarm'} [lightmap {obj.name}]"
        material["lightfarm_lightmap_of"] = obj.name
        if source is not None:
            material["lightfarm_source_material"] = source.name
    material.use_nodes = True
    nodes, links = material.node_tree.nodes, material.node_tree.links
    for node in [n for n in nodes if n.name.startswith("lightfarm ")]:
        nodes.remove(node)
    output = next((n for n in nodes if n.type == "OUTPUT_MATERIAL"), None)
    if output is None:
        output = nodes.new("ShaderNodeOutputMaterial")
    bsdf = next((n for n in nodes if n.type == "BSDF_PRINCIPLED"), None)
    uv = nodes.new("ShaderNodeUVMap")
    uv.name = "lightfarm uv"
    uv.uv_map = UV_LAYER
    texture = nodes.new("ShaderNodeTexImage")
    texture.name = "lightfarm lightmap"
    texture.image = image
    texture.interpolation = "Linear"
    texture.extension = "EXTEND"
    links.new(uv.outputs["UV"], texture.inputs["Vector"])
    emission = nodes.new("ShaderNodeEmission")
    emission.name = "lightfarm emission"
    emission.inputs["Strength"].default_value = 1.0
    if mode == "multiply":
        mix = nodes.new("ShaderNodeMix")
        mix.name = "lightfarm multiply"
        mix.data_type = "RGBA"
        mix.blend_type = "MULTIPLY"
        mix.inputs["Factor"].default_value = 1.0
        base = bsdf.inputs["Base Color"] if bsdf is not None else None
        if base is not None and base.is_linked:
            links.new(base.links[0].from_socket, mix.inputs["A"])
        elif base is not None:
            mix.inputs["A"].default_value = base.default_value
        links.new(texture.outputs["Color"], mix.inputs["B"])
        links.new(mix.outputs["Result"], emission.inputs["Color"])
    else:
        links.new(texture.outputs["Color"], emission.inputs["Color"])
    links.new(emission.outputs["Emission"], output.inputs["Surface"])
    nodes.active = texture
    for node, x in ((uv, -900), (texture, -700), (emission, -200)):
        node.location = (output.location[0] + x + 500, output.location[1] - 400)
    return material


def _wire_materials(obj, image, mode):
    mesh = obj.data
    if len(mesh.materials) == 0:
        mesh.materials.append(None)
    for k, source in enumerate(list(mesh.materials)):
        mesh.materials[k] = _lightmap_material(source, obj, image, mode)


def _apply_mesh(obj, clutter_id, records, mesh_input, t, mode):
    """Mesh clutter: its texels onto an image laid out by its own ``lightmap`` UVs (which
    Apply leaves as they are: the GLB carried them). Returns a problem message or None."""
    what = f"clutter \"{clutter_id}\""
    if mesh_input is None:
        return f"{what}: baked without \"lightmap\" UVs, so its texels have no place; not lit"
    if not records or not t:
        return f"{what}: no texels in the result; not lit"
    try:
        atlas = MeshLightmap(*mesh_input, t)
    except ValueError as error:
        return f"{what}: {error}; not lit"
    if atlas.texel_count != len(records) or records[-1]["index"] != len(records) - 1:
        return (f"{what}: the result has {len(records)} texels, its \"lightmap\" UVs "
                f"{atlas.texel_count} (changed since the bake? bake again); not lit")
    image = _image(f"lightmap {obj.name}", atlas.size, atlas.size)
    image.pixels.foreach_set(atlas.pixels([texel_value(r, mode) for r in records]))
    image.update()
    image["lightfarm_mode"] = mode
    _wire_materials(obj, image, mode)
    return None


def apply_result(result, objects, mode, bl_scene, mesh_lightmaps=None):
    """Puts the lightmaps of ``result`` (a RESULT.json document) on ``objects``
    (``("block" | "clutter", id) -> object name``, as ``scene_export.Export.objects``);
    ``mesh_lightmaps``: clutter id -> (triangles, glTF UVs) of the mesh clutter
    (``Export.mesh_lightmaps``). Returns (names of the objects lit, problems as
    (object name, message))."""
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, not {mode!r}")
    mesh_lightmaps = mesh_lightmaps or {}
    t = texels_per_face(result)
    surfaces = records_by_surface(result)
    scale = bl_scene.unit_settings.scale_length or 1.0
    lit, problems = [], []
    for key, name in objects.items():
        obj = bpy.data.objects.get(name)
        if obj is None:
            continue
        mesh = obj.data
        matrix = obj.matrix_world
        points = [frames.to_lightfarm(matrix @ v.co, scale) for v in mesh.vertices]
        box, why = analyse(points, [list(p.vertices) for p in mesh.polygons])
        if key[0] == "clutter" and box is None:
            problem = _apply_mesh(obj, key[1], surfaces.get(f"clutter:{key[1]}", []),
                                  mesh_lightmaps.get(key[1]), t, mode)
            if problem:
                problems.append((name, problem))
            else:
                lit.append(name)
            continue
        faces = box_faces(key, surfaces, t) if t else None
        if faces is None:
            problems.append((name, f"{key[0]} \"{key[1]}\": no box texels in the result; "
                             "not lit"))
            continue
        if box is None:
            problems.append((name, f"{key[0]} \"{key[1]}\" {why}; not lit"))
            continue
        lo, hi = box.min, box.max
        layout = BoxLightmap.for_faces(faces, t)
        image = _image(f"lightmap {name}", layout.width, layout.height)
        values = {face: [texel_value(r, mode) for r in records]
                  for face, records in faces.items()}
        image.pixels.foreach_set(layout.pixels(values))
        image.update()
        image["lightfarm_mode"] = mode
        uv_layer = mesh.uv_layers.get(UV_LAYER) or mesh.uv_layers.new(name=UV_LAYER)
        face_of = {p: f for f, ps in box.polygons_by_face.items() for p in ps}
        for polygon in mesh.polygons:
            face = face_of.get(polygon.index)
            for loop in polygon.loop_indices:
                if face in faces:
                    vertex = mesh.loops[loop].vertex_index
                    uv_layer.data[loop].uv = layout.uv(face, points[vertex], lo, hi)
                else:
                    uv_layer.data[loop].uv = layout.unlit_uv()
        _wire_materials(obj, image, mode)
        lit.append(name)
    return lit, problems
