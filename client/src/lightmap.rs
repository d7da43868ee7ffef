//! Lightmap export: per-texel radiance laid out as an atlas image, for people (8-bit sRGB, to
//! write as PNG) and for engines (raw f16 RGB).
//!
//! The atlas cuts every layout surface into T×T tiles (T: the side of a block face) on a grid,
//! one empty texel between tiles; texel `(i, j)` of a face (index `j·T + i`, `proto::face`
//! convention) lands at tile origin + `(i, j)`, so each face shows with its first tangent axis
//! to the right. A clutter box (one surface, six faces) takes six tiles. A mesh surface with its
//! own lightmap image (`Bundle::surface_atlases`: mesh clutter's atlas) is placed whole, as its
//! own region below the tiles, one empty texel between regions.
//!
//! Invariants: every layout texel maps to exactly one pixel; pixels between tiles are black
//! (8-bit) or zero (f16); the layout and radiance slices are in layout order.

use lightfarm_proto::bundle::{Layout, SurfaceAtlas};

/// Where each texel sits in the atlas image.
#[derive(Clone, Debug, PartialEq)]
pub struct Atlas {
    pub width: u32,
    pub height: u32,
    /// Pixel `(x, y)` of each layout texel, in layout order.
    pub texel_xy: Vec<(u32, u32)>,
}

/// Raw f16 atlas file: magic, width, height, then width·height RGB f16 (little-endian),
/// rows top to bottom.
pub const F16_MAGIC: &[u8; 8] = b"LFLMAP16";

impl Atlas {
    /// Lays out every surface of `layout` on a square-ish grid of equal T×T tiles, T the side of
    /// the largest square surface (a block face); a surface of n texels takes ⌈n / T²⌉ tiles,
    /// so a clutter box (six faces in one surface) shows as six tiles.
    pub fn from_layout(layout: &Layout) -> Atlas {
        Atlas::from_layout_with(layout, &[])
    }

    /// [`Atlas::from_layout`], with the surfaces in `surface_atlases` laid out as their own
    /// images (left to right on one row below the tiles) instead of cut into tiles.
    pub fn from_layout_with(layout: &Layout, surface_atlases: &[SurfaceAtlas]) -> Atlas {
        let own = |k: usize| surface_atlases.iter().find(|a| a.surface as usize == k);
        let square_side = |n: u32| {
            let s = (n as f64).sqrt().round() as u32;
            (s * s == n).then_some(s)
        };
        let tiled: Vec<&lightfarm_proto::bundle::SurfaceInfo> = layout
            .surfaces
            .iter()
            .enumerate()
            .filter(|(k, _)| own(*k).is_none())
            .map(|(_, s)| s)
            .collect();
        let tile = tiled
            .iter()
            .filter_map(|s| square_side(s.texel_count))
            .max()
            .or_else(|| {
                let most = tiled.iter().map(|s| s.texel_count).max()?;
                Some((most as f64).sqrt().ceil() as u32)
            })
            .unwrap_or(1)
            .max(1);
        let per_tile = tile * tile;
        let n_tiles: u32 = tiled.iter().map(|s| s.texel_count.div_ceil(per_tile)).sum();
        let columns = ((n_tiles as f64).sqrt().ceil() as u32).max(1);
        let rows = n_tiles.div_ceil(columns).max(1);
        let pitch = tile + 1;
        let mut texel_xy = vec![(0, 0); layout.n_texels()];
        let mut next_tile = 0u32;
        let (mut width, mut height) = (columns * pitch - 1, rows * pitch - 1);
        // Own images: one row below the tiles.
        let (mut x, y) = (0u32, height + 1);
        for a in surface_atlases {
            let Some(s) = layout.surfaces.get(a.surface as usize) else {
                continue;
            };
            for (k, xy) in a.texel_xy.iter().enumerate().take(s.texel_count as usize) {
                texel_xy[(s.texel_offset as usize) + k] = (x + xy[0], y + xy[1]);
            }
            width = width.max(x + a.width);
            height = height.max(y + a.height);
            x += a.width + 1;
        }
        for (k, s) in layout.surfaces.iter().enumerate() {
            if own(k).is_some() {
                continue;
            }
            for t in 0..s.texel_count {
                let k = next_tile + t / per_tile;
                let within = t % per_tile;
                let (tx, ty) = ((k % columns) * pitch, (k / columns) * pitch);
                texel_xy[(s.texel_offset + t) as usize] = (tx + within % tile, ty + within / tile);
            }
            next_tile += s.texel_count.div_ceil(per_tile);
        }
        Atlas {
            width,
            height,
            texel_xy,
        }
    }

    /// The atlas as row-major RGB f32 (zero where no texel lands).
    pub fn to_rgb(&self, radiance: &[[f32; 3]]) -> Vec<[f32; 3]> {
        let mut image = vec![[0.0f32; 3]; (self.width * self.height) as usize];
        for (&(x, y), l) in self.texel_xy.iter().zip(radiance) {
            image[(y * self.width + x) as usize] = *l;
        }
        image
    }

    /// The raw f16 file (see [`F16_MAGIC`]).
    pub fn to_f16_file(&self, radiance: &[[f32; 3]]) -> Vec<u8> {
        let mut out = Vec::with_capacity(16 + 6 * (self.width * self.height) as usize);
        out.extend_from_slice(F16_MAGIC);
        out.extend_from_slice(&self.width.to_le_bytes());
        out.extend_from_slice(&self.height.to_le_bytes());
        for px in self.to_rgb(radiance) {
            for v in px {
                out.extend_from_slice(&half::f16::from_f32(v).to_bits().to_le_bytes());
            }
        }
        out
    }

    /// 8-bit sRGB RGB pixels for people to look at: `x = exposure · radiance` through the tone
    /// curve `min(2x / (1 + x), 1)` (linear near black, white at x = 1), then sRGB-encoded.
    pub fn to_srgb8(&self, radiance: &[[f32; 3]], exposure: f32) -> Vec<u8> {
        let encode = |v: f32| {
            let x = (v * exposure).max(0.0);
            let mapped = (2.0 * x / (1.0 + x)).min(1.0);
            let srgb = if mapped <= 0.003_130_8 {
                12.92 * mapped
            } else {
                1.055 * mapped.powf(1.0 / 2.4) - 0.055
            };
            (srgb * 255.0).round().clamp(0.0, 255.0) as u8
        };
        self.to_rgb(radiance)
            .iter()
            .flat_map(|p| p.map(encode))
            .collect()
    }
}

/// An exposure that puts the 99th-percentile channel value of `radiance` at 1 (1 if all zero).
pub fn auto_exposure(radiance: &[[f32; 3]]) -> f32 {
    let mut values: Vec<f32> = radiance
        .iter()
        .flatten()
        .copied()
        .filter(|v| v.is_finite() && *v > 0.0)
        .collect();
    if values.is_empty() {
        return 1.0;
    }
    values.sort_by(f32::total_cmp);
    1.0 / values[(values.len() - 1) * 99 / 100]
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfarm_proto::bundle::SurfaceInfo;

    fn layout(counts: &[u32]) -> Layout {
        let mut l = Layout::default();
        let mut offset = 0;
        for (k, &n) in counts.iter().enumerate() {
            l.surfaces.push(SurfaceInfo {
                name: format!("s{k}"),
                texel_offset: offset,
                texel_count: n,
            });
            offset += n;
        }
        l.positions = vec![[0.0; 3]; offset as usize];
        l
    }

    #[test]
    fn every_texel_gets_its_own_pixel_and_tiles_keep_a_gap() {
        // Three faces, a six-face box, a 5-texel odd surface: 3 + 6 + 1 tiles of side 4 on a
        // 4-column grid with 1-texel gaps: 4·5−1 × 3·5−1.
        let l = layout(&[16, 16, 16, 96, 5]);
        let atlas = Atlas::from_layout(&l);
        assert_eq!((atlas.width, atlas.height), (19, 14));
        let mut seen = std::collections::HashSet::new();
        for &(x, y) in &atlas.texel_xy {
            assert!(x < atlas.width && y < atlas.height);
            assert!(x % 5 != 4 && y % 5 != 4, "({x}, {y}) lies in a gap");
            assert!(seen.insert((x, y)), "({x}, {y}) used twice");
        }
        // Texel (i, j) of the second surface at tile origin (5, 0) + (i, j).
        assert_eq!(atlas.texel_xy[16 + 4 + 3], (5 + 3, 1));
        // Texel 0 of the box's third face: tile 3 + 2 = 5, at (1·5, 1·5).
        assert_eq!(atlas.texel_xy[48 + 32], (5, 5));
    }

    /// A mesh surface with its own image keeps its atlas layout, below the tiles; the other
    /// surfaces are tiled as without it.
    #[test]
    fn mesh_surfaces_keep_their_own_image() {
        let l = layout(&[16, 16, 5]);
        let mesh = SurfaceAtlas {
            surface: 2,
            width: 7,
            height: 3,
            texel_xy: vec![[0, 0], [6, 0], [3, 1], [0, 2], [6, 2]],
        };
        let atlas = Atlas::from_layout_with(&l, std::slice::from_ref(&mesh));
        let tiles_only = Atlas::from_layout(&layout(&[16, 16]));
        assert_eq!(atlas.texel_xy[..32], tiles_only.texel_xy[..]);
        let y0 = tiles_only.height + 1;
        for (k, xy) in mesh.texel_xy.iter().enumerate() {
            assert_eq!(atlas.texel_xy[32 + k], (xy[0], y0 + xy[1]));
        }
        assert_eq!(
            (atlas.width, atlas.height),
            (tiles_only.width.max(7), y0 + 3)
        );
        let unique: std::collections::HashSet<_> = atlas.texel_xy.iter().collect();
        assert_eq!(unique.len(), atlas.texel_xy.len());
    }

    #[test]
    fn f16_file_holds_the_radiance_and_srgb_is_monotone() {
        let l = layout(&[4]);
        let atlas = Atlas::from_layout(&l);
        let radiance = vec![[0.0, 0.5, 1.0], [2.0, 4.0, 8.0], [0.25; 3], [1e-3; 3]];
        let f = atlas.to_f16_file(&radiance);
        assert_eq!(&f[..8], F16_MAGIC);
        assert_eq!(f.len(), 16 + 6 * 4);
        let px = |k: usize, c: usize| {
            let at = 16 + 6 * k + 2 * c;
            half::f16::from_bits(u16::from_le_bytes([f[at], f[at + 1]])).to_f32()
        };
        assert_eq!(px(1, 2), 8.0);
        assert_eq!(px(0, 1), 0.5);
        let rgb = atlas.to_srgb8(&radiance, 1.0);
        assert_eq!((rgb[0], rgb[2]), (0, 255));
        assert!(rgb[1] > 128 && rgb[1] < 255, "{}", rgb[1]);
        assert_eq!(&rgb[3..6], &[255, 255, 255]);
        assert!(rgb[6] > rgb[9] && rgb[9] > 0, "{:?}", &rgb[6..12]);
        assert_eq!(auto_exposure(&[[0.0; 3]]), 1.0);
    }
}
