//! Pooling the exact gather's few-hit entries by tile ([`TilePool`]): the bake side of
//! [`lightfarm_proto::bundle::GatherTiles`].
//!
//! A gather row counts, per texel hit, how many of the row's rays hit it; at 1,024 rays most
//! texels are hit once or twice, so a row holds hundreds of such entries and the gather is the
//! largest sparse operator of a DRT bundle (2.53 M entries on the maze at T=16). Here every
//! entry with at most [`POOLED_MAX_HITS`] hits on a rectangle surface (a block face or a
//! clutter box face, `t × t` texels) moves to the tile of that surface holding its texel: the
//! row reads the tile's mean direct light with the tile's summed count. Tiles are [`TILE`] ×
//! [`TILE`] texels, fewer where that would span more than a quarter of the face's side (2 × 2
//! at T=8, none below T=8): a fraction of the face, not a length, because nothing in a bake may
//! depend on the scene's unit (`tests/tests/stability_geometry.rs` bakes one scene from 2.5 mm to
//! 10 km). The rays still land where they did, on the tile, so the row's total weight is
//! unchanged; the direct light each such ray reads is averaged over the tile instead of taken
//! at one texel, which smooths the estimate's noise (a texel hit more often keeps its own
//! entry, so the near field and the strongest hits stay as they were). Mesh texels are never
//! pooled.
//!
//! Measured against Mitsuba at all bounces (`lfgt.py check … --bounces -1 --sample 1000`,
//! whole level / clutter texels), before → after: the maze at T=16 (4 × 4), 2.53 M → 0.89 M
//! entries, 0.0227 → 0.0224 / 0.0247 → 0.0235; a generated 80-block level with many props at
//! T=8 (2 × 2, `gen_level.py --blocks 80 --seed 4`), 0.76 M → 0.52 M entries, 0.0427 → 0.0427
//! / 0.0481 → 0.0480. 4 × 4 tiles at T=8 cost the exact gather next to the Cornell room's box
//! 0.0178 → 0.0202 (`drt_accuracy`'s scene-gather test; 0.0172 with 2 × 2) and pooling up to 4
//! hits cost error on the seed-4 props (0.0499).
//!
//! Columns: while pooling, a tile entry's column is `n_texels + first texel of the tile`;
//! [`TilePool::finish`] renumbers the tiles used to `n_texels + 0, 1, …` in the order of their
//! first texel (the order [`GatherTiles`] requires) and writes their texels.
//!
//! Invariant: deterministic (no hashing order, no threads); a row's summed weight is kept.

use lightfarm_proto::bundle::{GatherTiles, TexelGather};

use crate::bake::scene::geometry::{Geometry, Surface, SurfaceOwner};

/// Entries with at most this many hits move to their tile.
pub const POOLED_MAX_HITS: u32 = 2;

/// Largest side of a tile in texels.
pub const TILE: usize = 4;

/// A tile spans at most `1 / FACE_FRACTION` of its face's side: a surface's tiles are
/// [`TILE`], 2 or 1 texels on a side, the largest within it (1 texel: nothing pooled).
pub const FACE_FRACTION: usize = 4;

/// The tile side (texels) on `s`.
fn tile_side(s: &Surface) -> usize {
    let mut side = TILE;
    while side > 1 && side * FACE_FRACTION > s.t {
        side /= 2;
    }
    side
}

/// Which texels pool into which tile, and the tiles a gather used so far.
pub struct TilePool {
    n_texels: u32,
    /// Per texel, the first texel of its tile, or `u32::MAX` for a texel never pooled.
    tile_of: Vec<u32>,
    /// Per texel, the surface grid it lies on and its tiles' side: `(surface texel offset, t,
    /// side)`, for listing a tile's texels.
    grid_of: Vec<(u32, u32, u32)>,
    /// Per tile (by first texel), whether a row reads it.
    used: Vec<bool>,
}

impl TilePool {
    pub fn new(g: &Geometry) -> TilePool {
        let n = g.texels.len();
        let mut tile_of = vec![u32::MAX; n];
        let mut grid_of = vec![(0, 0, 1); n];
        for s in &g.surfaces {
            let side = tile_side(s);
            if matches!(s.owner, SurfaceOwner::ClutterMesh { .. })
                || s.n_texels != s.t * s.t
                || side == 1
            {
                continue;
            }
            for j in 0..s.t {
                for i in 0..s.t {
                    let x = s.texel_offset + j * s.t + i;
                    let first = s.texel_offset + (j - j % side) * s.t + (i - i % side);
                    tile_of[x] = first as u32;
                    grid_of[x] = (s.texel_offset as u32, s.t as u32, side as u32);
                }
            }
        }
        TilePool {
            n_texels: n as u32,
            tile_of,
            grid_of,
            used: vec![false; n],
        }
    }

    /// Moves the entries of `hits` (`(texel, hits)`, each texel once) with at most
    /// [`POOLED_MAX_HITS`] hits on a tiled texel to their tile (one entry per tile, the hits
    /// summed, column `n_texels + first texel`); the other entries keep their order, the tile
    /// entries follow in ascending order.
    pub fn pool(&mut self, hits: &mut Vec<(u32, u32)>) {
        let mut pooled: Vec<(u32, u32)> = Vec::new();
        hits.retain(|&(t, n)| {
            let tile = self.tile_of[t as usize];
            if n > POOLED_MAX_HITS || tile == u32::MAX {
                return true;
            }
            pooled.push((tile, n));
            false
        });
        pooled.sort_unstable();
        for (tile, n) in pooled {
            self.used[tile as usize] = true;
            match hits.last_mut() {
                Some((c, m)) if *c == self.n_texels + tile => *m += n,
                _ => hits.push((self.n_texels + tile, n)),
            }
        }
    }

    /// Renumbers the tile columns of `gather` (written by [`TilePool::pool`]) to
    /// `n_texels + i`, tile `i` being the `i`-th used tile by first texel, and sets the
    /// gather's tiles.
    pub fn finish(self, gather: &mut TexelGather) {
        let mut index = vec![u32::MAX; self.used.len()];
        let mut tiles = GatherTiles::default();
        let mut texels = Vec::with_capacity(TILE * TILE);
        for (first, _) in self.used.iter().enumerate().filter(|(_, u)| **u) {
            index[first] = tiles.len() as u32;
            let (offset, t, side) = self.grid_of[first];
            let local = first as u32 - offset;
            let (i0, j0) = (local % t, local / t);
            texels.clear();
            for j in j0..(j0 + side).min(t) {
                for i in i0..(i0 + side).min(t) {
                    texels.push(offset + j * t + i);
                }
            }
            tiles.push(&texels);
        }
        for c in &mut gather.cols {
            if *c >= self.n_texels {
                *c = self.n_texels + index[(*c - self.n_texels) as usize];
            }
        }
        gather.tiles = tiles;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::scene::geometry::Texel;

    /// A geometry of one `t × t` block face and `mesh` mesh texels after it.
    fn geometry(t: usize, mesh: usize) -> Geometry {
        let face = Surface {
            name: "block:a/-x".into(),
            owner: SurfaceOwner::Block {
                block: 0,
                face: lightfarm_proto::Face::NegX,
            },
            axis: 0,
            coord: 0.0,
            min: [0.0, 0.0],
            max: [1.0, 1.0],
            normal_sign: 1.0,
            t,
            texel_offset: 0,
            n_texels: t * t,
            index_offset: 0,
            albedo: [0.5; 3],
        };
        let mut g = Geometry {
            surfaces: vec![face],
            ..Default::default()
        };
        let texel = Texel {
            position: [0.0; 3],
            normal: [1.0, 0.0, 0.0],
            albedo: [0.5; 3],
            surface: 0,
            index: 0,
        };
        g.texels = vec![texel; t * t + mesh];
        g
    }

    #[test]
    fn few_hit_entries_move_to_their_tile_and_the_row_keeps_its_hits() {
        // An 18 × 18 face (texels 0..324; texel (i, j) is 18 j + i) and two mesh texels (324,
        // 325): 4 × 4 tiles, 2 texels wide along the last column and row.
        let mut pool = TilePool::new(&geometry(18, 2));
        // Texels 0, 1, 19 pool into tile 0; 16 into tile 16 (2 × 4); 323 into tile 304 (2 × 2);
        // 3 has 5 hits and keeps its entry; mesh texel 325 is never pooled.
        let mut row = vec![(0, 1), (1, 2), (19, 1), (16, 1), (323, 2), (3, 5), (325, 1)];
        let before: u32 = row.iter().map(|e| e.1).sum();
        pool.pool(&mut row);
        assert_eq!(row, vec![(3, 5), (325, 1), (326, 4), (342, 1), (630, 2)]);
        assert_eq!(row.iter().map(|e| e.1).sum::<u32>(), before);
        let mut g = TexelGather {
            rows: vec![324],
            row_start: vec![0, row.len() as u32],
            cols: row.iter().map(|e| e.0).collect(),
            values: row.iter().map(|e| e.1 as f32).collect(),
            ..Default::default()
        };
        pool.finish(&mut g);
        assert_eq!(g.cols, vec![3, 325, 326, 327, 328]);
        assert_eq!(g.tiles.len(), 3);
        assert_eq!(
            g.tiles.texels(0),
            &[0, 1, 2, 3, 18, 19, 20, 21, 36, 37, 38, 39, 54, 55, 56, 57]
        );
        assert_eq!(g.tiles.texels(1), &[16, 17, 34, 35, 52, 53, 70, 71]);
        assert_eq!(g.tiles.texels(2), &[304, 305, 322, 323]);
    }

    /// Tiles are 4, 2 or 1 texels on a side, the largest within a quarter of the face's side,
    /// whatever the face's size in metres.
    #[test]
    fn tiles_shrink_on_coarse_faces() {
        for (t, side) in [(32, 4), (16, 4), (12, 2), (8, 2), (7, 1), (4, 1)] {
            for size in [0.01, 4.0, 1e4] {
                let mut g = geometry(t, 0);
                g.surfaces[0].max = [size, size / 2.0];
                assert_eq!(tile_side(&g.surfaces[0]), side, "{size} m in {t} texels");
            }
        }
        // 4 texels a side: nothing pooled.
        let mut pool = TilePool::new(&geometry(4, 0));
        let mut row = vec![(0, 1), (1, 1)];
        pool.pool(&mut row);
        assert_eq!(row, vec![(0, 1), (1, 1)]);
    }

    #[test]
    fn rows_without_few_hit_entries_are_left_alone() {
        let mut pool = TilePool::new(&geometry(16, 0));
        let mut row = vec![(5, 3), (0, 9)];
        pool.pool(&mut row);
        assert_eq!(row, vec![(5, 3), (0, 9)]);
        let mut g = TexelGather::default();
        pool.finish(&mut g);
        assert!(g.tiles.is_empty());
    }
}
