//! One lightmap texture per box surface: its faces as tiles of one pixel per texel (so the
//! resolution follows the bake's texel density), each tile with a one-pixel border copied from
//! its own edge so bilinear filtering never mixes in another face, packed on shelves into a
//! roughly square image. Pixels are 8-bit sRGB from `lightfarm_client::lightmap::Atlas`'s tone
//! curve at one exposure for the whole level.
//!
//! Invariant: face `k`'s texel `(i, j)` is pixel `origin_k + (1 + i, 1 + j)`, and the face's
//! `uv` rectangle spans exactly its texels' pixels (texel centres at pixel centres).

use lightfarm_client::lightmap::Atlas;
use lightfarm_proto::bundle::Layout;

use super::faces::BoxFace;

/// A surface's texture and where each face sits in it.
#[derive(Clone, Debug)]
pub struct SurfaceTexture {
    pub width: u32,
    pub height: u32,
    /// Row-major RGB, sRGB-encoded.
    pub rgb: Vec<u8>,
    /// Per face: texture coordinates (glTF: origin top left) of the face's `(min_u, min_v)` and
    /// `(max_u, max_v)` corners.
    pub uv: Vec<[[f32; 2]; 2]>,
}

/// Packs `faces` and tone-maps `radiance` (all layout texels) into a texture.
pub fn face_texture(
    layout: &Layout,
    faces: &[BoxFace],
    radiance: &[[f32; 3]],
    exposure: f32,
) -> SurfaceTexture {
    let tiles: Vec<(u32, u32)> = faces
        .iter()
        .map(|f| (f.n_u as u32 + 2, f.n_v as u32 + 2))
        .collect();
    let area: u32 = tiles.iter().map(|(w, h)| w * h).sum();
    let widest = tiles.iter().map(|t| t.0).max().unwrap_or(1);
    let width = widest.max((area as f64).sqrt().ceil() as u32);
    let mut origins = Vec::with_capacity(tiles.len());
    let (mut x, mut y, mut shelf) = (0u32, 0u32, 0u32);
    for &(w, h) in &tiles {
        if x + w > width {
            x = 0;
            y += shelf;
            shelf = 0;
        }
        origins.push((x, y));
        x += w;
        shelf = shelf.max(h);
    }
    let height = (y + shelf).max(1);
    let mut texel_xy = Vec::new();
    let mut values = Vec::new();
    for (face, &(ox, oy)) in faces.iter().zip(&origins) {
        for j in 0..face.n_v {
            for i in 0..face.n_u {
                texel_xy.push((ox + 1 + i as u32, oy + 1 + j as u32));
                values.push(radiance[face.first_texel + j * face.n_u + i]);
            }
        }
    }
    let atlas = Atlas {
        width,
        height,
        texel_xy,
    };
    let mut rgb = atlas.to_srgb8(&values, exposure);
    // Borders: each border pixel copies the nearest pixel of its own tile.
    for (&(w, h), &(ox, oy)) in tiles.iter().zip(&origins) {
        for py in 0..h {
            for px in 0..w {
                if px > 0 && py > 0 && px < w - 1 && py < h - 1 {
                    continue;
                }
                let (sx, sy) = (px.clamp(1, w - 2), py.clamp(1, h - 2));
                let from = (((oy + sy) * width + ox + sx) * 3) as usize;
                let to = (((oy + py) * width + ox + px) * 3) as usize;
                rgb.copy_within(from..from + 3, to);
            }
        }
    }
    let uv = faces
        .iter()
        .zip(&origins)
        .map(|(f, &(ox, oy))| {
            let (x0, y0) = (ox + 1, oy + 1);
            [
                [x0 as f32 / width as f32, y0 as f32 / height as f32],
                [
                    (x0 + f.n_u as u32) as f32 / width as f32,
                    (y0 + f.n_v as u32) as f32 / height as f32,
                ],
            ]
        })
        .collect();
    debug_assert_eq!(layout.n_texels(), radiance.len());
    SurfaceTexture {
        width,
        height,
        rgb,
        uv,
    }
}

/// The texture as PNG bytes (sRGB chunk set).
pub fn png(texture: &SurfaceTexture) -> Result<Vec<u8>, String> {
    let mut bytes = Vec::new();
    {
        let mut encoder = png::Encoder::new(&mut bytes, texture.width, texture.height);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_source_srgb(png::SrgbRenderingIntent::Perceptual);
        let mut writer = encoder.write_header().map_err(|e| e.to_string())?;
        writer
            .write_image_data(&texture.rgb)
            .map_err(|e| e.to_string())?;
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::faces::box_faces;
    use lightfarm_proto::bundle::SurfaceInfo;

    /// Two 2×2 faces with distinct radiance per texel: every texel lands on its own pixel at
    /// its face's uv, and the borders repeat the tile's edge.
    #[test]
    fn tiles_hold_their_texels_and_borders_repeat_edges() {
        let mut layout = Layout::default();
        for (normal, coord) in [([0.0, 1.0, 0.0], 0.0), ([0.0, -1.0, 0.0], 3.0)] {
            for j in 0..2 {
                for i in 0..2 {
                    layout
                        .positions
                        .push([i as f32 + 0.5, coord, j as f32 + 0.5]);
                    layout.normals.push(normal);
                    layout.texel_size.push([1.0, 1.0]);
                }
            }
        }
        layout.surfaces.push(SurfaceInfo {
            name: "block:a".into(),
            texel_offset: 0,
            texel_count: 8,
        });
        let faces = box_faces(&layout, 0, 8).unwrap();
        // Radiance k/8 so each texel's pixel differs.
        let radiance: Vec<[f32; 3]> = (0..8).map(|k| [k as f32 / 8.0; 3]).collect();
        let t = face_texture(&layout, &faces, &radiance, 1.0);
        let srgb = Atlas {
            width: 8,
            height: 1,
            texel_xy: (0..8).map(|k| (k, 0)).collect(),
        }
        .to_srgb8(&radiance, 1.0);
        let px = |x: u32, y: u32| t.rgb[((y * t.width + x) * 3) as usize];
        for (k, face) in faces.iter().enumerate() {
            let [lo, hi] = t.uv[k];
            let x0 = (lo[0] * t.width as f32).round() as u32;
            let y0 = (lo[1] * t.height as f32).round() as u32;
            assert_eq!((hi[0] * t.width as f32).round() as u32, x0 + 2);
            for j in 0..2 {
                for i in 0..2 {
                    let texel = face.first_texel + j * 2 + i;
                    assert_eq!(px(x0 + i as u32, y0 + j as u32), srgb[texel * 3]);
                }
            }
            // The border left of texel (0, 1) and above texel (1, 0) repeat them.
            assert_eq!(px(x0 - 1, y0 + 1), px(x0, y0 + 1));
            assert_eq!(px(x0 + 1, y0 - 1), px(x0 + 1, y0));
            assert_eq!(px(x0 - 1, y0 - 1), px(x0, y0));
        }
        let png = png(&t).unwrap();
        assert_eq!(&png[1..4], b"PNG");
    }
}
