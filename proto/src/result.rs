//! RESULT.json: per-texel direct and indirect outgoing radiance, written by `lightfarm eval`
//! and `lightfarm reference` and read by `lightfarm compare` and the Mitsuba check.
//!
//! Invariant: texels are identified by `(surface, index)`; surfaces are named
//! `block:<id>/<face>` and `clutter:<id>`; the order is stable for a given scene and settings.
//! A long block baked as pieces has several layout surfaces per face name, its indices
//! running on from one piece to the next ([`Layout::surface_first_index`]).
//! Radiance in W/(sr·m²) per RGB channel.

use std::collections::HashMap;

use serde::{Deserialize, Serialize};

use crate::bundle::Layout;

/// One texel's record.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct TexelRecord {
    pub surface: String,
    pub index: u32,
    pub position: [f64; 3],
    pub normal: [f64; 3],
    pub albedo: [f64; 3],
    pub direct: [f64; 3],
    pub indirect: [f64; 3],
}

/// The whole RESULT.json.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "openapi", derive(utoipa::ToSchema))]
pub struct ResultFile {
    pub texels: Vec<TexelRecord>,
}

impl ResultFile {
    /// The record of each of `layout`'s texels (matched by surface name and index), in the
    /// layout's texel order; `None` where this result has no record for the texel.
    pub fn by_layout_texel(&self, layout: &Layout) -> Vec<Option<&TexelRecord>> {
        let records: HashMap<(&str, u32), &TexelRecord> = self
            .texels
            .iter()
            .map(|t| ((t.surface.as_str(), t.index), t))
            .collect();
        let mut out = vec![None; layout.n_texels()];
        for (s, first) in layout.surfaces.iter().zip(layout.surface_first_index()) {
            for k in 0..s.texel_count {
                if let Some(&t) = records.get(&(s.name.as_str(), first + k)) {
                    out[(s.texel_offset + k) as usize] = Some(t);
                }
            }
        }
        out
    }
}

/// Relative L2 error and 95th-percentile texel error of `ours` against `reference`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Comparison {
    /// sqrt(Σ|ours − ref|² / Σ|ref|²) over RGB of matched texels.
    pub relative_l2: f64,
    /// 95th percentile of |ours − ref| / mean |ref| over matched texels.
    pub p95: f64,
    /// Texels present in both files.
    pub matched: usize,
    /// Texels in only one of the files.
    pub unmatched: usize,
}

/// Compares the `indirect` fields of two results texel by texel (matched by surface and index).
pub fn compare(ours: &ResultFile, reference: &ResultFile) -> Comparison {
    let by_key: HashMap<(&str, u32), &TexelRecord> = reference
        .texels
        .iter()
        .map(|t| ((t.surface.as_str(), t.index), t))
        .collect();
    let mut num = 0.0;
    let mut den = 0.0;
    let mut errors = Vec::new();
    let mut ref_norm_sum = 0.0;
    for t in &ours.texels {
        if let Some(r) = by_key.get(&(t.surface.as_str(), t.index)) {
            let mut e2 = 0.0;
            let mut r2 = 0.0;
            for c in 0..3 {
                e2 += (t.indirect[c] - r.indirect[c]).powi(2);
                r2 += r.indirect[c].powi(2);
            }
            num += e2;
            den += r2;
            ref_norm_sum += r2.sqrt();
            errors.push(e2.sqrt());
        }
    }
    let matched = errors.len();
    let unmatched = ours.texels.len() + reference.texels.len() - 2 * matched;
    errors.sort_by(|a, b| a.total_cmp(b));
    let p95_abs = if errors.is_empty() {
        0.0
    } else {
        errors[((errors.len() as f64 * 0.95).ceil() as usize).clamp(1, errors.len()) - 1]
    };
    let mean_ref = if matched > 0 {
        ref_norm_sum / matched as f64
    } else {
        0.0
    };
    Comparison {
        relative_l2: if den > 0.0 { (num / den).sqrt() } else { 0.0 },
        p95: if mean_ref > 0.0 {
            p95_abs / mean_ref
        } else {
            0.0
        },
        matched,
        unmatched,
    }
}
