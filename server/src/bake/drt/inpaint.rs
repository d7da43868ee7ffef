//! Transport inpainting (paper 000 §5) of buried block texels: texels inside clutter (or whose
//! rays left through a back face) get, per source, the average of their nearest valid
//! neighbours' shadowed transport (`U + ΔU`) minus their own unshadowed transport `U`, so their
//! light continues the face's; with no valid neighbour on the face they get exactly `−U`
//! (they are dark, never NaN).
//!
//! Sources are every block whose MRT transport reaches the target, not only those with delta
//! rows. With `scene_gather: exact`, a buried texel next to a gathered one copies the first such
//! neighbour's gather instead (its light is the gather alone).
//!
//! Invariant: neighbours are searched in rings of growing radius on the same face, in a fixed
//! order, so the result is deterministic. A bake keeps the transport into the blocks
//! [`inpainting_targets`] marks; [`inpaint`] reads it into the blocks holding a buried texel
//! only, one block at a time (so a cached transport is read for them alone, and never all at
//! once).

use std::collections::BTreeMap;

use lightfarm_proto::scene::{Opening, Scene};

use crate::bake::drt::build::DrtInputs;
use crate::bake::drt::lit_source::LitSource;
use crate::bake::drt::rows::{add_row, RowsBySource};
use crate::bake::drt::sight::ClutterSight;
use crate::bake::scene::geometry::Geometry;
use crate::bake::transport::source::TransportUnavailable;

/// Per block: whether [`inpaint`] may read the MRT transport into it, decided before any ray
/// so that a bake can drop the rest of the transport first: whether clutter may be in sight
/// from the block ([`ClutterSight::block_may_see`]). Only blocks holding a buried texel are
/// inpainted, and a block texel is buried when it lies in a clutter box (then the box, a
/// sight goal grown by the burial test's margin, meets the block, and the walk starts in a
/// goal's block) or when its rays met a back face (then it was traced, which only texels in
/// clutter's sight are).
pub fn inpainting_targets(
    scene: &Scene,
    openings: &[[Option<Opening>; 6]],
    g: &Geometry,
) -> Vec<bool> {
    let sight = ClutterSight::new(scene, openings, g);
    (0..scene.blocks.len())
        .map(|b| sight.block_may_see(b))
        .collect()
}

/// Inpaints the buried block texels (`buried`, by global texel) of every target block into
/// `per_target` (or `gathered`), reading the MRT transport into each block with a buried texel
/// from `inputs.mrt`, one block at a time (a large level's would not fit beside the DRT
/// operators being built); `clutter_widths` are the DRT clutter objects' basis sizes.
/// Counts texels without a valid neighbour in `without_neighbours`.
pub fn inpaint(
    inputs: &DrtInputs,
    clutter_widths: &[usize],
    per_target: &mut [RowsBySource],
    buried: &[bool],
    gathered: &mut BTreeMap<u32, Vec<(u32, u32)>>,
    without_neighbours: &mut usize,
) -> Result<(), TransportUnavailable> {
    let (g, shapes) = (inputs.geometry, inputs.shapes);
    let n_blocks = inputs.scene.blocks.len();
    let mut only = vec![false; n_blocks];
    for (target, map) in per_target.iter_mut().enumerate() {
        let range = g.block_texels[target].clone();
        // Only blocks with a buried texel have anything to inpaint (the source search below
        // passes over the whole transport, so doing it for every block is quadratic).
        if !buried[range.clone()].iter().any(|b| *b) {
            continue;
        }
        // The transport into this block alone.
        only[target] = true;
        let mrt = inputs.mrt.into_targets(&only)?;
        only[target] = false;
        // Every source whose MRT transport reaches the target, not only those with delta rows:
        // a buried texel must cancel light arriving from neighbouring blocks too (a room
        // wholly inside a clutter box still receives MRT light through its openings).
        let mut sources: Vec<LitSource> = map.keys().copied().collect();
        for b in 0..n_blocks {
            let key = LitSource::Block(b as u32);
            if mrt.reaches(shapes, target, b) && !sources.contains(&key) {
                sources.push(key);
            }
        }
        for s in g
            .surfaces
            .iter()
            .filter(|s| s.texel_offset >= range.start && s.texel_offset < range.end)
        {
            let t = s.t;
            for j in 0..t {
                for i in 0..t {
                    let x = s.texel_offset + j * t + i;
                    if !buried[x] {
                        continue;
                    }
                    // Nearest ring of valid neighbours on the same face.
                    let mut neighbours = Vec::new();
                    for radius in 1..t.max(2) {
                        for dj in -(radius as i64)..=radius as i64 {
                            for di in -(radius as i64)..=radius as i64 {
                                if di.abs().max(dj.abs()) != radius as i64 {
                                    continue;
                                }
                                let (ni, nj) = (i as i64 + di, j as i64 + dj);
                                if ni < 0 || nj < 0 || ni >= t as i64 || nj >= t as i64 {
                                    continue;
                                }
                                let n = s.texel_offset + nj as usize * t + ni as usize;
                                if !buried[n] {
                                    neighbours.push(n);
                                }
                            }
                        }
                        if !neighbours.is_empty() {
                            break;
                        }
                    }
                    if neighbours.is_empty() {
                        *without_neighbours += 1;
                    }
                    // Next to gathered texels: copy the first one's gather (its light is
                    // the gather alone, so averaging MRT-based values would be brighter).
                    if let Some(row) = neighbours.iter().find_map(|n| gathered.get(&(*n as u32))) {
                        let row = row.clone();
                        gathered.insert(x as u32, row);
                        continue;
                    }
                    let x_local = x - range.start;
                    for &key in &sources {
                        let width = match key {
                            LitSource::Block(b) => shapes[b as usize].rank(),
                            LitSource::Clutter(c) => clutter_widths[c as usize],
                        };
                        let unshadowed = |row: usize| -> Vec<f64> {
                            match key {
                                LitSource::Block(b) => mrt
                                    .row(shapes, target, b as usize, row)
                                    .unwrap_or_else(|| vec![0.0; width]),
                                LitSource::Clutter(_) => vec![0.0; width],
                            }
                        };
                        // ΔU[x] = mean_n (U[n] + ΔU[n]) − U[x]; no neighbours: −U[x].
                        let mut value = vec![0.0; width];
                        if !neighbours.is_empty() {
                            let w = 1.0 / neighbours.len() as f64;
                            for &n in &neighbours {
                                let u = unshadowed(n - range.start);
                                let delta = map.get(&key).and_then(|m| m.get(&(n as u32)));
                                for c in 0..width {
                                    value[c] += w * (u[c] + delta.map_or(0.0, |d| d[c]));
                                }
                            }
                        }
                        let own = unshadowed(x_local);
                        for c in 0..width {
                            value[c] -= own[c];
                        }
                        if value.iter().any(|v| *v != 0.0) {
                            add_row(map, key, x as u32, &value, 1.0);
                        }
                    }
                }
            }
        }
    }
    Ok(())
}
