//! The DRT exact gather ([`TexelGather`]) in the form the frame loop reads: sparse rows over the
//! direct light with narrow column indices and, where the bake's weights allow, 8-bit weights.
//!
//! A gather weight is a ray-hit fraction, `hits / rays_per_texel`, so every weight of a bundle
//! is a small integer times one unit. [`PackedGather::new`] finds that unit (the smallest
//! positive weight) and keeps the integers in a byte when *every* weight is exactly
//! `unit · count` in f32 with `count ≤ 255`, else in 16 bits when every count is at most
//! 65,535 (a texel close to a wall can send hundreds of its rays to one texel there: on the
//! maze, counts reach 399 of 1,024 rays); column indices are kept in 16 bits when the layout
//! has at most 65,536 texels. Anything else keeps the bundle's u32 / f32 form. An entry is then
//! read as 3 or 4 bytes instead of 8 (the gather is the largest sparse operator of a DRT
//! frame, and relighting by a change streams its entries from memory).
//!
//! [`GatherColumns`] holds the same entries by column (per texel, the rows reading it), so
//! relighting by a change of light runs only the entries that read a changed texel
//! ([`GatherColumns::scatter`]): on the maze, moving one light, 0.63 M of the 1.47 M entries of
//! the rows that read the blocks it reaches. Its sums agree with the rows' to float rounding
//! (the terms are added in another order).
//!
//! A gather of format 2.6 has tiles ([`GatherTiles`]): column `n_texels + i` reads the mean
//! direct light of tile `i`. The rows read it from the padded light, whose tile lanes
//! [`PackedGather::fill_tiles`] sets per application; by the change,
//! [`GatherColumns::scatter_tiles`] takes each tile's mean of the change (a tile lies on one
//! surface, so the tiles of a block's or clutter object's texels are consecutive:
//! [`GatherColumns::tiles_of`]). The tile table is shared by both ([`Arc`]), not copied.
//!
//! Invariants:
//! - Lossless: with 8- or 16-bit weights a row is summed as `unit · Σ count · l` instead of
//!   `Σ (unit · count) · l`; the two agree exactly when `unit` is a power of two (the usual
//!   `rays_per_texel`) and to float rounding otherwise.
//! - Rows are visited in the bundle's order and each row's terms in a fixed order (four
//!   interleaved partial sums, see `accumulate`) whatever the storage, so results do not depend
//!   on the CPU. No allocation per call.
//! - The bundle decoder has validated the gather (column indices < texel count, ascending
//!   `row_start`), so indexing here cannot go out of bounds.

use std::ops::Range;
use std::sync::Arc;

use lightfarm_proto::bundle::{gather_counts, gather_counts_u16, GatherTiles, TexelGather};

/// Indices of the gather's entries: their columns (texels) in [`PackedGather`], their rows in
/// [`GatherColumns`].
#[derive(Clone, Debug, PartialEq)]
enum Columns {
    U16(Vec<u16>),
    U32(Vec<u32>),
}

/// Weights of the gather's entries.
#[derive(Clone, Debug, PartialEq)]
enum Weights {
    /// `weight = unit · count`.
    Counts {
        unit: f32,
        counts: Vec<u8>,
    },
    /// `weight = unit · count`, some count above 255.
    Counts16 {
        unit: f32,
        counts: Vec<u16>,
    },
    F32(Vec<f32>),
}

/// A packed exact gather: `out[rows[i]] += Σ_k weight[k] · direct[col[k]]` over
/// `row_start[i] .. row_start[i + 1]`, per channel.
#[derive(Clone, Debug, PartialEq)]
pub struct PackedGather {
    rows: Vec<u32>,
    row_start: Vec<u32>,
    cols: Columns,
    weights: Weights,
    /// Shared with the [`GatherColumns`] made from it.
    tiles: Arc<TileMeans>,
}

/// The gather's tiles ([`GatherTiles`]): column `n_texels + i` reads the mean direct light of
/// tile `i`'s texels.
#[derive(Clone, Debug, PartialEq)]
struct TileMeans {
    n_texels: usize,
    tiles: GatherTiles,
    /// Each tile's first texel, ascending (the tiles of a texel range by binary search).
    first: Vec<u32>,
}

impl TileMeans {
    fn new(tiles: &GatherTiles, n_texels: usize) -> TileMeans {
        TileMeans {
            n_texels,
            first: (0..tiles.len()).map(|i| tiles.texels(i)[0]).collect(),
            tiles: tiles.clone(),
        }
    }

    /// Columns of the gather: texels, then tiles.
    fn n_columns(&self) -> usize {
        self.n_texels + self.tiles.len()
    }

    /// Mean of `direct` over tile `i`'s texels, summed in their order.
    #[inline]
    fn mean<const N: usize>(&self, i: usize, direct: &[[f32; N]]) -> [f32; N] {
        let texels = self.tiles.texels(i);
        let mut sum = [0.0f32; N];
        for &t in texels {
            for (s, l) in sum.iter_mut().zip(&direct[t as usize]) {
                *s += l;
            }
        }
        sum.map(|s| s / texels.len() as f32)
    }

    /// The tiles whose first texel lies in `texels` (every tile of a range of whole surfaces).
    fn tiles_of(&self, texels: Range<usize>) -> Range<usize> {
        let at = |t: usize| self.first.partition_point(|&f| (f as usize) < t);
        at(texels.start)..at(texels.end)
    }
}

impl PackedGather {
    /// Packs `gather` over a layout of `n_texels` texels.
    pub fn new(gather: &TexelGather, n_texels: usize) -> PackedGather {
        let tiles = Arc::new(TileMeans::new(&gather.tiles, n_texels));
        let cols = if tiles.n_columns() <= 1 << 16 {
            Columns::U16(gather.cols.iter().map(|&c| c as u16).collect())
        } else {
            Columns::U32(gather.cols.clone())
        };
        let weights = if let Some((unit, counts)) = gather_counts(&gather.values) {
            Weights::Counts { unit, counts }
        } else if let Some((unit, counts)) = gather_counts_u16(&gather.values) {
            Weights::Counts16 { unit, counts }
        } else {
            Weights::F32(gather.values.clone())
        };
        PackedGather {
            rows: gather.rows.clone(),
            row_start: gather.row_start.clone(),
            cols,
            weights,
            tiles,
        }
    }

    /// Columns the gather reads: the layout's texels, then its tiles (the length of the
    /// padded direct light [`PackedGather::add_to_padded`] reads).
    pub fn n_columns(&self) -> usize {
        self.tiles.n_columns()
    }

    /// Sets the tile columns of `padded` (the texels' direct light padded by [`pad_direct`],
    /// [`PackedGather::n_columns`] long) to each tile's mean.
    pub fn fill_tiles(&self, padded: &mut [[f32; 4]]) {
        let n = self.tiles.n_texels;
        for i in 0..self.tiles.tiles.len() {
            padded[n + i] = self.tiles.mean(i, padded);
        }
    }

    /// Bytes one application reads (entries, row indices and row starts).
    pub fn bytes(&self) -> usize {
        let cols = match &self.cols {
            Columns::U16(c) => 2 * c.len(),
            Columns::U32(c) => 4 * c.len(),
        };
        let weights = match &self.weights {
            Weights::Counts { counts, .. } => counts.len(),
            Weights::Counts16 { counts, .. } => 2 * counts.len(),
            Weights::F32(v) => 4 * v.len(),
        };
        cols + weights + 4 * (self.rows.len() + self.row_start.len())
    }

    /// The texel row `i` of the gather adds to.
    pub fn row_texel(&self, i: usize) -> usize {
        self.rows[i] as usize
    }

    /// Rows of the gather.
    pub fn n_rows(&self) -> usize {
        self.rows.len()
    }

    /// Whether the weights are kept as 8-bit counts (for reports and tests).
    pub fn is_8bit(&self) -> bool {
        matches!(self.weights, Weights::Counts { .. })
    }

    /// Adds the gather of `direct` (texel radiance, albedo-free, padded to four lanes by
    /// [`pad_direct`] into a buffer the caller keeps, its tiles' means by
    /// [`PackedGather::fill_tiles`]) to `out`: one 16-byte load per entry, so
    /// each entry is a load, a broadcast weight, a multiply and an add on four lanes (the
    /// fourth unused) instead of three scalar multiply-adds.
    pub fn add_to_padded(&self, direct: &[[f32; 4]], out: &mut [[f32; 3]]) {
        match (&self.cols, &self.weights) {
            (Columns::U16(c), Weights::Counts { unit, counts }) => {
                self.accumulate(c, counts, *unit, direct, out)
            }
            (Columns::U32(c), Weights::Counts { unit, counts }) => {
                self.accumulate(c, counts, *unit, direct, out)
            }
            (Columns::U16(c), Weights::Counts16 { unit, counts }) => {
                self.accumulate(c, counts, *unit, direct, out)
            }
            (Columns::U32(c), Weights::Counts16 { unit, counts }) => {
                self.accumulate(c, counts, *unit, direct, out)
            }
            (Columns::U16(c), Weights::F32(v)) => self.accumulate(c, v, 1.0, direct, out),
            (Columns::U32(c), Weights::F32(v)) => self.accumulate(c, v, 1.0, direct, out),
        }
    }

    /// The same entries by column ([`GatherColumns`]), in the same storage (row indices in 16
    /// bits when the gather has at most 65,536 rows). Allocates; made once, on the first
    /// relight by the change.
    pub fn by_columns(&self) -> GatherColumns {
        let cols: Vec<u32> = match &self.cols {
            Columns::U16(c) => c.iter().map(|&c| c as u32).collect(),
            Columns::U32(c) => c.clone(),
        };
        let n_columns = self.n_columns();
        let mut col_start = vec![0u32; n_columns + 1];
        for &c in &cols {
            col_start[c as usize + 1] += 1;
        }
        for t in 0..n_columns {
            col_start[t + 1] += col_start[t];
        }
        // Entries in column order, each column's by ascending row (a counting sort).
        let mut next = col_start.clone();
        let mut source = vec![0u32; cols.len()];
        let mut row_of = vec![0u32; cols.len()];
        for i in 0..self.rows.len() {
            for k in self.row_start[i] as usize..self.row_start[i + 1] as usize {
                let slot = &mut next[cols[k] as usize];
                source[*slot as usize] = k as u32;
                row_of[*slot as usize] = i as u32;
                *slot += 1;
            }
        }
        let rows = if self.rows.len() <= 1 << 16 {
            Columns::U16(row_of.iter().map(|&i| i as u16).collect())
        } else {
            Columns::U32(row_of)
        };
        let weights = match &self.weights {
            Weights::Counts { unit, counts } => Weights::Counts {
                unit: *unit,
                counts: source.iter().map(|&k| counts[k as usize]).collect(),
            },
            Weights::Counts16 { unit, counts } => Weights::Counts16 {
                unit: *unit,
                counts: source.iter().map(|&k| counts[k as usize]).collect(),
            },
            Weights::F32(v) => Weights::F32(source.iter().map(|&k| v[k as usize]).collect()),
        };
        GatherColumns {
            col_start,
            rows,
            weights,
            tiles: Arc::clone(&self.tiles),
        }
    }

    /// `out[row] += scale · Σ w · direct[col]` for every row; one loop for every storage. Entry `k`
    /// of a row goes to partial sum `k mod 4` and the partials are added as `(p0 + p1) + (p2 +
    /// p3)`: four independent chains instead of one hide the adder's latency (one chain bound
    /// the loop at one entry per 4 cycles), and the order is still fixed by the code. Each lane
    /// is a multiply then an add (never fused), so the SSE and portable paths agree bit for
    /// bit.
    fn accumulate<C, W>(
        &self,
        cols: &[C],
        weights: &[W],
        scale: f32,
        direct: &[[f32; 4]],
        out: &mut [[f32; 3]],
    ) where
        C: Copy + Into<u32>,
        W: Copy + Into<f32>,
    {
        for i in 0..self.rows.len() {
            let (start, end) = (self.row_start[i] as usize, self.row_start[i + 1] as usize);
            let q = row_sum(&cols[start..end], &weights[start..end], direct);
            let o = &mut out[self.rows[i] as usize];
            for ch in 0..3 {
                o[ch] += scale * q[ch];
            }
        }
    }
}

/// `units` (disjoint texel ranges of a layout of `n_texels`) followed by each run of texels
/// in none of them as a unit of its own, and every texel's unit.
pub(crate) fn texel_units(
    units: &[Range<usize>],
    n_texels: usize,
) -> (Vec<Range<usize>>, Vec<u32>) {
    const NONE: u32 = u32::MAX;
    let mut unit_of = vec![NONE; n_texels];
    let mut ranges = units.to_vec();
    for (u, r) in units.iter().enumerate() {
        unit_of[r.clone()].fill(u as u32);
    }
    let mut t = 0;
    while t < n_texels {
        if unit_of[t] != NONE {
            t += 1;
            continue;
        }
        let start = t;
        while t < n_texels && unit_of[t] == NONE {
            unit_of[t] = ranges.len() as u32;
            t += 1;
        }
        ranges.push(start..t);
    }
    (ranges, unit_of)
}

/// The exact gather by column: per texel `c`, the rows reading it and their weights
/// (`rows[col_start[c] .. col_start[c + 1]]`, ascending), so a change of light on a few texels
/// runs their entries alone. Made by [`PackedGather::by_columns`].
///
/// A call sums into per-row four-lane partials (`sums`, one per gather row, zero between
/// calls); the caller lists the rows it may have touched ([`GatherColumns::rows_reading`] the
/// same texels, which it can make once per unit of texels) and [`GatherColumns::finish`] adds
/// `unit · sum` to each listed row's texel, as [`PackedGather::add_to_padded`] adds its row
/// sums, and clears the partials (a listed row no lit texel fed adds zero). Texels are visited
/// in the order given and each texel's entries by ascending row, so the result is
/// deterministic; it equals the rows' sums to float rounding only (another order of the same
/// terms).
#[derive(Clone, Debug, PartialEq)]
pub struct GatherColumns {
    col_start: Vec<u32>,
    rows: Columns,
    weights: Weights,
    /// The [`PackedGather`]'s, shared.
    tiles: Arc<TileMeans>,
}

impl GatherColumns {
    /// Adds `w · direct[c]` for every entry of every texel `c` in `texels` whose light is not
    /// exactly zero (NaN is not zero, so it propagates) into `sums[row]`; whether any texel
    /// carried light. The rows it may have written are [`GatherColumns::rows_reading`] the
    /// same texels, listed by the caller (once per unit, not once per entry: a mark per entry
    /// was a third of this loop).
    pub fn scatter(
        &self,
        texels: Range<usize>,
        direct: &[[f32; 3]],
        sums: &mut [[f32; 4]],
    ) -> bool {
        let light = |c: usize| direct[c];
        self.scatter_by(texels, light, sums)
    }

    /// [`GatherColumns::scatter`] for the tile columns of the tiles in `tiles` (indices into
    /// the gather's tiles), each reading the mean of `direct` over its texels; whether any
    /// tile carried light.
    pub fn scatter_tiles(
        &self,
        tiles: Range<usize>,
        direct: &[[f32; 3]],
        sums: &mut [[f32; 4]],
    ) -> bool {
        let n = self.tiles.n_texels;
        let light = |c: usize| self.tiles.mean(c - n, direct);
        self.scatter_by(self.tile_columns(tiles), light, sums)
    }

    /// The tiles whose texels lie in `texels`, a range of whole surfaces (a block's or a
    /// clutter object's texels): consecutive, by the tiles' order.
    pub fn tiles_of(&self, texels: Range<usize>) -> Range<usize> {
        self.tiles.tiles_of(texels)
    }

    /// The columns of the tiles in `tiles`.
    pub fn tile_columns(&self, tiles: Range<usize>) -> Range<usize> {
        self.tiles.n_texels + tiles.start..self.tiles.n_texels + tiles.end
    }

    #[inline(always)]
    fn scatter_by(
        &self,
        columns: Range<usize>,
        light: impl Fn(usize) -> [f32; 3],
        sums: &mut [[f32; 4]],
    ) -> bool {
        match (&self.rows, &self.weights) {
            (Columns::U16(r), Weights::Counts { counts, .. }) => {
                self.scatter_in(columns, r, counts, light, sums)
            }
            (Columns::U32(r), Weights::Counts { counts, .. }) => {
                self.scatter_in(columns, r, counts, light, sums)
            }
            (Columns::U16(r), Weights::Counts16 { counts, .. }) => {
                self.scatter_in(columns, r, counts, light, sums)
            }
            (Columns::U32(r), Weights::Counts16 { counts, .. }) => {
                self.scatter_in(columns, r, counts, light, sums)
            }
            (Columns::U16(r), Weights::F32(v)) => self.scatter_in(columns, r, v, light, sums),
            (Columns::U32(r), Weights::F32(v)) => self.scatter_in(columns, r, v, light, sums),
        }
    }

    #[inline(always)]
    fn scatter_in<R, W>(
        &self,
        columns: Range<usize>,
        rows: &[R],
        weights: &[W],
        light: impl Fn(usize) -> [f32; 3],
        sums: &mut [[f32; 4]],
    ) -> bool
    where
        R: Copy + Into<u32>,
        W: Copy + Into<f32>,
    {
        let mut lit = false;
        for c in columns {
            let l = light(c);
            if l == [0.0; 3] {
                continue;
            }
            lit = true;
            let l = [l[0], l[1], l[2], 0.0];
            let (start, end) = (self.col_start[c] as usize, self.col_start[c + 1] as usize);
            for (&r, &w) in rows[start..end].iter().zip(&weights[start..end]) {
                let w: f32 = w.into();
                let s = &mut sums[r.into() as usize];
                for ch in 0..4 {
                    s[ch] += w * l[ch];
                }
            }
        }
        lit
    }

    /// Appends to `rows` every row reading a column of `columns` (texels, or tiles by
    /// [`GatherColumns::tile_columns`]) that `marked` does not hold yet, and marks it: the rows
    /// [`GatherColumns::scatter`] over those columns may write.
    pub fn rows_reading(&self, columns: Range<usize>, marked: &mut [bool], rows: &mut Vec<u32>) {
        let (start, end) = (
            self.col_start[columns.start] as usize,
            self.col_start[columns.end] as usize,
        );
        for k in start..end {
            let r = match &self.rows {
                Columns::U16(r) => r[k] as u32,
                Columns::U32(r) => r[k],
            };
            if !std::mem::replace(&mut marked[r as usize], true) {
                rows.push(r);
            }
        }
    }

    /// Adds each touched row's sum, times the weights' unit, to its texel in `out` (the row's
    /// texel in `gather`, the gather these columns were made from), and clears the sums, the
    /// marks and the list.
    pub fn finish(
        &self,
        gather: &PackedGather,
        sums: &mut [[f32; 4]],
        touched: &mut Vec<u32>,
        marked: &mut [bool],
        out: &mut [[f32; 3]],
    ) {
        let scale = match &self.weights {
            Weights::Counts { unit, .. } | Weights::Counts16 { unit, .. } => *unit,
            Weights::F32(_) => 1.0,
        };
        for &i in touched.iter() {
            let i = i as usize;
            let q = std::mem::take(&mut sums[i]);
            let o = &mut out[gather.rows[i] as usize];
            for ch in 0..3 {
                o[ch] += scale * q[ch];
            }
            marked[i] = false;
        }
        touched.clear();
    }
}

/// Copies direct light into four-lane texels (the fourth lane 0) for
/// [`PackedGather::add_to_padded`].
pub fn pad_direct(direct: &[[f32; 3]], padded: &mut [[f32; 4]]) {
    for (p, d) in padded.iter_mut().zip(direct) {
        *p = [d[0], d[1], d[2], 0.0];
    }
}

/// `(p0 + p1) + (p2 + p3)` with `p_k = Σ_{j ≡ k mod 4} w_j · direct[c_j]`, lane by lane.
#[inline(always)]
fn row_sum<C, W>(cols: &[C], weights: &[W], direct: &[[f32; 4]]) -> [f32; 4]
where
    C: Copy + Into<u32>,
    W: Copy + Into<f32>,
{
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::*;
        // SAFETY: SSE is part of the x86_64 baseline; loads are unaligned loads of 16 bytes
        // from `[f32; 4]` elements in bounds (columns validated < texel count = direct.len()).
        unsafe {
            let mut p = [_mm_setzero_ps(); 4];
            let mut c4 = cols.chunks_exact(4);
            let mut w4 = weights.chunks_exact(4);
            for (c, w) in (&mut c4).zip(&mut w4) {
                for k in 0..4 {
                    let l = _mm_loadu_ps(direct[c[k].into() as usize].as_ptr());
                    p[k] = _mm_add_ps(p[k], _mm_mul_ps(_mm_set1_ps(w[k].into()), l));
                }
            }
            for (k, (&c, &w)) in c4.remainder().iter().zip(w4.remainder()).enumerate() {
                let l = _mm_loadu_ps(direct[c.into() as usize].as_ptr());
                p[k] = _mm_add_ps(p[k], _mm_mul_ps(_mm_set1_ps(w.into()), l));
            }
            let q = _mm_add_ps(_mm_add_ps(p[0], p[1]), _mm_add_ps(p[2], p[3]));
            let mut out = [0.0f32; 4];
            _mm_storeu_ps(out.as_mut_ptr(), q);
            out
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        row_sum_portable(cols, weights, direct)
    }
}

/// The same sums as [`row_sum`] in plain Rust (other architectures, and the tests' check that
/// both agree bit for bit).
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
fn row_sum_portable<C, W>(cols: &[C], weights: &[W], direct: &[[f32; 4]]) -> [f32; 4]
where
    C: Copy + Into<u32>,
    W: Copy + Into<f32>,
{
    #[inline(always)]
    fn add(p: &mut [f32; 4], w: f32, l: &[f32; 4]) {
        for ch in 0..4 {
            p[ch] += w * l[ch];
        }
    }
    let mut p = [[0.0f32; 4]; 4];
    let mut c4 = cols.chunks_exact(4);
    let mut w4 = weights.chunks_exact(4);
    for (c, w) in (&mut c4).zip(&mut w4) {
        for k in 0..4 {
            add(&mut p[k], w[k].into(), &direct[c[k].into() as usize]);
        }
    }
    for (k, (&c, &w)) in c4.remainder().iter().zip(w4.remainder()).enumerate() {
        add(&mut p[k], w.into(), &direct[c.into() as usize]);
    }
    let mut q = [0.0f32; 4];
    for ch in 0..4 {
        q[ch] = (p[0][ch] + p[1][ch]) + (p[2][ch] + p[3][ch]);
    }
    q
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::occluders::tests::Lcg;

    /// The columns hold every entry once; scattering the texels that carry light gives what
    /// the whole gather gives, to float rounding, the rows reading them are exactly the rows
    /// that read a lit texel, each listed once, and finishing leaves the scratch clean for the
    /// next call (8-bit, 16-bit and f32 weights).
    #[test]
    fn the_columns_scatter_what_the_rows_gather() {
        let mut rng = Lcg(11);
        let n = 500;
        for (rays, most) in [(1024.0f32, 30.0), (1000.0, 30.0), (1024.0, 800.0)] {
            // Rows reading windows of 60 texels here and there.
            let mut source = TexelGather {
                row_start: vec![0],
                ..Default::default()
            };
            for r in 0..40u32 {
                source.rows.push(r * 12);
                let first = (rng.unit() * 440.0) as u32;
                for c in (first..first + 60).step_by(1 + (rng.unit() * 9.0) as usize) {
                    source.cols.push(c);
                    source
                        .values
                        .push((1 + (rng.unit() * most) as u32) as f32 / rays);
                }
                source.row_start.push(source.cols.len() as u32);
            }
            // One ray's weight, the unit the counts are found in.
            source.values[0] = 1.0 / rays;
            let g = PackedGather::new(&source, n);
            let kind = match (&g.weights, rays == 1024.0, most > 255.0) {
                (Weights::Counts { .. }, true, false) => "8-bit",
                (Weights::Counts16 { .. }, true, true) => "16-bit",
                (Weights::F32(_), false, _) => "f32",
                _ => panic!("{rays} rays, counts to {most}: unexpected storage"),
            };
            let columns = g.by_columns();
            assert_eq!(columns.col_start[n] as usize, source.cols.len());
            let mut sums = vec![[0.0f32; 4]; g.n_rows()];
            let mut marked = vec![false; g.n_rows()];
            let mut touched = Vec::new();
            for lit in [vec![100..250], vec![0..30, 300..480, 499..500]] {
                let mut direct = vec![[0.0f32; 3]; n];
                for r in &lit {
                    for d in &mut direct[r.clone()] {
                        *d = [rng.unit(), rng.unit(), rng.unit()];
                    }
                }
                let mut whole = vec![[0.0f32; 3]; n];
                g.add_to(&direct, &mut whole);
                let mut scattered = vec![[0.0f32; 3]; n];
                // A range without light adds nothing and says so.
                assert!(!columns.scatter(250..300, &direct, &mut sums));
                assert!(sums.iter().all(|s| *s == [0.0; 4]));
                for r in &lit {
                    assert!(columns.scatter(r.clone(), &direct, &mut sums));
                    columns.rows_reading(r.clone(), &mut marked, &mut touched);
                }
                let want: Vec<u32> = (0..g.n_rows() as u32)
                    .filter(|&i| {
                        let (a, b) = (
                            source.row_start[i as usize],
                            source.row_start[i as usize + 1],
                        );
                        source.cols[a as usize..b as usize]
                            .iter()
                            .any(|&c| lit.iter().any(|r| r.contains(&(c as usize))))
                    })
                    .collect();
                let mut got = touched.clone();
                got.sort_unstable();
                assert_eq!(got, want, "{kind}, {lit:?}");
                assert!(want.len() < g.n_rows());
                columns.finish(&g, &mut sums, &mut touched, &mut marked, &mut scattered);
                for (t, (a, b)) in scattered.iter().zip(&whole).enumerate() {
                    for ch in 0..3 {
                        assert!(
                            (a[ch] - b[ch]).abs() <= 1e-6 * b[ch].abs().max(1e-3),
                            "{kind}, texel {t}: {a:?} against {b:?}"
                        );
                    }
                }
                assert!(touched.is_empty() && marked.iter().all(|m| !m));
                assert!(sums.iter().all(|s| *s == [0.0; 4]));
            }
        }
    }

    /// A gather with tiles (format 2.6): the rows read each tile's mean, as the same gather
    /// with every tile entry spread over the tile's texels (weight / tile size each) reads
    /// their light, to float rounding; scattering each lit range's texels and then its tiles
    /// by column gives the same, and the rows listed are those reading a lit texel or tile.
    #[test]
    fn tile_columns_read_their_texels_mean_by_rows_and_by_columns() {
        let mut rng = Lcg(12);
        let n = 120;
        // Tiles of 4 texels over 0..100 (in two "surfaces" 0..60 and 60..100), a lone tile.
        let mut tiles = GatherTiles::default();
        for first in (0..100).step_by(4) {
            tiles.push(&[first, first + 1, first + 2, first + 3]);
        }
        tiles.push(&[110]);
        let n_tiles = tiles.len() as u32;
        let mut g = TexelGather {
            row_start: vec![0],
            tiles,
            ..Default::default()
        };
        for r in 0..30u32 {
            g.rows.push(r * 4);
            for c in 0..n as u32 + n_tiles {
                if rng.unit() >= 0.3 {
                    continue;
                }
                g.cols.push(c);
                g.values
                    .push((1 + (rng.unit() * 3.0) as u32) as f32 / 1024.0);
            }
            g.row_start.push(g.cols.len() as u32);
        }
        g.values[0] = 1.0 / 1024.0;
        // The same gather over texels alone.
        let mut spread = TexelGather {
            rows: g.rows.clone(),
            row_start: vec![0],
            ..Default::default()
        };
        for i in 0..g.rows.len() {
            let mut row: Vec<(u32, f32)> = Vec::new();
            for k in g.row_start[i] as usize..g.row_start[i + 1] as usize {
                let (texels, share) = g.column_texels(n, &g.cols[k]);
                row.extend(texels.iter().map(|&t| (t, g.values[k] * share as f32)));
            }
            spread.cols.extend(row.iter().map(|e| e.0));
            spread.values.extend(row.iter().map(|e| e.1));
            spread.row_start.push(spread.cols.len() as u32);
        }
        let packed = PackedGather::new(&g, n);
        assert!(packed.is_8bit());
        assert_eq!(packed.n_columns(), n + n_tiles as usize);
        let columns = packed.by_columns();
        let (mut sums, mut marked, mut touched) =
            (vec![[0.0f32; 4]; 30], vec![false; 30], Vec::new());
        for lit in [vec![0..30, 30..60], vec![60..100, 100..120]] {
            let mut direct = vec![[0.0f32; 3]; n];
            for r in &lit {
                for d in &mut direct[r.clone()] {
                    *d = [rng.unit(), rng.unit(), rng.unit()];
                }
            }
            let (mut rows, mut want, mut scattered) = (
                vec![[0.0f32; 3]; n],
                vec![[0.0f32; 3]; n],
                vec![[0.0f32; 3]; n],
            );
            packed.add_to(&direct, &mut rows);
            reference(&spread, &direct, &mut want);
            for r in &lit {
                let t = columns.tiles_of(r.clone());
                columns.scatter(r.clone(), &direct, &mut sums);
                columns.scatter_tiles(t.clone(), &direct, &mut sums);
                columns.rows_reading(r.clone(), &mut marked, &mut touched);
                columns.rows_reading(columns.tile_columns(t), &mut marked, &mut touched);
            }
            columns.finish(
                &packed,
                &mut sums,
                &mut touched,
                &mut marked,
                &mut scattered,
            );
            assert!(want.iter().filter(|w| w[0] > 0.0).count() >= 25, "{lit:?}");
            for t in 0..n {
                for ch in 0..3 {
                    let w = want[t][ch];
                    assert!(
                        (rows[t][ch] - w).abs() <= 1e-6 * w.max(1e-3),
                        "rows, texel {t}"
                    );
                    assert!(
                        (scattered[t][ch] - w).abs() <= 1e-6 * w.max(1e-3),
                        "columns, {t}"
                    );
                }
            }
        }
        // The tiles of a range of whole surfaces.
        assert_eq!(columns.tiles_of(0..60), 0..15);
        assert_eq!(columns.tiles_of(60..100), 15..25);
        assert_eq!(columns.tiles_of(100..120), 25..26);
    }

    #[test]
    fn simd_and_portable_row_sums_agree_bit_for_bit() {
        let mut rng = Lcg(7);
        let direct: Vec<[f32; 4]> = (0..300)
            .map(|_| [rng.unit(), rng.unit() * 10.0, rng.unit() * 0.01, 0.0])
            .collect();
        for len in [0usize, 1, 3, 4, 5, 17, 256] {
            let cols: Vec<u16> = (0..len).map(|_| (rng.unit() * 299.0) as u16).collect();
            let counts: Vec<u8> = (0..len).map(|_| 1 + (rng.unit() * 9.0) as u8).collect();
            let a = row_sum(&cols, &counts, &direct);
            let b = row_sum_portable(&cols, &counts, &direct);
            assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits), "length {len}");
        }
    }

    impl PackedGather {
        /// `add_to_padded` over unpadded direct light (allocates; tests only).
        fn add_to(&self, direct: &[[f32; 3]], out: &mut [[f32; 3]]) {
            let mut padded = vec![[0.0f32; 4]; self.n_columns()];
            pad_direct(direct, &mut padded);
            self.fill_tiles(&mut padded);
            self.add_to_padded(&padded, out);
        }
    }

    /// A gather of `rows` rows over `n` texels with weights `count / rays`.
    fn gather(rows: usize, n: usize, rays: u32, rng: &mut Lcg) -> TexelGather {
        let mut g = TexelGather {
            row_start: vec![0],
            ..Default::default()
        };
        for r in 0..rows {
            g.rows.push((r * 3) as u32);
            let mut col = 0u32;
            loop {
                col += 1 + (rng.unit() * 40.0) as u32;
                if col as usize >= n {
                    break;
                }
                let count = 1 + (rng.unit() * 30.0) as u32;
                g.cols.push(col);
                g.values.push((count as f64 / rays as f64) as f32);
            }
            g.row_start.push(g.cols.len() as u32);
        }
        g
    }

    /// The bundle's form summed in f64.
    fn reference(g: &TexelGather, direct: &[[f32; 3]], out: &mut [[f32; 3]]) {
        for (i, &row) in g.rows.iter().enumerate() {
            let mut s = [0.0f64; 3];
            for k in g.row_start[i] as usize..g.row_start[i + 1] as usize {
                let l = direct[g.cols[k] as usize];
                for ch in 0..3 {
                    s[ch] += g.values[k] as f64 * l[ch] as f64;
                }
            }
            for ch in 0..3 {
                out[row as usize][ch] = (out[row as usize][ch] as f64 + s[ch]) as f32;
            }
        }
    }

    /// `packed` applied to random direct light agrees with `g` summed in f64.
    fn matches_the_f64_sum(g: &TexelGather, packed: &PackedGather, n: usize, rng: &mut Lcg) {
        let l = direct(n, rng);
        let (mut a, mut b) = (vec![[0.0f32; 3]; n], vec![[0.0f32; 3]; n]);
        reference(g, &l, &mut a);
        packed.add_to(&l, &mut b);
        assert_close(&a, &b);
    }

    fn assert_close(a: &[[f32; 3]], b: &[[f32; 3]]) {
        for (x, y) in a.iter().flatten().zip(b.iter().flatten()) {
            assert!((x - y).abs() <= 2e-6 * x.abs().max(1.0), "{x} vs {y}");
        }
    }

    fn direct(n: usize, rng: &mut Lcg) -> Vec<[f32; 3]> {
        (0..n)
            .map(|_| [rng.unit(), 2.0 * rng.unit(), 0.5])
            .collect()
    }

    #[test]
    fn power_of_two_rays_pack_to_bytes_and_match_the_f64_sum() {
        let mut rng = Lcg(7);
        let n = 3000;
        let g = gather(200, n, 1024, &mut rng);
        let packed = PackedGather::new(&g, n);
        assert!(packed.is_8bit());
        assert_eq!(packed.bytes(), 3 * g.values.len() + 4 * (200 + 201));
        // The 8-bit form sums exactly what the f32 form sums when the unit is a power of two.
        sums_what_the_f32_form_sums(&g, &packed, n, &mut rng);
    }

    /// Counts above a byte (a texel sending hundreds of its rays to one texel) keep 16 bits
    /// instead of falling back to f32, and sum exactly what the f32 form sums.
    #[test]
    fn counts_above_a_byte_pack_to_16_bits_and_sum_what_the_f32_form_sums() {
        let mut rng = Lcg(5);
        let n = 3000;
        let mut g = gather(200, n, 1024, &mut rng);
        for k in (0..g.values.len()).step_by(97) {
            g.values[k] = (256 + (rng.unit() * 700.0) as u32) as f32 / 1024.0;
        }
        let packed = PackedGather::new(&g, n);
        assert!(matches!(packed.weights, Weights::Counts16 { unit: u, .. } if u == 1.0 / 1024.0));
        assert_eq!(packed.bytes(), 4 * g.values.len() + 4 * (200 + 201));
        sums_what_the_f32_form_sums(&g, &packed, n, &mut rng);
    }

    /// `packed` applied to random direct light agrees with `g` summed in f64, and equals bit
    /// for bit the same entries with f32 weights (counts of a power-of-two unit).
    fn sums_what_the_f32_form_sums(
        g: &TexelGather,
        packed: &PackedGather,
        n: usize,
        rng: &mut Lcg,
    ) {
        let l = direct(n, rng);
        let (mut a, mut b) = (vec![[0.1f32; 3]; n], vec![[0.1f32; 3]; n]);
        reference(g, &l, &mut a);
        packed.add_to(&l, &mut b);
        assert_close(&a, &b);
        let wide = PackedGather {
            weights: Weights::F32(g.values.clone()),
            ..packed.clone()
        };
        let mut c = vec![[0.1f32; 3]; n];
        wide.add_to(&l, &mut c);
        assert_eq!(b, c);
    }

    #[test]
    fn other_ray_counts_agree_to_rounding() {
        let mut rng = Lcg(11);
        let n = 2000;
        let g = gather(100, n, 1000, &mut rng);
        let packed = PackedGather::new(&g, n);
        matches_the_f64_sum(&g, &packed, n, &mut rng);
    }

    #[test]
    fn weights_off_a_common_unit_and_large_layouts_keep_the_wide_form() {
        let mut rng = Lcg(3);
        let n = 70_000;
        let mut g = gather(20, n, 1024, &mut rng);
        g.values[5] = 0.123_456_7;
        let packed = PackedGather::new(&g, n);
        assert!(!packed.is_8bit());
        assert_eq!(
            packed.bytes(),
            8 * g.values.len() + 4 * (g.rows.len() + g.row_start.len())
        );
        matches_the_f64_sum(&g, &packed, n, &mut rng);
    }

    #[test]
    fn counts_above_a_byte_and_empty_gathers_are_handled() {
        assert_eq!(gather_counts(&[]), None);
        assert_eq!(gather_counts(&[0.0, 0.0]), None);
        assert_eq!(gather_counts(&[0.5, 1.0]), Some((0.5, vec![1, 2])));
        assert_eq!(gather_counts(&[1.0, 256.0]), None);
        assert_eq!(gather_counts_u16(&[1.0, 256.0]), Some((1.0, vec![1, 256])));
        assert_eq!(gather_counts_u16(&[1.0, 65_536.0]), None);
        assert_eq!(gather_counts_u16(&[0.5, 0.7]), None);
        assert_eq!(
            gather_counts(&[0.25, 0.0, 0.75]),
            Some((0.25, vec![1, 0, 3]))
        );
    }
}
