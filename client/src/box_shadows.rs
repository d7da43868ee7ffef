//! One light's shadows on a run of texels at once: which occluders can cross any shadow
//! segment from a box around the texels' samples to the light, so that a run the light sees
//! whole, or that one occluder hides whole, costs no shadow ray, and the rest test only the
//! few occluders that can matter to them.
//!
//! [`BoxShadows::query`] walks the [`LightBuffer`] cells that the directions from the light to
//! the box pick (every entry [`LightBuffer::occluded`] could test for an origin in the box),
//! and classifies each primitive against the whole box with
//! [`Occluders::prim_crosses_box_segments`]:
//! - [`BoxShadow::Dark`]: one primitive crosses every segment, so every sample is occluded;
//! - [`BoxShadow::Clear`]: none can cross any, so no sample is;
//! - [`BoxShadow::Listed`]: the primitives that may ([`BoxShadows::listed`]); a shadow ray from
//!   the box is occluded exactly when one of them crosses it;
//! - [`BoxShadow::Unknown`]: the box covers too many cells to be worth it (near the light).
//!
//! After `Listed`, [`BoxShadows::refine`] answers the same for a box inside the queried one (a
//! texel of the run) from the listed primitives alone.
//!
//! Why the answers are the f32 test's, bit for bit. A point `o` of the box and the light `l`,
//! both f32, give the segment `o + t (l − o)` that counts a rect `(axis a, plane c)` for
//! `tmin < t < tmax`, `t = (c − o_a) / (l_a − o_a)` in f32. A difference of f32 values has the
//! sign of the exact one and rounding keeps order, so when `c` is not strictly between `o_a`
//! and `l_a` that `t` is ≤ 0 or ≥ 1 (or the test is skipped with `l_a = o_a`): never a hit.
//! When the plane is strictly between the light and the whole box, the crossings lie in the
//! central projection of the box, inside the box around its eight corners' projections;
//! outside the rect by a slack a hundred times the f32 rounding, there is no hit, inside it by
//! that slack (with `t` inside the interval by a margin) every segment hits. A triangle is only
//! ever declared missed, when the light and the box lie strictly on one side of its plane.
//! Anything else is `Maybe`, tested per ray.
//!
//! Units: metres, world frame. Invariant: for any origin in the box, `occluded` over
//! [`BoxShadows::listed`] (after `Listed`) answers what the buffer answers.

use std::ops::Range;

use lightfarm_proto::bundle::Layout;

use crate::light_buffer::LightBuffer;
use crate::occluders::{BoxCross, Occluders};
use crate::texel_samples::{sample_bounds, TexelAt};

/// Texels of one run: consecutive in the layout, one normal.
pub(crate) const TILE_TEXELS: usize = 8;
/// Most buffer cells a query walks; a box covering more (close to the light) is `Unknown`.
const MAX_CELLS: usize = 64;

/// What every shadow segment from a box to the light meets ([`BoxShadows::query`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum BoxShadow {
    /// Nothing: no sample in the box is shadowed.
    Clear,
    /// One occluder crosses every segment: every sample is shadowed.
    Dark,
    /// Only [`BoxShadows::listed`] can cross them.
    Listed,
    /// Not worked out; trace as usual.
    Unknown,
}

/// Scratch for box queries, kept across runs (no allocation per query once sized).
#[derive(Clone, Debug, Default)]
pub(crate) struct BoxShadows {
    /// Per buffer rank, the query that last classified that primitive.
    seen: Vec<u32>,
    stamp: u32,
    listed: Vec<u32>,
    /// What [`BoxShadows::refine`] kept of `listed`.
    refined: Vec<u32>,
}

impl BoxShadows {
    pub(crate) fn new() -> BoxShadows {
        BoxShadows::default()
    }

    /// Classifies the occluders `buffer` lists toward the box `[lo, hi]` (module doc).
    /// `occluders` must be the set the buffer was built over.
    pub(crate) fn query(
        &mut self,
        buffer: &LightBuffer,
        occluders: &Occluders,
        lo: [f64; 3],
        hi: [f64; 3],
    ) -> BoxShadow {
        self.listed.clear();
        if self.seen.len() < buffer.len() {
            self.seen = vec![0; buffer.len()];
            self.stamp = 0;
        }
        self.stamp = self.stamp.wrapping_add(1);
        if self.stamp == 0 {
            self.seen.fill(0);
            self.stamp = 1;
        }
        let light = buffer.light();
        let l = light.map(f64::from);
        let reach = (0..8)
            .map(|corner| {
                (0..3)
                    .map(|k| {
                        let x = if corner >> k & 1 == 0 { lo[k] } else { hi[k] };
                        (x - l[k]) * (x - l[k])
                    })
                    .sum::<f64>()
            })
            .fold(0.0f64, f64::max)
            .sqrt();
        if !reach.is_finite() {
            return BoxShadow::Unknown;
        }
        let (seen, stamp, listed) = (&mut self.seen, self.stamp, &mut self.listed);
        let segments = occluders.box_segments(light, lo, hi);
        let walked = buffer.entries_toward_box(lo, hi, reach, MAX_CELLS, |prim, rank| {
            let s = &mut seen[rank as usize];
            if *s == stamp {
                return true;
            }
            *s = stamp;
            match occluders.prim_crosses_box_segments(prim as usize, &segments) {
                BoxCross::Never => true,
                BoxCross::Every => false,
                BoxCross::Maybe => {
                    listed.push(prim);
                    true
                }
            }
        });
        match walked {
            None => BoxShadow::Unknown,
            Some(false) => BoxShadow::Dark,
            Some(true) if self.listed.is_empty() => BoxShadow::Clear,
            Some(true) => BoxShadow::Listed,
        }
    }

    /// The primitives the last `Listed` query kept.
    #[cfg(test)]
    pub(crate) fn listed(&self) -> &[u32] {
        &self.listed
    }

    /// After a query answered `Listed`, the same answer for a smaller box `[lo, hi]` whose
    /// shadow segments only the query's listed primitives can cross (a texel of the queried
    /// run: its samples lie in the run's box), from those primitives alone: `Clear` when none
    /// can cross them, `Dark` when one crosses every one, else `Listed` with the ones that may
    /// in [`BoxShadows::refined`]. The query's list stays as it was.
    pub(crate) fn refine(
        &mut self,
        occluders: &Occluders,
        light: [f32; 3],
        lo: [f64; 3],
        hi: [f64; 3],
    ) -> BoxShadow {
        self.refined.clear();
        let segments = occluders.box_segments(light, lo, hi);
        for &prim in &self.listed {
            match occluders.prim_crosses_box_segments(prim as usize, &segments) {
                BoxCross::Never => {}
                BoxCross::Every => return BoxShadow::Dark,
                BoxCross::Maybe => self.refined.push(prim),
            }
        }
        if self.refined.is_empty() {
            BoxShadow::Clear
        } else {
            BoxShadow::Listed
        }
    }

    /// The primitives the last `Listed` refinement kept.
    pub(crate) fn refined(&self) -> &[u32] {
        &self.refined
    }
}

/// The runs of `texels` a box query answers for: consecutive texels sharing one normal, at
/// most [`TILE_TEXELS`] each.
pub(crate) fn runs(
    layout: &Layout,
    texels: Range<usize>,
) -> impl Iterator<Item = Range<usize>> + '_ {
    let end = texels.end;
    let mut start = texels.start;
    std::iter::from_fn(move || {
        if start >= end {
            return None;
        }
        let n = layout.normals[start];
        let mut stop = start + 1;
        while stop < end && stop - start < TILE_TEXELS && layout.normals[stop] == n {
            stop += 1;
        }
        let run = start..stop;
        start = stop;
        Some(run)
    })
}

/// The widening [`run_bounds`] puts around each texel centre of `run` (texels sharing one
/// normal): [`sample_bounds`] of a texel at the origin at the run's widest size, so every
/// sample point of a texel at `x` lies in `[x + lo, x + hi]` up to the rounding of `x`'s own
/// coordinates (which `run_bounds` pads for).
pub(crate) fn texel_extent(layout: &Layout, run: Range<usize>, m: usize) -> ([f64; 3], [f64; 3]) {
    let first = run.start;
    let mut size = [0.0f32; 2];
    for t in run {
        let s = layout.texel_size.get(t).copied().unwrap_or([0.0, 0.0]);
        size = [size[0].max(s[0].abs()), size[1].max(s[1].abs())];
    }
    let at = TexelAt {
        x: [0.0; 3],
        n: layout.normals[first],
        rho: [0.0; 3],
        size,
    };
    sample_bounds(&at, m)
}

/// A box holding every one of the `m × m` sample points of the texels `run`, which share
/// one normal ([`runs`]): [`sample_bounds`] of a texel at the run's widest size, around each
/// centre (the box around the centres, widened by that texel's box about its centre).
pub(crate) fn run_bounds(layout: &Layout, run: Range<usize>, m: usize) -> ([f64; 3], [f64; 3]) {
    run_box(layout, run.clone(), texel_extent(layout, run, m))
}

/// [`run_bounds`] with the widening `(wlo, whi)` of a run holding `run` ([`texel_extent`] of
/// it: of one run, for its texels one at a time).
#[inline]
pub(crate) fn run_box(
    layout: &Layout,
    run: Range<usize>,
    (wlo, whi): ([f64; 3], [f64; 3]),
) -> ([f64; 3], [f64; 3]) {
    let first = run.start;
    let mut lo = layout.positions[first];
    let mut hi = lo;
    for t in run.clone() {
        let x = layout.positions[t];
        for k in 0..3 {
            lo[k] = lo[k].min(x[k]);
            hi[k] = hi[k].max(x[k]);
        }
    }
    let mag = lo
        .iter()
        .chain(&hi)
        .fold(0.0f64, |a, &c| a.max((c as f64).abs()));
    // `sample_bounds` pads relative to the coordinates it sees: pad for these ones too.
    let pad = 1e-6 * mag;
    let mut blo = [0.0; 3];
    let mut bhi = [0.0; 3];
    for k in 0..3 {
        let p = if whi[k] > 0.0 { pad } else { 0.0 };
        blo[k] = lo[k] as f64 + wlo[k] - p;
        bhi[k] = hi[k] as f64 + whi[k] + p;
    }
    if blo.iter().chain(&bhi).all(|c| c.is_finite()) {
        (blo, bhi)
    } else {
        ([f64::NEG_INFINITY; 3], [f64::INFINITY; 3])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::occluders::tests::{points_in, random_box, scene_with_walls, Lcg};
    use crate::texel_samples::{sample_points, ADAPTIVE_MAX_SAMPLES_PER_EDGE};
    use lightfarm_proto::bundle::Layout;

    /// Every sample point of every texel of a run, at any samples per edge, lies in the run's
    /// box, axis-aligned and slanted texels alike, far from the origin too; an axis-aligned
    /// run's box is flat along the normal when its texels share a plane.
    #[test]
    fn a_runs_box_holds_every_sample_of_its_texels() {
        let mut rng = Lcg(0x05a3_b1e5);
        for case in 0..300 {
            let n: [f32; 3] = match case % 3 {
                0 => [0.0, 0.0, -1.0],
                1 => [1.0, 0.0, 0.0],
                _ => {
                    let v = rng.point(-1.0, 1.0);
                    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-3);
                    v.map(|x| x / l)
                }
            };
            let far = if case % 5 == 0 { 1e4 } else { 1.0 };
            let base = rng.point(-5.0, 5.0).map(|x| x * far);
            let count = 1 + case % 8;
            let mut layout = Layout {
                scene_name: "test".into(),
                surfaces: vec![],
                positions: vec![],
                normals: vec![n; count],
                albedo: vec![[0.5; 3]; count],
                texel_size: vec![],
                rects: vec![],
                triangles: vec![],
            };
            for _ in 0..count {
                let o = rng.point(-1.0, 1.0);
                // Texels on one plane when axis-aligned (along a row), anywhere when slanted.
                let a = crate::texel_samples::dominant_axis(n);
                let mut x = [base[0] + o[0], base[1] + o[1], base[2] + o[2]];
                if case % 3 != 2 {
                    x[a] = base[a];
                }
                layout.positions.push(x);
                layout
                    .texel_size
                    .push([rng.range(0.0, 0.6), rng.range(0.0, 0.6)]);
            }
            for m in [1, 2, 4, ADAPTIVE_MAX_SAMPLES_PER_EDGE as usize, 12] {
                let (lo, hi) = run_bounds(&layout, 0..count, m);
                let mut points = vec![[0.0f32; 3]; m * m];
                for t in 0..count {
                    let at = TexelAt::of(&layout, t);
                    sample_points(at.x, at.n, at.size, m, &mut points);
                    for p in points.iter().chain([&at.x]) {
                        assert!(
                            (0..3).all(|k| lo[k] <= p[k] as f64 && p[k] as f64 <= hi[k]),
                            "case {case}, m {m}: {p:?} outside {lo:?} … {hi:?}"
                        );
                    }
                }
                if case % 3 != 2 {
                    let a = crate::texel_samples::dominant_axis(n);
                    assert_eq!(
                        (lo[a], hi[a]),
                        (base[a] as f64, base[a] as f64),
                        "case {case}"
                    );
                }
            }
        }
    }

    /// Whether `p` is in shadow by a box's `verdict` over the box (by `listed`, the
    /// primitives it listed, when `Listed`); `None` when it does not say (`Unknown`).
    fn verdicts_answer(
        verdict: BoxShadow,
        listed: &[u32],
        occ: &Occluders,
        light: [f32; 3],
        p: [f32; 3],
    ) -> Option<bool> {
        match verdict {
            BoxShadow::Clear => Some(false),
            BoxShadow::Dark => Some(true),
            BoxShadow::Listed => Some(
                occ.shadow_segment(p, light)
                    .is_some_and(|seg| listed.iter().any(|&i| occ.prim_crosses(i as usize, &seg))),
            ),
            BoxShadow::Unknown => None,
        }
    }

    /// Against the light buffer, point by point: a `Clear` box has no occluded point, a `Dark`
    /// one no lit point, and a `Listed` one gets the buffer's answer from its list alone; with
    /// the buffer over all occluders and over a subset, and every verdict occurring.
    #[test]
    fn a_box_query_answers_what_the_buffer_answers_at_each_point() {
        let mut rng = Lcg(0x0b0c_5ad0);
        let mut counts = [0usize; 4];
        let mut query = BoxShadows::new();
        let mut buffer = LightBuffer::new();
        for case in 0..30 {
            let (rects, tris) = scene_with_walls(&mut rng, 40, 10);
            let occ = Occluders::new(&rects, &tris);
            let keep: Vec<u32> = (0..occ.len() as u32).filter(|i| i % 3 != 1).collect();
            for round in 0..20 {
                let light = rng.point(-6.0, 6.0);
                let subset = round % 2 == 1;
                buffer.build(&occ, light, subset.then_some(&keep[..]));
                let (lo, hi) = random_box(&mut rng, &rects);
                let (blo, bhi) = (lo.map(f64::from), hi.map(f64::from));
                let verdict = query.query(&buffer, &occ, blo, bhi);
                counts[verdict as usize] += 1;
                for p in points_in(&mut rng, lo, hi, 24) {
                    let want = buffer.occluded(&occ, p);
                    let got =
                        verdicts_answer(verdict, query.listed(), &occ, light, p).unwrap_or(want);
                    assert_eq!(got, want, "case {case}.{round}: {verdict:?} at {p:?}");
                }
            }
        }
        // Clear, Dark, Listed, Unknown.
        assert!(counts[..3].iter().all(|&c| c >= 20), "{counts:?}");
    }

    /// After a `Listed` query, a box inside the queried one refined from the listed
    /// primitives alone gets the buffer's answer at each of its points, as a query would: a
    /// `Clear` box has no occluded point, a `Dark` one no lit point, a `Listed` one the
    /// buffer's answer from its shorter list; every verdict occurs.
    #[test]
    fn a_refined_box_answers_what_the_buffer_answers_at_each_point() {
        let mut rng = Lcg(0x7e1f_11ed);
        let mut counts = [0usize; 4];
        let mut query = BoxShadows::new();
        let mut buffer = LightBuffer::new();
        for case in 0..60 {
            let (rects, tris) = scene_with_walls(&mut rng, 40, 10);
            let occ = Occluders::new(&rects, &tris);
            for round in 0..20 {
                let light = rng.point(-6.0, 6.0);
                buffer.build(&occ, light, None);
                let (lo, hi) = random_box(&mut rng, &rects);
                let (blo, bhi) = (lo.map(f64::from), hi.map(f64::from));
                if query.query(&buffer, &occ, blo, bhi) != BoxShadow::Listed {
                    continue;
                }
                let listed = query.listed().len();
                for _ in 0..4 {
                    // A box inside the queried one (two random points of it: its 9th, after the
                    // corners).
                    let [a, b] = [0, 1].map(|_| points_in(&mut rng, lo, hi, 1)[8]);
                    let slo = [0, 1, 2].map(|k| a[k].min(b[k]));
                    let shi = [0, 1, 2].map(|k| a[k].max(b[k]));
                    let (sl, sh) = (slo.map(f64::from), shi.map(f64::from));
                    let verdict = query.refine(&occ, light, sl, sh);
                    assert_eq!(query.listed().len(), listed, "the query's list stays");
                    assert!(query.refined().len() <= listed);
                    counts[verdict as usize] += 1;
                    for p in points_in(&mut rng, slo, shi, 24) {
                        let want = buffer.occluded(&occ, p);
                        let got = verdicts_answer(verdict, query.refined(), &occ, light, p)
                            .expect("a refinement always answers");
                        assert_eq!(got, want, "case {case}.{round}: {verdict:?} at {p:?}");
                    }
                }
            }
        }
        // Clear, Dark, Listed.
        assert!(counts[..3].iter().all(|&c| c >= 20), "{counts:?}");
    }
}
