//! Shadow-ray queries against the bundle's occluding geometry (axis-aligned rects and triangles).
//!
//! Owns a small bounding-volume hierarchy: median split over primitive centroids along the
//! longest centroid axis, leaves of at most [`LEAF_SIZE`] primitives, nodes in one flat array
//! (an inner node's children sit next to each other), traversed iteratively with a fixed-size
//! stack. The query is [`Occluders::occluded`]: does any primitive cross the open segment
//! between two points? [`Occluders::prims_in_box`] and [`Occluders::subset`] cut out the part
//! of a level some segments can meet (`reach_direct`), keeping the level's margins.
//!
//! Two levels: the level's hierarchy is shared (`Arc`), and [`Occluders::with_triangles`] adds
//! posed dynamic objects in a hierarchy of their own over them alone, numbered after the
//! level's primitives. Placing objects every frame then costs a build over the objects'
//! triangles, not over the level, and keeps the level's primitive numbers (the rooms' lists of
//! `reach_direct` stay valid); a query asks both hierarchies, which answers what one over all
//! the primitives would. The objects' triangles may carry their object's number
//! ([`Occluders::with_objects_triangles`]), so that a query from inside one object leaves its
//! own surface out ([`Occluders::occluded_except`]: the light-probe input at an object's
//! centre), with one hierarchy for every object of a frame.
//!
//! Invariants:
//! - Hits count only strictly inside the segment, away from both ends by
//!   `T_EPS_REL + EPS_SCALE · scale / length` (in units of the segment, so the margin is about
//!   `1e-4 ·` scene scale in distance plus `1e-4 ·` the segment length). A shadow ray leaving a
//!   texel centre on a wall does not hit that wall; a light sitting on or near a surface does not
//!   hit the surface it sits on. A segment shorter than twice the margin is never occluded.
//! - Rect hits are inclusive at the edges, so rects sharing an edge leave no crack; triangles use
//!   Möller–Trumbore, inclusive at edges. A segment lying in a primitive's plane does not hit it.
//! - Node boxes are padded by a tiny multiple of the scene scale, so the hierarchy never culls a
//!   primitive the exact primitive test would report: traversal answers exactly what a brute-force
//!   loop over all primitives with the same tests answers.
//! - Construction never panics, whatever the input (degenerate rects and triangles are kept and
//!   simply never hit, or hit as their exact tests say).
//!
//! # Layout
//! - this file: [`Occluders`] (the level's hierarchy and the posed objects'), its construction,
//!   the segment margins and the shadow-ray queries.
//! - `tree`: the primitives (rects, triangles) and their exact tests, and the BVH over them
//!   (build, box query, traversal).
//! - `box_cross`: what a primitive does to every shadow segment from a box to a light
//!   (`BoxCross`, for `box_shadows`).
//! - `tests`: queries against brute force, the box answers at points of the box, the
//!   fixtures other modules' tests share.

mod box_cross;
#[cfg(test)]
pub(crate) mod tests;
mod tree;

use std::sync::Arc;

use lightfarm_proto::bundle::{Layout, Rect};
use lightfarm_proto::glam::Vec3;

pub(crate) use box_cross::BoxCross;
pub use tree::LEAF_SIZE;
use tree::{union, Prim, Tree, NO_OWNER};

/// Segment end margin, relative to the segment length.
const T_EPS_REL: f32 = 1e-4;
/// Segment end margin, relative to the scene scale (a distance).
const EPS_SCALE: f32 = 1e-4;
/// Node-box padding, relative to the scene scale.
const BOX_PAD: f32 = 1e-5;

/// A shadow segment `o + t·d`, a hit counting for `tmin < t < tmax`
/// ([`Occluders::shadow_segment`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Segment {
    o: Vec3,
    d: Vec3,
    tmin: f32,
    tmax: f32,
}

/// Occluding geometry with a BVH for shadow rays.
#[derive(Clone, Debug)]
pub struct Occluders {
    /// The level's primitives, numbered `0 .. level.prims.len()` (shared by the copies with
    /// posed objects in).
    level: Arc<Tree>,
    /// Posed dynamic objects' triangles ([`Occluders::with_triangles`]), numbered after the
    /// level's.
    posed: Option<Tree>,
    /// Bounds of all primitives (`None` when there are none).
    bounds: Option<([f32; 3], [f32; 3])>,
    /// Diagonal of the level's bounds, or 1 when that is zero or there are no primitives.
    scale: f32,
}

impl Occluders {
    /// The layout's rects and triangles.
    pub fn from_layout(layout: &Layout) -> Occluders {
        Occluders::new(&layout.rects, &layout.triangles)
    }

    /// Builds the hierarchy over `rects` and `triangles`.
    pub fn new(rects: &[Rect], triangles: &[[[f32; 3]; 3]]) -> Occluders {
        let mut prims: Vec<Prim> = Vec::with_capacity(rects.len() + triangles.len());
        for r in rects {
            prims.push(Prim::Rect {
                axis: r.axis.min(2),
                coord: r.coord,
                min: [r.min[0].min(r.max[0]), r.min[1].min(r.max[1])],
                max: [r.min[0].max(r.max[0]), r.min[1].max(r.max[1])],
            });
        }
        prims.extend(triangles.iter().map(|t| Prim::Tri(*t)));
        let bounds = prims.iter().map(Prim::bounds).reduce(union);
        let scale = match bounds {
            Some((lo, hi)) => {
                let diag = (Vec3::from(hi) - Vec3::from(lo)).length();
                if diag.is_finite() && diag > 0.0 {
                    diag
                } else {
                    1.0
                }
            }
            None => 1.0,
        };
        Occluders::build(prims, scale)
    }

    /// These occluders and `triangles` (posed dynamic objects, [`crate::dynamic_shadows`]):
    /// the level's hierarchy shared, the triangles (with any this one's objects already had)
    /// in a hierarchy of their own numbered after the level's primitives, this one's
    /// [`Occluders::scale`] kept, so its margins are this one's: a segment none of
    /// `triangles` crosses gets exactly this one's answer. Costs a build over the objects'
    /// triangles only.
    pub fn with_triangles(&self, triangles: &[[[f32; 3]; 3]]) -> Occluders {
        self.with_objects_triangles(triangles, &[])
    }

    /// [`Occluders::with_triangles`] with each triangle's object: `owners[k]` numbers the
    /// object triangle k belongs to (empty: none), so that
    /// [`Occluders::occluded_except`] can leave one object's own triangles out.
    pub fn with_objects_triangles(&self, triangles: &[[[f32; 3]; 3]], owners: &[u32]) -> Occluders {
        debug_assert!(owners.is_empty() || owners.len() == triangles.len());
        let mut prims: Vec<(Prim, u32)> = match &self.posed {
            Some(t) => (t.prims.iter().enumerate())
                .map(|(i, &p)| (p, t.owners.get(i).copied().unwrap_or(NO_OWNER)))
                .collect(),
            None => Vec::new(),
        };
        let added = triangles
            .iter()
            .enumerate()
            .map(|(k, t)| (Prim::Tri(*t), owners.get(k).copied().unwrap_or(NO_OWNER)));
        let first_added = prims.len();
        prims.extend(added);
        let added_bounds = prims[first_added..]
            .iter()
            .map(|(p, _)| p.bounds())
            .reduce(union);
        let bounds = match (self.bounds, added_bounds) {
            (Some(a), Some(b)) => Some(union(a, b)),
            (a, b) => a.or(b),
        };
        let owned = prims.iter().any(|&(_, o)| o != NO_OWNER);
        let posed = (!prims.is_empty()).then(|| {
            let mut tree = Tree::build_owned(prims, BOX_PAD * self.scale);
            if !owned {
                tree.owners = Vec::new();
            }
            tree
        });
        Occluders {
            level: Arc::clone(&self.level),
            posed,
            bounds,
            scale: self.scale,
        }
    }

    /// One hierarchy over `prims`, with margins and node padding relative to `scale`.
    fn build(prims: Vec<Prim>, scale: f32) -> Occluders {
        let bounds = prims.iter().map(Prim::bounds).reduce(union);
        Occluders {
            level: Arc::new(Tree::build(prims, BOX_PAD * scale)),
            posed: None,
            bounds,
            scale,
        }
    }

    /// Primitive `i` (the level's, then the posed objects').
    #[inline]
    fn prim(&self, i: usize) -> &Prim {
        let n = self.level.prims.len();
        if i < n {
            &self.level.prims[i]
        } else {
            &self
                .posed
                .as_ref()
                .expect("a primitive index below len()")
                .prims[i - n]
        }
    }

    /// The hierarchies, each with the number of its first primitive.
    fn trees(&self) -> impl Iterator<Item = (&Tree, u32)> {
        let n = self.level.prims.len() as u32;
        std::iter::once((&*self.level, 0)).chain(self.posed.iter().map(move |t| (t, n)))
    }
}

impl Occluders {
    /// Appends to `out` the indices (in this hierarchy's primitive order, for
    /// [`Occluders::subset`]) of the primitives whose bounds meet the closed box `[lo, hi]`:
    /// the level's, then the posed objects'.
    pub fn prims_in_box(&self, lo: [f32; 3], hi: [f32; 3], out: &mut Vec<u32>) {
        for (tree, first) in self.trees() {
            tree.prims_in_box(lo, hi, first, out);
        }
    }

    /// The primitives `indices` (from [`Occluders::prims_in_box`]) in a hierarchy of their
    /// own that keeps this one's [`Occluders::scale`], so its margins are this one's:
    /// `subset(ix).occluded(a, b)` is true exactly when one of those primitives crosses the
    /// segment as [`Occluders::occluded`] tests it.
    pub fn subset(&self, indices: &[u32]) -> Occluders {
        Occluders::build(
            indices.iter().map(|&i| *self.prim(i as usize)).collect(),
            self.scale,
        )
    }

    /// Number of primitives.
    pub fn len(&self) -> usize {
        self.level.prims.len() + self.posed.as_ref().map_or(0, |t| t.prims.len())
    }

    /// True when there is nothing to hit.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bounds `(min, max)` of all primitives, `None` when there are none.
    pub fn bounds(&self) -> Option<([f32; 3], [f32; 3])> {
        self.bounds
    }

    /// Scene scale the epsilons are relative to: the diagonal of [`Occluders::bounds`], or 1.
    pub fn scale(&self) -> f32 {
        self.scale
    }

    /// Primitive `i`'s bounds (this hierarchy's primitive order), as [`Occluders::prims_in_box`]
    /// compares them.
    pub(crate) fn prim_bounds(&self, i: usize) -> ([f32; 3], [f32; 3]) {
        self.prim(i).bounds()
    }

    /// Primitive `i`'s bounds (this hierarchy's primitive order), padded as the hierarchy pads
    /// its node boxes: a segment the query reports as crossing primitive `i` touches this box
    /// (the invariant that makes traversal equal to a loop over every primitive).
    pub(crate) fn padded_prim_bounds(&self, i: usize) -> ([f32; 3], [f32; 3]) {
        let (mut lo, mut hi) = self.prim(i).bounds();
        let pad = BOX_PAD * self.scale;
        for k in 0..3 {
            lo[k] -= pad;
            hi[k] += pad;
        }
        (lo, hi)
    }

    /// The segment from `origin` to `target` as [`Occluders::occluded`] tests it (`None`:
    /// never occluded), for [`Occluders::prim_crosses`].
    #[inline]
    pub(crate) fn shadow_segment(&self, origin: [f32; 3], target: [f32; 3]) -> Option<Segment> {
        let o = Vec3::from(origin);
        self.segment(o, Vec3::from(target))
            .map(|(d, tmin, tmax)| Segment { o, d, tmin, tmax })
    }

    /// Does primitive `i` cross `seg` (the test [`Occluders::occluded`] applies per primitive)?
    #[inline]
    pub(crate) fn prim_crosses(&self, i: usize, seg: &Segment) -> bool {
        self.prim(i).hit(seg.o, seg.d, seg.tmin, seg.tmax)
    }

    /// Segment direction and the open parameter interval a hit must fall in; `None` when the
    /// segment is too short (or not finite) to be occluded.
    fn segment(&self, origin: Vec3, target: Vec3) -> Option<(Vec3, f32, f32)> {
        let d = target - origin;
        let len = d.length();
        if !(len > 0.0 && len.is_finite()) {
            return None;
        }
        let eps = T_EPS_REL + EPS_SCALE * self.scale / len;
        let (tmin, tmax) = (eps, 1.0 - eps);
        (tmin < tmax).then_some((d, tmin, tmax))
    }

    /// Does any primitive cross the segment strictly between `origin` and `target` (away from
    /// both ends by the margins in the module doc)?
    pub fn occluded(&self, origin: [f32; 3], target: [f32; 3]) -> bool {
        if self.is_empty() {
            return false;
        }
        let origin = Vec3::from(origin);
        let Some((d, tmin, tmax)) = self.segment(origin, Vec3::from(target)) else {
            return false;
        };
        self.trees()
            .any(|(tree, _)| tree.occluded(origin, d, tmin, tmax))
    }

    /// [`Occluders::occluded`] without posed object `object`'s own triangles (its number in
    /// [`Occluders::with_objects_triangles`]): what occluders made with every other object's
    /// triangles alone would answer (a query from inside an object, which its own surface
    /// encloses).
    pub fn occluded_except(&self, origin: [f32; 3], target: [f32; 3], object: u32) -> bool {
        if self.is_empty() {
            return false;
        }
        let origin = Vec3::from(origin);
        let Some((d, tmin, tmax)) = self.segment(origin, Vec3::from(target)) else {
            return false;
        };
        self.level.occluded(origin, d, tmin, tmax)
            || self.posed.as_ref().is_some_and(|t| {
                t.occluded_by(origin, d, tmin, tmax, |i| {
                    t.owners.get(i).is_none_or(|&o| o != object)
                })
            })
    }

    /// [`Occluders::occluded`] against the posed objects' triangles alone
    /// ([`Occluders::with_triangles`]; false without any): with the level's answer from
    /// elsewhere (a light buffer over its primitives), the same answer.
    pub(crate) fn posed_occluded(&self, origin: [f32; 3], target: [f32; 3]) -> bool {
        let Some(tree) = &self.posed else {
            return false;
        };
        let origin = Vec3::from(origin);
        let Some((d, tmin, tmax)) = self.segment(origin, Vec3::from(target)) else {
            return false;
        };
        tree.occluded(origin, d, tmin, tmax)
    }

    /// The same query by testing every primitive (the reference for the hierarchy).
    #[cfg(test)]
    fn occluded_brute(&self, origin: [f32; 3], target: [f32; 3]) -> bool {
        let origin = Vec3::from(origin);
        let Some((d, tmin, tmax)) = self.segment(origin, Vec3::from(target)) else {
            return false;
        };
        (0..self.len()).any(|i| self.prim(i).hit(origin, d, tmin, tmax))
    }
}
