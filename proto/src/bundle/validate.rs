//! [`Bundle::validate`]: every index, size and rank of a bundle checked against its data, so
//! the runtime can index without checks. `decode` runs it; a hand-built bundle can too.

use super::*;

impl Bundle {
    /// Checks every index, size and rank against the data (what `decode` runs).
    pub fn validate(&self) -> Result<(), BundleError> {
        let bad = |m: String| Err(BundleError::Invalid(m));
        let n_texels = self.layout.n_texels() as u64;
        // What decoding guarantees by construction, re-checked for bundles built by hand.
        let layout = &self.layout;
        let n = layout.positions.len();
        if layout.normals.len() != n || layout.albedo.len() != n || layout.texel_size.len() != n {
            return bad(
                "layout: positions, normals, albedo and texel sizes differ in length".into(),
            );
        }
        let mut next = 0u64;
        for surface in &layout.surfaces {
            if surface.texel_offset as u64 != next {
                return bad(format!(
                    "layout: surface {} is not contiguous",
                    surface.name
                ));
            }
            next += surface.texel_count as u64;
        }
        if next != n as u64 {
            return bad("layout: surfaces do not cover the texels".into());
        }
        let mut matrices: Vec<&Matrix> = Vec::new();
        for s in &self.shapes {
            matrices.extend([&s.u_b, &s.t_db]);
            matrices.extend(s.openings.iter().map(|o| &o.u_r));
        }
        match &self.transport {
            Some(TransportOps::Lightfield(e)) => matrices.extend(e.iter().map(|e| &e.matrix)),
            Some(TransportOps::Traced(e)) => matrices.extend(e.iter().map(|e| &e.matrix)),
            Some(TransportOps::Compact(e)) => matrices.extend(e.iter().flat_map(|e| [&e.y, &e.z])),
            Some(TransportOps::Factored(f)) => {
                matrices.extend(f.bases.iter().map(|b| &b.q));
                matrices.extend(f.entries.iter().flat_map(|e| [&e.y, &e.z]));
            }
            None => {}
        }
        if let Some(d) = &self.drt {
            matrices.extend(d.clutter.iter().map(|c| &c.t_dc));
            matrices.extend(d.entries.iter().map(|e| &e.matrix));
        }
        if let Some(p) = &self.probes {
            matrices.extend(p.entries.iter().map(|e| &e.matrix));
            matrices.extend(p.entries.iter().filter_map(|e| e.mix.as_ref()));
        }
        if matrices
            .iter()
            .any(|m| m.data.len() as u64 != m.rows as u64 * m.cols as u64)
        {
            return bad("a matrix holds the wrong number of values".into());
        }
        for (k, s) in self.shapes.iter().enumerate() {
            let n = s.u_b.rows;
            if s.t_db.cols != n || s.t_db.rows != s.u_b.cols {
                return bad(format!(
                    "shape {k}: U_b is {}×{}, T_d→b is {}×{}",
                    s.u_b.rows, s.u_b.cols, s.t_db.rows, s.t_db.cols
                ));
            }
            // Ranks never exceed texel counts, so scratch sizes are bounded by real data.
            if s.u_b.cols > n || n as u64 > n_texels {
                return bad(format!(
                    "shape {k}: rank {} exceeds its {n} texels",
                    s.u_b.cols
                ));
            }
            for o in &s.openings {
                if o.face > 5 || o.u_r.rows != n || o.u_r.cols > n {
                    return bad(format!(
                        "shape {k}: opening operator does not match the shape"
                    ));
                }
            }
        }
        let mut next_free = 0u64;
        for b in &self.blocks {
            let Some(shape) = self.shapes.get(b.shape as usize) else {
                return bad(format!("block {}: shape {} does not exist", b.id, b.shape));
            };
            if b.texel_offset as u64 + shape.u_b.rows as u64 > n_texels {
                return bad(format!("block {}: texel range past the layout", b.id));
            }
            // Ascending, disjoint ranges: the runtime works on blocks independently.
            if (b.texel_offset as u64) < next_free {
                return bad(format!(
                    "block {}: texel range overlaps or precedes the previous block's",
                    b.id
                ));
            }
            next_free = b.texel_offset as u64 + shape.u_b.rows as u64;
            if let Some(sym) = &b.symmetry {
                if let Err(e) = sym.check(shape) {
                    return bad(format!("block {}: {e}", b.id));
                }
            }
        }
        let block_shape = |i: u32| -> Option<&ShapeOps> {
            self.blocks
                .get(i as usize)
                .map(|b| &self.shapes[b.shape as usize])
        };
        match &self.transport {
            Some(TransportOps::Lightfield(entries)) => {
                for e in entries {
                    let (Some(target), Some(source)) =
                        (block_shape(e.target_block), block_shape(e.source_block))
                    else {
                        return bad("transport: entry names a missing block".into());
                    };
                    let Some(opening) = target.openings.iter().find(|o| o.face == e.target_face)
                    else {
                        return bad("transport: entry names an opening the shape lacks".into());
                    };
                    if e.matrix.rows != opening.u_r.cols || e.matrix.cols != source.u_b.cols {
                        return bad("transport: propagation matrix has the wrong size".into());
                    }
                }
            }
            Some(TransportOps::Traced(entries)) => {
                for e in entries {
                    let (Some(target), Some(source)) =
                        (block_shape(e.target_block), block_shape(e.source_block))
                    else {
                        return bad("transport: entry names a missing block".into());
                    };
                    if e.matrix.rows != target.u_b.rows || e.matrix.cols != source.u_b.cols {
                        return bad("transport: traced matrix has the wrong size".into());
                    }
                }
            }
            Some(TransportOps::Compact(entries)) => {
                check_compact(entries, &block_shape, |_, rank| rank)?;
            }
            Some(TransportOps::Factored(f)) => {
                for (k, b) in f.bases.iter().enumerate() {
                    if k > 0 && f.bases[k - 1].source_block >= b.source_block {
                        return bad("transport: source bases not ascending by block".into());
                    }
                    let Some(source) = block_shape(b.source_block) else {
                        return bad(format!(
                            "transport: source basis {k} names missing block {}",
                            b.source_block
                        ));
                    };
                    if b.q.cols != source.u_b.cols || b.q.rows == 0 || b.q.rows > b.q.cols {
                        return bad(format!(
                            "transport: source basis of block {} is {}×{}, the block's rank is {}",
                            b.source_block, b.q.rows, b.q.cols, source.u_b.cols
                        ));
                    }
                }
                check_compact(&f.entries, &block_shape, |s, rank| f.width(s, rank))?;
            }
            None => {}
        }
        if let Some(f) = &self.full {
            if f.n as u64 != n_texels || f.row_start.len() as u64 != n_texels + 1 {
                return bad("full: size does not match the layout".into());
            }
            if f.row_start.first() != Some(&0)
                || f.row_start.windows(2).any(|w| w[1] < w[0])
                || *f.row_start.last().unwrap() as usize != f.cols.len()
                || f.cols.len() != f.values.len()
            {
                return bad("full: row starts are inconsistent".into());
            }
            if f.cols.iter().any(|c| *c >= f.n) || f.values.iter().any(|v| !v.is_finite()) {
                return bad("full: column index or value out of range".into());
            }
        }
        if let Some(d) = &self.drt {
            let n_blocks = self.blocks.len() as u64;
            let n_clutter = d.clutter.len() as u64;
            for (k, c) in d.clutter.iter().enumerate() {
                if c.texel_offset as u64 + c.t_dc.cols as u64 > n_texels
                    || c.t_dc.rows > c.t_dc.cols
                {
                    return bad(format!("drt: clutter {k} texel range past the layout"));
                }
            }
            for (k, e) in d.entries.iter().enumerate() {
                let cols = match e.source {
                    DeltaSource::Block(b) if (b as u64) < n_blocks => {
                        self.shapes[self.blocks[b as usize].shape as usize].u_b.cols
                    }
                    DeltaSource::Clutter(c) if (c as u64) < n_clutter => {
                        d.clutter[c as usize].t_dc.rows
                    }
                    DeltaSource::Direct { first, count }
                        if first as u64 + count as u64 <= n_texels =>
                    {
                        count
                    }
                    _ => return bad(format!("drt: entry {k} names a missing source")),
                };
                let (inner, mix_ok) = match &e.mix {
                    Some(mix) => (mix.rows, mix.cols == cols),
                    None => (cols, true),
                };
                if e.matrix.rows as usize != e.rows.len() || e.matrix.cols != inner || !mix_ok {
                    return bad(format!("drt: entry {k} matrix has the wrong size"));
                }
                if e.rows.iter().any(|r| *r as u64 >= n_texels)
                    || e.rows.windows(2).any(|w| w[1] <= w[0])
                {
                    return bad(format!("drt: entry {k} rows out of range or not ascending"));
                }
            }
            if d.buried.iter().any(|r| *r as u64 >= n_texels) {
                return bad("drt: buried texel out of range".into());
            }
            // Block texels: the ranges the blocks' shapes cover (sorted by start, with the
            // largest end so far, so each lookup is a binary search).
            let mut ranges: Vec<(u64, u64)> = self
                .blocks
                .iter()
                .map(|b| {
                    let n = self.shapes.get(b.shape as usize).map_or(0, |s| s.u_b.rows);
                    (b.texel_offset as u64, b.texel_offset as u64 + n as u64)
                })
                .collect();
            ranges.sort_unstable();
            let mut reach = 0;
            for r in ranges.iter_mut() {
                reach = reach.max(r.1);
                r.1 = reach;
            }
            let in_block = |t: u32| {
                let i = ranges.partition_point(|(start, _)| *start <= t as u64);
                i > 0 && ranges[i - 1].1 > t as u64
            };
            if d.replaced.iter().any(|r| !in_block(*r))
                || d.replaced.windows(2).any(|w| w[1] <= w[0])
            {
                return bad("drt: replaced texels are not ascending block texels".into());
            }
            if let Some(g) = &d.direct_gather {
                let starts: Vec<u32> = self
                    .layout
                    .surfaces
                    .iter()
                    .map(|s| s.texel_offset)
                    .collect();
                if let Some(why) = g.tiles.check(&starts, n_texels) {
                    return bad(format!("drt: {why}"));
                }
                // Columns past the texels are tiles.
                let n_columns = n_texels + g.tiles.len() as u64;
                let ok = g.row_start.len() == g.rows.len() + 1
                    && g.row_start.first() == Some(&0)
                    && g.row_start.windows(2).all(|w| w[1] >= w[0])
                    && g.row_start.last().map(|l| *l as usize) == Some(g.cols.len())
                    && g.cols.len() == g.values.len()
                    && g.rows.windows(2).all(|w| w[1] > w[0])
                    && g.rows.iter().all(|r| (*r as u64) < n_texels)
                    && g.cols.iter().all(|c| (*c as u64) < n_columns)
                    && g.values.iter().all(|v| v.is_finite());
                if !ok {
                    return bad("drt: direct gather is inconsistent".into());
                }
            }
        }
        if let Some(p) = &self.probes {
            let cells = p
                .dims
                .iter()
                .try_fold(1u64, |acc, d| acc.checked_mul(*d as u64))
                .unwrap_or(u64::MAX);
            if !(p.spacing.is_finite() && p.spacing > 0.0)
                || p.origin.iter().any(|x| !x.is_finite())
            {
                return bad("probes: bad grid origin or spacing".into());
            }
            if cells != p.slot.len() as u64 || p.n_probes as u64 > cells {
                return bad("probes: grid size does not match its slots".into());
            }
            if p.slot.iter().any(|s| *s != u32::MAX && *s >= p.n_probes) {
                return bad("probes: slot names a missing probe".into());
            }
            let n_clutter = self.drt.as_ref().map_or(0, |d| d.clutter.len()) as u64;
            let rows_max = p.n_probes as u64 * crate::sh::SH_COEFFS as u64;
            for (k, e) in p.entries.iter().enumerate() {
                let cols = match e.source {
                    DeltaSource::Block(b) if (b as u64) < self.blocks.len() as u64 => {
                        self.shapes[self.blocks[b as usize].shape as usize].u_b.cols
                    }
                    DeltaSource::Clutter(c) if (c as u64) < n_clutter => {
                        self.drt.as_ref().unwrap().clutter[c as usize].t_dc.rows
                    }
                    _ => return bad(format!("probes: entry {k} names a missing source")),
                };
                let (inner, mix_ok) = match &e.mix {
                    Some(mix) => (mix.rows, mix.cols == cols),
                    None => (cols, true),
                };
                if e.matrix.rows as usize != e.rows.len() || e.matrix.cols != inner || !mix_ok {
                    return bad(format!("probes: entry {k} matrix has the wrong size"));
                }
                if e.rows.iter().any(|r| *r as u64 >= rows_max)
                    || e.rows.windows(2).any(|w| w[1] <= w[0])
                {
                    return bad(format!(
                        "probes: entry {k} rows out of range or not ascending"
                    ));
                }
            }
        }
        if let Some(sh) = &self.sh {
            let clutter = self.drt.as_ref().map_or(&[][..], |d| &d.clutter[..]);
            let width = |source: DeltaSource| match source {
                DeltaSource::Block(b) => self
                    .blocks
                    .get(b as usize)
                    .map(|blk| self.shapes[blk.shape as usize].u_b.cols),
                DeltaSource::Clutter(c) => clutter.get(c as usize).map(|c| c.t_dc.rows),
                DeltaSource::Direct { .. } => None, // SH entries read b and c only
            };
            sh_responses::validate(sh, n_texels, &width)?;
        }
        if let Some(grids) = &self.dnrt {
            for (k, g) in grids.iter().enumerate() {
                g.validate()
                    .map_err(|e| BundleError::Invalid(e.to_string()))?;
                if grids[..k].iter().any(|o| o.object == g.object) {
                    return bad(format!("dnrt: two grids for object \"{}\"", g.object));
                }
            }
        }
        if let Some(rooms) = &self.rooms {
            rooms
                .check(self.blocks.len(), self.layout.surfaces.len())
                .map_err(BundleError::Invalid)?;
        }
        dynamic_shapes::check(&self.dynamic_shapes).map_err(BundleError::Invalid)?;
        let mut previous = None;
        for a in &self.surface_atlases {
            let Some(s) = self.layout.surfaces.get(a.surface as usize) else {
                return bad(format!("lightmap: surface {} out of range", a.surface));
            };
            if previous.is_some_and(|p| p >= a.surface) {
                return bad("lightmap: surfaces not strictly ascending".to_string());
            }
            previous = Some(a.surface);
            if a.texel_xy.len() != s.texel_count as usize
                || a.texel_xy
                    .iter()
                    .any(|xy| xy[0] >= a.width || xy[1] >= a.height)
            {
                return bad(format!(
                    "lightmap: surface \"{}\" texels out of its image",
                    s.name
                ));
            }
        }
        Ok(())
    }
}

/// Compact transport entries (kinds 2 and 3): ascending targets, ascending existing sources,
/// `y` texels_target × k with k ≤ texels, `z` k × Σ `width(source, source rank)`.
fn check_compact<'a>(
    entries: &[CompactEntry],
    block_shape: &impl Fn(u32) -> Option<&'a ShapeOps>,
    width: impl Fn(u32, u32) -> u32,
) -> Result<(), BundleError> {
    let bad = |m: String| Err(BundleError::Invalid(m));
    for (k, e) in entries.iter().enumerate() {
        if k > 0 && entries[k - 1].target_block >= e.target_block {
            return bad("transport: compact entries not ascending by target".into());
        }
        let Some(target) = block_shape(e.target_block) else {
            return bad("transport: entry names a missing block".into());
        };
        if e.sources.windows(2).any(|w| w[1] <= w[0]) {
            return bad("transport: compact sources not ascending".into());
        }
        let mut cols = 0u64;
        for s in &e.sources {
            let Some(source) = block_shape(*s) else {
                return bad("transport: entry names a missing block".into());
            };
            cols += u64::from(width(*s, source.u_b.cols));
        }
        if e.y.rows != target.u_b.rows
            || e.z.rows != e.y.cols
            || e.z.cols as u64 != cols
            || e.y.cols > e.y.rows
        {
            return bad(format!(
                "transport: compact entry {k} has the wrong size (y {}×{}, z {}×{})",
                e.y.rows, e.y.cols, e.z.rows, e.z.cols
            ));
        }
    }
    Ok(())
}
