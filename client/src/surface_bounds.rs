//! Where the layout's texels are, by surface ([`SurfaceBounds`]): the box around each surface's
//! texel centres, so that work around a point (a dynamic object's DNRT grid,
//! [`crate::DnrtInstance::apply_texels_near`]) visits the surfaces that may hold a texel within
//! reach of it instead of every texel of the level.
//!
//! Frames and units: world metres, the layout's texel centres (`Layout::positions`); a box
//! holds the centres only (what the DNRT grid tests), not the texels' extents.
//!
//! Invariants: every texel lies in exactly one entry's range (the layout's surfaces, plus one
//! entry per run of texels no surface lists); entries are in texel order; [`SurfaceBounds::near`]
//! never leaves out a texel whose centre lies within the radius (a box is tested by its nearest
//! point, in f64).

use std::ops::Range;

use lightfarm_proto::bundle::Layout;

/// Per run of texels (a surface of the layout), the bounding box of its texel centres.
#[derive(Clone, Debug, Default)]
pub struct SurfaceBounds {
    entries: Vec<(Range<usize>, [f32; 3], [f32; 3])>,
}

impl SurfaceBounds {
    /// The boxes of `layout`'s surfaces (one pass over its texels; at load).
    pub fn new(layout: &Layout) -> SurfaceBounds {
        let n = layout.positions.len();
        let mut runs: Vec<Range<usize>> = layout
            .surfaces
            .iter()
            .map(|s| {
                let start = (s.texel_offset as usize).min(n);
                start..(start + s.texel_count as usize).min(n)
            })
            .filter(|r| !r.is_empty())
            .collect();
        runs.sort_unstable_by_key(|r| r.start);
        // Texels no surface lists get runs of their own, so every texel is in one range.
        let mut all = Vec::with_capacity(runs.len());
        let mut at = 0;
        for r in runs {
            if r.start > at {
                all.push(at..r.start);
            }
            let start = r.start.max(at);
            if r.end > start {
                all.push(start..r.end);
                at = r.end;
            }
        }
        if at < n {
            all.push(at..n);
        }
        let entries = all
            .into_iter()
            .map(|r| {
                let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
                for p in &layout.positions[r.clone()] {
                    for k in 0..3 {
                        lo[k] = lo[k].min(p[k]);
                        hi[k] = hi[k].max(p[k]);
                    }
                }
                (r, lo, hi)
            })
            .collect();
        SurfaceBounds { entries }
    }

    /// Replaces `out` with the texel ranges of the surfaces whose box comes within `radius` of
    /// `centre` (ascending, disjoint): every texel whose centre lies within `radius` of
    /// `centre` is in one of them. A NaN centre or radius lists every range (nothing can be
    /// ruled out).
    pub fn near(&self, centre: [f32; 3], radius: f32, out: &mut Vec<Range<usize>>) {
        out.clear();
        let known = centre.iter().all(|c| !c.is_nan()) && !radius.is_nan();
        let r = radius as f64;
        for (range, lo, hi) in &self.entries {
            let d2: f64 = (0..3)
                .map(|k| {
                    let c = centre[k] as f64;
                    let d = (lo[k] as f64 - c).max(c - hi[k] as f64).max(0.0);
                    d * d
                })
                .sum();
            if !known || d2 <= r * r {
                match out.last_mut() {
                    Some(last) if last.end == range.start => last.end = range.end,
                    _ => out.push(range.clone()),
                }
            }
        }
    }

    /// Number of ranges (surfaces and unlisted runs).
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether the layout has no texel.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfarm_proto::bundle::SurfaceInfo;

    fn layout(positions: Vec<[f32; 3]>, surfaces: &[(u32, u32)]) -> Layout {
        Layout {
            surfaces: surfaces
                .iter()
                .map(|&(o, c)| SurfaceInfo {
                    name: format!("s{o}"),
                    texel_offset: o,
                    texel_count: c,
                })
                .collect(),
            normals: vec![[0.0, 1.0, 0.0]; positions.len()],
            albedo: vec![[0.5; 3]; positions.len()],
            texel_size: vec![[0.1; 2]; positions.len()],
            positions,
            ..Default::default()
        }
    }

    /// Every texel within the radius is in a listed range, ranges are ascending and disjoint,
    /// far surfaces are left out, and texels no surface lists are covered by runs of their own.
    #[test]
    fn near_lists_every_texel_within_reach_and_leaves_far_surfaces_out() {
        // Texels along x at 0, 1, 2, …, 19; surfaces of 4 texels, texels 8..12 in none.
        let positions: Vec<[f32; 3]> = (0..20).map(|i| [i as f32, 0.5, -1.0]).collect();
        let l = layout(positions.clone(), &[(0, 4), (4, 4), (12, 4), (16, 4)]);
        let b = SurfaceBounds::new(&l);
        assert_eq!(b.len(), 5);
        // Stale ranges from an earlier call are dropped.
        let mut out = vec![0..1, 3..4];
        let pairs = |v: &[Range<usize>]| -> Vec<(usize, usize)> {
            v.iter().map(|r| (r.start, r.end)).collect()
        };
        for (centre, radius) in [
            ([9.5f32, 0.5, -1.0], 1.0f32),
            ([2.0, 3.0, -1.0], 2.6),
            ([30.0, 0.0, 0.0], 5.0),
        ] {
            b.near(centre, radius, &mut out);
            // Ascending and disjoint, touching ranges joined.
            assert!(out.windows(2).all(|w| w[0].end < w[1].start));
            for (t, p) in positions.iter().enumerate() {
                let d = (0..3)
                    .map(|k| (p[k] - centre[k]).powi(2))
                    .sum::<f32>()
                    .sqrt();
                if d <= radius {
                    assert!(out.iter().any(|r| r.contains(&t)), "texel {t} at {d}");
                }
            }
        }
        b.near([9.5, 0.5, -1.0], 1.0, &mut out);
        assert_eq!(pairs(&out), [(8, 12)], "the unlisted run alone");
        b.near([2.0, 3.0, -1.0], 2.6, &mut out);
        assert_eq!(pairs(&out), [(0, 4)]);
        b.near([30.0, 0.0, 0.0], 5.0, &mut out);
        assert!(out.is_empty());
        b.near([f32::NAN, 0.0, 0.0], 1.0, &mut out);
        assert_eq!(
            pairs(&out),
            [(0, 20)],
            "NaN rules nothing out; touching ranges join"
        );
    }
}
