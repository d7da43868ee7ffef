//! The glTF document of a lit level: one node and mesh per object (a block's or clutter box's
//! faces textured with their lightmap, all mesh clutter coloured per vertex), unlit
//! materials, a linear clamped sampler, and one `KHR_lights_punctual` point light per light.
//!
//! Invariants: every accessor's data lives in the one binary buffer, 4-byte aligned; POSITION
//! accessors carry exact min/max; normals are unit; triangles wind counter-clockwise seen from
//! the lit side, so a viewer that culls back faces shows block interiors and clutter
//! exteriors. Light colour is the intensity divided by its largest channel and `intensity`
//! that channel (W/sr as given; glTF reads candela, so only ratios between lights carry over).

use glam::Vec3;
use serde_json::{json, Value};

use lightfarm_client::lightmap::auto_exposure;
use lightfarm_proto::bundle::{Layout, SurfaceAtlas};
use lightfarm_proto::lights::LightSet;

use super::faces::{box_faces, BoxFace};
use super::lighting::LitObject;
use super::mesh_colours::{corner_colours, linear_colours, MeshTexels};
use super::textures::{face_texture, png};
use super::{ExportError, ExportOptions};

/// A document and its binary buffer.
pub struct Built {
    pub json: Value,
    pub binary: Vec<u8>,
    pub exposure: f32,
}

const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
const FLOAT: u32 = 5126;
const UNSIGNED_INT: u32 = 5125;
const LINEAR: u32 = 9729;
const CLAMP_TO_EDGE: u32 = 33071;

/// The binary buffer with its views and accessors.
#[derive(Default)]
struct Buffer {
    bytes: Vec<u8>,
    views: Vec<Value>,
    accessors: Vec<Value>,
}

impl Buffer {
    fn view(&mut self, data: &[u8], target: Option<u32>) -> usize {
        while self.bytes.len() % 4 != 0 {
            self.bytes.push(0);
        }
        let mut view =
            json!({ "buffer": 0, "byteOffset": self.bytes.len(), "byteLength": data.len() });
        if let Some(t) = target {
            view["target"] = json!(t);
        }
        self.bytes.extend_from_slice(data);
        self.views.push(view);
        self.views.len() - 1
    }

    /// A float accessor of `N`-vectors; with min/max when `bounds`.
    fn floats<const N: usize>(&mut self, data: &[[f32; N]], kind: &str, bounds: bool) -> usize {
        let bytes: Vec<u8> = data
            .iter()
            .flatten()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        let view = self.view(&bytes, Some(ARRAY_BUFFER));
        let mut accessor = json!({
            "bufferView": view, "componentType": FLOAT, "count": data.len(), "type": kind
        });
        if bounds {
            let mut min = [f32::INFINITY; N];
            let mut max = [f32::NEG_INFINITY; N];
            for v in data {
                for c in 0..N {
                    min[c] = min[c].min(v[c]);
                    max[c] = max[c].max(v[c]);
                }
            }
            accessor["min"] = json!(min.to_vec());
            accessor["max"] = json!(max.to_vec());
        }
        self.accessors.push(accessor);
        self.accessors.len() - 1
    }

    fn indices(&mut self, data: &[u32]) -> usize {
        let bytes: Vec<u8> = data.iter().flat_map(|x| x.to_le_bytes()).collect();
        let view = self.view(&bytes, Some(ELEMENT_ARRAY_BUFFER));
        self.accessors.push(json!({
            "bufferView": view, "componentType": UNSIGNED_INT, "count": data.len(), "type": "SCALAR"
        }));
        self.accessors.len() - 1
    }
}

/// The (unnormalised) face normal of a triangle by winding: `(t1 − t0) × (t2 − t0)`.
fn winding_normal(t: [[f32; 3]; 3]) -> Vec3 {
    let [a, b, c] = t.map(Vec3::from);
    (b - a).cross(c - a)
}

/// The document's growing lists, for adding meshes.
struct Parts<'a> {
    buffer: &'a mut Buffer,
    materials: &'a mut Vec<Value>,
    meshes: &'a mut Vec<Value>,
    nodes: &'a mut Vec<Value>,
}

impl Parts<'_> {
    /// One node and mesh `name` of `triangles` (non-degenerate), flat normals from their
    /// winding and `colours` per corner, with an unlit material of its own.
    fn coloured_mesh(
        &mut self,
        name: &str,
        triangles: &[[[f32; 3]; 3]],
        colours: &[[f32; 4]],
        double_sided: bool,
    ) {
        let positions: Vec<[f32; 3]> = triangles.iter().flatten().copied().collect();
        let normals: Vec<[f32; 3]> = triangles
            .iter()
            .flat_map(|t| {
                let n = winding_normal(*t);
                [(n / n.length()).to_array(); 3]
            })
            .collect();
        let mut material = json!({
            "name": name,
            "pbrMetallicRoughness": { "metallicFactor": 0.0, "roughnessFactor": 1.0 },
            "extensions": { "KHR_materials_unlit": {} }
        });
        if double_sided {
            material["doubleSided"] = json!(true);
        }
        self.materials.push(material);
        let attributes = json!({
            "POSITION": self.buffer.floats(&positions, "VEC3", true),
            "NORMAL": self.buffer.floats(&normals, "VEC3", false),
            "COLOR_0": self.buffer.floats(colours, "VEC4", false),
        });
        self.meshes.push(json!({
            "name": name,
            "primitives": [{ "attributes": attributes, "material": self.materials.len() - 1 }]
        }));
        self.nodes
            .push(json!({ "name": name, "mesh": self.meshes.len() - 1 }));
    }
}

/// Builds the document; `radiance` holds every layout texel's radiance for the chosen mode.
/// `posed` are the posed dynamic objects, lit.
pub fn build(
    layout: &Layout,
    surface_atlases: &[SurfaceAtlas],
    radiance: &[[f32; 3]],
    posed: &[LitObject],
    lights: &LightSet,
    options: ExportOptions,
) -> Result<Built, ExportError> {
    let exposure = auto_exposure(radiance);
    let mut buffer = Buffer::default();
    let (mut nodes, mut meshes, mut materials, mut textures, mut images) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut mesh_texels = (Vec::new(), Vec::new(), Vec::new());
    // One mesh per object: a block's faces are surfaces `block:<id>/<face>`, a clutter box's
    // six faces one surface `clutter:<id>`.
    let mut objects: Vec<(String, Vec<BoxFace>)> = Vec::new();
    for (k, surface) in layout.surfaces.iter().enumerate() {
        let (offset, count) = (surface.texel_offset as usize, surface.texel_count as usize);
        if surface_atlases.iter().any(|a| a.surface as usize == k) {
            for t in offset..offset + count {
                mesh_texels.0.push(layout.positions[t]);
                mesh_texels.1.push(layout.normals[t]);
                mesh_texels.2.push(radiance[t]);
            }
            continue;
        }
        let faces = box_faces(layout, offset, count).map_err(|detail| ExportError::Faces {
            surface: surface.name.clone(),
            detail,
        })?;
        let object = surface.name.split('/').next().unwrap_or_default();
        match objects.last_mut() {
            Some((name, list)) if name == object => list.extend(faces),
            _ => objects.push((object.to_string(), faces)),
        }
    }
    for (name, faces) in &objects {
        if faces.is_empty() {
            continue;
        }
        let texture = face_texture(layout, faces, radiance, exposure);
        let png = png(&texture).map_err(|detail| ExportError::Texture {
            surface: name.clone(),
            detail,
        })?;
        let (mut positions, mut normals, mut uvs, mut indices) =
            (Vec::new(), Vec::new(), Vec::new(), Vec::<u32>::new());
        for (face, [lo, hi]) in faces.iter().zip(&texture.uv) {
            let base = positions.len() as u32;
            for (a, b) in [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)] {
                positions.push(face.point(a, b));
                normals.push(face.normal());
                uvs.push([lo[0] + a * (hi[0] - lo[0]), lo[1] + b * (hi[1] - lo[1])]);
            }
            let c = &positions[base as usize..];
            let counter_clockwise =
                winding_normal([c[0], c[1], c[2]]).dot(Vec3::from(face.normal())) > 0.0;
            let order: [u32; 6] = if counter_clockwise {
                [0, 1, 2, 0, 2, 3]
            } else {
                [0, 2, 1, 0, 3, 2]
            };
            indices.extend(order.map(|i| base + i));
        }
        images.push(
            json!({ "bufferView": buffer.view(&png, None), "mimeType": "image/png", "name": name }),
        );
        textures.push(json!({ "sampler": 0, "source": images.len() - 1 }));
        materials.push(json!({
            "name": name,
            "pbrMetallicRoughness": {
                "baseColorTexture": { "index": textures.len() - 1 },
                "metallicFactor": 0.0,
                "roughnessFactor": 1.0
            },
            "extensions": { "KHR_materials_unlit": {} }
        }));
        let attributes = json!({
            "POSITION": buffer.floats(&positions, "VEC3", true),
            "NORMAL": buffer.floats(&normals, "VEC3", false),
            "TEXCOORD_0": buffer.floats(&uvs, "VEC2", false),
        });
        meshes.push(json!({
            "name": name,
            "primitives": [{ "attributes": attributes, "indices": buffer.indices(&indices), "material": materials.len() - 1 }]
        }));
        nodes.push(json!({ "name": name, "mesh": meshes.len() - 1 }));
    }
    let mut parts = Parts {
        buffer: &mut buffer,
        materials: &mut materials,
        meshes: &mut meshes,
        nodes: &mut nodes,
    };
    // Mesh clutter: its triangles, coloured per corner.
    let triangles: Vec<[[f32; 3]; 3]> = layout
        .triangles
        .iter()
        .filter(|t| winding_normal(**t).length_squared() > 1e-20)
        .copied()
        .collect();
    if !triangles.is_empty() {
        let texels = MeshTexels::new(mesh_texels.0, mesh_texels.1, &mesh_texels.2, exposure);
        let colours = corner_colours(&triangles, &texels);
        parts.coloured_mesh("mesh clutter", &triangles, &colours, false);
    }
    // Posed dynamic objects: their triangles, coloured per corner by the light leaving them
    // (tone-mapped with the level's exposure), drawn from both sides.
    for LitObject {
        id,
        triangles,
        corners,
    } in posed
    {
        let kept: Vec<usize> = (0..triangles.len())
            .filter(|&k| winding_normal(triangles[k]).length_squared() > 1e-20)
            .collect();
        if kept.is_empty() {
            continue;
        }
        let kept_triangles: Vec<[[f32; 3]; 3]> = kept.iter().map(|&k| triangles[k]).collect();
        let radiance: Vec<[f32; 3]> = kept
            .iter()
            .flat_map(|&k| [corners[3 * k], corners[3 * k + 1], corners[3 * k + 2]])
            .collect();
        let colours = linear_colours(&radiance, exposure);
        parts.coloured_mesh(&format!("dynamic:{id}"), &kept_triangles, &colours, true);
    }
    let mut punctual = Vec::new();
    for (k, light) in lights.lights.iter().enumerate() {
        let peak = light.intensity.iter().fold(0.0f64, |m, x| m.max(*x));
        let colour = if peak > 0.0 {
            light.intensity.map(|x| x / peak)
        } else {
            [1.0; 3]
        };
        punctual.push(json!({ "type": "point", "name": format!("light {k}"), "color": colour, "intensity": peak }));
        nodes.push(json!({
            "name": format!("light {k}"),
            "translation": light.position,
            "extensions": { "KHR_lights_punctual": { "light": k } }
        }));
    }
    let mut used = vec!["KHR_materials_unlit"];
    if !punctual.is_empty() {
        used.push("KHR_lights_punctual");
    }
    let mut doc = json!({
        "asset": {
            "version": "2.0",
            "generator": "lightfarm export",
            "extras": { "lightfarm": {
                "scene": layout.scene_name,
                "mode": options.mode.name(),
                "bounces": options.bounces,
                "exposure": exposure
            } }
        },
        "extensionsUsed": used,
        "scene": 0,
        "scenes": [{ "name": layout.scene_name, "nodes": (0..nodes.len()).collect::<Vec<_>>() }],
        "nodes": nodes,
        "meshes": meshes,
        "materials": materials,
        "accessors": buffer.accessors,
        "bufferViews": buffer.views,
        "buffers": [{ "byteLength": buffer.bytes.len().next_multiple_of(4) }],
    });
    if !images.is_empty() {
        doc["samplers"] = json!([{ "magFilter": LINEAR, "minFilter": LINEAR, "wrapS": CLAMP_TO_EDGE, "wrapT": CLAMP_TO_EDGE }]);
        doc["textures"] = json!(textures);
        doc["images"] = json!(images);
    }
    if !punctual.is_empty() {
        doc["extensions"] = json!({ "KHR_lights_punctual": { "lights": punctual } });
    }
    Ok(Built {
        json: doc,
        binary: buffer.bytes,
        exposure,
    })
}
