//! The albedo a mesh carries on its surface (glTF base colour): per triangle, per-vertex
//! colours (`baseColorFactor × COLOR_0`) and optionally a base-colour texture sampled at the
//! interpolated `TEXCOORD_n`, so a ray hit anywhere on the mesh gets its own RGB albedo.
//!
//! glTF's base colour is `factor × COLOR_0 × texture`; the factor and `COLOR_0` are linear,
//! the texture is sRGB-encoded and decoded to linear here. Alpha is ignored, values are clamped
//! to [0, 1]. A triangle whose primitive has no colour of its own (no `COLOR_0`, no texture and
//! a white factor) has no albedo here and takes the object's albedo setting (the scene's
//! per-mesh albedo). Textures are sampled bilinearly with repeat wrapping (the glTF default
//! sampler); other sampler modes and `KHR_texture_transform` are not read.
//!
//! Invariant: every stored colour and texel is finite and in [0, 1]; [`MeshAlbedo::at`] never
//! panics for any triangle index below `triangles.len()` and any barycentric coordinates.

use glam::DVec3;

/// A base-colour texture, decoded to linear RGB.
#[derive(Clone, Debug, PartialEq)]
pub struct AlbedoTexture {
    pub width: u32,
    pub height: u32,
    /// Row-major from the top row (glTF UV (0, 0) is the top-left corner).
    pub texels: Vec<[f32; 3]>,
}

impl AlbedoTexture {
    /// Bilinear sample at `uv` with repeat wrapping.
    pub fn sample(&self, uv: [f64; 2]) -> [f64; 3] {
        let (w, h) = (self.width as usize, self.height as usize);
        if w == 0 || h == 0 || self.texels.len() != w * h {
            return [1.0; 3];
        }
        let wrap = |i: i64, n: usize| i.rem_euclid(n as i64) as usize;
        let x = if uv[0].is_finite() { uv[0] } else { 0.0 } * w as f64 - 0.5;
        let y = if uv[1].is_finite() { uv[1] } else { 0.0 } * h as f64 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let at = |i: i64, j: i64| self.texels[wrap(j, h) * w + wrap(i, w)];
        let mut out = [0.0; 3];
        for (i, j, weight) in [
            (x0, y0, (1.0 - fx) * (1.0 - fy)),
            (x0 + 1, y0, fx * (1.0 - fy)),
            (x0, y0 + 1, (1.0 - fx) * fy),
            (x0 + 1, y0 + 1, fx * fy),
        ] {
            let t = at(i, j);
            for c in 0..3 {
                out[c] += weight * t[c] as f64;
            }
        }
        out
    }
}

/// The albedo of one triangle.
#[derive(Clone, Debug, PartialEq)]
pub struct TriangleAlbedo {
    /// Linear RGB at the three vertices (`factor × COLOR_0`).
    pub vertex: [[f64; 3]; 3],
    /// Texture coordinates at the vertices and the texture (index into
    /// [`MeshAlbedo::textures`]) that multiplies the vertex colour.
    pub texture: Option<([[f64; 2]; 3], u32)>,
}

/// Per-triangle albedo of a mesh, aligned with its triangles.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MeshAlbedo {
    /// `None`: the triangle takes the object's albedo setting.
    pub triangles: Vec<Option<TriangleAlbedo>>,
    pub textures: Vec<AlbedoTexture>,
}

impl MeshAlbedo {
    /// True when no triangle has a colour of its own.
    pub fn is_empty(&self) -> bool {
        self.triangles.iter().all(Option::is_none)
    }

    /// Albedo at barycentric `bary` of triangle `tri`; `fallback` where the triangle has none.
    pub fn at(&self, tri: usize, bary: [f64; 3], fallback: [f64; 3]) -> [f64; 3] {
        let Some(Some(t)) = self.triangles.get(tri) else {
            return fallback;
        };
        let mut out: [f64; 3] =
            std::array::from_fn(|c| (0..3).map(|v| bary[v] * t.vertex[v][c]).sum());
        if let Some((uv, image)) = &t.texture {
            if let Some(texture) = self.textures.get(*image as usize) {
                let p = [0, 1].map(|k| (0..3).map(|v| bary[v] * uv[v][k]).sum());
                let s = texture.sample(p);
                for c in 0..3 {
                    out[c] *= s[c];
                }
            }
        }
        out.map(|x| {
            if x.is_finite() {
                x.clamp(0.0, 1.0)
            } else {
                0.0
            }
        })
    }

    /// Feeds every colour, texture coordinate and texel into a content hash.
    pub fn hash_into(&self, h: &mut blake3::Hasher) {
        h.update(&(self.triangles.len() as u64).to_le_bytes());
        for t in &self.triangles {
            match t {
                None => {
                    h.update(&[0]);
                }
                Some(t) => {
                    h.update(&[1]);
                    for x in t.vertex.iter().flatten() {
                        h.update(&x.to_bits().to_le_bytes());
                    }
                    if let Some((uv, image)) = &t.texture {
                        h.update(&[1]);
                        for x in uv.iter().flatten() {
                            h.update(&x.to_bits().to_le_bytes());
                        }
                        h.update(&image.to_le_bytes());
                    } else {
                        h.update(&[0]);
                    }
                }
            }
        }
        h.update(&(self.textures.len() as u64).to_le_bytes());
        for t in &self.textures {
            h.update(&t.width.to_le_bytes());
            h.update(&t.height.to_le_bytes());
            for x in t.texels.iter().flatten() {
                h.update(&x.to_bits().to_le_bytes());
            }
        }
    }
}

/// How a bake looks up the albedo where a ray hits the object.
#[derive(Clone, Copy, Debug)]
pub enum SurfaceAlbedo<'a> {
    /// One albedo for the whole object.
    Uniform([f64; 3]),
    /// The mesh's own colours, `fallback` on triangles without any.
    Mesh {
        albedo: &'a MeshAlbedo,
        fallback: [f64; 3],
    },
}

impl SurfaceAlbedo<'_> {
    /// Albedo at `point` on triangle `tri` (vertices `v`).
    pub fn at(&self, tri: usize, v: &[[f64; 3]; 3], point: [f64; 3]) -> [f64; 3] {
        match self {
            SurfaceAlbedo::Uniform(a) => *a,
            SurfaceAlbedo::Mesh { albedo, fallback } => {
                albedo.at(tri, barycentric(v, point), *fallback)
            }
        }
    }
}

/// Barycentric coordinates of `p` projected onto the triangle's plane (clamped into the
/// triangle; a degenerate triangle gives its centroid).
pub fn barycentric(v: &[[f64; 3]; 3], p: [f64; 3]) -> [f64; 3] {
    let [v0, v1, v2] = v.map(DVec3::from);
    let (e1, e2, d) = (v1 - v0, v2 - v0, DVec3::from(p) - v0);
    let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (d1, d2) = (d.dot(e1), d.dot(e2));
    let den = d11 * d22 - d12 * d12;
    if den.is_nan() || den <= 0.0 {
        return [1.0 / 3.0; 3];
    }
    let b1 = ((d22 * d1 - d12 * d2) / den).clamp(0.0, 1.0);
    let b2 = ((d11 * d2 - d12 * d1) / den).clamp(0.0, 1.0 - b1);
    [1.0 - b1 - b2, b1, b2]
}

/// sRGB-encoded 8-bit value to linear.
pub fn srgb_to_linear(x: u8) -> f32 {
    let c = x as f32 / 255.0;
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Decodes a glTF image (any of its formats) into a linear-RGB texture; 8-bit data is taken
/// as sRGB (the base-colour texture's encoding), 16-bit and float data as linear.
pub fn texture_from_gltf(image: &gltf::image::Data) -> AlbedoTexture {
    use gltf::image::Format;
    let n = image.width as usize * image.height as usize;
    let (channels, bytes) = match image.format {
        Format::R8 => (1, 1),
        Format::R8G8 => (2, 1),
        Format::R8G8B8 => (3, 1),
        Format::R8G8B8A8 => (4, 1),
        Format::R16 => (1, 2),
        Format::R16G16 => (2, 2),
        Format::R16G16B16 => (3, 2),
        Format::R16G16B16A16 => (4, 2),
        Format::R32G32B32FLOAT => (3, 4),
        Format::R32G32B32A32FLOAT => (4, 4),
    };
    let stride = channels * bytes;
    if image.pixels.len() < n * stride {
        return AlbedoTexture {
            width: 0,
            height: 0,
            texels: Vec::new(),
        };
    }
    let channel = |px: &[u8], c: usize| -> f32 {
        // Grey (and grey-alpha) images repeat their first channel.
        let c = if channels < 3 { 0 } else { c };
        let b = &px[c * bytes..(c + 1) * bytes];
        let v = match bytes {
            1 => srgb_to_linear(b[0]),
            2 => u16::from_le_bytes([b[0], b[1]]) as f32 / 65535.0,
            _ => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        };
        if v.is_finite() {
            v.clamp(0.0, 1.0)
        } else {
            0.0
        }
    };
    AlbedoTexture {
        width: image.width,
        height: image.height,
        texels: image
            .pixels
            .chunks_exact(stride)
            .take(n)
            .map(|px| [0, 1, 2].map(|c| channel(px, c)))
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vertex_colours_interpolate_and_textures_multiply() {
        let tri = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let albedo = MeshAlbedo {
            triangles: vec![
                Some(TriangleAlbedo {
                    vertex: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
                    texture: None,
                }),
                Some(TriangleAlbedo {
                    vertex: [[0.5; 3]; 3],
                    texture: Some(([[0.25, 0.5], [0.25, 0.5], [0.25, 0.5]], 0)),
                }),
                None,
            ],
            textures: vec![AlbedoTexture {
                width: 2,
                height: 1,
                texels: vec![[0.2, 0.4, 0.6], [1.0, 1.0, 1.0]],
            }],
        };
        let s = SurfaceAlbedo::Mesh {
            albedo: &albedo,
            fallback: [0.3, 0.3, 0.3],
        };
        let a = s.at(0, &tri, [0.25, 0.5, 0.0]);
        for (x, want) in a.iter().zip([0.25, 0.25, 0.5]) {
            assert!((x - want).abs() < 1e-12, "{a:?}");
        }
        // u = 0.25 is the centre of texel 0: 0.5 × (0.2, 0.4, 0.6).
        let b = s.at(1, &tri, [0.1, 0.1, 0.0]);
        for (x, want) in b.iter().zip([0.1, 0.2, 0.3]) {
            assert!((x - want).abs() < 1e-6, "{b:?}");
        }
        assert_eq!(s.at(2, &tri, [0.1, 0.1, 0.0]), [0.3; 3]);
        assert_eq!(s.at(7, &tri, [0.1, 0.1, 0.0]), [0.3; 3]);
    }

    #[test]
    fn barycentric_reconstructs_the_point() {
        let v = [[0.0, 0.0, 1.0], [2.0, 0.0, 1.0], [0.0, 3.0, 1.0]];
        let b = barycentric(&v, [0.5, 0.75, 1.0]);
        for (x, want) in b.iter().zip([0.5, 0.25, 0.25]) {
            assert!((x - want).abs() < 1e-12, "{b:?}");
        }
        assert!((srgb_to_linear(255) - 1.0).abs() < 1e-6);
        assert!((srgb_to_linear(188) - 0.5).abs() < 0.01);
    }
}
