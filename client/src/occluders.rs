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

use std::sync::Arc;

use lightfarm_proto::bundle::{Layout, Rect};
use lightfarm_proto::glam::Vec3;

/// Most primitives in a leaf.
pub const LEAF_SIZE: usize = 4;
/// Depth of the traversal stack. Median splits halve the primitive count per level, so depth
/// is at most `log2(n / LEAF_SIZE) + 1`: 64 covers any count that fits in memory.
const STACK_DEPTH: usize = 64;
/// Segment end margin, relative to the segment length.
const T_EPS_REL: f32 = 1e-4;
/// Segment end margin, relative to the scene scale (a distance).
const EPS_SCALE: f32 = 1e-4;
/// Node-box padding, relative to the scene scale.
const BOX_PAD: f32 = 1e-5;
/// [`Occluders::prim_crosses_box_segments`]'s slack on positions, relative to the largest
/// coordinate or the scale: a hundred times the f32 test's rounding.
const BOX_SLACK_REL: f64 = 1e-5;
/// [`Occluders::prim_crosses_box_segments`]'s slack on segment parameters (the f32 test rounds `t`
/// to a few 1e-7).
const BOX_T_SLACK: f64 = 1e-5;

/// The shadow segments from a box to a light ([`Occluders::box_segments`]): the light and the
/// box in f64, whether all are finite, the slack on positions and the box's distance to the
/// light.
#[derive(Clone, Copy, Debug)]
pub(crate) struct BoxSegments {
    l: [f64; 3],
    lo: [f64; 3],
    hi: [f64; 3],
    finite: bool,
    slack: f64,
    len_min: f64,
}

/// What one primitive does to a box's shadow segments ([`Occluders::prim_crosses_box_segments`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum BoxCross {
    /// It crosses none of them.
    Never,
    /// It crosses every one.
    Every,
    /// Some, or it cannot tell.
    Maybe,
}

/// Distance from `p` to the closed box `[lo, hi]` (0 inside).
fn box_distance(p: [f64; 3], lo: [f64; 3], hi: [f64; 3]) -> f64 {
    (0..3)
        .map(|k| {
            let gap = (lo[k] - p[k]).max(p[k] - hi[k]).max(0.0);
            gap * gap
        })
        .sum::<f64>()
        .sqrt()
}

/// One occluding primitive.
#[derive(Clone, Copy, Debug)]
enum Prim {
    /// `axis`, plane `coord`, tangent-axis bounds (tangents are the other two axes ascending).
    Rect {
        axis: u8,
        coord: f32,
        min: [f32; 2],
        max: [f32; 2],
    },
    Tri([[f32; 3]; 3]),
}

/// A shadow segment `o + t·d`, a hit counting for `tmin < t < tmax`
/// ([`Occluders::shadow_segment`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Segment {
    o: Vec3,
    d: Vec3,
    tmin: f32,
    tmax: f32,
}

/// A BVH node. `count > 0`: a leaf holding `prims[first .. first + count]`; `count == 0`: an
/// inner node whose children are `nodes[first]` and `nodes[first + 1]`.
#[derive(Clone, Copy, Debug)]
struct Node {
    min: [f32; 3],
    max: [f32; 3],
    first: u32,
    count: u32,
}

/// A BVH over primitives (see the module doc).
#[derive(Clone, Debug)]
struct Tree {
    /// Primitives, reordered so every leaf's are contiguous.
    prims: Vec<Prim>,
    /// Per primitive (same order), the posed object it belongs to
    /// ([`Occluders::with_objects_triangles`]; [`NO_OWNER`] for none); empty when no
    /// primitive has one.
    owners: Vec<u32>,
    nodes: Vec<Node>,
}

/// The owner of a primitive that belongs to no posed object.
const NO_OWNER: u32 = u32::MAX;

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

/// The other two axes of `axis`, ascending (a rect's tangents; a texel plane's axes).
pub(crate) fn tangent_axes(axis: u8) -> (usize, usize) {
    match axis {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    }
}

impl Prim {
    fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        match *self {
            Prim::Rect {
                axis,
                coord,
                min,
                max,
            } => {
                let (u, v) = tangent_axes(axis);
                let (mut lo, mut hi) = ([0.0; 3], [0.0; 3]);
                lo[axis as usize] = coord;
                hi[axis as usize] = coord;
                lo[u] = min[0];
                hi[u] = max[0];
                lo[v] = min[1];
                hi[v] = max[1];
                (lo, hi)
            }
            Prim::Tri(p) => {
                let mut lo = p[0];
                let mut hi = p[0];
                for q in &p[1..] {
                    for a in 0..3 {
                        lo[a] = lo[a].min(q[a]);
                        hi[a] = hi[a].max(q[a]);
                    }
                }
                (lo, hi)
            }
        }
    }

    fn centroid(&self) -> [f32; 3] {
        let (lo, hi) = self.bounds();
        [
            0.5 * (lo[0] + hi[0]),
            0.5 * (lo[1] + hi[1]),
            0.5 * (lo[2] + hi[2]),
        ]
    }

    /// Does the primitive cross the segment `o + t·d` for `tmin < t < tmax`?
    #[inline]
    fn hit(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
        match *self {
            Prim::Rect {
                axis,
                coord,
                min,
                max,
            } => {
                let a = axis as usize;
                if d[a] == 0.0 {
                    return false;
                }
                let t = (coord - o[a]) / d[a];
                // `!(t > tmin && t < tmax)` also rejects NaN.
                if !(t > tmin && t < tmax) {
                    return false;
                }
                let (u, v) = tangent_axes(axis);
                let pu = o[u] + t * d[u];
                let pv = o[v] + t * d[v];
                pu >= min[0] && pu <= max[0] && pv >= min[1] && pv <= max[1]
            }
            Prim::Tri(p) => {
                // Möller–Trumbore.
                let [p0, p1, p2] = p.map(Vec3::from);
                let e1 = p1 - p0;
                let e2 = p2 - p0;
                let pv = d.cross(e2);
                let det = e1.dot(pv);
                if det == 0.0 {
                    return false;
                }
                let inv = 1.0 / det;
                let s = o - p0;
                let u = s.dot(pv) * inv;
                if !(0.0..=1.0).contains(&u) {
                    return false;
                }
                let qv = s.cross(e1);
                let v = d.dot(qv) * inv;
                if !(v >= 0.0 && u + v <= 1.0) {
                    return false;
                }
                let t = e2.dot(qv) * inv;
                t > tmin && t < tmax
            }
        }
    }
}

fn union(a: ([f32; 3], [f32; 3]), b: ([f32; 3], [f32; 3])) -> ([f32; 3], [f32; 3]) {
    let mut out = a;
    for k in 0..3 {
        out.0[k] = out.0[k].min(b.0[k]);
        out.1[k] = out.1[k].max(b.1[k]);
    }
    out
}

/// Does the segment `o + t·d`, `tmin ≤ t ≤ tmax`, touch the closed box? Exact for axes the
/// segment does not move along.
#[inline]
fn segment_hits_box(o: Vec3, inv_d: Vec3, d: Vec3, tmin: f32, tmax: f32, n: &Node) -> bool {
    let (mut t0, mut t1) = (tmin, tmax);
    for a in 0..3 {
        if d[a] == 0.0 {
            if o[a] < n.min[a] || o[a] > n.max[a] {
                return false;
            }
        } else {
            let ta = (n.min[a] - o[a]) * inv_d[a];
            let tb = (n.max[a] - o[a]) * inv_d[a];
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
    }
    t0 <= t1
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

impl Tree {
    /// The hierarchy over `prims`, node boxes padded by `pad`.
    fn build(prims: Vec<Prim>, pad: f32) -> Tree {
        let (tree, _) = Tree::build_with(prims.into_iter().map(|p| (p, ())).collect(), pad);
        tree
    }

    /// [`Tree::build`] over primitives with their owners (kept in [`Tree::owners`]).
    fn build_owned(prims: Vec<(Prim, u32)>, pad: f32) -> Tree {
        let (mut tree, owners) = Tree::build_with(prims, pad);
        tree.owners = owners;
        tree
    }

    /// The hierarchy over `prims` (each with a payload, returned in the tree's primitive
    /// order), node boxes padded by `pad`.
    fn build_with<O: Copy>(prims: Vec<(Prim, O)>, pad: f32) -> (Tree, Vec<O>) {
        let mut nodes: Vec<Node> = Vec::with_capacity(2 * prims.len().div_ceil(LEAF_SIZE).max(1));
        let (mut sorted, mut payloads) = (Vec::new(), Vec::new());
        if !prims.is_empty() {
            let mut centroids: Vec<([f32; 3], Prim, O)> =
                prims.iter().map(|&(p, o)| (p.centroid(), p, o)).collect();
            nodes.push(Node {
                min: [0.0; 3],
                max: [0.0; 3],
                first: 0,
                count: 0,
            });
            // (node index, primitive range) still to be built.
            let mut work: Vec<(usize, usize, usize)> = vec![(0, 0, centroids.len())];
            while let Some((ni, start, end)) = work.pop() {
                let items = &mut centroids[start..end];
                let (mut lo, mut hi) = items[0].1.bounds();
                for (_, p, _) in items.iter() {
                    (lo, hi) = union((lo, hi), p.bounds());
                }
                for k in 0..3 {
                    lo[k] -= pad;
                    hi[k] += pad;
                }
                nodes[ni].min = lo;
                nodes[ni].max = hi;
                if items.len() <= LEAF_SIZE {
                    nodes[ni].first = start as u32;
                    nodes[ni].count = items.len() as u32;
                    continue;
                }
                let (mut clo, mut chi) = (items[0].0, items[0].0);
                for (c, _, _) in items.iter() {
                    (clo, chi) = union((clo, chi), (*c, *c));
                }
                let ext = Vec3::from(chi) - Vec3::from(clo);
                let axis = if ext[0] >= ext[1] && ext[0] >= ext[2] {
                    0
                } else if ext[1] >= ext[2] {
                    1
                } else {
                    2
                };
                let mid = items.len() / 2;
                items.select_nth_unstable_by(mid, |a, b| a.0[axis].total_cmp(&b.0[axis]));
                let left = nodes.len();
                nodes.push(Node {
                    min: [0.0; 3],
                    max: [0.0; 3],
                    first: 0,
                    count: 0,
                });
                nodes.push(Node {
                    min: [0.0; 3],
                    max: [0.0; 3],
                    first: 0,
                    count: 0,
                });
                nodes[ni].first = left as u32;
                nodes[ni].count = 0;
                work.push((left, start, start + mid));
                work.push((left + 1, start + mid, end));
            }
            (sorted, payloads) = centroids.into_iter().map(|(_, p, o)| (p, o)).unzip();
        }
        let tree = Tree {
            prims: sorted,
            owners: Vec::new(),
            nodes,
        };
        (tree, payloads)
    }

    /// Appends `first +` the index of every primitive whose bounds meet the closed box
    /// `[lo, hi]`.
    fn prims_in_box(&self, lo: [f32; 3], hi: [f32; 3], first: u32, out: &mut Vec<u32>) {
        let meets = |a: &[f32; 3], b: &[f32; 3]| (0..3).all(|k| a[k] <= hi[k] && b[k] >= lo[k]);
        if self.nodes.is_empty() {
            return;
        }
        let mut stack = vec![0usize];
        while let Some(ni) = stack.pop() {
            let node = &self.nodes[ni];
            if !meets(&node.min, &node.max) {
                continue;
            }
            if node.count == 0 {
                stack.extend([node.first as usize, node.first as usize + 1]);
                continue;
            }
            for i in node.first..node.first + node.count {
                let (a, b) = self.prims[i as usize].bounds();
                if meets(&a, &b) {
                    out.push(first + i);
                }
            }
        }
    }

    /// Does a primitive cross `origin + t·d` for `tmin < t < tmax`? (the traversal of
    /// [`Occluders::occluded`]).
    fn occluded(&self, origin: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
        self.occluded_by(origin, d, tmin, tmax, |_| true)
    }

    /// [`Tree::occluded`] by the primitives `counts(i)` holds (i in the tree's order).
    #[inline(always)]
    fn occluded_by(
        &self,
        origin: Vec3,
        d: Vec3,
        tmin: f32,
        tmax: f32,
        counts: impl Fn(usize) -> bool,
    ) -> bool {
        if self.nodes.is_empty() {
            return false;
        }
        let inv_d = 1.0 / d;
        let mut stack = [0u32; STACK_DEPTH];
        let mut top = 0usize;
        let mut ni = 0usize;
        loop {
            let node = &self.nodes[ni];
            if segment_hits_box(origin, inv_d, d, tmin, tmax, node) {
                if node.count > 0 {
                    let first = node.first as usize;
                    let leaf = &self.prims[first..first + node.count as usize];
                    let hit =
                        |(k, p): (usize, &Prim)| counts(first + k) && p.hit(origin, d, tmin, tmax);
                    if leaf.iter().enumerate().any(hit) {
                        return true;
                    }
                } else {
                    // Depth is bounded (see STACK_DEPTH), so the stack cannot overflow.
                    stack[top] = node.first + 1;
                    top += 1;
                    ni = node.first as usize;
                    continue;
                }
            }
            if top == 0 {
                return false;
            }
            top -= 1;
            ni = stack[top] as usize;
        }
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

    /// [`Occluders::prim_crosses_box_segments`] of one box (the form the tests use).
    #[cfg(test)]
    pub(crate) fn prim_crosses_from_box(
        &self,
        i: usize,
        light: [f32; 3],
        lo: [f64; 3],
        hi: [f64; 3],
    ) -> BoxCross {
        self.prim_crosses_box_segments(i, &self.box_segments(light, lo, hi))
    }

    /// The segments from the box `[lo, hi]` to `light`, prepared for
    /// [`Occluders::prim_crosses_box_segments`] (what the tests of every primitive share).
    pub(crate) fn box_segments(&self, light: [f32; 3], lo: [f64; 3], hi: [f64; 3]) -> BoxSegments {
        let l = light.map(f64::from);
        let finite = l.iter().chain(&lo).chain(&hi).all(|x| x.is_finite());
        // Slack for the f32 test's rounding: coordinates and the scale set its size.
        let mag = (0..3).fold(self.scale as f64, |m, k| {
            m.max(l[k].abs()).max(lo[k].abs()).max(hi[k].abs())
        });
        BoxSegments {
            l,
            lo,
            hi,
            finite,
            slack: BOX_SLACK_REL * mag,
            len_min: if finite {
                box_distance(l, lo, hi)
            } else {
                f64::NAN
            },
        }
    }

    /// What primitive `i` does to every segment [`Occluders::occluded`] tests from a point of
    /// the box `[lo, hi]` to `light` (prepared by [`Occluders::box_segments`], once for all the
    /// primitives a box query tests; module [`crate::box_shadows`] says why each answer is
    /// exact to the f32 test): [`BoxCross::Never`] when it crosses none, [`BoxCross::Every`]
    /// when it crosses each one, else [`BoxCross::Maybe`]. Conservative: `Maybe` is always a
    /// correct answer, and a non-finite box or light gets it.
    pub(crate) fn prim_crosses_box_segments(&self, i: usize, b: &BoxSegments) -> BoxCross {
        let BoxSegments {
            l,
            lo,
            hi,
            finite,
            slack,
            len_min,
        } = *b;
        if !finite {
            return BoxCross::Maybe;
        }
        match *self.prim(i) {
            Prim::Rect {
                axis,
                coord,
                min,
                max,
            } => {
                let a = axis as usize;
                let c = coord as f64;
                // The plane is not strictly between the light and any point: the f32 test's
                // `t = (c − o_a) / (l_a − o_a)` is ≤ 0, ≥ 1 or not taken (`d_a = 0`), for a
                // difference of f32 values keeps its sign and rounding keeps their order.
                if (l[a] >= c && lo[a] >= c) || (l[a] <= c && hi[a] <= c) {
                    return BoxCross::Never;
                }
                if !((l[a] < c && lo[a] > c) || (l[a] > c && hi[a] < c)) {
                    return BoxCross::Maybe;
                }
                // Every segment crosses the plane: where, is the central projection from the
                // light of the box onto it, inside the box around its corners' projections.
                // A corner's projection along tangent k takes `s` from its coordinate along
                // the normal and its own coordinate along k: the eight corners give, per
                // tangent, the four pairs of (lo or hi along a, lo or hi along k), two
                // divisions in all.
                let (u, v) = tangent_axes(axis);
                let (mut plo, mut phi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
                for pa in [lo[a], hi[a]] {
                    let s = (c - l[a]) / (pa - l[a]);
                    for (j, k) in [u, v].into_iter().enumerate() {
                        for pk in [lo[k], hi[k]] {
                            let x = l[k] + s * (pk - l[k]);
                            plo[j] = plo[j].min(x);
                            phi[j] = phi[j].max(x);
                        }
                    }
                }
                let (rmin, rmax) = (min.map(f64::from), max.map(f64::from));
                if (0..2).any(|j| phi[j] < rmin[j] - slack || plo[j] > rmax[j] + slack) {
                    return BoxCross::Never;
                }
                if !(0..2).all(|j| plo[j] > rmin[j] + slack && phi[j] < rmax[j] - slack) {
                    return BoxCross::Maybe;
                }
                // Inside the rect everywhere: a hit when `t` is inside the segment's open
                // interval, whose margin is widest for the shortest segment.
                let t_at = |oa: f64| (c - oa) / (l[a] - oa);
                let (t0, t1) = (t_at(lo[a]), t_at(hi[a]));
                if len_min.is_nan() || len_min <= 0.0 {
                    return BoxCross::Maybe;
                }
                let eps = T_EPS_REL as f64 + EPS_SCALE as f64 * self.scale as f64 / len_min;
                let margin = eps * (1.0 + BOX_T_SLACK) + BOX_T_SLACK;
                if t0.min(t1) > margin && t0.max(t1) < 1.0 - margin {
                    BoxCross::Every
                } else {
                    BoxCross::Maybe
                }
            }
            Prim::Tri(p) => {
                // Only the plane: the light and the whole box strictly on one side of it, by
                // more than the test's rounding, put the line's crossing outside the segment.
                let p = p.map(|q| q.map(f64::from));
                let e1 = [0, 1, 2].map(|k| p[1][k] - p[0][k]);
                let e2 = [0, 1, 2].map(|k| p[2][k] - p[0][k]);
                let n = [
                    e1[1] * e2[2] - e1[2] * e2[1],
                    e1[2] * e2[0] - e1[0] * e2[2],
                    e1[0] * e2[1] - e1[1] * e2[0],
                ];
                let norm = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                if !norm.is_finite() || norm <= 0.0 {
                    return BoxCross::Maybe;
                }
                let side = |q: [f64; 3]| {
                    ((q[0] - p[0][0]) * n[0] + (q[1] - p[0][1]) * n[1] + (q[2] - p[0][2]) * n[2])
                        / norm
                };
                let sl = side(l);
                if sl.is_nan() || sl.abs() <= slack {
                    return BoxCross::Maybe;
                }
                let all_with_light = (0..8).all(|corner| {
                    let q = [0, 1, 2].map(|k| if corner >> k & 1 == 0 { lo[k] } else { hi[k] });
                    side(q) * sl.signum() > slack
                });
                if all_with_light {
                    BoxCross::Never
                } else {
                    BoxCross::Maybe
                }
            }
        }
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

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A fixed-seed linear congruential generator (no `rand` in this crate).
    pub(crate) use lightfarm_proto::testing::Lcg;

    /// Random rects and triangles in a 10 m box (seeded).
    pub(crate) fn random_scene(
        rng: &mut Lcg,
        n_rects: usize,
        n_tris: usize,
    ) -> (Vec<Rect>, Vec<[[f32; 3]; 3]>) {
        let rects = (0..n_rects)
            .map(|_| {
                let (a, b) = (rng.range(-5.0, 5.0), rng.range(-5.0, 5.0));
                let (w, h) = (rng.range(0.0, 2.0), rng.range(0.0, 2.0));
                Rect {
                    axis: (rng.next_u32() % 3) as u8,
                    coord: rng.range(-5.0, 5.0),
                    min: [a, b],
                    max: [a + w, b + h],
                }
            })
            .collect();
        let tris = (0..n_tris)
            .map(|_| {
                let c = rng.point(-5.0, 5.0);
                let p = |rng: &mut Lcg| {
                    let o = rng.point(-1.0, 1.0);
                    [c[0] + o[0], c[1] + o[1], c[2] + o[2]]
                };
                [p(rng), p(rng), p(rng)]
            })
            .collect();
        (rects, tris)
    }

    /// [`random_scene`] with every fourth rect a wall 3-8 m across, which hides whole boxes.
    pub(crate) fn scene_with_walls(
        rng: &mut Lcg,
        n_rects: usize,
        n_tris: usize,
    ) -> (Vec<Rect>, Vec<[[f32; 3]; 3]>) {
        let (mut rects, tris) = random_scene(rng, n_rects, n_tris);
        for r in rects.iter_mut().step_by(4) {
            r.max = [
                r.min[0] + rng.range(3.0, 8.0),
                r.min[1] + rng.range(3.0, 8.0),
            ];
        }
        (rects, tris)
    }

    /// A random box with f32 corners (so its corners are points a texel can have): half of
    /// them flat on a rect's plane, inside it or across its edge (a texel on a wall), the rest
    /// solid, from a centimetre to a metre.
    pub(crate) fn random_box(rng: &mut Lcg, rects: &[Rect]) -> ([f32; 3], [f32; 3]) {
        let size = rng.range(0.01, 1.0);
        let mut lo = rng.point(-5.0, 5.0);
        let mut hi = [0.0; 3];
        for k in 0..3 {
            hi[k] = lo[k] + rng.range(0.0, size);
        }
        if rng.next_u32() % 2 == 0 && !rects.is_empty() {
            let r = &rects[rng.next_u32() as usize % rects.len()];
            let (u, v) = tangent_axes(r.axis);
            let a = r.axis as usize;
            lo[a] = r.coord;
            hi[a] = r.coord;
            lo[u] = rng.range(r.min[0] - 0.2, r.max[0]);
            lo[v] = rng.range(r.min[1] - 0.2, r.max[1]);
            hi[u] = lo[u] + rng.range(0.0, size);
            hi[v] = lo[v] + rng.range(0.0, size);
        }
        (lo, hi)
    }

    /// Points of the f32 box `[lo, hi]`: its eight corners and random ones inside.
    pub(crate) fn points_in(rng: &mut Lcg, lo: [f32; 3], hi: [f32; 3], n: usize) -> Vec<[f32; 3]> {
        let corners =
            (0..8).map(|c: u32| [0, 1, 2].map(|k| if c >> k & 1 == 0 { lo[k] } else { hi[k] }));
        let inside = (0..n).map(|_| {
            [0, 1, 2].map(|k| (lo[k] + rng.range(0.0, 1.0) * (hi[k] - lo[k])).clamp(lo[k], hi[k]))
        });
        corners.chain(inside).collect()
    }

    /// Where `prim_crosses_from_box` says a primitive crosses no segment from the box to the
    /// light, or every one, the per-segment test agrees at every point tried (the corners and
    /// random points), with lights anywhere, on rects' planes and on boxes' faces; and both
    /// answers occur often.
    #[test]
    fn box_answers_hold_at_every_point_of_the_box() {
        let mut rng = Lcg(0xb0c5_5eed);
        let (mut never, mut every, mut maybe) = (0usize, 0usize, 0usize);
        for case in 0..40 {
            let (rects, tris) = scene_with_walls(&mut rng, 30, 10);
            let occ = Occluders::new(&rects, &tris);
            for round in 0..25 {
                let (lo, hi) = random_box(&mut rng, &rects);
                let mut light = rng.point(-6.0, 6.0);
                match round % 5 {
                    // On a rect's plane, and on the box's own plane.
                    0 => {
                        let r = &rects[rng.next_u32() as usize % rects.len()];
                        light[r.axis as usize] = r.coord;
                    }
                    1 => {
                        let k = rng.next_u32() as usize % 3;
                        light[k] = lo[k];
                    }
                    _ => {}
                }
                let points = points_in(&mut rng, lo, hi, 24);
                let (blo, bhi) = (lo.map(f64::from), hi.map(f64::from));
                for i in 0..occ.len() {
                    let verdict = occ.prim_crosses_from_box(i, light, blo, bhi);
                    match verdict {
                        BoxCross::Never => never += 1,
                        BoxCross::Every => every += 1,
                        BoxCross::Maybe => {
                            maybe += 1;
                            continue;
                        }
                    }
                    for p in &points {
                        let hit = occ
                            .shadow_segment(*p, light)
                            .is_some_and(|seg| occ.prim_crosses(i, &seg));
                        assert_eq!(
                            hit,
                            verdict == BoxCross::Every,
                            "case {case}.{round}: prim {i} {verdict:?}, point {p:?}, light {light:?}"
                        );
                    }
                }
            }
        }
        assert!(
            never > 10 * every && every > 100 && maybe > 100,
            "{never} {every} {maybe}"
        );
    }

    #[test]
    fn bvh_matches_brute_force_on_random_scenes() {
        let mut rng = Lcg(0x5eed_1234);
        let mut hits = 0;
        let mut total = 0;
        for scene in 0..40 {
            let (rects, tris) = random_scene(&mut rng, scene * 3, (scene * 7) % 50);
            let occ = Occluders::new(&rects, &tris);
            assert_eq!(occ.len(), rects.len() + tris.len());
            for _ in 0..400 {
                let o = rng.point(-6.0, 6.0);
                let t = rng.point(-6.0, 6.0);
                let got = occ.occluded(o, t);
                assert_eq!(
                    got,
                    occ.occluded_brute(o, t),
                    "scene {scene}: {o:?} → {t:?}"
                );
                hits += got as usize;
                total += 1;
            }
            // Segments that start on a primitive (texel-like origins) and axis-parallel ones.
            for r in &rects {
                let (u, v) = tangent_axes(r.axis);
                let mut o = [0.0; 3];
                o[r.axis as usize] = r.coord;
                o[u] = rng.range(r.min[0], r.max[0]);
                o[v] = rng.range(r.min[1], r.max[1]);
                let mut t = rng.point(-6.0, 6.0);
                assert_eq!(occ.occluded(o, t), occ.occluded_brute(o, t));
                t = o;
                t[(rng.next_u32() % 3) as usize] += rng.range(-8.0, 8.0);
                assert_eq!(occ.occluded(o, t), occ.occluded_brute(o, t));
            }
        }
        // The test is only meaningful if both answers occur often.
        assert!(
            hits > total / 10 && hits < total * 9 / 10,
            "{hits} of {total}"
        );
    }

    /// Leaving one object's triangles out ([`Occluders::occluded_except`] over every object
    /// numbered, [`Occluders::with_objects_triangles`]) answers what occluders made with the
    /// other objects' triangles alone answer, for every object, segments through and from
    /// inside the objects included.
    #[test]
    fn leaving_one_object_out_answers_what_the_others_alone_answer() {
        let mut rng = Lcg(0x0b_1ec7);
        let (mut differ, mut total) = (0, 0);
        for scene in 0..12 {
            let (rects, tris) = random_scene(&mut rng, 8 + scene, 36);
            let (level_tris, posed) = tris.split_at(6);
            let level = Occluders::new(&rects, level_tris);
            // Five objects of six triangles each, in order.
            let owners: Vec<u32> = (0..posed.len() as u32).map(|k| k / 6).collect();
            let all = level.with_objects_triangles(posed, &owners);
            assert_eq!(all.len(), level.len() + posed.len());
            for object in 0..5u32 {
                let others: Vec<_> = (posed.iter().zip(&owners))
                    .filter(|&(_, &o)| o != object)
                    .map(|(t, _)| *t)
                    .collect();
                let want_from = level.with_triangles(&others);
                for _ in 0..150 {
                    // From a vertex of the object half the time: a ray leaving its surface.
                    let o = if rng.next_u32().is_multiple_of(2) {
                        posed[(object as usize) * 6][0]
                    } else {
                        rng.point(-6.0, 6.0)
                    };
                    let t = rng.point(-6.0, 6.0);
                    let got = all.occluded_except(o, t, object);
                    assert_eq!(
                        got,
                        want_from.occluded(o, t),
                        "scene {scene} object {object}"
                    );
                    differ += (got != all.occluded(o, t)) as usize;
                    total += 1;
                }
            }
            // An object no triangle has leaves nothing out.
            for _ in 0..50 {
                let (o, t) = (rng.point(-6.0, 6.0), rng.point(-6.0, 6.0));
                assert_eq!(all.occluded_except(o, t, 99), all.occluded(o, t));
            }
        }
        assert!(
            differ * 200 > total,
            "the object's own triangles matter: {differ}/{total}"
        );
    }

    /// Triangles added in a hierarchy of their own ([`Occluders::with_triangles`], twice, as
    /// objects placed in two calls) answer every segment as one hierarchy over all the
    /// primitives does, keep the level's scale and numbers, and find the same primitives in a
    /// box.
    #[test]
    fn triangles_in_a_second_hierarchy_answer_what_one_hierarchy_answers() {
        let mut rng = Lcg(0x2_1e7e1);
        let (mut hits, mut total) = (0, 0);
        for scene in 0..20 {
            let (rects, tris) = random_scene(&mut rng, 10 + scene * 3, 40);
            let (level_tris, posed) = tris.split_at(10);
            let (first, second) = posed.split_at(scene % 30);
            let level = Occluders::new(&rects, level_tris);
            let two = level.with_triangles(first).with_triangles(second);
            // One hierarchy over all of them, with the level's margins.
            let one = two.subset(&(0..two.len() as u32).collect::<Vec<_>>());
            assert_eq!(two.len(), one.len());
            assert_eq!(two.len(), rects.len() + tris.len());
            assert_eq!(two.scale(), level.scale());
            assert_eq!(two.bounds(), Occluders::new(&rects, &tris).bounds());
            for i in 0..level.len() {
                assert_eq!(
                    two.prim_bounds(i),
                    level.prim_bounds(i),
                    "the level's numbers"
                );
            }
            for _ in 0..400 {
                let (o, t) = (rng.point(-6.0, 6.0), rng.point(-6.0, 6.0));
                let got = two.occluded(o, t);
                assert_eq!(
                    got,
                    two.occluded_brute(o, t),
                    "scene {scene}: {o:?} → {t:?}"
                );
                assert_eq!(got, one.occluded(o, t), "scene {scene}: {o:?} → {t:?}");
                hits += got as usize;
                total += 1;
            }
            let (lo, hi) = random_box(&mut rng, &rects);
            let (mut a, mut b) = (Vec::new(), Vec::new());
            two.prims_in_box(lo, hi, &mut a);
            one.prims_in_box(lo, hi, &mut b);
            assert_eq!(a.len(), b.len(), "scene {scene}");
            assert!(a.iter().all(|&i| (i as usize) < two.len()));
        }
        assert!(
            hits > total / 10 && hits < total * 9 / 10,
            "{hits} of {total}"
        );
    }

    #[test]
    fn build_is_a_proper_tree() {
        let mut rng = Lcg(7);
        let (rects, tris) = random_scene(&mut rng, 300, 300);
        let occ = Occluders::new(&rects, &tris);
        let mut seen = vec![0u32; occ.level.prims.len()];
        for n in &occ.level.nodes {
            if n.count > 0 {
                assert!(n.count as usize <= LEAF_SIZE);
                for s in &mut seen[n.first as usize..(n.first + n.count) as usize] {
                    *s += 1;
                }
            }
        }
        assert!(
            seen.iter().all(|&s| s == 1),
            "every primitive in exactly one leaf"
        );
    }

    #[test]
    fn empty_scene_never_occludes() {
        let occ = Occluders::new(&[], &[]);
        assert!(occ.is_empty());
        assert!(!occ.occluded([0.0; 3], [1.0, 2.0, 3.0]));
    }

    /// A 4 m room: floor z = 0 and ceiling z = 4, walls at x = 0 and x = 4.
    fn room() -> Occluders {
        let wall = |axis, coord| Rect {
            axis,
            coord,
            min: [0.0, 0.0],
            max: [4.0, 4.0],
        };
        Occluders::new(
            &[wall(2, 0.0), wall(2, 4.0), wall(0, 0.0), wall(0, 4.0)],
            &[],
        )
    }

    #[test]
    fn ray_leaving_a_wall_texel_does_not_hit_the_wall() {
        let occ = room();
        // Texel centres on the floor and the wall, light inside the room.
        assert!(!occ.occluded([1.3, 2.1, 0.0], [2.0, 2.0, 3.0]));
        assert!(!occ.occluded([0.0, 1.7, 2.9], [3.0, 2.0, 1.0]));
        // Grazing, but still leaving the floor.
        assert!(!occ.occluded([0.1, 2.0, 0.0], [3.9, 2.0, 0.05]));
    }

    #[test]
    fn light_near_or_on_a_surface_still_lights() {
        let occ = room();
        // On the ceiling, and a hair below it.
        assert!(!occ.occluded([1.0, 1.0, 0.0], [2.0, 2.0, 4.0]));
        assert!(!occ.occluded([1.0, 1.0, 0.0], [2.0, 2.0, 4.0 - 1e-5]));
        // A hair inside the ceiling (the light's own surface is within the end margin).
        assert!(!occ.occluded([1.0, 1.0, 0.0], [2.0, 2.0, 4.0 + 1e-5]));
        // ...but a light clearly beyond the ceiling is shadowed.
        assert!(occ.occluded([1.0, 1.0, 0.0], [2.0, 2.0, 4.1]));
        // Near the wall the texel is on.
        assert!(!occ.occluded([0.0, 1.0, 1.0], [1e-4, 2.0, 2.0]));
    }

    #[test]
    fn a_blocker_between_occludes() {
        let mut rects = vec![Rect {
            axis: 2,
            coord: 2.0,
            min: [1.0, 1.0],
            max: [3.0, 3.0],
        }];
        let occ = Occluders::new(&rects, &[]);
        assert!(occ.occluded([2.0, 2.0, 0.0], [2.0, 2.0, 4.0]));
        assert!(!occ.occluded([0.5, 2.0, 0.0], [0.5, 2.0, 4.0]));
        assert!(
            !occ.occluded([2.0, 2.0, 0.0], [2.0, 2.0, 1.5]),
            "blocker beyond the target"
        );
        // Inclusive edges: two rects sharing the edge x = 2 leave no crack.
        rects = vec![
            Rect {
                axis: 2,
                coord: 2.0,
                min: [1.0, 1.0],
                max: [2.0, 3.0],
            },
            Rect {
                axis: 2,
                coord: 2.0,
                min: [2.0, 1.0],
                max: [3.0, 3.0],
            },
        ];
        let occ = Occluders::new(&rects, &[]);
        assert!(occ.occluded([2.0, 2.0, 0.0], [2.0, 2.0, 4.0]));
        assert!(occ.occluded([1.0, 2.0, 0.0], [3.0, 2.0, 4.0]));
        // Edge of a lone rect counts too.
        let occ = Occluders::new(&rects[..1], &[]);
        assert!(occ.occluded([1.0, 1.0, 0.0], [1.0, 1.0, 4.0]));
    }

    #[test]
    fn triangles_occlude() {
        let tri = [[0.0, 0.0, 1.0], [2.0, 0.0, 1.0], [0.0, 2.0, 1.0]];
        let occ = Occluders::new(&[], &[tri]);
        assert!(occ.occluded([0.5, 0.5, 0.0], [0.5, 0.5, 2.0]));
        assert!(
            occ.occluded([0.5, 0.5, 2.0], [0.5, 0.5, 0.0]),
            "either winding"
        );
        assert!(
            !occ.occluded([1.5, 1.5, 0.0], [1.5, 1.5, 2.0]),
            "outside the hypotenuse"
        );
        assert!(
            !occ.occluded([0.5, 0.5, 0.0], [0.5, 0.5, 0.9]),
            "stops short"
        );
        // A shared edge between two triangles has no crack (the diagonal x + y = 2).
        let other = [[2.0, 0.0, 1.0], [2.0, 2.0, 1.0], [0.0, 2.0, 1.0]];
        let occ = Occluders::new(&[], &[tri, other]);
        assert!(occ.occluded([1.0, 1.0, 0.0], [1.0, 1.0, 2.0]));
    }
}
