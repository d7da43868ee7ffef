//! A light buffer: shadow rays towards one point light answered from a cube of direction cells
//! around the light, each listing the occluders seen in that direction, nearest first.
//!
//! Every shadow ray of a point light ends at the light, so its direction from the light picks
//! one cell of a cube map centred there (six faces of [`CELLS_PER_EDGE`]² cells), and only the
//! occluders whose padded bounds project onto that cell can cross it. Each cell's list is
//! sorted by the occluder's distance from the light, and the walk stops at the first occluder
//! farther away than the segment is long: a texel near the light tests the few occluders
//! around it, not a hierarchy. This is the light buffer of Haines & Greenberg (1986), built
//! from occluder bounds in a few microseconds per hundred occluders, so a moving light
//! rebuilds it every frame.
//!
//! Units and frames: metres, world frame; cube faces are indexed `2·axis + (direction < 0)`,
//! and a direction `w` on the face of axis `a` has cell coordinates `w[u] / |w[a]|` and
//! `w[v] / |w[a]|` in [−1, 1], `(u, v)` the other two axes ascending.
//!
//! Shadow rays of neighbouring texels are mostly blocked by the same occluder, so each query
//! first tests the last one that blocked (a hint kept per buffer, reset by every build; the
//! answer does not depend on it): on the maze and a 320-block level it cut the direct light
//! of relighting everything by 8-9%.
//!
//! Invariant: [`LightBuffer::occluded`] tests, with the per-primitive test of
//! [`Occluders::occluded`], every listed occluder whose padded bounds (padded as the
//! hierarchy pads its nodes) the segment can touch, so it answers what
//! [`Occluders::occluded`] answers with the light as the target: both are the loop over every
//! primitive wherever a reported crossing lies within the padding of its primitive's bounds
//! (the hierarchy's invariant). A bound's projection is conservative (the whole box in front
//! of the light, not only the part inside the face's pyramid) and widened by `1e-9` in cell
//! coordinates against f64 rounding; the
//! distance cut compares exact f64 distances with a relative `1e-9` margin.

use std::sync::atomic::{AtomicU32, Ordering};

use lightfarm_proto::face::tangent_axes;

use crate::occluders::Occluders;

/// Cells per cube-face edge: 6 × 16² direction cells. A moving light rebuilds its buffer
/// every frame, and a finer cube listed each wall in more cells than the shorter lists saved:
/// at 32 the maze's moving light (T = 16) took 7-12% more direct-light time and the
/// 1,000-block level's relight of every light 12% more (`frame-time --update one-light`, the
/// two side by side); 8 and 12 measured as 16 on the maze.
pub const CELLS_PER_EDGE: usize = 16;
/// The most occluders a buffer is built over when a light's texels are not known to lie in a
/// few rooms (the whole level): a buffer's build costs a projection per occluder, so a larger
/// level traces its hierarchy instead, whose cost follows the texels lit.
pub const WHOLE_LEVEL_MAX_OCCLUDERS: usize = 4096;
/// Widening of a projected range in cell coordinates (f64 rounding is ~1e-16 of them).
const UV_MARGIN: f64 = 1e-9;
/// Relative margin of the distance cut.
const DIST_MARGIN: f64 = 1e-9;

/// One listed occluder: its padded bounds' distance from the light, its index and its rank
/// among the buffer's occluders (nearest first; it fills the padding of the struct).
#[derive(Clone, Copy, Debug)]
struct Entry {
    dmin: f64,
    prim: u32,
    rank: u32,
}

/// The occluders around one point light, by direction cell (see the module doc). Reusable:
/// [`LightBuffer::build`] keeps its allocations.
#[derive(Clone, Debug, Default)]
pub struct LightBuffer {
    light: [f32; 3],
    /// Start of each cell's entries (`6 · n² + 1`).
    offsets: Vec<u32>,
    entries: Vec<Entry>,
    /// Scratch: (distance, primitive, padded bounds relative to the light) sorted by
    /// distance, and each one's cell rectangles per face.
    order: Vec<(f64, u32, [f64; 3], [f64; 3])>,
    rects: Vec<(u32, u8, [u16; 4])>,
    /// The occluder that blocked the last occluded segment, tested first by the next query.
    last_blocker: LastBlocker,
}

/// A primitive index the buffer lists (or [`LastBlocker::NONE`]), shared by the queries of
/// one buffer: only a hint of which occluder to test first, so which thread wrote it last
/// changes no answer.
#[derive(Debug)]
struct LastBlocker(AtomicU32);

impl LastBlocker {
    const NONE: u32 = u32::MAX;
}

impl Default for LastBlocker {
    fn default() -> LastBlocker {
        LastBlocker(AtomicU32::new(LastBlocker::NONE))
    }
}

impl Clone for LastBlocker {
    fn clone(&self) -> LastBlocker {
        LastBlocker(AtomicU32::new(self.0.load(Ordering::Relaxed)))
    }
}

impl LightBuffer {
    /// An empty buffer (answers nothing until built).
    pub fn new() -> LightBuffer {
        LightBuffer::default()
    }

    /// Builds the buffer of the light at `light` over `occluders`' primitives `prims` (indices
    /// in their order, e.g. from [`Occluders::prims_in_box`]), or over all of them (`None`).
    /// Queries then test only these primitives.
    pub fn build(&mut self, occluders: &Occluders, light: [f32; 3], prims: Option<&[u32]>) {
        self.light = light;
        self.last_blocker
            .0
            .store(LastBlocker::NONE, Ordering::Relaxed);
        let p = light.map(f64::from);
        self.order.clear();
        let mut push = |i: u32| {
            let (lo, hi) = occluders.padded_prim_bounds(i as usize);
            let lo = [0, 1, 2].map(|k| lo[k] as f64 - p[k]);
            let hi = [0, 1, 2].map(|k| hi[k] as f64 - p[k]);
            let d2: f64 = (0..3)
                .map(|k| {
                    let gap = if lo[k] > 0.0 {
                        lo[k]
                    } else if hi[k] < 0.0 {
                        -hi[k]
                    } else {
                        0.0
                    };
                    gap * gap
                })
                .sum();
            self.order.push((d2.sqrt(), i, lo, hi));
        };
        match prims {
            Some(ix) => ix.iter().for_each(|&i| push(i)),
            None => (0..occluders.len() as u32).for_each(push),
        }
        // Nearest first; ties by index, so the lists are the same whatever the input order.
        self.order
            .sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));

        let n = CELLS_PER_EDGE;
        self.rects.clear();
        for (rank, &(_, _, lo, hi)) in self.order.iter().enumerate() {
            for face in 0..6u8 {
                if let Some(r) = face_cells(face, lo, hi) {
                    self.rects.push((rank as u32, face, r));
                }
            }
        }
        self.offsets.clear();
        self.offsets.resize(6 * n * n + 1, 0);
        for &(_, face, [i0, i1, j0, j1]) in &self.rects {
            for j in j0..=j1 {
                let row = (face as usize * n + j as usize) * n;
                for i in i0..=i1 {
                    self.offsets[row + i as usize + 1] += 1;
                }
            }
        }
        for c in 0..6 * n * n {
            self.offsets[c + 1] += self.offsets[c];
        }
        let total = self.offsets[6 * n * n] as usize;
        self.entries.clear();
        self.entries.resize(
            total,
            Entry {
                dmin: 0.0,
                prim: 0,
                rank: 0,
            },
        );
        // Filled in rank order, so each cell's list comes out nearest first.
        let mut cursor = std::mem::take(&mut self.offsets);
        for &(rank, face, [i0, i1, j0, j1]) in &self.rects {
            let (dmin, prim, _, _) = self.order[rank as usize];
            for j in j0..=j1 {
                let row = (face as usize * n + j as usize) * n;
                for i in i0..=i1 {
                    let c = &mut cursor[row + i as usize];
                    self.entries[*c as usize] = Entry { dmin, prim, rank };
                    *c += 1;
                }
            }
        }
        // `cursor[c]` ran from cell c's start to cell c + 1's: shift back into offsets.
        for c in (1..6 * n * n + 1).rev() {
            cursor[c] = cursor[c - 1];
        }
        cursor[0] = 0;
        self.offsets = cursor;
    }

    /// The light this buffer was built for.
    pub fn light(&self) -> [f32; 3] {
        self.light
    }

    /// Primitives listed in some cell (the occluders the queries can test).
    pub fn len(&self) -> usize {
        self.order.len()
    }

    /// True when no primitive is listed.
    pub fn is_empty(&self) -> bool {
        self.order.is_empty()
    }

    /// `occluders.occluded(origin, self.light())`, testing only the primitives listed in the
    /// direction of `origin` that are near enough to cross the segment (module doc). `occluders`
    /// must be the set the buffer was built over.
    #[inline]
    pub fn occluded(&self, occluders: &Occluders, origin: [f32; 3]) -> bool {
        if self.entries.is_empty() {
            return false;
        }
        let Some(seg) = occluders.shadow_segment(origin, self.light) else {
            return false;
        };
        // Neighbouring texels are mostly blocked by the same occluder: test it first. It is one
        // the buffer lists, so a crossing is the answer the lists would give.
        let last = self.last_blocker.0.load(Ordering::Relaxed);
        if last != LastBlocker::NONE && occluders.prim_crosses(last as usize, &seg) {
            return true;
        }
        let w = [0, 1, 2].map(|k| origin[k] as f64 - self.light[k] as f64);
        let a = [0, 1, 2].map(|k| w[k].abs());
        let axis = if a[0] >= a[1] && a[0] >= a[2] {
            0
        } else if a[1] >= a[2] {
            1
        } else {
            2
        };
        let (u, v) = tangent_axes(axis);
        let face = 2 * axis + usize::from(w[axis] < 0.0);
        let n = CELLS_PER_EDGE;
        let cell = |t: f64| (((t + 1.0) * 0.5 * n as f64) as usize).min(n - 1);
        let x = a[axis];
        let c = (face * n + cell(w[v] / x)) * n + cell(w[u] / x);
        let reach = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt() * (1.0 + DIST_MARGIN);
        let list = &self.entries[self.offsets[c] as usize..self.offsets[c + 1] as usize];
        for e in list {
            if e.dmin > reach {
                return false;
            }
            if occluders.prim_crosses(e.prim as usize, &seg) {
                self.last_blocker.0.store(e.prim, Ordering::Relaxed);
                return true;
            }
        }
        false
    }
}

impl LightBuffer {
    /// Calls `f(prim, rank)` on every primitive listed in a cell that the direction from the
    /// light to some point of the box `[lo, hi]` (world frame) picks, up to the first entry
    /// farther than `reach` in each cell: every primitive [`LightBuffer::occluded`] can test
    /// for an origin in the box whose segment is at most `reach` long (a primitive listed in
    /// several cells comes once per cell; `rank < self.len()` numbers them). `f` returns false
    /// to stop. `None` (and no call) when the box covers more than `max_cells` cells; else
    /// whether every entry was visited.
    pub(crate) fn entries_toward_box(
        &self,
        lo: [f64; 3],
        hi: [f64; 3],
        reach: f64,
        max_cells: usize,
        mut f: impl FnMut(u32, u32) -> bool,
    ) -> Option<bool> {
        if self.entries.is_empty() {
            return Some(true);
        }
        let p = self.light.map(f64::from);
        let rlo = [0, 1, 2].map(|k| lo[k] - p[k]);
        let rhi = [0, 1, 2].map(|k| hi[k] - p[k]);
        let rects = [0u8, 1, 2, 3, 4, 5].map(|face| face_cells(face, rlo, rhi));
        let cells: usize = rects
            .iter()
            .flatten()
            .map(|&[i0, i1, j0, j1]| (i1 - i0 + 1) as usize * (j1 - j0 + 1) as usize)
            .sum();
        if cells > max_cells {
            return None;
        }
        let n = CELLS_PER_EDGE;
        let reach = reach * (1.0 + DIST_MARGIN);
        for (face, rect) in rects.iter().enumerate() {
            let Some([i0, i1, j0, j1]) = *rect else {
                continue;
            };
            for j in j0..=j1 {
                let row = (face * n + j as usize) * n;
                for i in i0..=i1 {
                    let c = row + i as usize;
                    let list =
                        &self.entries[self.offsets[c] as usize..self.offsets[c + 1] as usize];
                    for e in list {
                        if e.dmin > reach {
                            break;
                        }
                        if !f(e.prim, e.rank) {
                            return Some(false);
                        }
                    }
                }
            }
        }
        Some(true)
    }
}

/// The cell rectangle `[i0, i1] × [j0, j1]` (i along the face's first tangent axis) covering
/// the projection onto cube face `face` of the box `[lo, hi]` given relative to the light: every
/// direction from the light to a point of the box that lies on this face's pyramid falls in it.
fn face_cells(face: u8, lo: [f64; 3], hi: [f64; 3]) -> Option<[u16; 4]> {
    let axis = (face / 2) as usize;
    let (xlo, xhi) = if face.is_multiple_of(2) {
        (lo[axis], hi[axis])
    } else {
        (-hi[axis], -lo[axis])
    };
    if xhi <= 0.0 {
        return None;
    }
    let (u, v) = tangent_axes(axis);
    let (u0, u1) = ratio_range(lo[u], hi[u], xlo, xhi)?;
    let (v0, v1) = ratio_range(lo[v], hi[v], xlo, xhi)?;
    let n = CELLS_PER_EDGE;
    let cell = |t: f64| (((t.clamp(-1.0, 1.0) + 1.0) * 0.5 * n as f64) as usize).min(n - 1) as u16;
    Some([cell(u0), cell(u1), cell(v0), cell(v1)])
}

/// The range of `y / x` over `y ∈ [ylo, yhi]`, `x ∈ (max(xlo, 0), xhi]` (`xhi > 0`), widened by
/// [`UV_MARGIN`]; `None` when it misses [−1, 1].
fn ratio_range(ylo: f64, yhi: f64, xlo: f64, xhi: f64) -> Option<(f64, f64)> {
    let (lo, hi) = if xlo > 0.0 {
        (
            if ylo >= 0.0 { ylo / xhi } else { ylo / xlo },
            if yhi >= 0.0 { yhi / xlo } else { yhi / xhi },
        )
    } else {
        // The box reaches the light's plane: x runs down to 0.
        (
            if ylo >= 0.0 {
                ylo / xhi
            } else {
                f64::NEG_INFINITY
            },
            if yhi <= 0.0 { yhi / xhi } else { f64::INFINITY },
        )
    };
    let (lo, hi) = (lo - UV_MARGIN, hi + UV_MARGIN);
    (lo <= 1.0 && hi >= -1.0).then_some((lo, hi))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::occluders::tests::{random_scene, Lcg};
    use lightfarm_proto::bundle::Rect;

    /// Random rects and triangles in a 10 m box, every fifth rect a wall across it.
    fn scene(rng: &mut Lcg, n_rects: usize, n_tris: usize) -> Occluders {
        let (mut rects, tris) = random_scene(rng, n_rects, n_tris);
        for r in rects.iter_mut().step_by(5) {
            r.max = [
                r.min[0] + rng.range(4.0, 10.0),
                r.min[1] + rng.range(4.0, 10.0),
            ];
        }
        Occluders::new(&rects, &tris)
    }

    /// Against the hierarchy (itself checked against every primitive): random segments, segments
    /// from points on the primitives (texel-like origins), lights on and beside primitives, and
    /// axis-aligned and diagonal directions on the cube's face and cell boundaries.
    #[test]
    fn answers_what_the_hierarchy_answers() {
        let mut rng = Lcg(0x11_9b7_b0ff);
        let mut buffer = LightBuffer::new();
        let (mut hits, mut total) = (0usize, 0usize);
        for case in 0..30 {
            let occ = scene(&mut rng, 4 + case * 3, (case * 5) % 40);
            for l in 0..8 {
                let light = match l % 4 {
                    // On a primitive's corner, and on a cube-cell boundary of a round position.
                    0 if !occ.is_empty() => occ.padded_prim_bounds(0).0,
                    1 => [0.0, 0.0, 0.0],
                    _ => rng.point(-6.0, 6.0),
                };
                buffer.build(&occ, light, None);
                let mut check = |o: [f32; 3]| {
                    let want = occ.occluded(o, light);
                    assert_eq!(
                        buffer.occluded(&occ, o),
                        want,
                        "case {case}: {o:?} to the light at {light:?}"
                    );
                    hits += usize::from(want);
                    total += 1;
                };
                for _ in 0..300 {
                    check(rng.point(-6.0, 6.0));
                }
                for i in 0..occ.len() {
                    let (lo, hi) = occ.padded_prim_bounds(i);
                    let t = rng.range(0.0, 1.0);
                    check([0, 1, 2].map(|k| lo[k] + t * (hi[k] - lo[k])));
                }
                for dx in [-3.0f32, 0.0, 3.0] {
                    for dy in [-3.0f32, 0.0, 3.0] {
                        for dz in [-3.0f32, 0.0, 3.0] {
                            check([light[0] + dx, light[1] + dy, light[2] + dz]);
                            let s = 2.0 / CELLS_PER_EDGE as f32;
                            check([light[0] + 3.0, light[1] + dy * s, light[2] + dz * 5.0 * s]);
                        }
                    }
                }
            }
        }
        assert!(
            hits > total / 10 && hits < total * 9 / 10,
            "{hits} of {total}"
        );
    }

    /// A random scene of 60 primitives, every third of them kept, and the hierarchy over those:
    /// (the generator, the scene, the kept indices, their hierarchy).
    fn subset_case(seed: u64) -> (Lcg, Occluders, Vec<u32>, Occluders) {
        let mut rng = Lcg(seed);
        let occ = scene(&mut rng, 60, 20);
        let keep: Vec<u32> = (0..occ.len() as u32).filter(|i| i % 3 == 0).collect();
        let sub = occ.subset(&keep);
        (rng, occ, keep, sub)
    }

    /// A subset of the primitives: the buffer answers for those alone.
    #[test]
    fn a_subset_answers_for_its_primitives() {
        let (mut rng, occ, keep, sub) = subset_case(77);
        let mut buffer = LightBuffer::new();
        for _ in 0..10 {
            let light = rng.point(-4.0, 4.0);
            buffer.build(&occ, light, Some(&keep));
            assert_eq!(buffer.len(), keep.len());
            for _ in 0..300 {
                let o = rng.point(-6.0, 6.0);
                assert_eq!(buffer.occluded(&occ, o), sub.occluded(o, light));
            }
        }
    }

    /// The occluder remembered as the last blocker is one the current build lists: after a
    /// rebuild over a subset, a segment blocked only by a primitive outside it is not occluded,
    /// whatever the query before the rebuild found.
    #[test]
    fn the_last_blocker_is_forgotten_by_a_rebuild() {
        let (mut rng, occ, keep, sub) = subset_case(78);
        let mut buffer = LightBuffer::new();
        let mut checked = 0;
        for _ in 0..400 {
            let light = rng.point(-4.0, 4.0);
            let o = rng.point(-6.0, 6.0);
            if !occ.occluded(o, light) || sub.occluded(o, light) {
                continue;
            }
            buffer.build(&occ, light, None);
            assert!(buffer.occluded(&occ, o));
            buffer.build(&occ, light, Some(&keep));
            assert!(!buffer.occluded(&occ, o), "{o:?} to {light:?}");
            checked += 1;
        }
        assert!(checked > 20, "{checked}");
    }

    /// In a closed room a texel's shadow ray tests a handful of walls, not all of them: the
    /// nearest-first lists stop at the segment's length.
    #[test]
    fn cell_lists_stop_at_the_segment() {
        let wall = |axis, coord| Rect {
            axis,
            coord,
            min: [0.0, 0.0],
            max: [4.0, 4.0],
        };
        let mut rects: Vec<Rect> = (0..3).flat_map(|a| [wall(a, 0.0), wall(a, 4.0)]).collect();
        // Far walls outside the room, behind every wall.
        for k in 1..40 {
            rects.push(wall((k % 3) as u8, 4.0 + k as f32));
        }
        let occ = Occluders::new(&rects, &[]);
        let mut buffer = LightBuffer::new();
        buffer.build(&occ, [2.0, 2.5, 1.5], None);
        assert!(!buffer.occluded(&occ, [4.0, 1.0, 3.0]));
        assert!(!buffer.occluded(&occ, [0.5, 0.0, 3.5]));
        assert!(buffer.occluded(&occ, [9.0, 1.0, 3.0]));
        // Average list length up to the room's walls.
        let longest = (0..6 * CELLS_PER_EDGE * CELLS_PER_EDGE)
            .map(|c| {
                buffer.entries[buffer.offsets[c] as usize..buffer.offsets[c + 1] as usize]
                    .iter()
                    .take_while(|e| e.dmin <= 2.5 * 3f64.sqrt())
                    .count()
            })
            .max()
            .unwrap();
        assert!(longest <= 6, "{longest}");
    }
}
