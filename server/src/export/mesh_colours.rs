//! Vertex colours: for posed dynamic objects the light leaving each corner
//! ([`linear_colours`]); for mesh clutter: the bundle keeps a mesh's triangles and its lightmap texels but
//! not the triangles' lightmap coordinates, so each triangle corner takes the tone-mapped
//! radiance of the nearest mesh texel facing the same way (normals within 60°), as a linear
//! `COLOR_0` (glTF vertex colours are linear).
//!
//! Invariant: every corner gets a colour; with no facing texel within the search, the nearest
//! texel of any orientation.

use glam::Vec3;
use lightfarm_client::lightmap::Atlas;

/// Mesh texels: world position, unit normal and sRGB8 colour.
pub struct MeshTexels {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub srgb: Vec<[u8; 3]>,
}

impl MeshTexels {
    /// Tone-maps `radiance` (the same curve and exposure as the textures).
    pub fn new(
        positions: Vec<[f32; 3]>,
        normals: Vec<[f32; 3]>,
        radiance: &[[f32; 3]],
        exposure: f32,
    ) -> MeshTexels {
        let srgb = srgb8(radiance, exposure);
        MeshTexels {
            positions,
            normals,
            srgb,
        }
    }
}

/// `radiance` tone-mapped with `exposure` to sRGB8, as the textures are.
fn srgb8(radiance: &[[f32; 3]], exposure: f32) -> Vec<[u8; 3]> {
    let n = radiance.len() as u32;
    let bytes = Atlas {
        width: n.max(1),
        height: 1,
        texel_xy: (0..n).map(|k| (k, 0)).collect(),
    }
    .to_srgb8(radiance, exposure);
    bytes
        .chunks(3)
        .take(n as usize)
        .map(|c| [c[0], c[1], c[2]])
        .collect()
}

/// Linear RGBA vertex colours showing `radiance` as the textures do: tone-mapped with
/// `exposure` to sRGB8, then back to linear (glTF's `COLOR_0` is linear).
pub fn linear_colours(radiance: &[[f32; 3]], exposure: f32) -> Vec<[f32; 4]> {
    srgb8(radiance, exposure)
        .into_iter()
        .map(|c| {
            let [r, g, b] = c.map(srgb_to_linear);
            [r, g, b, 1.0]
        })
        .collect()
}

fn srgb_to_linear(v: u8) -> f32 {
    let c = v as f32 / 255.0;
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

fn normal_of(t: &[[f32; 3]; 3]) -> [f32; 3] {
    let [p0, p1, p2] = t.map(Vec3::from);
    let n = (p1 - p0).cross(p2 - p0);
    // Divided by the length (not `normalize`, which multiplies by its reciprocal).
    (n / n.length().max(1e-20)).to_array()
}

/// Per triangle corner, a linear RGBA colour.
pub fn corner_colours(triangles: &[[[f32; 3]; 3]], texels: &MeshTexels) -> Vec<[f32; 4]> {
    let mut out = Vec::with_capacity(triangles.len() * 3);
    for t in triangles {
        let n = normal_of(t);
        for p in t {
            let mut best: Option<(f32, usize)> = None;
            let mut any: Option<(f32, usize)> = None;
            for (k, q) in texels.positions.iter().enumerate() {
                let d2: f32 = (0..3).map(|c| (p[c] - q[c]).powi(2)).sum();
                if any.is_none_or(|(d, _)| d2 < d) {
                    any = Some((d2, k));
                }
                let m = texels.normals[k];
                let facing = n[0] * m[0] + n[1] * m[1] + n[2] * m[2] > 0.5;
                if facing && best.is_none_or(|(d, _)| d2 < d) {
                    best = Some((d2, k));
                }
            }
            let colour = best
                .or(any)
                .map_or([0.5; 3], |(_, k)| texels.srgb[k].map(srgb_to_linear));
            out.push([colour[0], colour[1], colour[2], 1.0]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A floor triangle takes the upward texel under it, not the nearer downward one.
    #[test]
    fn corners_take_the_nearest_texel_facing_their_way() {
        let texels = MeshTexels::new(
            vec![[0.0, 0.0, 0.0], [0.0, 0.01, 0.0], [5.0, 0.0, 0.0]],
            vec![[0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 1.0, 0.0]],
            &[[1.0; 3], [0.0; 3], [0.1; 3]],
            1.0,
        );
        // Counter-clockwise seen from +y: normal +y.
        let tri = [[0.0, 0.02, 0.0], [0.0, 0.02, 1.0], [1.0, 0.02, 0.0]];
        let c = corner_colours(&[tri], &texels);
        assert_eq!(c.len(), 3);
        assert!((c[0][0] - 1.0).abs() < 1e-6, "{:?}", c[0]);
        let tri_down = [tri[0], tri[2], tri[1]];
        let c = corner_colours(&[tri_down], &texels);
        assert_eq!(c[0][0], 0.0, "{:?}", c[0]);
    }
}
