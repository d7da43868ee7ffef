//! The region a texel's rays swept: per direction cell, the longest ray segment from the texel
//! to its first hit. Used to decide, exactly and conservatively, that a changed object could
//! not have met any of the rays (incremental rebake, `drt::rays`).
//!
//! Directions are binned cube-map style: the dominant axis and sign pick one of six faces, and
//! the two other components divided by the dominant one pick one of `CELLS × CELLS` squares.
//! Each cell is a convex polyhedral cone with its apex at the texel (five half-spaces through
//! the apex), so "every segment in the cell" lies in that cone cut at the cell's longest length.
//! A box meets no segment when it lies beyond the longest length or wholly outside one of the
//! half-spaces (tested on its corners, with a margin).
//!
//! Frames: world, metres. Invariant: `meets` never answers false for a box some recorded
//! segment touches (to within the margin); it may answer true for boxes no segment touches.

use lightfarm_proto::face::tangent_axes;

/// Squares per cube face side.
const CELLS: usize = 4;

/// The cell id [`RayReach::everywhere`] stores: every direction, unbounded.
const EVERYWHERE: u8 = u8::MAX;

/// Longest segment per direction cell, from one origin.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RayReach {
    /// (cell, longest segment length; +∞ when a ray escaped), ascending by cell.
    pub cells: Vec<(u8, f32)>,
}

/// The cell a direction falls in.
fn cell_of(d: [f64; 3]) -> u8 {
    // The largest |component|, the last of equals (as `max_by` picks).
    let [x, y, z] = d.map(f64::abs);
    let a = if z >= x && z >= y {
        2
    } else if y >= x {
        1
    } else {
        0
    };
    let (u, v) = tangent_axes(a);
    let major = d[a].abs().max(f64::MIN_POSITIVE);
    let bin = |x: f64| (((x / major + 1.0) * 0.5 * CELLS as f64) as usize).min(CELLS - 1);
    let face = 2 * a + usize::from(d[a] > 0.0);
    (face * CELLS * CELLS + bin(d[v]) * CELLS + bin(d[u])) as u8
}

/// Cells of a whole cube map.
const ALL_CELLS: usize = 6 * CELLS * CELLS;

/// A [`RayReach`] being recorded: the longest segment per cell in a dense table (a texel's
/// 1,024 rays each update one slot, where a sorted list took a search and insertions), turned
/// into the sparse form by [`ReachRecorder::finish`].
#[derive(Clone, Debug)]
pub struct ReachRecorder {
    /// Per cell, the longest segment recorded; −∞ where none was.
    longest: [f32; ALL_CELLS],
}

impl Default for ReachRecorder {
    fn default() -> ReachRecorder {
        ReachRecorder {
            longest: [f32::NEG_INFINITY; ALL_CELLS],
        }
    }
}

impl ReachRecorder {
    /// Records a segment from the origin along unit direction `d` of length `t` (∞: escaped).
    pub fn add(&mut self, d: [f64; 3], t: f64) {
        // Rounded up so the stored length never falls short of the segment.
        let len = if t.is_finite() {
            (t * (1.0 + 1e-6) + 1e-9) as f32
        } else {
            f32::INFINITY
        };
        let slot = &mut self.longest[cell_of(d) as usize];
        *slot = slot.max(len);
    }

    /// The cells that hold a segment, ascending, with their longest.
    pub fn finish(&self) -> RayReach {
        RayReach {
            cells: (0..ALL_CELLS)
                .filter(|&c| self.longest[c] != f32::NEG_INFINITY)
                .map(|c| (c as u8, self.longest[c]))
                .collect(),
        }
    }
}

impl RayReach {
    /// A reach that meets every box: for a texel whose rays were not traced, so that nothing
    /// is ever concluded from them.
    pub fn everywhere() -> RayReach {
        RayReach {
            cells: vec![(EVERYWHERE, f32::INFINITY)],
        }
    }

    /// Whether some segment recorded from `origin` could meet the box `[min, max]` grown by
    /// `margin` on every side.
    pub fn meets(&self, origin: [f64; 3], bounds: &[[f64; 3]; 2], margin: f64) -> bool {
        let lo = [0, 1, 2].map(|k| bounds[0][k] - margin - origin[k]);
        let hi = [0, 1, 2].map(|k| bounds[1][k] + margin - origin[k]);
        // Distance from the origin to the box.
        let gap = (0..3)
            .map(|k| lo[k].max(-hi[k]).max(0.0).powi(2))
            .sum::<f64>()
            .sqrt();
        let corners: [[f64; 3]; 8] =
            std::array::from_fn(|c| [0, 1, 2].map(|k| if c >> k & 1 == 1 { hi[k] } else { lo[k] }));
        // Some corner on the inner side of the half-space n·p ≥ 0 (else the box is outside).
        let inside = |n: [f64; 3]| {
            corners
                .iter()
                .any(|p| n[0] * p[0] + n[1] * p[1] + n[2] * p[2] >= 0.0)
        };
        const SLACK: f64 = 1e-6;
        self.cells.iter().any(|&(cell, len)| {
            if cell == EVERYWHERE {
                return true;
            }
            if gap > len as f64 {
                return false;
            }
            let cell = cell as usize;
            let face = cell / (CELLS * CELLS);
            let (a, s) = (face / 2, if face % 2 == 1 { 1.0 } else { -1.0 });
            let (u, v) = tangent_axes(a);
            let (iv, iu) = ((cell / CELLS) % CELLS, cell % CELLS);
            let edge = |i: usize| -1.0 + 2.0 * i as f64 / CELLS as f64;
            let (u0, u1) = (edge(iu) - SLACK, edge(iu + 1) + SLACK);
            let (v0, v1) = (edge(iv) - SLACK, edge(iv + 1) + SLACK);
            // d_u / (s d_a) ∈ [u0, u1], likewise v, and s d_a ≥ 0.
            let mut major = [0.0; 3];
            major[a] = s;
            let plane = |axis: usize, sign: f64, bound: f64| {
                let mut n = [0.0; 3];
                n[axis] = sign;
                n[a] -= sign * bound * s;
                n
            };
            inside(major)
                && inside(plane(u, 1.0, u0))
                && inside(plane(u, -1.0, u1))
                && inside(plane(v, 1.0, v0))
                && inside(plane(v, -1.0, v1))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::math::sampling::{sample_cosine_hemisphere, sobol_2d, to_world};

    fn slab_hits(origin: [f64; 3], d: [f64; 3], b: &[[f64; 3]; 2]) -> Option<f64> {
        let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
        for k in 0..3 {
            if d[k].abs() < 1e-15 {
                if origin[k] < b[0][k] || origin[k] > b[1][k] {
                    return None;
                }
                continue;
            }
            let (a, c) = ((b[0][k] - origin[k]) / d[k], (b[1][k] - origin[k]) / d[k]);
            t0 = t0.max(a.min(c));
            t1 = t1.min(a.max(c));
        }
        (t0 <= t1).then_some(t0)
    }

    /// Random segments and random boxes: whenever a segment truly meets a box, `meets` says so;
    /// and far or behind boxes are told apart (the test is not "always true").
    #[test]
    fn never_misses_a_box_a_segment_meets_and_rules_out_most_others() {
        let origin = [0.3, 0.2, -0.1];
        let n = [0.0, 0.0, 1.0];
        let mut recorder = ReachRecorder::default();
        let mut segments = Vec::new();
        for i in 0..512 {
            let d = to_world(sample_cosine_hemisphere(sobol_2d(7, i)), n);
            let t = 0.5 + 3.0 * sobol_2d(9, i)[0];
            recorder.add(d, t);
            segments.push((d, t));
        }
        let reach = recorder.finish();
        let (mut ruled_out, mut total) = (0, 0);
        for i in 0..4000u32 {
            let u = sobol_2d(11, i);
            let w = sobol_2d(13, i);
            let c = [
                origin[0] + 8.0 * (u[0] - 0.5),
                origin[1] + 8.0 * (u[1] - 0.5),
                origin[2] + 8.0 * (w[0] - 0.5),
            ];
            let h = 0.05 + 0.3 * w[1];
            let b = [
                [c[0] - h, c[1] - h, c[2] - h],
                [c[0] + h, c[1] + h, c[2] + h],
            ];
            let truly = segments
                .iter()
                .any(|(d, t)| slab_hits(origin, *d, &b).is_some_and(|s| s <= *t));
            let said = reach.meets(origin, &b, 1e-9);
            assert!(!truly || said, "box {b:?} met by a segment but ruled out");
            total += 1;
            if !said {
                ruled_out += 1;
            }
        }
        // Half the boxes lie below the texel's plane or beyond 3.5 m: most must be ruled out.
        assert!(
            ruled_out * 2 > total,
            "only {ruled_out} of {total} ruled out"
        );
    }

    #[test]
    fn an_escaped_ray_reaches_everything_in_its_cell_only() {
        let mut recorder = ReachRecorder::default();
        recorder.add([0.0, 0.0, 1.0], f64::INFINITY);
        let reach = recorder.finish();
        let far_ahead = [[-0.1, -0.1, 1e6], [0.1, 0.1, 1e6 + 1.0]];
        let behind = [[-0.1, -0.1, -5.0], [0.1, 0.1, -4.0]];
        assert!(reach.meets([0.0; 3], &far_ahead, 0.0));
        assert!(!reach.meets([0.0; 3], &behind, 0.0));
    }
}
