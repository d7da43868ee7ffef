"""A ``lightfarm.scene/1`` document (and optionally LIGHTS.json) -> Blender objects.

Blocks become mesh cuboids in the collection ``lightfarm_blocks`` with polygons on their
closed faces only, wound so normals point into the block (the lit side); clutter boxes
become cuboids in ``lightfarm_clutter`` with outward normals. One object per block/clutter,
named by its id, its origin at the box centre. Colours become materials named by their
albedo (a Principled BSDF base colour, and the viewport colour), shared between objects;
a block's own albedo is material slot 0, its ``face_albedo`` entries further slots. A closed
face that coincides with another block's face gets the custom property ``lightfarm_closed``
(otherwise the exporter would open it); the scene's ``name`` and ``settings`` are kept as the
Blender scene's custom properties ``lightfarm_name`` and ``lightfarm_settings``.

Invariant: ``scene_export.export_scene`` after :func:`import_scene` gives back the document
(coordinates and colours up to float formatting). What cannot be imported (mesh clutter,
dynamic objects, light regions, poses) is returned as ``(what, message)`` problems.
"""

import json

import bpy

from . import frames
from .cuboid import Cuboid, coincide
from .scene_export import BLOCKS, CLUTTER


def _collection(name, bl_scene):
    collection = bpy.data.collections.get(name)
    if collection is None:
        collection = bpy.data.collections.new(name)
    if collection.name not in bl_scene.collection.children:
        bl_scene.collection.children.link(collection)
    return collection


def albedo_material(albedo):
    """The shared material of one albedo (linear RGB)."""
    name = "lightfarm albedo {:g} {:g} {:g}".format(*albedo)
    material = bpy.data.materials.get(name)
    if material is None:
        material = bpy.data.materials.new(name)
        material.use_nodes = True
        bsdf = next(n for n in material.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
        bsdf.inputs["Base Color"].default_value = (*albedo, 1.0)
        material.diffuse_color = (*albedo, 1.0)
    return material


def _quad(lo, hi, face, inward):
    """The four corners (lightfarm frame) of one face, counter-clockwise about its lit side."""
    axis = frames.face_axis(face)
    u, v = frames.tangent_axes(face)
    plane = hi[axis] if frames.face_is_max(face) else lo[axis]
    corners = []
    for a, b in ((lo[u], lo[v]), (hi[u], lo[v]), (hi[u], hi[v]), (lo[u], hi[v])):
        p = [0.0, 0.0, 0.0]
        p[axis], p[u], p[v] = plane, a, b
        corners.append(p)
    # u × v points along +x, -y, +z for faces on x, y, z.
    natural = (1.0, -1.0, 1.0)[axis]
    outward = 1.0 if frames.face_is_max(face) else -1.0
    wanted = -outward if inward else outward
    return corners if natural == wanted else corners[::-1]


def _box_object(name, lo, hi, faces, inward, material_of_face, collection, scale):
    """A cuboid object with polygons on ``faces``; material slot 0 is
    ``material_of_face(None)`` (the object's own albedo); returns the object."""
    centre = [(a + b) / 2.0 for a, b in zip(lo, hi)]
    verts, polygons, materials, slots = [], [], [], [material_of_face(None)]
    for face in faces:
        polygon = []
        for corner in _quad(lo, hi, face, inward):
            key = tuple(corner)
            if key not in verts:
                verts.append(key)
            polygon.append(verts.index(key))
        polygons.append(polygon)
        material = material_of_face(face)
        if material not in slots:
            slots.append(material)
        materials.append(slots.index(material))
    origin = frames.to_blender(centre, scale)
    local = [tuple(c - o for c, o in zip(frames.to_blender(p, scale), origin)) for p in verts]
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(local, [], polygons)
    for polygon, index in zip(mesh.polygons, materials):
        polygon.material_index = index
    for material in slots:
        mesh.materials.append(material)
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    obj.location = origin
    collection.objects.link(obj)
    return obj


def import_scene(document, bl_scene):
    """Creates the scene's objects in ``bl_scene``; returns (objects created, problems)."""
    scale = bl_scene.unit_settings.scale_length or 1.0
    problems = []
    blocks_collection = _collection(BLOCKS, bl_scene)
    clutter_collection = _collection(CLUTTER, bl_scene)
    bl_scene["lightfarm_name"] = document.get("name", bl_scene.name)
    bl_scene["lightfarm_settings"] = json.dumps(document.get("settings", {}))
    created = []

    boxes = [Cuboid(b["min"], b["max"], {}) for b in document.get("blocks", [])]
    for k, block in enumerate(document.get("blocks", [])):
        open_faces = set(block.get("open", []))
        closed = [f for f in frames.FACES if f not in open_faces]
        face_albedo = block.get("face_albedo", {})
        base = albedo_material(block["albedo"])

        def material_of_face(face, face_albedo=face_albedo, base=base):
            if face in face_albedo:
                return albedo_material(face_albedo[face])
            return base

        obj = _box_object(block["id"], block["min"], block["max"], closed, True,
                          material_of_face, blocks_collection, scale)
        kept_closed = [f for f in closed
                       if any(coincide(boxes[k], f, other, frames.opposite(f))
                              for m, other in enumerate(boxes) if m != k)]
        if kept_closed:
            obj["lightfarm_closed"] = " ".join(kept_closed)
        created.append(obj)

    for item in document.get("clutter", []):
        if "box" not in item:
            problems.append((item["id"], f"clutter \"{item['id']}\": mesh clutter "
                             f"({item.get('mesh')}) is not imported; add the mesh yourself"))
            continue
        material = albedo_material(item["albedo"])
        obj = _box_object(item["id"], item["box"]["min"], item["box"]["max"], frames.FACES,
                          False, lambda face, m=material: m, clutter_collection, scale)
        created.append(obj)

    for item in document.get("dynamic", []):
        problems.append((item["id"], f"dynamic \"{item['id']}\": dynamic objects are not "
                         "imported"))
    if document.get("light_regions"):
        problems.append(("light_regions", "light_regions are not imported"))
    return created, problems


def import_lights(document, bl_scene):
    """Creates one point light per LIGHTS.json light (``light_<k>``); returns them."""
    scale = bl_scene.unit_settings.scale_length or 1.0
    created = []
    for k, light in enumerate(document.get("lights", [])):
        power, colour = frames.intensity_to_watts(light["intensity"])
        data = bpy.data.lights.new(f"light_{k}", type="POINT")
        data.energy = power
        data.color = colour
        data.shadow_soft_size = 0.0
        obj = bpy.data.objects.new(f"light_{k}", data)
        obj.location = frames.to_blender(light["position"], scale)
        bl_scene.collection.objects.link(obj)
        created.append(obj)
    return created
