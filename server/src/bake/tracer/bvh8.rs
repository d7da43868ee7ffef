//! An eight-wide BVH over primitive bounds, traversed one ray at a time with f32 box tests in
//! two 4-lane halves.
//!
//! Owns the node layout and the traversal; what a leaf's primitive is, and how it is tested,
//! is the caller's (the traversal hands it a *slot*, an index into [`Bvh8::primitive_indices`],
//! so per-primitive data stored in slot order is read from neighbouring memory, or a whole
//! leaf's slots at once with [`Bvh8::traverse_leaves`]).
//!
//! Built from `obvhs`'s BVH2 (PLOC, reinsertion, SAH leaf collapse) by pulling each node's
//! grandchildren up until it has eight children. Each node stores its children's boxes as
//! structure-of-arrays `f32` lanes, so one ray tests eight boxes with two handfuls of SSE
//! instructions (glam's `Vec4` is an `__m128` on x86-64), then visits the hit children nearest
//! first: the nearest next, without a trip through the stack (6.5 → 7.5 Mrays/s on the bench's
//! triangle rays, one thread), the others pushed farthest first. Eight children rather than
//! four: 7.5-7.9 → 8.5 Mrays/s on those rays (fewer nodes per ray; 4.5 four-wide nodes per ray
//! on the maze).
//!
//! Units and frames: world metres, the boxes as given (callers pad them). Invariant: the box
//! test is conservative for any box it reaches — a ray whose segment `[0, tmax]` touches a
//! child's box (to within f32 rounding of the slab distances, or of `o · inv` in the fused
//! test) visits that child, including rays parallel to a slab (a zero direction component is
//! replaced by ±1e-30 before inverting, so the slab test stays finite and ordered). Which
//! slots a ray visits depends on the tree, so callers that want an answer independent of it
//! must make their choice among hits order-independent (the tracer does).

use glam::{Vec3A, Vec4};
use obvhs::{aabb::Aabb, bvh2::builder::build_bvh2, Boundable, BvhBuildParams};
use std::mem::MaybeUninit;
use std::time::Duration;

/// Child slot marked as a leaf: bit 31 set, bits 27..31 the primitive count - 1, bits 0..27 the
/// first slot.
const LEAF: u32 = 1 << 31;
const COUNT_SHIFT: u32 = 27;
const FIRST_MASK: u32 = (1 << COUNT_SHIFT) - 1;
/// Most primitives per leaf (the count is coded in four bits).
const MAX_LEAF: u32 = 8;
/// The SAH cost of a traversal step against one primitive test, for the leaf collapse, when a
/// leaf's primitives are tested one by one (rectangles): obvhs's preset says 3; 1 makes smaller
/// leaves, which pays here because the tracer's primitive test (f32 with margins) costs more
/// than a wide box test. Measured on the bench's rays, one thread: maze triangles 4.99 (obvhs
/// CWBVH) → 7.19 Mrays/s, rectangles 5.90 → 8.83; cost 1.5 gave 7.10 / 7.25, cost 3 about
/// 10–25% less.
pub const COLLAPSE_COST: f32 = 1.0;
/// [`COLLAPSE_COST`] for leaves of triangles, which the tracer tests four at a time (one packet
/// test costs about one triangle's), so a step costs more against each triangle and larger
/// leaves pay. Measured with the AVX-512 copy, interleaved (Mrays/s on the bench's triangle
/// rays, one thread): maze 9.21 / 8.97 / 8.77 / 9.10 / 9.08 at cost 1 against 9.33 / 9.26 /
/// 9.25 / 9.36 / 9.12 at 2 (1.5: in between; 3: 6-8% below cost 1); cornell_mesh +4-5%; the
/// same cost on rectangles lost 8-20% (maze 10.1-10.8 → 8.2-8.4), hence two costs.
pub const TRIANGLE_COLLAPSE_COST: f32 = 2.0;
/// Entries of the traversal stack kept on the machine stack; a deeper tree (needing more than
/// seven per level of inner nodes, plus the root) takes a heap stack instead.
const STACK: usize = 128;
/// Children per node.
const W: usize = 8;

/// One node: its children's boxes as lanes (`bounds[2·axis]` the minima, `bounds[2·axis + 1]`
/// the maxima, each as two halves of four lanes), what each child is, and which exist. Aligned
/// to a cache line, so a node is four whole lines (bench rays, interleaved: +0.7%).
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
struct Node {
    bounds: [[Vec4; 2]; 6],
    child: [u32; W],
    /// Bit `i` set when child `i` exists.
    valid: u32,
}

/// An eight-wide BVH; see the module doc.
#[derive(Clone, Debug)]
pub struct Bvh8 {
    nodes: Vec<Node>,
    /// Slot → the index of the primitive given to [`Bvh8::build`].
    pub primitive_indices: Vec<u32>,
    /// The most stack entries a traversal can hold: each inner node visited pushes at most
    /// three (its nearest hit child is visited next, not pushed).
    stack_need: usize,
}

struct Bounded(Aabb);

impl Boundable for Bounded {
    fn aabb(&self) -> Aabb {
        self.0
    }
}

impl Bvh8 {
    /// Builds the tree over boxes (min, max), one per primitive, its leaves collapsed at
    /// `collapse_cost` (a traversal step's cost against one primitive test: [`COLLAPSE_COST`],
    /// [`TRIANGLE_COLLAPSE_COST`]); None when there are none.
    pub fn build(boxes: &[(Vec3A, Vec3A)], collapse_cost: f32) -> Option<Bvh8> {
        if boxes.is_empty() {
            return None;
        }
        let bounded: Vec<Bounded> = boxes
            .iter()
            .map(|&(lo, hi)| Bounded(Aabb::new(lo, hi)))
            .collect();
        let params = BvhBuildParams {
            max_prims_per_leaf: MAX_LEAF,
            collapse_traversal_cost: collapse_cost,
            ..BvhBuildParams::very_slow_build()
        };
        let bvh2 = build_bvh2(&bounded, params, &mut Duration::default());
        let n2 = &bvh2.nodes;
        let mut out = Bvh8 {
            nodes: Vec::with_capacity(n2.len() / 2 + 1),
            primitive_indices: bvh2.primitive_indices.clone(),
            stack_need: 0,
        };
        assert!(
            out.primitive_indices.len() <= FIRST_MASK as usize,
            "{} primitives are more than the BVH's slot code holds",
            out.primitive_indices.len()
        );
        let root = out.node_of(n2, &[0]);
        debug_assert_eq!(root, 0);
        out.stack_need = (W - 1) * out.depth(0) + 1;
        Some(out)
    }

    /// The most entries a traversal's stack holds (tests check the tree is deep).
    #[cfg(test)]
    pub(crate) fn stack_need(&self) -> usize {
        self.stack_need
    }

    /// Levels of inner nodes from `node` down, itself included.
    fn depth(&self, node: u32) -> usize {
        let n = &self.nodes[node as usize];
        1 + (0..W)
            .filter(|&lane| n.valid & (1 << lane) != 0 && n.child[lane] & LEAF == 0)
            .map(|lane| self.depth(n.child[lane]))
            .max()
            .unwrap_or(0)
    }

    /// Makes the node whose children are the BVH2 nodes `start`, widened to eight, and returns
    /// its index (children are made after their parent, so the root is node 0).
    fn node_of(&mut self, n2: &[obvhs::bvh2::node::Bvh2Node], start: &[u32]) -> u32 {
        let mut kids: Vec<u32> = start.to_vec();
        // Open the largest inner child until there are eight children or only leaves.
        while kids.len() < W {
            let inner = kids
                .iter()
                .enumerate()
                .filter(|(_, &k)| n2[k as usize].prim_count == 0)
                .max_by(|(_, &a), (_, &b)| {
                    let area = |k: u32| n2[k as usize].aabb.half_area();
                    area(a).total_cmp(&area(b))
                })
                .map(|(i, _)| i);
            let Some(i) = inner else { break };
            let k = kids.swap_remove(i) as usize;
            let first = n2[k].first_index;
            kids.push(first);
            kids.push(first + 1);
        }
        let index = self.nodes.len() as u32;
        let mut node = Node {
            bounds: [[Vec4::ZERO; 2]; 6],
            child: [0; W],
            valid: 0,
        };
        self.nodes.push(node);
        for (lane, &k) in kids.iter().enumerate() {
            let n = &n2[k as usize];
            for axis in 0..3 {
                node.bounds[2 * axis][lane / 4][lane % 4] = n.aabb.min[axis];
                node.bounds[2 * axis + 1][lane / 4][lane % 4] = n.aabb.max[axis];
            }
            node.valid |= 1 << lane;
            node.child[lane] = if n.prim_count == 0 {
                self.node_of(n2, &[n.first_index, n.first_index + 1])
            } else {
                self.leaf(n.first_index, n.prim_count, lane, &node)
            };
        }
        self.nodes[index as usize] = node;
        index
    }

    /// The child code of slots `first..first + count`, whose box is lane `lane` of `parent`: a
    /// leaf, or, over [`MAX_LEAF`] slots (the collapse is bounded by it, so not expected), a
    /// node of up to eight such children sharing that box.
    fn leaf(&mut self, first: u32, count: u32, lane: usize, parent: &Node) -> u32 {
        if count <= MAX_LEAF {
            return LEAF | ((count - 1) << COUNT_SHIFT) | first;
        }
        let index = self.nodes.len() as u32;
        let mut node = Node {
            bounds: parent
                .bounds
                .map(|b| [Vec4::splat(b[lane / 4][lane % 4]); 2]),
            child: [0; W],
            valid: 0,
        };
        self.nodes.push(node);
        let share = count.div_ceil(W as u32);
        for part in 0..W as u32 {
            let start = first + part * share;
            let end = (start + share).min(first + count);
            if start < end {
                node.valid |= 1 << part;
                node.child[part as usize] = self.leaf(start, end - start, part as usize, &node);
            }
        }
        self.nodes[index as usize] = node;
        index
    }

    /// Visits, nearest box first, the slots whose boxes the ray `o + t·d`, `0 ≤ t ≤ tmax`,
    /// reaches; `test(slot)` returns the primitive's distance (infinity for a miss), and a
    /// distance below the current `tmax` becomes the new `tmax`, so boxes beyond it are skipped.
    /// `test` may return a negative value to stop the traversal. Returns the final `tmax`.
    /// `COPY` is the tracer's compiled copy ([`super::InstructionSet`] as 0, 1, 2): from 1 the
    /// box test fuses its multiply and subtract ([`hits`]); it panics on a CPU without FMA.
    #[inline(always)]
    pub fn traverse<const COPY: u8>(
        &self,
        o: Vec3A,
        d: Vec3A,
        tmax: f32,
        mut test: impl FnMut(usize) -> f32,
    ) -> f32 {
        self.traverse_leaves::<COPY>(
            o,
            d,
            tmax,
            #[inline(always)]
            |first, count| {
                let mut nearest = f32::INFINITY;
                for slot in first..first + count {
                    let t = test(slot);
                    if t < 0.0 {
                        return t;
                    }
                    nearest = nearest.min(t);
                }
                nearest
            },
        )
    }

    /// [`Bvh8::traverse`] a leaf at a time: `leaf(first, count)` tests slots
    /// `first..first + count` and returns the nearest distance among them (infinity: none; a
    /// negative value stops the traversal). For callers that test a leaf's primitives together.
    #[inline(always)]
    pub fn traverse_leaves<const COPY: u8>(
        &self,
        o: Vec3A,
        d: Vec3A,
        tmax: f32,
        leaf: impl FnMut(usize, usize) -> f32,
    ) -> f32 {
        assert!(COPY == 0 || fma_detected(), "the fused box test needs FMA");
        if self.stack_need <= STACK {
            // Not zeroed (a kilobyte per ray): entries below the top are always written first.
            let mut stack = [const { MaybeUninit::<(u32, f32)>::uninit() }; STACK];
            self.walk::<COPY>(&mut stack, o, d, tmax, leaf)
        } else {
            let mut stack = vec![MaybeUninit::uninit(); self.stack_need];
            self.walk::<COPY>(&mut stack, o, d, tmax, leaf)
        }
    }

    /// Every leaf's slots, `(first, count)`, in slot order.
    pub fn leaves(&self) -> Vec<(usize, usize)> {
        let mut out: Vec<(usize, usize)> = self
            .nodes
            .iter()
            .flat_map(|n| {
                (0..W)
                    .filter(move |&l| n.valid & (1 << l) != 0)
                    .map(move |l| n.child[l])
            })
            .filter(|&code| code & LEAF != 0)
            .map(|code| {
                let first = (code & FIRST_MASK) as usize;
                (first, ((code >> COUNT_SHIFT) & 0xF) as usize + 1)
            })
            .collect();
        out.sort_unstable();
        out
    }

    /// [`Bvh8::traverse`] with a stack of at least `stack_need` entries.
    #[inline(always)]
    fn walk<const COPY: u8>(
        &self,
        stack: &mut [MaybeUninit<(u32, f32)>],
        o: Vec3A,
        d: Vec3A,
        tmax: f32,
        mut leaf: impl FnMut(usize, usize) -> f32,
    ) -> f32 {
        let safe = |x: f32| {
            if x.abs() < 1e-30 {
                1e30f32.copysign(x)
            } else {
                1.0 / x
            }
        };
        let inv = [safe(d.x), safe(d.y), safe(d.z)];
        let o = o.to_array();
        let ray = RayConstants {
            o,
            o_inv: [0, 1, 2].map(|k| o[k] * inv[k]),
            inv,
            near: inv.map(|i| usize::from(i < 0.0)),
        };
        let mut tmax = tmax;
        // The node being visited; the nearest hit child is visited next without a trip through
        // the stack, the others are pushed farthest first.
        let mut code = 0u32; // the root, entered at distance 0
        let mut top = 0usize;
        loop {
            if code & LEAF != 0 {
                let first = (code & FIRST_MASK) as usize;
                let count = ((code >> COUNT_SHIFT) & 0xF) as usize + 1;
                let t = leaf(first, count);
                if t < tmax {
                    if t < 0.0 {
                        return t;
                    }
                    tmax = t;
                }
            } else {
                let node = &self.nodes[code as usize];
                let (mask, t) = hits::<COPY>(node, &ray, tmax);
                let mut hits = mask & node.valid;
                if hits != 0 {
                    if hits & (hits - 1) == 0 {
                        code = node.child[hits.trailing_zeros() as usize];
                        continue;
                    }
                    let first = hits.trailing_zeros() as usize;
                    let rest = hits & (hits - 1);
                    if rest & (rest - 1) == 0 {
                        // Two: the nearer next, the other pushed (the sort's order on a tie).
                        let second = rest.trailing_zeros() as usize;
                        let (near, far) = if t[second] <= t[first] {
                            (second, first)
                        } else {
                            (first, second)
                        };
                        stack[top].write((node.child[far], t[far]));
                        top += 1;
                        code = node.child[near];
                        continue;
                    }
                    // Sort the hit children nearest first; push all but the nearest.
                    let mut order = [(0f32, 0u32); W];
                    let mut n = 0;
                    while hits != 0 {
                        let lane = hits.trailing_zeros() as usize;
                        hits &= hits - 1;
                        let mut i = n;
                        while i > 0 && order[i - 1].0 < t[lane] {
                            order[i] = order[i - 1];
                            i -= 1;
                        }
                        order[i] = (t[lane], node.child[lane]);
                        n += 1;
                    }
                    for &(entry, child) in &order[..n - 1] {
                        stack[top].write((child, entry));
                        top += 1;
                    }
                    code = order[n - 1].1;
                    continue;
                }
            }
            // Next: the nearest pushed child still within reach.
            loop {
                if top == 0 {
                    return tmax;
                }
                top -= 1;
                // SAFETY: every slot below `top` was written by the push that raised `top`
                // past it.
                let (next, entry) = unsafe { stack[top].assume_init() };
                if entry <= tmax {
                    code = next;
                    break;
                }
            }
        }
    }
}

/// What the box test reads of a ray: its origin, the inverse direction and, per axis, which of
/// a box's two planes it meets first (1: the maximum).
struct RayConstants {
    o: [f32; 3],
    inv: [f32; 3],
    /// `o · inv` per axis (the fused box test's).
    o_inv: [f32; 3],
    near: [usize; 3],
}

/// Whether the CPU runs FMA (std caches the answer).
fn fma_detected() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The children of `node` the ray reaches before `tmax` (bit per lane) and each lane's entry
/// distance, four lanes at a time (an eight-lane AVX copy of this test measured no faster:
/// 7.7-7.9 against 7.9-8.6 Mrays/s on the bench's triangle rays; an eight-lane fused one,
/// 5.7 against 7.3, slower still). `COPY` ≥ 1 takes [`hits_fused`] (FMA checked by
/// [`Bvh8::traverse_leaves`]).
#[inline(always)]
fn hits<const COPY: u8>(node: &Node, ray: &RayConstants, tmax: f32) -> (u32, [f32; W]) {
    #[cfg(target_arch = "x86_64")]
    if COPY >= 1 {
        // SAFETY: `Bvh8::traverse_leaves` checked the CPU runs FMA (and SSE, x86-64's
        // baseline, is always there).
        return unsafe { hits_fused(node, ray, tmax) };
    }
    let b = &node.bounds;
    let near = ray.near;
    let [ox, oy, oz] = ray.o.map(Vec4::splat);
    let [ix, iy, iz] = ray.inv.map(Vec4::splat);
    let tm = Vec4::splat(tmax);
    let mut mask = 0u32;
    let mut t = [0f32; W];
    for h in 0..2 {
        let tnear = ((b[near[0]][h] - ox) * ix)
            .max((b[2 + near[1]][h] - oy) * iy)
            .max((b[4 + near[2]][h] - oz) * iz)
            .max(Vec4::ZERO);
        let tfar = ((b[1 - near[0]][h] - ox) * ix)
            .min((b[3 - near[1]][h] - oy) * iy)
            .min((b[5 - near[2]][h] - oz) * iz)
            .min(tm);
        mask |= tnear.cmple(tfar).bitmask() << (4 * h);
        t[4 * h..4 * h + 4].copy_from_slice(&tnear.to_array());
    }
    (mask, t)
}

/// [`hits`] with each slab distance `(b − o) · inv` taken as `b · inv − o · inv` in one fused
/// multiply-subtract (`o · inv` made once per ray): a shorter chain per node (bench rays,
/// maze triangles, one thread, interleaved: 7.36 → 7.55 Mrays/s). Rounding differs from the
/// plain test's by about `|o| · 2⁻²⁴` along an axis, far inside the padding of the boxes
/// (module doc), so no primitive a ray can hit is skipped either way.
///
/// # Safety
/// The CPU must run FMA.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
unsafe fn hits_fused(node: &Node, ray: &RayConstants, tmax: f32) -> (u32, [f32; W]) {
    use std::arch::x86_64::*;
    // Lane `l` of bounds row `i` is float `8 i + l` of the node (rows of two `Vec4` halves).
    let b = node.bounds.as_ptr().cast::<f32>();
    let near = ray.near;
    let inv = ray.inv.map(|x| _mm_set1_ps(x));
    let o_inv = ray.o_inv.map(|x| _mm_set1_ps(x));
    let (zero, tm) = (_mm_setzero_ps(), _mm_set1_ps(tmax));
    let mut mask = 0u32;
    let mut t = [0f32; W];
    for h in 0..2 {
        // SAFETY: rows 0..6 and halves 0..2 lie inside `node.bounds`; FMA per the caller.
        let slab = |row: usize, k: usize| unsafe {
            _mm_fmsub_ps(_mm_loadu_ps(b.add(8 * row + 4 * h)), inv[k], o_inv[k])
        };
        let tnear = _mm_max_ps(
            _mm_max_ps(slab(near[0], 0), slab(2 + near[1], 1)),
            _mm_max_ps(slab(4 + near[2], 2), zero),
        );
        let tfar = _mm_min_ps(
            _mm_min_ps(slab(1 - near[0], 0), slab(3 - near[1], 1)),
            _mm_min_ps(slab(5 - near[2], 2), tm),
        );
        mask |= (_mm_movemask_ps(_mm_cmple_ps(tnear, tfar)) as u32) << (4 * h);
        // SAFETY: lanes 4h..4h + 4 of `t`.
        unsafe { _mm_storeu_ps(t.as_mut_ptr().add(4 * h), tnear) };
    }
    (mask, t)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(state: &mut u64) -> f32 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*state >> 40) as f32 / (1u64 << 24) as f32
    }

    /// A leaf over the coded size (which obvhs's collapse does not make) becomes nodes of
    /// leaves that together visit every slot once.
    #[test]
    fn an_oversized_leaf_is_split_and_every_slot_visited_once() {
        let mut bvh = Bvh8 {
            nodes: Vec::new(),
            primitive_indices: (0..45).collect(),
            stack_need: 0,
        };
        let mut root = Node {
            bounds: [-1.0, 1.0, -1.0, 1.0, -1.0, 1.0].map(|x| [Vec4::splat(x); 2]),
            child: [0; W],
            valid: 1,
        };
        bvh.nodes.push(root);
        root.child[0] = bvh.leaf(0, 45, 0, &root);
        bvh.nodes[0] = root;
        bvh.stack_need = (W - 1) * bvh.depth(0) + 1;
        assert!(bvh.depth(0) >= 2, "45 slots need a level below the root");
        let mut seen = vec![0; 45];
        bvh.traverse::<0>(Vec3A::ZERO, Vec3A::X, 10.0, |slot| {
            seen[slot] += 1;
            f32::INFINITY
        });
        assert_eq!(seen, vec![1; 45]);
    }

    /// Every box a ray's segment crosses is visited, on random boxes and rays including ones
    /// parallel to the axes, and the nearest-first order lets a closest-hit search stop early
    /// without losing the closest box entry: with the plain box test, and with the fused one
    /// where the CPU runs FMA.
    #[test]
    fn visits_every_box_the_segment_crosses() {
        visits_every_box::<0>();
        if fma_detected() {
            visits_every_box::<1>();
        }
    }

    fn visits_every_box<const COPY: u8>() {
        let mut s = 7u64;
        for n in [1usize, 2, 5, 17, 300] {
            let boxes: Vec<(Vec3A, Vec3A)> = (0..n)
                .map(|_| {
                    let c = Vec3A::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) * 10.0;
                    let h = Vec3A::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) * 0.8 + 0.01;
                    (c - h, c + h)
                })
                .collect();
            let bvh = Bvh8::build(&boxes, COLLAPSE_COST).unwrap();
            let mut sorted = bvh.primitive_indices.clone();
            sorted.sort_unstable();
            assert_eq!(sorted, (0..n as u32).collect::<Vec<_>>());
            for r in 0..400 {
                let o = Vec3A::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) * 10.0;
                let mut d = Vec3A::new(lcg(&mut s), lcg(&mut s), lcg(&mut s)) - 0.5;
                if r % 4 == 0 {
                    d[r / 4 % 3] = 0.0; // parallel to one slab
                }
                if r % 8 == 0 {
                    d[(r / 8 + 1) % 3] = 0.0;
                }
                let d = d.normalize();
                let tmax = 6.0;
                // Expected: boxes the segment crosses, by an f64 slab test with a margin.
                let crosses = |(lo, hi): (Vec3A, Vec3A), margin: f64| {
                    let (mut a, mut b) = (0.0f64, tmax as f64);
                    for k in 0..3 {
                        let (o, d) = (o[k] as f64, d[k] as f64);
                        let (l, h) = (lo[k] as f64 - margin, hi[k] as f64 + margin);
                        if d == 0.0 {
                            if o < l || o > h {
                                return false;
                            }
                        } else {
                            let (t0, t1) = ((l - o) / d, (h - o) / d);
                            a = a.max(t0.min(t1));
                            b = b.min(t0.max(t1));
                        }
                    }
                    a <= b
                };
                let mut visited = vec![false; n];
                bvh.traverse::<COPY>(o, d, tmax, |slot| {
                    visited[bvh.primitive_indices[slot] as usize] = true;
                    f32::INFINITY
                });
                // The nearest box entry, found with pruning, as by brute force.
                let entry = |(lo, hi): (Vec3A, Vec3A)| {
                    let (mut a, mut b) = (0.0f32, tmax);
                    for k in 0..3 {
                        if d[k] == 0.0 {
                            if o[k] < lo[k] || o[k] > hi[k] {
                                return f32::INFINITY;
                            }
                        } else {
                            let (t0, t1) = ((lo[k] - o[k]) / d[k], (hi[k] - o[k]) / d[k]);
                            a = a.max(t0.min(t1));
                            b = b.min(t0.max(t1));
                        }
                    }
                    if a <= b {
                        a
                    } else {
                        f32::INFINITY
                    }
                };
                let nearest = bvh.traverse::<COPY>(o, d, tmax, |slot| {
                    entry(boxes[bvh.primitive_indices[slot] as usize])
                });
                let brute = boxes.iter().map(|&b| entry(b)).fold(tmax, f32::min);
                assert!(
                    (nearest - brute).abs() <= 1e-4,
                    "ray {r}: {nearest} vs {brute}"
                );
                for (i, &b) in boxes.iter().enumerate() {
                    if crosses(b, -1e-4) {
                        assert!(visited[i], "box {i} of {n}, ray {r} crosses it unvisited");
                    }
                }
            }
        }
    }
}
