//! The occluding primitives (axis-aligned rects and triangles) with their exact segment
//! tests, and the bounding-volume hierarchy over them ([`Tree`]): median split over centroids
//! along the longest centroid axis, leaves of at most [`LEAF_SIZE`] primitives, nodes in one
//! flat array, traversed iteratively with a fixed-size stack. Primitives may carry the posed
//! object they belong to ([`Tree::owners`]), kept through the build's reordering.
//!
//! Units: metres, world frame, f32. Invariant: node boxes are padded (by the caller's `pad`),
//! so traversal answers exactly what a loop over every primitive with the same tests answers.

use lightfarm_proto::glam::Vec3;

use lightfarm_proto::face::tangent_axes;

/// Most primitives in a leaf.
pub const LEAF_SIZE: usize = 4;
/// Depth of the traversal stack. Median splits halve the primitive count per level, so depth
/// is at most `log2(n / LEAF_SIZE) + 1`: 64 covers any count that fits in memory.
const STACK_DEPTH: usize = 64;

/// One occluding primitive.
#[derive(Clone, Copy, Debug)]
pub(super) enum Prim {
    /// `axis`, plane `coord`, tangent-axis bounds (tangents are the other two axes ascending).
    Rect {
        axis: u8,
        coord: f32,
        min: [f32; 2],
        max: [f32; 2],
    },
    Tri([[f32; 3]; 3]),
}

/// A BVH node. `count > 0`: a leaf holding `prims[first .. first + count]`; `count == 0`: an
/// inner node whose children are `nodes[first]` and `nodes[first + 1]`.
#[derive(Clone, Copy, Debug)]
pub(super) struct Node {
    pub(super) min: [f32; 3],
    pub(super) max: [f32; 3],
    pub(super) first: u32,
    pub(super) count: u32,
}

/// A BVH over primitives (see the module doc).
#[derive(Clone, Debug)]
pub(super) struct Tree {
    /// Primitives, reordered so every leaf's are contiguous.
    pub(super) prims: Vec<Prim>,
    /// Per primitive (same order), the posed object it belongs to
    /// ([`Occluders::with_objects_triangles`]; [`NO_OWNER`] for none); empty when no
    /// primitive has one.
    pub(super) owners: Vec<u32>,
    pub(super) nodes: Vec<Node>,
}

/// The owner of a primitive that belongs to no posed object.
pub(super) const NO_OWNER: u32 = u32::MAX;

impl Prim {
    pub(super) fn bounds(&self) -> ([f32; 3], [f32; 3]) {
        match *self {
            Prim::Rect {
                axis,
                coord,
                min,
                max,
            } => {
                let (u, v) = tangent_axes(axis as usize);
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

    pub(super) fn centroid(&self) -> [f32; 3] {
        let (lo, hi) = self.bounds();
        [
            0.5 * (lo[0] + hi[0]),
            0.5 * (lo[1] + hi[1]),
            0.5 * (lo[2] + hi[2]),
        ]
    }

    /// Does the primitive cross the segment `o + t·d` for `tmin < t < tmax`?
    #[inline]
    pub(super) fn hit(&self, o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
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
                let (u, v) = tangent_axes(axis as usize);
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

pub(super) fn union(a: ([f32; 3], [f32; 3]), b: ([f32; 3], [f32; 3])) -> ([f32; 3], [f32; 3]) {
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

impl Tree {
    /// The hierarchy over `prims`, node boxes padded by `pad`.
    pub(super) fn build(prims: Vec<Prim>, pad: f32) -> Tree {
        let (tree, _) = Tree::build_with(prims.into_iter().map(|p| (p, ())).collect(), pad);
        tree
    }

    /// [`Tree::build`] over primitives with their owners (kept in [`Tree::owners`]).
    pub(super) fn build_owned(prims: Vec<(Prim, u32)>, pad: f32) -> Tree {
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
    pub(super) fn prims_in_box(&self, lo: [f32; 3], hi: [f32; 3], first: u32, out: &mut Vec<u32>) {
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
    pub(super) fn occluded(&self, origin: Vec3, d: Vec3, tmin: f32, tmax: f32) -> bool {
        self.occluded_by(origin, d, tmin, tmax, |_| true)
    }

    /// [`Tree::occluded`] by the primitives `counts(i)` holds (i in the tree's order).
    #[inline(always)]
    pub(super) fn occluded_by(
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
