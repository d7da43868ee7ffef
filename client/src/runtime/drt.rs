//! [`Method::Drt`](super::Method::Drt) (delta radiance transfer) beyond MRT: the clutter
//! coefficients (DRT step 2), the delta entries (step 3), the `replaced` texels of an exact
//! scene gather and the exact clutter gather. `source_coefficients`, the `x` a delta entry
//! multiplies, also serves the probe entries and the SH responses.
//!
//! Units: `c` are the clutter objects' reduced coefficients of direct radiance, like the
//! blocks' `b`; every term here is albedo-free indirect radiance added to `out`, the albedo
//! comes last (`multiply_albedo`).
//!
//! Invariants: every stage is a no-op without a DRT section (or an exact gather); entries are
//! applied in the bundle's order, so the result is deterministic; nothing allocates (scratch is
//! taken from the runtime and given back).

use std::ops::Range;

use lightfarm_proto::bundle::DeltaSource;

use crate::packed_gather::{pad_direct, texel_units, GatherColumns, PackedGather};

use super::incremental::units_of_rows;
use super::kernels::{group, planar, scatter_matvec, set_matvec};
use super::Runtime;

impl Runtime {
    /// DRT step 2, after [`Runtime::project_blocks`] (which fills `ld`): projects direct light
    /// on every clutter object to its coefficients `c`. Does nothing without a DRT section.
    pub(super) fn project_clutter(&mut self) {
        let n = self.n_texels;
        let Runtime {
            bundle,
            ld,
            clutter_coef,
            c,
            ops,
            scratch,
            reach,
            ..
        } = self;
        let Some(drt) = &bundle.drt else { return };
        // 2. c_j = t_dc · l_d^j.
        for (j, ((clutter, t_dc), &(start, m))) in drt
            .clutter
            .iter()
            .zip(&ops.clutter)
            .zip(clutter_coef.iter())
            .enumerate()
        {
            if reach.as_ref().is_some_and(|r| !r.clutter[j]) {
                c[start..start + 3 * m].fill(0.0);
                continue;
            }
            let x = planar(ld, n, clutter.texel_offset as usize, t_dc.cols());
            set_matvec(&mut c[start..start + 3 * m], m, t_dc, x, scratch);
        }
    }

    /// The coefficients a delta entry's matrix multiplies: the source block's `b`, the source
    /// clutter object's `c` or a texel range of the direct light, first `cols` of each channel.
    /// Needs `ld` and `b` (and `c`) filled.
    #[inline]
    pub(super) fn source_coefficients(&self, source: DeltaSource, cols: usize) -> [&[f32]; 3] {
        match source {
            DeltaSource::Block(k) => {
                let s = &self.blocks[k as usize];
                group(&self.b, s.coef_start, s.rank, cols)
            }
            DeltaSource::Clutter(j) => {
                let (start, m) = self.clutter_coef[j as usize];
                group(&self.c, start, m, cols)
            }
            DeltaSource::Direct { first, .. } => {
                planar(&self.ld, self.n_texels, first as usize, cols)
            }
        }
    }

    /// Whether a delta entry's source has non-zero input (always, outside
    /// [`Runtime::apply_delta`]); an unreached source's coefficients are exact zeros.
    #[inline]
    pub(super) fn source_reached(&self, source: DeltaSource) -> bool {
        let Some(reach) = &self.reach else {
            return true;
        };
        match source {
            DeltaSource::Block(k) => reach.blocks[k as usize],
            DeltaSource::Clutter(j) => reach.clutter[j as usize],
            DeltaSource::Direct { first, count } => {
                let n = self.n_texels;
                let (first, count) = (first as usize, count as usize);
                (0..3).any(|ch| {
                    let range = &self.ld[ch * n + first..ch * n + first + count];
                    range.iter().any(|v| !(*v == 0.0))
                })
            }
        }
    }

    /// DRT step 3, after [`Runtime::project_blocks`] and [`Runtime::project_clutter`]: adds
    /// every delta entry (albedo-free). Does nothing without a DRT section.
    pub(super) fn add_drt_deltas(&mut self, out: &mut [[f32; 3]]) {
        self.add_deltas_of(out, Deltas::All);
    }

    /// [`Runtime::add_drt_deltas`] over the entries `which` selects.
    pub(super) fn add_deltas_of(&mut self, out: &mut [[f32; 3]], which: Deltas) {
        let Some(drt) = &self.bundle.drt else { return };
        let mut scratch = std::mem::take(&mut self.scratch);
        // Relighting by the change at one bounce: the rows written are marked.
        let mut sparse = if self.sparse.as_ref().is_some_and(|s| s.active) {
            self.sparse.take()
        } else {
            None
        };
        // 3. out[rows[i]] += matrix.row(i) · (b_source or c_source), in entry order. Relighting
        // by the change, only the entries whose sources read a reached unit are looked at
        // (not a pass over every entry of the level).
        let candidates = sparse.as_mut().map(|s| s.reached_entries());
        debug_assert!(candidates.as_ref().is_none_or(|c| {
            (0..drt.entries.len())
                .all(|i| !self.source_reached(drt.entries[i].source) || c.contains(&(i as u32)))
        }));
        let all = 0..drt.entries.len() as u32;
        let order: &mut dyn Iterator<Item = u32> = match &candidates {
            Some(c) => &mut c.iter().copied(),
            None => &mut all.clone(),
        };
        for i in order {
            let i = i as usize;
            let (e, m, mix) = (&drt.entries[i], &self.ops.deltas[i], &self.ops.delta_mix[i]);
            let direct = matches!(e.source, DeltaSource::Direct { .. });
            let selected = match which {
                Deltas::All => true,
                Deltas::OfCoefficients => !direct,
                Deltas::OfLight => direct,
            };
            if !selected || !self.source_reached(e.source) {
                continue;
            }
            if let Some(sparse) = sparse.as_mut() {
                sparse.mark_entry_rows(i);
            }
            match mix {
                None => {
                    let x = self.source_coefficients(e.source, m.cols());
                    scatter_matvec(out, &e.rows, m, x, &mut scratch);
                }
                Some(mix) => {
                    // Low rank: y = mix · x (k values per channel), then rows += matrix · y.
                    let k = mix.rows();
                    let (y, rest) = scratch.split_at_mut(3 * k);
                    let x = self.source_coefficients(e.source, mix.cols());
                    set_matvec(y, k, mix, x, rest);
                    scatter_matvec(out, &e.rows, m, planar(y, k, 0, k), rest);
                }
            }
        }
        self.scratch = scratch;
        if let Some(mut sparse) = sparse {
            sparse.give_back_entries(candidates.unwrap_or_default());
            self.sparse = Some(sparse);
        }
    }

    /// DRT with `scene_gather: exact`: texels whose light is the gather alone lose MRT's.
    pub(super) fn drop_replaced(&self, out: &mut [[f32; 3]]) {
        if let Some(d) = &self.bundle.drt {
            for &x in &d.replaced {
                out[x as usize] = [0.0; 3];
            }
        }
    }

    /// Makes the exact gather by column ([`GatherByChange`]) that relighting by the change
    /// reads, if the bundle has a gather and it is not made yet.
    pub(super) fn prepare_gather_by_change(&mut self) {
        let Some(g) = &self.ops.gather else { return };
        if self.gather_by_change.is_none() {
            let units = self.texel_units();
            self.gather_by_change = Some(GatherByChange::new(g, &units, self.n_texels));
        }
    }

    /// DRT exact clutter gather: sparse rows over the direct light (albedo-free). Relighting by
    /// the change ([`Runtime::apply_delta`]), only the entries reading a texel of a reached
    /// block or clutter object whose light is not zero run, by column ([`GatherColumns`]):
    /// the gather's cost follows the changed texels, not the level nor the rows they feed.
    pub(super) fn add_direct_gather(&mut self, direct: &[[f32; 3]], out: &mut [[f32; 3]]) {
        if self.reach.is_some() {
            self.prepare_gather_by_change();
        }
        let Some(g) = &self.ops.gather else { return };
        let Some(reach) = &self.reach else {
            pad_direct(direct, &mut self.direct_padded);
            g.fill_tiles(&mut self.direct_padded);
            g.add_to_padded(&self.direct_padded, out);
            return;
        };
        let Some(by_change) = self.gather_by_change.as_mut() else {
            return;
        };
        let n_blocks = reach.blocks.len();
        let reached = (0..n_blocks)
            .filter(|&k| reach.blocks[k])
            .chain(
                (0..reach.clutter.len())
                    .filter(|&j| reach.clutter[j])
                    .map(|j| n_blocks + j),
            )
            .chain(by_change.units..by_change.ranges.len());
        let GatherByChange {
            columns,
            ranges,
            tiles,
            unit_rows,
            row_units,
            lit_units,
            sums,
            touched,
            marked,
            ..
        } = by_change;
        lit_units.clear();
        for u in reached {
            let lit = columns.scatter(ranges[u].clone(), direct, sums);
            if columns.scatter_tiles(tiles[u].clone(), direct, sums) | lit {
                lit_units.push(u as u32);
                for &r in unit_rows.get(u) {
                    if !std::mem::replace(&mut marked[r as usize], true) {
                        touched.push(r);
                    }
                }
            }
        }
        if let Some(sparse) = self.sparse.as_mut().filter(|s| s.active) {
            for &u in lit_units.iter() {
                sparse.mark_units(row_units.get(u as usize));
            }
        }
        columns.finish(g, sums, touched, marked, out);
    }
}

/// Which delta entries [`Runtime::add_deltas_of`] adds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Deltas {
    All,
    /// Entries whose source is a block's or clutter object's coefficients.
    OfCoefficients,
    /// Entries over a texel range of the light (`DeltaSource::Direct`, the exact clutter
    /// gather in low-rank form).
    OfLight,
}

/// The exact gather's state when relighting by the change: its entries by column, the texel
/// ranges of the units (blocks, clutter objects, then the runs of texels in neither, which
/// every call scans), the rows reading each unit and one application's per-row sums (zero
/// between calls).
#[derive(Clone, Debug)]
pub(super) struct GatherByChange {
    columns: GatherColumns,
    ranges: Vec<Range<usize>>,
    /// Per unit, the gather's tiles on its texels.
    tiles: Vec<Range<usize>>,
    /// Units given (blocks and clutter objects); `ranges[units..]` are the texels in neither.
    units: usize,
    /// Per unit, the rows reading one of its texels (listed when the unit carries light).
    unit_rows: Ragged,
    /// Per unit, the units of those rows' texels, each once in the order the rows first reach
    /// them (what this call writes when the unit carries light).
    row_units: Ragged,
    /// Scratch: the units that carried light this call.
    lit_units: Vec<u32>,
    sums: Vec<[f32; 4]>,
    touched: Vec<u32>,
    marked: Vec<bool>,
}

impl GatherByChange {
    fn new(gather: &PackedGather, units: &[Range<usize>], n_texels: usize) -> GatherByChange {
        let (columns, n_rows) = (gather.by_columns(), gather.n_rows());
        let (ranges, unit_of) = texel_units(units, n_texels);
        let tiles: Vec<Range<usize>> = ranges.iter().map(|r| columns.tiles_of(r.clone())).collect();
        let mut marked = vec![false; n_rows];
        let mut unit_rows = Ragged::default();
        for (r, t) in ranges.iter().zip(&tiles) {
            let first = unit_rows.items.len();
            columns.rows_reading(r.clone(), &mut marked, &mut unit_rows.items);
            columns.rows_reading(
                columns.tile_columns(t.clone()),
                &mut marked,
                &mut unit_rows.items,
            );
            for &i in &unit_rows.items[first..] {
                marked[i as usize] = false;
            }
            unit_rows.start.push(unit_rows.items.len() as u32);
        }
        let row_texels: Vec<u32> = (0..n_rows).map(|i| gather.row_texel(i) as u32).collect();
        let texels_of = |u: usize| -> Vec<u32> {
            unit_rows
                .get(u)
                .iter()
                .map(|&i| row_texels[i as usize])
                .collect()
        };
        let lists: Vec<Vec<u32>> = (0..ranges.len()).map(texels_of).collect();
        let (items, start) = units_of_rows(lists.iter().map(Vec::as_slice), &unit_of, ranges.len());
        let row_units = Ragged { items, start };
        GatherByChange {
            row_units,
            lit_units: Vec::new(),
            columns,
            ranges,
            tiles,
            units: units.len(),
            unit_rows,
            sums: vec![[0.0; 4]; n_rows],
            touched: Vec::new(),
            marked,
        }
    }
}

/// Lists of `u32` stored end to end: list `i` is `items[start[i] .. start[i + 1]]`.
#[derive(Clone, Debug)]
struct Ragged {
    items: Vec<u32>,
    start: Vec<u32>,
}

impl Default for Ragged {
    fn default() -> Ragged {
        Ragged {
            items: Vec::new(),
            start: vec![0],
        }
    }
}

impl Ragged {
    fn get(&self, i: usize) -> &[u32] {
        &self.items[self.start[i] as usize..self.start[i + 1] as usize]
    }
}
