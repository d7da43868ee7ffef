"""Blender data -> a ``lightfarm.scene/1`` document and a LIGHTS.json document.

What maps (lightfarm frame and units: ``frames``):
- mesh objects in the collection ``lightfarm_blocks`` -> ``blocks``: axis-aligned cuboids
  (``cuboid``), id = object name. A face is open when another block's face coincides with it
  (unless the object's custom property ``lightfarm_closed`` lists it: a wall between two
  rooms), when the mesh has no polygon on it, or when the custom property ``lightfarm_open``
  lists it (``"-x +z"``, lightfarm face names). Albedo: the first material's base colour;
  faces whose polygons use another material -> ``face_albedo``.
- mesh objects in ``lightfarm_clutter`` -> ``clutter``: a ``box`` where the mesh is an
  axis-aligned cuboid, otherwise a closed (manifold) mesh uploaded as GLB (``mesh`` is set to
  the asset hash by the caller; the GLB bytes are in ``Export.meshes``). The mesh's UV layer
  ``lightmap`` goes along as ``TEXCOORD_1`` (the bake's lightmap UVs); a mesh without one gets
  it here first (``ensure_lightmap_uv``: Smart UV Project, else Lightmap Pack), so export
  may add that layer to the object's mesh. ``Export.mesh_lightmaps`` keeps the GLB's float32
  triangles and UVs, from which Apply places the texels (``mesh_lightmap``).
- visible point lights -> ``lights`` (W/sr, ``frames.watts_to_intensity``).
- the scene's custom properties ``lightfarm_name`` and ``lightfarm_settings`` (JSON) ->
  ``name`` and ``settings`` (set by the importer; absent: the Blender scene's name, defaults).

Invariant: nothing is dropped silently: every object that does not map (a rotated block, a
non-manifold mesh, a spot light, a non-mesh object in a lightfarm collection) is left out
with a ``(object name, message)`` entry in ``Export.problems``.
"""

import json

import bpy

from . import frames
from .cuboid import DIGITS, analyse, coincide, rounded
from .glb import write_glb
from .mesh_lightmap import f32, uv_area

BLOCKS = "lightfarm_blocks"
CLUTTER = "lightfarm_clutter"
# Blender's default base colour, used for an object without a material.
DEFAULT_ALBEDO = (0.8, 0.8, 0.8)
# The UV layer holding lightmap UVs (mesh clutter's TEXCOORD_1; Apply fills it on boxes).
LIGHTMAP_UV = "lightmap"
# lightfarm's default texels_per_face (proto/src/scene.rs).
DEFAULT_TEXELS_PER_FACE = 16


class Export:
    """The result of :func:`export_scene`."""

    def __init__(self):
        self.scene = None
        self.lights = None
        # (object name, message), in the order found.
        self.problems = []
        # clutter id -> GLB bytes of a mesh clutter object (upload, then set ``mesh``).
        self.meshes = {}
        # clutter id -> (triangles, glTF UVs) of a mesh clutter object, the float32 numbers its
        # GLB holds: ``mesh_lightmap.MeshLightmap`` places its texels from them.
        self.mesh_lightmaps = {}
        # ("block" | "clutter", id) -> Blender object name.
        self.objects = {}


def material_albedo(material):
    """Base colour (linear RGB) of a material's Principled BSDF, else its viewport colour."""
    if material is None:
        return list(DEFAULT_ALBEDO)
    if material.use_nodes and material.node_tree is not None:
        for node in material.node_tree.nodes:
            if node.type == "BSDF_PRINCIPLED":
                return list(node.inputs["Base Color"].default_value[:3])
    return list(material.diffuse_color[:3])


def _rounded_albedo(values):
    return [round(v, DIGITS) + 0.0 for v in values]


def _world_mesh(obj, depsgraph, scale):
    """(points in the lightfarm frame, polygons as vertex lists, material index per polygon,
    whether the object's transform mirrors) of an object's evaluated mesh."""
    evaluated = obj.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        matrix = obj.matrix_world
        points = [frames.to_lightfarm(matrix @ v.co, scale) for v in mesh.vertices]
        polygons = [list(p.vertices) for p in mesh.polygons]
        materials = [p.material_index for p in mesh.polygons]
        edge_use = {}
        for p in mesh.polygons:
            for key in p.edge_keys:
                edge_use[key] = edge_use.get(key, 0) + 1
        mesh.calc_loop_triangles()
        triangles = [tuple(t.vertices) for t in mesh.loop_triangles]
        layer = mesh.uv_layers.get(LIGHTMAP_UV)
        uvs = None
        if layer is not None:
            uvs = [tuple(tuple(layer.data[k].uv) for k in t.loops) for t in mesh.loop_triangles]
    finally:
        evaluated.to_mesh_clear()
    open_edges = sum(1 for n in edge_use.values() if n != 2)
    return points, polygons, materials, triangles, open_edges, matrix.determinant() < 0, uvs


def texels_per_face(bl_scene):
    """The bake's T: the panel's override, else the scene's settings, else the default."""
    state = getattr(bl_scene, "lightfarm", None)
    if state is not None and state.texels_per_face:
        return state.texels_per_face
    return int(_settings(bl_scene).get("texels_per_face", DEFAULT_TEXELS_PER_FACE))


def ensure_lightmap_uv(obj, texels_per_face):
    """Adds a ``lightmap`` UV layer to ``obj``'s mesh when it has none: Blender's Smart UV
    Project (islands within 66°), its margin about two texels of the atlas the bake will make
    at ``texels_per_face``; Blender's Lightmap Pack where Smart UV Project cannot run (the
    object is not in the view layer). The other layers and the active one are kept.
    Returns whether a layer was added."""
    mesh = obj.data
    if mesh.uv_layers.get(LIGHTMAP_UV) is not None or not mesh.polygons:
        return False
    active = mesh.uv_layers.active.name if mesh.uv_layers.active else None
    mesh.uv_layers.new(name=LIGHTMAP_UV)
    mesh.uv_layers.active = mesh.uv_layers[LIGHTMAP_UV]
    if not _smart_project(obj, 0.02):
        from bl_operators.uvcalc_lightmap import lightmap_uvpack
        lightmap_uvpack([mesh], PREF_SEL_ONLY=False, PREF_BOX_DIV=12, PREF_MARGIN_DIV=100)
    else:
        # The atlas side the bake will choose (mesh_lightmap): margin about two texels of it.
        layer = mesh.uv_layers[LIGHTMAP_UV]
        polygons = [[tuple(layer.data[k].uv) for k in p.loop_indices] for p in mesh.polygons]
        world = sum(p.area for p in mesh.polygons)
        area = uv_area([(uv[0], uv[k], uv[k + 1]) for uv in polygons
                        for k in range(1, len(uv) - 1)])
        extent = max(max(v.co[a] for v in mesh.vertices) - min(v.co[a] for v in mesh.vertices)
                     for a in range(3))
        if area > 0.0 and extent > 0.0:
            side = (world / area) ** 0.5 / (extent / texels_per_face)
            _smart_project(obj, min(max(2.0 / side, 0.02), 0.2))
    if active is not None:
        mesh.uv_layers.active = mesh.uv_layers[active]
    return True


def _smart_project(obj, margin):
    """Smart UV Project of all of ``obj``'s faces into its active UV layer (in edit mode, with
    ``obj`` alone selected and active for the moment; selection and active object restored).
    False when it cannot run: the object is not in the view layer, hidden, or another object
    is in edit mode."""
    import math
    view_layer = bpy.context.view_layer
    if (obj.name not in view_layer.objects or not obj.visible_get()
            or bpy.context.mode != "OBJECT"):
        return False
    active = view_layer.objects.active
    selected = [o for o in view_layer.objects if o.select_get()]
    try:
        for other in selected:
            other.select_set(False)
        obj.select_set(True)
        view_layer.objects.active = obj
        bpy.ops.object.mode_set(mode="EDIT")
        try:
            bpy.ops.mesh.select_all(action="SELECT")
            bpy.ops.uv.smart_project(angle_limit=math.radians(66.0), island_margin=margin,
                                     area_weight=0.0, scale_to_bounds=False)
        finally:
            bpy.ops.object.mode_set(mode="OBJECT")
    except RuntimeError:
        return False
    finally:
        obj.select_set(False)
        for other in selected:
            other.select_set(True)
        view_layer.objects.active = active
    return True


def _slot_albedo(obj, index):
    slots = obj.material_slots
    material = slots[index].material if index < len(slots) else None
    return _rounded_albedo(material_albedo(material))


def _collection_objects(name):
    collection = bpy.data.collections.get(name)
    return list(collection.all_objects) if collection is not None else []


def _settings(bl_scene):
    text = bl_scene.get("lightfarm_settings")
    if not text:
        return {}
    try:
        return json.loads(text)
    except ValueError:
        return {}


def _face_property(obj, name):
    text = str(obj.get(name, "")).replace(",", " ")
    return [f for f in text.split() if f]


def export_scene(bl_scene):
    """Builds the scene and lights documents from ``bl_scene`` (see the module doc)."""
    out = Export()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    scale = bl_scene.unit_settings.scale_length or 1.0

    blocks = []  # (obj, cuboid, albedo per polygon)
    for obj in _collection_objects(BLOCKS):
        if obj.type != "MESH":
            out.problems.append((obj.name, f"block \"{obj.name}\": a {obj.type.lower()} is "
                                 "no block (only mesh cuboids are); left out"))
            continue
        points, polygons, materials, _, _, _, _ = _world_mesh(obj, depsgraph, scale)
        box, why = analyse(points, polygons)
        if box is None:
            out.problems.append((obj.name, f"block \"{obj.name}\" {why}; left out"))
            continue
        for prop in ("lightfarm_open", "lightfarm_closed"):
            bad = [f for f in _face_property(obj, prop) if f not in frames.FACES]
            if bad:
                out.problems.append((obj.name, f"block \"{obj.name}\": {prop} names "
                                     f"{bad[0]!r}, not a face (-x +x -y +y -z +z); ignored"))
        blocks.append((obj, box, materials))

    opens = []
    for k, (obj, box, _) in enumerate(blocks):
        faces = set(f for f in _face_property(obj, "lightfarm_open") if f in frames.FACES)
        faces |= {f for f in frames.FACES if not box.polygons_by_face[f]}
        closed = set(_face_property(obj, "lightfarm_closed"))
        for m, (_, other, _) in enumerate(blocks):
            if m == k:
                continue
            for face in frames.FACES:
                if face not in closed and coincide(box, face, other, frames.opposite(face)):
                    faces.add(face)
        opens.append(faces)

    scene_blocks = []
    for (obj, box, materials), faces in zip(blocks, opens):
        albedo = _slot_albedo(obj, 0)
        block = {"id": obj.name, "min": box.min, "max": box.max,
                 "open": [f for f in frames.FACES if f in faces], "albedo": albedo}
        face_albedo = {}
        for face in frames.FACES:
            polygons = box.polygons_by_face[face]
            if face in faces or not polygons:
                continue
            colour = _slot_albedo(obj, materials[polygons[0]])
            if colour != albedo:
                face_albedo[face] = colour
        if face_albedo:
            block["face_albedo"] = face_albedo
        scene_blocks.append(block)
        out.objects[("block", obj.name)] = obj.name

    scene_clutter = []
    for obj in _collection_objects(CLUTTER):
        if obj.type != "MESH":
            out.problems.append((obj.name, f"clutter \"{obj.name}\": a {obj.type.lower()} is "
                                 "no clutter (only meshes are); left out"))
            continue
        points, polygons, _, triangles, open_edges, mirrored, uvs = _world_mesh(
            obj, depsgraph, scale)
        box, _ = analyse(points, polygons)
        if (box is None and not open_edges and triangles
                and ensure_lightmap_uv(obj, texels_per_face(bl_scene))):
            depsgraph = bpy.context.evaluated_depsgraph_get()
            points, polygons, _, triangles, open_edges, mirrored, uvs = _world_mesh(
                obj, depsgraph, scale)
        item = {"id": obj.name}
        if box is not None:
            item["box"] = {"min": box.min, "max": box.max}
        elif open_edges:
            out.problems.append((obj.name, f"clutter \"{obj.name}\": the mesh is not closed "
                                 f"({open_edges} non-manifold edges); left out"))
            continue
        elif not triangles:
            out.problems.append((obj.name, f"clutter \"{obj.name}\": the mesh has no faces; "
                                 "left out"))
            continue
        else:
            if mirrored:
                triangles = [(a, c, b) for a, b, c in triangles]
                uvs = uvs and [(a, c, b) for a, b, c in uvs]
            positions = [tuple(f32(x) for x in rounded(p)) for p in points]
            gltf_uvs = None
            if uvs is not None:
                # glTF's v runs down: v = 1 − Blender's v.
                gltf_uvs = [tuple((f32(u), f32(1.0 - v)) for u, v in corners)
                            for corners in uvs]
                why = None
                if any(not -1e-6 <= x <= 1.0 + 1e-6 for t in gltf_uvs for p in t for x in p):
                    why = "leave [0, 1]"
                elif not uv_area(gltf_uvs) > 1e-12:
                    why = "cover no area"
                if why:
                    out.problems.append((obj.name, f"clutter \"{obj.name}\": its \"lightmap\" "
                                         f"UVs {why}; baked on a generated atlas, which Apply "
                                         "cannot show"))
                    gltf_uvs = None
            out.meshes[obj.name] = write_glb(positions, triangles, gltf_uvs)
            if gltf_uvs is not None:
                out.mesh_lightmaps[obj.name] = (
                    [tuple(positions[k] for k in t) for t in triangles], gltf_uvs)
            item["mesh"] = None  # the asset hash, once uploaded
        item["albedo"] = _slot_albedo(obj, 0)
        scene_clutter.append(item)
        out.objects[("clutter", obj.name)] = obj.name

    lights = []
    for obj in bl_scene.objects:
        if obj.type != "LIGHT" or obj.hide_render:
            continue
        light = obj.data
        if light.type != "POINT":
            out.problems.append((obj.name, f"light \"{obj.name}\": {light.type.lower()} lights "
                                 "do not map onto LIGHTS.json (point lights only); left out"))
            continue
        position = frames.to_lightfarm(obj.matrix_world.translation, scale)
        intensity = frames.watts_to_intensity(light.energy, light.color)
        lights.append({"kind": "point", "position": rounded(position),
                       "intensity": [round(v, DIGITS) + 0.0 for v in intensity]})

    out.scene = {"format": "lightfarm.scene/1",
                 "name": bl_scene.get("lightfarm_name", bl_scene.name)}
    if _settings(bl_scene):
        out.scene["settings"] = _settings(bl_scene)
    out.scene["blocks"] = scene_blocks
    if scene_clutter:
        out.scene["clutter"] = scene_clutter
    out.lights = {"lights": lights, "poses": []}
    return out
