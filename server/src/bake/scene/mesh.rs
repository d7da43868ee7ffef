//! Loading clutter and dynamic-object meshes (OBJ through `tobj`, glTF/GLB through `gltf`) into
//! world-space triangles.
//!
//! Invariant: returned triangles are finite and have positive area; zero-area triangles are
//! dropped and counted, a NaN or infinite vertex is an error naming the object and triangle.
//! Paths are relative to the scene file's directory. A mesh given as bytes (an upload) must be
//! self-contained: a glTF's buffers and images may only be data URIs or the GLB's own chunk, so
//! parsing it reads no file.

use std::path::{Path, PathBuf};

use glam::DVec3;
use lightfarm_proto::scene::Transform;

use crate::bake::scene::mesh_albedo::{texture_from_gltf, MeshAlbedo, TriangleAlbedo};

/// A triangle mesh in world coordinates (metres).
#[derive(Clone, Debug, Default)]
pub struct TriangleMesh {
    pub triangles: Vec<[[f64; 3]; 3]>,
    /// The surface colours a glTF carries (base colour factor, `COLOR_0`, base-colour
    /// texture), aligned with `triangles`; empty for OBJ files.
    pub albedo: MeshAlbedo,
    /// Zero-area triangles that were dropped.
    pub dropped_degenerate: usize,
    /// A glTF's lightmap UVs (`TEXCOORD_1`) per triangle, aligned with `triangles`; `None` for
    /// triangles whose primitive has no `TEXCOORD_1` (and for OBJ files).
    pub lightmap_uv: Vec<Option<[[f64; 2]; 3]>>,
}

impl TriangleMesh {
    /// Reverses triangle `k`'s winding (swaps its second and third vertex, with their colours
    /// and texture coordinates), so its lit side becomes the other one.
    pub fn flip(&mut self, k: usize) {
        self.triangles[k].swap(1, 2);
        if let Some(Some(uv)) = self.lightmap_uv.get_mut(k) {
            uv.swap(1, 2);
        }
        if let Some(Some(a)) = self.albedo.triangles.get_mut(k) {
            a.vertex.swap(1, 2);
            if let Some((uv, _)) = a.texture.as_mut() {
                uv.swap(1, 2);
            }
        }
    }

    /// The lightmap UVs when every triangle has them.
    pub fn full_lightmap_uv(&self) -> Option<Vec<[[f64; 2]; 3]>> {
        self.lightmap_uv.iter().copied().collect()
    }
}

/// Why a mesh could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    #[error("{object}: cannot read mesh {path}: {message}")]
    Read {
        object: String,
        path: PathBuf,
        message: String,
    },
    #[error("{object}: triangle {triangle} has a non-finite vertex")]
    NonFinite { object: String, triangle: usize },
    #[error("{object}: triangle {triangle} has a non-finite colour or texture coordinate")]
    NonFiniteColour { object: String, triangle: usize },
    #[error("{object}: mesh has {count} triangles, more than the limit of {limit}")]
    TooLarge {
        object: String,
        count: usize,
        limit: usize,
    },
    #[error("{object}: mesh has no triangles with positive area")]
    Empty { object: String },
}

/// Most triangles one mesh may have.
pub const MAX_TRIANGLES: usize = 2_000_000;

/// Which parser a mesh's bytes go to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeshFormat {
    /// Wavefront OBJ text (materials are not read).
    Obj,
    /// glTF 2.0, JSON or binary (GLB).
    Gltf,
}

/// Loads a mesh file and applies `transform`. The format follows the extension (`.obj`, else
/// glTF); a glTF's relative buffer and image URIs resolve against the file's directory.
pub fn load_mesh(
    object: &str,
    base_dir: &Path,
    relative: &str,
    transform: &Transform,
) -> Result<TriangleMesh, MeshError> {
    let path = base_dir.join(relative);
    let bytes = std::fs::read(&path).map_err(|e| MeshError::Read {
        object: object.to_string(),
        path: path.clone(),
        message: e.to_string(),
    })?;
    let format = if relative.to_ascii_lowercase().ends_with(".obj") {
        MeshFormat::Obj
    } else {
        MeshFormat::Gltf
    };
    let base = path.parent().unwrap_or(Path::new("./"));
    parse_mesh(object, &path, &bytes, format, Some(base), transform)
}

/// Parses a self-contained mesh from memory (an uploaded asset) and applies `transform`: a
/// glTF that refers to any file (a relative or `file:` URI) is refused, so nothing but `bytes`
/// is read. `label` names the bytes in errors.
pub fn load_mesh_bytes(
    object: &str,
    label: &str,
    bytes: &[u8],
    format: MeshFormat,
    transform: &Transform,
) -> Result<TriangleMesh, MeshError> {
    parse_mesh(object, Path::new(label), bytes, format, None, transform)
}

/// Both loaders' parser: `base` is where a glTF's relative URIs resolve, `None` to refuse them.
fn parse_mesh(
    object: &str,
    path: &Path,
    bytes: &[u8],
    format: MeshFormat,
    base: Option<&Path>,
    transform: &Transform,
) -> Result<TriangleMesh, MeshError> {
    let read_err = |message: String| MeshError::Read {
        object: object.to_string(),
        path: path.to_path_buf(),
        message,
    };
    let mut textures = Vec::new();
    type RawTriangle = ([[f64; 3]; 3], Option<TriangleAlbedo>, Option<[[f64; 2]; 3]>);
    let raw: Vec<RawTriangle> = if format == MeshFormat::Obj {
        let (models, _) = tobj::load_obj_buf(
            &mut std::io::Cursor::new(bytes),
            &tobj::LoadOptions {
                triangulate: true,
                single_index: true,
                ..Default::default()
            },
            |_| Err(tobj::LoadError::OpenFileFailed),
        )
        .map_err(|e| read_err(e.to_string()))?;
        let mut tris = Vec::new();
        for model in models {
            let m = model.mesh;
            let vertex = |i: u32| -> [f64; 3] {
                let i = i as usize * 3;
                [
                    m.positions[i] as f64,
                    m.positions[i + 1] as f64,
                    m.positions[i + 2] as f64,
                ]
            };
            for idx in m.indices.chunks_exact(3) {
                if idx
                    .iter()
                    .any(|i| (*i as usize + 1) * 3 > m.positions.len())
                {
                    return Err(read_err("face index out of range".into()));
                }
                tris.push(([vertex(idx[0]), vertex(idx[1]), vertex(idx[2])], None, None));
            }
        }
        tris
    } else {
        let gltf_err = |e: gltf::Error| read_err(e.to_string());
        let gltf::Gltf {
            document: doc,
            blob,
        } = gltf::Gltf::from_slice(bytes).map_err(gltf_err)?;
        let base = match base {
            Some(base) => base,
            None => {
                refuse_file_uris(&doc).map_err(read_err)?;
                // Every URI is a data URI now, which the importer decodes without looking at
                // the base (it only refuses an image data URI when given none).
                Path::new(".")
            }
        };
        let buffers = gltf::import_buffers(&doc, Some(base), blob).map_err(gltf_err)?;
        let images = gltf::import_images(&doc, Some(base), &buffers).map_err(gltf_err)?;
        textures = images.iter().map(texture_from_gltf).collect();
        let mut tris = Vec::new();
        let scene = doc.default_scene().or_else(|| doc.scenes().next());
        let Some(scene) = scene else {
            return Err(read_err("glTF has no scene".into()));
        };
        let mut stack: Vec<(gltf::Node, [[f64; 4]; 4])> =
            scene.nodes().map(|n| (n, identity4())).collect();
        while let Some((node, parent)) = stack.pop() {
            let local = node.transform().matrix().map(|c| c.map(|x| x as f64));
            let world = mul4(parent, local);
            if let Some(mesh) = node.mesh() {
                for prim in mesh.primitives() {
                    if prim.mode() != gltf::mesh::Mode::Triangles {
                        continue;
                    }
                    let reader = prim.reader(|b| Some(&buffers[b.index()]));
                    let Some(pos) = reader.read_positions() else {
                        continue;
                    };
                    let pos: Vec<[f64; 3]> =
                        pos.map(|p| apply4(&world, p.map(|x| x as f64))).collect();
                    let indices: Vec<u32> = match reader.read_indices() {
                        Some(i) => i.into_u32().collect(),
                        None => (0..pos.len() as u32).collect(),
                    };
                    // Base colour: factor × COLOR_0 × texture (at TEXCOORD_n).
                    let pbr = prim.material().pbr_metallic_roughness();
                    let factor = pbr.base_color_factor().map(|x| x as f64);
                    let colours: Option<Vec<[f64; 3]>> = reader
                        .read_colors(0)
                        .map(|c| c.into_rgb_f32().map(|v| v.map(|x| x as f64)).collect());
                    let texture = pbr.base_color_texture().and_then(|info| {
                        let uv: Vec<[f64; 2]> = reader
                            .read_tex_coords(info.tex_coord())?
                            .into_f32()
                            .map(|v| v.map(|x| x as f64))
                            .collect();
                        Some((uv, info.texture().source().index() as u32))
                    });
                    let lightmap_uv: Option<Vec<[f64; 2]>> = reader
                        .read_tex_coords(1)
                        .map(|uv| uv.into_f32().map(|v| v.map(|x| x as f64)).collect());
                    let coloured = colours.is_some()
                        || texture.is_some()
                        || factor[..3].iter().any(|x| *x != 1.0);
                    for idx in indices.chunks_exact(3) {
                        let get = |i: u32| {
                            pos.get(i as usize)
                                .copied()
                                .ok_or_else(|| read_err("index out of range".into()))
                        };
                        let tri = [get(idx[0])?, get(idx[1])?, get(idx[2])?];
                        let albedo = if coloured {
                            let colour = |i: u32| -> Result<[f64; 3], MeshError> {
                                let c = match &colours {
                                    Some(c) => *c.get(i as usize).ok_or_else(|| {
                                        read_err("COLOR_0 index out of range".into())
                                    })?,
                                    None => [1.0; 3],
                                };
                                Ok(std::array::from_fn(|k| factor[k] * c[k]))
                            };
                            let texture = match &texture {
                                Some((uv, image)) => {
                                    let at = |i: u32| {
                                        uv.get(i as usize).copied().ok_or_else(|| {
                                            read_err("TEXCOORD index out of range".into())
                                        })
                                    };
                                    Some(([at(idx[0])?, at(idx[1])?, at(idx[2])?], *image))
                                }
                                None => None,
                            };
                            Some(TriangleAlbedo {
                                vertex: [colour(idx[0])?, colour(idx[1])?, colour(idx[2])?],
                                texture,
                            })
                        } else {
                            None
                        };
                        let lightmap = match &lightmap_uv {
                            Some(uv) => {
                                let at = |i: u32| {
                                    uv.get(i as usize).copied().ok_or_else(|| {
                                        read_err("TEXCOORD_1 index out of range".into())
                                    })
                                };
                                Some([at(idx[0])?, at(idx[1])?, at(idx[2])?])
                            }
                            None => None,
                        };
                        tris.push((tri, albedo, lightmap));
                    }
                }
            }
            stack.extend(node.children().map(|c| (c, world)));
        }
        tris
    };
    if raw.len() > MAX_TRIANGLES {
        return Err(MeshError::TooLarge {
            object: object.to_string(),
            count: raw.len(),
            limit: MAX_TRIANGLES,
        });
    }
    let mut mesh = TriangleMesh::default();
    mesh.albedo.textures = textures;
    for (k, (tri, albedo, lightmap)) in raw.into_iter().enumerate() {
        let bad_uv = lightmap.is_some_and(|t| t.iter().flatten().any(|x| !x.is_finite()));
        if bad_uv
            || albedo.as_ref().is_some_and(|a| {
                a.vertex.iter().flatten().any(|x| !x.is_finite())
                    || a.texture
                        .iter()
                        .flat_map(|t| t.0)
                        .flatten()
                        .any(|x| !x.is_finite())
            })
        {
            return Err(MeshError::NonFiniteColour {
                object: object.to_string(),
                triangle: k,
            });
        }
        if tri.iter().flatten().any(|x| !x.is_finite()) {
            return Err(MeshError::NonFinite {
                object: object.to_string(),
                triangle: k,
            });
        }
        let world = tri.map(|v| transform.apply(v));
        if triangle_area(&world) <= 0.0 {
            mesh.dropped_degenerate += 1;
            continue;
        }
        mesh.triangles.push(world);
        mesh.lightmap_uv.push(lightmap);
        mesh.albedo.triangles.push(albedo.map(|a| TriangleAlbedo {
            vertex: a.vertex.map(|v| v.map(|x| x.clamp(0.0, 1.0))),
            ..a
        }));
    }
    if mesh.triangles.is_empty() {
        return Err(MeshError::Empty {
            object: object.to_string(),
        });
    }
    Ok(mesh)
}

/// Checks that a mesh's bytes are self-contained without loading it: an OBJ always is (its
/// material libraries are never read); a glTF or GLB must embed every buffer and image (data URIs
/// or the GLB chunk). The message names the first buffer or image that refers to a file, as
/// [`load_mesh_bytes`] does. For bytes stored by an older upload check, before they are laid out
/// as a file that [`load_mesh`] would resolve URIs next to.
pub fn refuse_external_files(bytes: &[u8], format: MeshFormat) -> Result<(), String> {
    match format {
        MeshFormat::Obj => Ok(()),
        MeshFormat::Gltf => {
            let doc = gltf::Gltf::from_slice(bytes).map_err(|e| e.to_string())?;
            refuse_file_uris(&doc)
        }
    }
}

/// A self-contained glTF's buffers and images are data URIs or the GLB chunk; the message names
/// the first one that refers to a file.
fn refuse_file_uris(doc: &gltf::Document) -> Result<(), String> {
    let buffers = doc.buffers().filter_map(|b| match b.source() {
        gltf::buffer::Source::Uri(uri) => Some(("buffer", b.index(), uri)),
        gltf::buffer::Source::Bin => None,
    });
    let images = doc.images().filter_map(|i| match i.source() {
        gltf::image::Source::Uri { uri, .. } => Some(("image", i.index(), uri)),
        gltf::image::Source::View { .. } => None,
    });
    match buffers
        .chain(images)
        .find(|(_, _, uri)| !uri.starts_with("data:"))
    {
        Some((kind, index, uri)) => Err(format!(
            "{kind} {index} refers to the file \"{uri}\"; an uploaded mesh must embed its data \
             (data: URIs or GLB)"
        )),
        None => Ok(()),
    }
}

/// Area of a triangle.
pub fn triangle_area(t: &[[f64; 3]; 3]) -> f64 {
    let e1 = DVec3::from(t[1]) - DVec3::from(t[0]);
    let e2 = DVec3::from(t[2]) - DVec3::from(t[0]);
    0.5 * e1.cross(e2).length()
}

fn identity4() -> [[f64; 4]; 4] {
    let mut m = [[0.0; 4]; 4];
    for (i, row) in m.iter_mut().enumerate() {
        row[i] = 1.0;
    }
    m
}

/// Column-major 4×4 product (glTF convention: `m[col][row]`).
fn mul4(a: [[f64; 4]; 4], b: [[f64; 4]; 4]) -> [[f64; 4]; 4] {
    let mut out = [[0.0; 4]; 4];
    for c in 0..4 {
        for r in 0..4 {
            out[c][r] = (0..4).map(|k| a[k][r] * b[c][k]).sum();
        }
    }
    out
}

fn apply4(m: &[[f64; 4]; 4], p: [f64; 3]) -> [f64; 3] {
    let mut out = [0.0; 3];
    for (r, o) in out.iter_mut().enumerate() {
        *o = m[0][r] * p[0] + m[1][r] * p[1] + m[2][r] * p[2] + m[3][r];
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn obj_loads_transformed_and_drops_degenerate_triangles() {
        let dir = std::env::temp_dir().join(format!("lf-mesh-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("m.obj"),
            "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\n",
        )
        .unwrap();
        let t = Transform {
            translation: [1.0, 2.0, 3.0],
            rotation: [0.0, 0.0, 0.0, 1.0],
            scale: [2.0, 2.0, 2.0],
        };
        let mesh = load_mesh("clutter \"m\"", &dir, "m.obj", &t).unwrap();
        assert_eq!(mesh.triangles.len(), 1);
        assert_eq!(mesh.dropped_degenerate, 1);
        assert_eq!(mesh.triangles[0][1], [3.0, 2.0, 3.0]);
        std::fs::write(
            dir.join("bad.obj"),
            "v 0 0 0\nv 1 0 0\nv 0 nan 0\nf 1 2 3\n",
        )
        .unwrap();
        let err = load_mesh(
            "clutter \"pillar2\"",
            &dir,
            "bad.obj",
            &Transform::default(),
        );
        match err {
            Err(e) => assert!(e.to_string().starts_with("clutter \"pillar2\": "), "{e}"),
            Ok(m) => panic!("accepted a NaN vertex: {:?}", m.triangles),
        }
        let missing =
            load_mesh("clutter \"x\"", &dir, "missing.obj", &Transform::default()).unwrap_err();
        assert!(missing.to_string().contains("missing.obj"), "{missing}");
    }

    /// A PNG (8-bit RGB, stored deflate block) of `w × h` pixels, row-major from the top.
    fn png(w: u32, h: u32, rgb: &[[u8; 3]]) -> Vec<u8> {
        fn crc32(bytes: &[u8]) -> u32 {
            let mut c = 0xffff_ffffu32;
            for b in bytes {
                c ^= *b as u32;
                for _ in 0..8 {
                    c = if c & 1 != 0 {
                        0xedb8_8320 ^ (c >> 1)
                    } else {
                        c >> 1
                    };
                }
            }
            !c
        }
        let mut raw = Vec::new();
        for row in rgb.chunks_exact(w as usize) {
            raw.push(0u8); // filter: none
            raw.extend(row.iter().flatten());
        }
        let (mut a, mut b) = (1u32, 0u32);
        for x in &raw {
            a = (a + *x as u32) % 65521;
            b = (b + a) % 65521;
        }
        let mut z = vec![0x78, 0x01, 0x01];
        z.extend((raw.len() as u16).to_le_bytes());
        z.extend((!(raw.len() as u16)).to_le_bytes());
        z.extend(&raw);
        z.extend(((b << 16) | a).to_be_bytes());
        let mut ihdr = Vec::new();
        ihdr.extend(w.to_be_bytes());
        ihdr.extend(h.to_be_bytes());
        ihdr.extend([8, 2, 0, 0, 0]);
        let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
        for (kind, data) in [(b"IHDR", ihdr), (b"IDAT", z), (b"IEND", Vec::new())] {
            out.extend((data.len() as u32).to_be_bytes());
            let mut chunk = kind.to_vec();
            chunk.extend(&data);
            out.extend(&chunk);
            out.extend(crc32(&chunk).to_be_bytes());
        }
        out
    }

    /// A glTF triangle with a base-colour factor and an sRGB texture: the albedo at a hit is
    /// the factor times the decoded (linear) texel at the interpolated TEXCOORD_0.
    #[test]
    fn gltf_base_colour_texture_and_factor_give_the_hit_albedo() {
        let dir = std::env::temp_dir().join(format!("lf-mesh-tex-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(
            dir.join("tex.png"),
            png(2, 1, &[[188, 94, 0], [255, 255, 255]]),
        )
        .unwrap();
        let pos: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        // Every vertex at u = 0.25 (the first texel's centre).
        let uv: [[f32; 2]; 3] = [[0.25, 0.5]; 3];
        let mut bin = Vec::new();
        for v in pos.iter().flatten().chain(uv.iter().flatten()) {
            bin.extend(v.to_le_bytes());
        }
        std::fs::write(dir.join("tri.bin"), &bin).unwrap();
        let json = r#"{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],"nodes":[{"mesh":0}],
"meshes":[{"primitives":[{"attributes":{"POSITION":0,"TEXCOORD_0":1},"material":0}]}],
"materials":[{"pbrMetallicRoughness":{"baseColorFactor":[0.5,1.0,1.0,1.0],"baseColorTexture":{"index":0}}}],
"textures":[{"source":0}],"images":[{"uri":"tex.png"}],
"buffers":[{"uri":"tri.bin","byteLength":60}],
"bufferViews":[{"buffer":0,"byteOffset":0,"byteLength":36},{"buffer":0,"byteOffset":36,"byteLength":24}],
"accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]},
{"bufferView":1,"componentType":5126,"count":3,"type":"VEC2"}]}"#;
        std::fs::write(dir.join("tri.gltf"), json).unwrap();
        let mesh = load_mesh("dynamic \"tri\"", &dir, "tri.gltf", &Transform::default()).unwrap();
        assert_eq!(mesh.albedo.textures.len(), 1);
        let a = mesh.albedo.at(0, [0.2, 0.3, 0.5], [0.9; 3]);
        let lin = |x: f64| ((x / 255.0 + 0.055) / 1.055).powf(2.4);
        let want = [0.5 * lin(188.0), lin(94.0), 0.0];
        for c in 0..3 {
            assert!((a[c] - want[c]).abs() < 1e-4, "{a:?} vs {want:?}");
        }
        // From memory (an upload): the same file names are refused, nothing is read from disk;
        // with both files as data URIs the same mesh and albedo come back.
        let from_memory = |json: &str| {
            load_mesh_bytes(
                "asset a",
                "upload.gltf",
                json.as_bytes(),
                MeshFormat::Gltf,
                &Transform::default(),
            )
        };
        let refused = from_memory(json).unwrap_err();
        assert!(
            refused.to_string().starts_with(
                "asset a: cannot read mesh upload.gltf: buffer 0 refers to the file \"tri.bin\""
            ),
            "{refused}"
        );
        use base64::engine::{general_purpose::STANDARD, Engine};
        let buffer_embedded = json.replace(
            "\"tri.bin\"",
            &format!(
                "\"data:application/octet-stream;base64,{}\"",
                STANDARD.encode(&bin)
            ),
        );
        let image_refused = from_memory(&buffer_embedded).unwrap_err();
        assert!(
            image_refused
                .to_string()
                .ends_with("image 0 refers to the file \"tex.png\"; an uploaded mesh must embed its data (data: URIs or GLB)"),
            "{image_refused}"
        );
        let embedded = buffer_embedded.replace(
            "\"tex.png\"",
            &format!(
                "\"data:image/png;base64,{}\"",
                STANDARD.encode(std::fs::read(dir.join("tex.png")).unwrap())
            ),
        );
        let from_bytes = from_memory(&embedded).unwrap();
        assert_eq!(from_bytes.triangles, mesh.triangles);
        assert_eq!(from_bytes.albedo.at(0, [0.2, 0.3, 0.5], [0.9; 3]), a);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
