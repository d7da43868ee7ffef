//! Tiles of the exact gather ([`GatherTiles`], format 2.6): small groups of texels on one
//! surface whose *mean* direct light a gather column may read instead of a single texel's.
//!
//! A gather row is a Monte Carlo estimate: of a texel's 1,024 rays most hit a texel of their
//! own once or twice, so a row holds hundreds of entries of count 1 or 2 (2.53 M entries on the
//! maze at T=16). The bake pools those few-hit entries by tile of the surface they hit
//! (`server/src/bake/drt/tiles.rs`): the rays still land on the tile, and the tile's mean
//! direct light stands for the texel each ray hit, which averages the estimate's noise over
//! the tile instead of keeping it. Column `n_texels + i` of a gather is tile `i`.
//!
//! Stored after the replaced texels of a DRT section of kind 21 as `start:u32s texels:u32s`:
//! tile `i` is `texels[start[i] .. start[i + 1]]`.
//!
//! Invariants (checked by `Bundle::validate`): `start` is empty (no tiles) or ascends strictly
//! from 0 to `texels.len()`, so no tile is empty; a tile's texels ascend strictly and lie on one
//! surface of the layout; tiles are ordered by their first texel. So the tiles of a texel range
//! made of whole surfaces (a block's, a clutter object's) are consecutive.

use crate::wire::{Reader, WireError, Writer};

use super::index_lists::{read_index_list, write_index_list, IndexLists};
use super::TexelGather;

impl TexelGather {
    /// The texels column `col` of a gather over `n_texels` texels reads, and the share of the
    /// column's weight each takes: `col` itself whole, or a tile's texels `1 / len` each.
    pub fn column_texels<'a>(&'a self, n_texels: usize, col: &'a u32) -> (&'a [u32], f64) {
        match (*col as usize).checked_sub(n_texels) {
            None => (std::slice::from_ref(col), 1.0),
            Some(i) => {
                let tile = self.tiles.texels(i);
                (tile, 1.0 / tile.len() as f64)
            }
        }
    }
}

/// Tiles of a gather: tile `i` is `texels[start[i] .. start[i + 1]]` (module doc).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GatherTiles {
    pub start: Vec<u32>,
    pub texels: Vec<u32>,
}

impl GatherTiles {
    /// Number of tiles.
    pub fn len(&self) -> usize {
        self.start.len().saturating_sub(1)
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Texels of tile `i`.
    pub fn texels(&self, i: usize) -> &[u32] {
        &self.texels[self.start[i] as usize..self.start[i + 1] as usize]
    }

    /// Appends a tile of `texels`.
    pub fn push(&mut self, texels: &[u32]) {
        if self.start.is_empty() {
            self.start.push(0);
        }
        self.texels.extend_from_slice(texels);
        self.start.push(self.texels.len() as u32);
    }

    pub(super) fn write(&self, w: &mut Writer, lists: IndexLists) {
        write_index_list(w, &self.start, lists);
        write_index_list(w, &self.texels, lists);
    }

    pub(super) fn read(r: &mut Reader, lists: IndexLists) -> Result<GatherTiles, WireError> {
        Ok(GatherTiles {
            start: read_index_list(r, lists)?,
            texels: read_index_list(r, lists)?,
        })
    }

    /// Whether the invariants of the module doc hold for a layout whose surfaces start at
    /// `surface_starts` (ascending texel offsets) and hold `n_texels` texels; `None` when they
    /// do, else what is wrong.
    pub(super) fn check(&self, surface_starts: &[u32], n_texels: u64) -> Option<&'static str> {
        if self.start.is_empty() {
            return (!self.texels.is_empty()).then_some("gather tiles have texels but no starts");
        }
        if self.start[0] != 0
            || self.start.windows(2).any(|w| w[1] <= w[0])
            || *self.start.last().expect("a start") as usize != self.texels.len()
        {
            return Some("gather tile starts do not ascend from 0 to the texel count");
        }
        let surface_of = |t: u32| surface_starts.partition_point(|&s| s <= t);
        let mut previous_first: Option<u32> = None;
        for i in 0..self.len() {
            let tile = self.texels(i);
            if tile.iter().any(|&t| t as u64 >= n_texels) {
                return Some("a gather tile names a texel outside the layout");
            }
            if tile.windows(2).any(|w| w[1] <= w[0]) {
                return Some("a gather tile's texels do not ascend");
            }
            if surface_of(tile[0]) != surface_of(tile[tile.len() - 1]) {
                return Some("a gather tile spans two surfaces");
            }
            if previous_first.is_some_and(|p| tile[0] <= p) {
                return Some("gather tiles are not ordered by their first texel");
            }
            previous_first = Some(tile[0]);
        }
        None
    }
}
