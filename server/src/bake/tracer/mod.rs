//! Ray casting against a [`Geometry`](crate::bake::scene::geometry::Geometry)'s primitives
//! through an eight-wide BVH ([`bvh8`]: built from obvhs's BVH2, traversed here).
//!
//! The exact answer is f64's: rectangles are closed at their edges so a closed box is
//! watertight, and where two coincident rectangles are hit at the same distance (back-to-back
//! walls of neighbouring blocks) the one whose lit side faces the ray wins; of hits of exactly
//! equal value the lower primitive index wins, so the answer does not depend on the BVH or the
//! order its leaves are visited in. Most rays never need f64 in the traversal, so each is
//! traced twice at most:
//! 1. **f32 first** (`Fast`, in BVH slot order): each primitive the traversal reaches is tested
//!    in f32 and comes out a sure miss, a sure hit, or unsure. "Sure" means by a margin about a
//!    hundred times f32's rounding bound (relative to the scene's scale, growing as the ray
//!    grazes the primitive); unsure is a hit or miss within the margin of a rectangle's edge or
//!    a triangle's, of `epsilon` or of `tmax`, or a primitive the ray nearly parallels. Two sure
//!    hits within each other's margins (coincident walls, corners) are compared by their exact
//!    f64 values, as the f64 path compares them.
//! 2. **f64 where it decides:** a ray with any unsure test is traced again with the f64 test in
//!    the traversal; any other ray's winner is its closest sure hit, whose distance is then
//!    computed in f64. Both give the same hit, bit for bit: a sure test agrees with f64's, and
//!    the closest sure hit (ties compared exactly) is f64's closest. `occluded` stops at the
//!    first sure hit and asks f64 only about unsure ones. An unsure test ends the f32
//!    traversal at once (the callback's negative distance), as a shadow ray's first hit does.
//!
//! `closest` takes a leaf at a time: its triangles go through module `packet` four at a time (each
//! lane's verdict is the one-triangle test's, bit for bit), its rectangles one by one.
//!
//! `closest` and `occluded` are compiled three times ([`InstructionSet`]): for the target's
//! baseline (SSE2 on x86-64), for AVX2 and for AVX-512, and run as the widest the CPU has
//! (checked once). The code is the same and so are the answers, bit for bit (no operation
//! changes its result; Rust fuses no multiply-add unless told to); the wider sets give the
//! inlined traversal, box and triangle tests three-operand forms and, with AVX-512VL, 32
//! vector registers instead of 16. One part differs on purpose: their box test fuses its
//! multiply and subtract (`bvh8`'s `hits_fused`), which moves a slab distance by a rounding
//! step, far inside the boxes' padding, so it changes no hit (bundles `cmp`-identical on
//! cornell_mesh, ball_corridor and the maze). The closures the traversal calls are marked
//! `#[inline(always)]`, since a closure left out of line is compiled for the baseline whatever
//! its caller is. On the bench's triangle rays (maze, one thread, interleaved): baseline 8.3,
//! AVX2 8.6, AVX-512 8.9 Mrays/s; `bench --throughput` side by side with Embree 0.91-0.92 : 1
//! on the baseline and 0.94-1.00 : 1 on AVX-512. (An eight-lane AVX box test on top measured
//! no faster.) With the fused box test, two hit children handled without the sort and
//! cache-line-aligned nodes, six interleaved runs each: 7.23 → 7.50 Mrays/s (medians, on a
//! slower day), and against Embree three runs 0.98, 0.95, 0.97 : 1 where the old binary gave
//! 0.94, 0.96 beside them.
//!
//! Layout: [`bvh8`] owns the tree and its traversal; `packet` the four-lane triangle test;
//! this file the primitives' tests and the choice among hits.
//!
//! Invariant: `closest` only reports hits with `t > epsilon`, where epsilon is relative to the
//! scene's scale, so rays leaving a surface never hit that surface again.

pub mod bvh8;
mod packet;

use glam::{DVec3, Vec3A};

use bvh8::Bvh8;
use packet::{FastTriangle, TrianglePacket};

use lightfarm_proto::face::tangent_axes;

use crate::bake::scene::geometry::Primitive;

/// A ray hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f64,
    pub primitive: u32,
    pub point: [f64; 3],
    /// For rectangles with a lit surface: true when the ray arrives on the lit side.
    pub front: bool,
    /// Geometric normal facing the ray origin.
    pub normal: [f64; 3],
}

/// A primitive's f32 copy for the first test, stored in BVH slot order (the order
/// `Bvh8::primitive_indices` lists) so a leaf reads neighbouring memory and no `Primitive`.
#[derive(Clone, Copy, Debug)]
enum Fast {
    /// The plane's axis and coordinate, and the extent along the two tangents.
    Rect {
        axis: u8,
        coord: f32,
        min: [f32; 2],
        max: [f32; 2],
    },
    Triangle(FastTriangle),
}

/// How [`Tracer::closest`] tests one leaf: its triangles' packets
/// (`packets[first..end]`), then its rectangles one by one.
#[derive(Clone, Copy, Debug, Default)]
struct LeafTests {
    packets: (u32, u32),
    rects: bool,
}

/// [`Tracer::closest`]'s closest sure hit so far: its slot, f32 distance and margin, and its
/// exact value once a near tie asked for it.
type SureHit = (usize, f32, f32, Option<f32>);

/// What the f32 test says about one primitive.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Verdict {
    Miss,
    /// A hit at this f32 distance, with this margin on it.
    Hit(f32, f32),
    Unsure,
}

/// The margin of the f32 test, relative to its rounding bound (~1e-7 of the scene's scale).
const F32_MARGIN: f32 = 2e-6;

/// Each leaf's triangles as packets of four, and per leaf (at its first slot) where they are.
fn leaf_packets(bvh: &Bvh8, fast: &[Fast]) -> (Vec<TrianglePacket>, Vec<LeafTests>) {
    let mut packets = Vec::new();
    let mut leaves = vec![LeafTests::default(); fast.len()];
    for (first, count) in bvh.leaves() {
        let begin = packets.len() as u32;
        let mut lanes = Vec::with_capacity(4);
        let mut rects = false;
        for (slot, f) in fast.iter().enumerate().skip(first).take(count) {
            match *f {
                Fast::Triangle(t) => lanes.push((slot as u32, t)),
                Fast::Rect { .. } => rects = true,
            }
            if lanes.len() == 4 {
                packets.push(TrianglePacket::new(&lanes));
                lanes.clear();
            }
        }
        if !lanes.is_empty() {
            packets.push(TrianglePacket::new(&lanes));
        }
        leaves[first] = LeafTests {
            packets: (begin, packets.len() as u32),
            rects,
        };
    }
    (packets, leaves)
}

/// The instruction set the traversal and the f32 tests are compiled for (the same code,
/// compiled more than once; `closest` and `occluded` give the same answer bit for bit on every
/// one, since none changes an f32 or f64 operation's result: Rust never fuses a multiply and an
/// add unless told to, and the wider sets only add registers and three-operand forms).
/// Ordered narrowest first.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Debug)]
pub enum InstructionSet {
    /// x86-64's baseline (SSE2), or whatever the target is built for elsewhere.
    Baseline,
    /// AVX2 with FMA, BMI1/2, LZCNT and POPCNT.
    Avx2,
    /// The AVX2 set plus AVX-512F and VL (sixteen more vector registers for 128-bit lanes).
    Avx512,
}

impl InstructionSet {
    /// The widest set this CPU runs (checked once), capped by the environment variable
    /// `LIGHTFARM_INSTRUCTION_SET` (`baseline` or `avx2`; for comparing the copies' speed in a
    /// whole bake, since every copy gives the same bytes).
    pub fn detected() -> InstructionSet {
        static DETECTED: std::sync::OnceLock<InstructionSet> = std::sync::OnceLock::new();
        *DETECTED.get_or_init(|| {
            let cap = std::env::var("LIGHTFARM_INSTRUCTION_SET").unwrap_or_default();
            if cap.eq_ignore_ascii_case("baseline") {
                return InstructionSet::Baseline;
            }
            #[cfg(target_arch = "x86_64")]
            {
                use std::arch::is_x86_feature_detected as has;
                let avx2 = has!("avx2")
                    && has!("fma")
                    && has!("bmi1")
                    && has!("bmi2")
                    && has!("lzcnt")
                    && has!("popcnt");
                if avx2 && has!("avx512f") && has!("avx512vl") && !cap.eq_ignore_ascii_case("avx2")
                {
                    return InstructionSet::Avx512;
                }
                if avx2 {
                    return InstructionSet::Avx2;
                }
            }
            InstructionSet::Baseline
        })
    }
}

/// `pub fn $name(&self, args) -> ret` running `$portable::<COPY>` (an `#[inline(always)]`
/// method) as compiled for [`Tracer::instruction_set`]: `$avx2` and `$avx512` are the copies
/// compiled with those target features, `COPY` 0, 1, 2 the baseline, AVX2 and AVX-512.
macro_rules! compiled_copies {
    (
        $(#[$doc:meta])*
        fn $name:ident, $avx2:ident, $avx512:ident = $portable:ident(
            $($arg:ident: $ty:ty),* $(,)?
        ) -> $ret:ty
    ) => {
        $(#[$doc])*
        pub fn $name(&self, $($arg: $ty),*) -> $ret {
            #[cfg(target_arch = "x86_64")]
            match self.isa {
                // SAFETY: the CPU runs the set (`isa` is at most `InstructionSet::detected`);
                // the copies have no other contract.
                InstructionSet::Avx512 => return unsafe { self.$avx512($($arg),*) },
                InstructionSet::Avx2 => return unsafe { self.$avx2($($arg),*) },
                InstructionSet::Baseline => {}
            }
            self.$portable::<0>($($arg),*)
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
        unsafe fn $avx2(&self, $($arg: $ty),*) -> $ret {
            self.$portable::<1>($($arg),*)
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx512f,avx512vl,avx2,fma,bmi1,bmi2,lzcnt,popcnt")]
        unsafe fn $avx512(&self, $($arg: $ty),*) -> $ret {
            self.$portable::<2>($($arg),*)
        }
    };
}

/// A BVH over primitives.
pub struct Tracer {
    bvh: Option<Bvh8>,
    /// Per BVH slot: the f32 copy of the primitive `bvh.primitive_indices[slot]` names.
    fast: Vec<Fast>,
    /// Every leaf's triangles in packets of four (leaf by leaf, in slot order).
    packets: Vec<TrianglePacket>,
    /// Per BVH slot that begins a leaf: its packets and whether it holds rectangles.
    leaves: Vec<LeafTests>,
    primitives: Vec<Primitive>,
    /// Per primitive index, a triangle's normal `(v1 − v0) × (v2 − v0)` and that divided by
    /// its length, made once so a hit does not take a square root (zeros for rectangles).
    triangle_normals: Vec<[DVec3; 2]>,
    /// Smallest accepted hit distance.
    pub epsilon: f64,
    edge_epsilon: f64,
    /// The scene's scale (f32), which the f32 test's margins follow.
    scale: f32,
    /// What `closest` and `occluded` run as (at most [`InstructionSet::detected`]).
    isa: InstructionSet,
}

fn v3(p: [f64; 3]) -> Vec3A {
    Vec3A::new(p[0] as f32, p[1] as f32, p[2] as f32)
}

fn primitive_bounds(p: &Primitive, pad: f64) -> ([f64; 3], [f64; 3]) {
    let (mut lo, mut hi) = match p {
        Primitive::Rect {
            axis,
            coord,
            min,
            max,
            ..
        } => {
            let (u, v) = tangent_axes(*axis);
            let mut lo = [0.0; 3];
            let mut hi = [0.0; 3];
            lo[*axis] = *coord;
            hi[*axis] = *coord;
            lo[u] = min[0];
            hi[u] = max[0];
            lo[v] = min[1];
            hi[v] = max[1];
            (lo, hi)
        }
        Primitive::Triangle { v, .. } => {
            let mut lo = v[0];
            let mut hi = v[0];
            for p in v {
                for k in 0..3 {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
            }
            (lo, hi)
        }
    };
    for k in 0..3 {
        let pad_k = pad + (lo[k].abs().max(hi[k].abs())) * 1e-6;
        lo[k] -= pad_k;
        hi[k] += pad_k;
    }
    (lo, hi)
}

impl Tracer {
    /// Builds the BVH. `scale` is the scene's largest coordinate magnitude.
    pub fn new(primitives: Vec<Primitive>, scale: f64) -> Tracer {
        let epsilon = 1e-5 * scale.max(1e-3);
        let boxes: Vec<(Vec3A, Vec3A)> = primitives
            .iter()
            .map(|p| {
                let (lo, hi) = primitive_bounds(p, epsilon);
                (v3(lo), v3(hi))
            })
            .collect();
        // Leaves collapse at the cost of what most primitives are (a leaf's triangles are
        // tested four at a time, its rectangles one by one).
        let triangles = primitives
            .iter()
            .filter(|p| matches!(p, Primitive::Triangle { .. }))
            .count();
        let collapse_cost = if 2 * triangles > primitives.len() {
            bvh8::TRIANGLE_COLLAPSE_COST
        } else {
            bvh8::COLLAPSE_COST
        };
        let bvh = Bvh8::build(&boxes, collapse_cost);
        let fast = bvh.as_ref().map_or(Vec::new(), |bvh| {
            let f = |x: f64| x as f32;
            let v3d = |p: DVec3| v3(p.to_array());
            bvh.primitive_indices
                .iter()
                .map(|&i| match &primitives[i as usize] {
                    Primitive::Rect {
                        axis,
                        coord,
                        min,
                        max,
                        ..
                    } => Fast::Rect {
                        axis: *axis as u8,
                        coord: f(*coord),
                        min: min.map(f),
                        max: max.map(f),
                    },
                    Primitive::Triangle { v, .. } => {
                        let [v0, v1, v2] = v.map(DVec3::from);
                        Fast::Triangle(FastTriangle {
                            v0: v3d(v0),
                            e1: v3d(v1 - v0),
                            e2: v3d(v2 - v0),
                            len1: (v1 - v0).length() as f32,
                            len2: (v2 - v0).length() as f32,
                        })
                    }
                })
                .collect()
        });
        let (packets, leaves) = match &bvh {
            Some(bvh) => leaf_packets(bvh, &fast),
            None => (Vec::new(), Vec::new()),
        };
        Tracer {
            bvh,
            fast,
            packets,
            leaves,
            triangle_normals: primitives
                .iter()
                .map(|p| match p {
                    Primitive::Triangle { v, .. } => {
                        let [v0, v1, v2] = v.map(DVec3::from);
                        let n = (v1 - v0).cross(v2 - v0);
                        [n, n / n.length()]
                    }
                    Primitive::Rect { .. } => [DVec3::ZERO; 2],
                })
                .collect(),
            primitives,
            epsilon,
            edge_epsilon: 1e-9 * scale.max(1e-3),
            scale: scale.max(1e-3) as f32,
            isa: InstructionSet::detected(),
        }
    }

    /// The same tracer running `closest` and `occluded` as `isa`, or as the detected set when
    /// `isa` is wider than this CPU runs (for comparing the compiled copies; each gives the
    /// same answers).
    pub fn with_instruction_set(mut self, isa: InstructionSet) -> Tracer {
        self.isa = isa.min(InstructionSet::detected());
        self
    }

    /// What `closest` and `occluded` run as.
    pub fn instruction_set(&self) -> InstructionSet {
        self.isa
    }

    /// The f32 test of BVH slot `slot` against the ray `o + t·d` (as f32) for
    /// `epsilon < t < far`; see the module doc. The margins: on a distance, `F32_MARGIN` of the
    /// scale divided by how squarely the ray meets the primitive, plus the same fraction of the
    /// distance; on a position (a rectangle) or a barycentric coordinate (a triangle), the
    /// distance's margin carried over plus that of the point itself. A hit's distance is
    /// returned with its margin; the caller judges it against `far` and other hits.
    #[inline(always)]
    fn classify(&self, slot: usize, o: Vec3A, d: Vec3A, epsilon: f32, far: f32) -> Verdict {
        let s = self.scale;
        match self.fast[slot] {
            Fast::Rect {
                axis,
                coord,
                min,
                max,
            } => {
                let a = axis as usize;
                let da = d[a];
                let t = (coord - o[a]) / da;
                let mt = F32_MARGIN * (s / da.abs() + t.abs());
                if da == 0.0 || t < epsilon - mt || t > far + mt {
                    return Verdict::Miss;
                }
                let (u, v) = tangent_axes(a);
                let pu = o[u] + t * d[u];
                let pv = o[v] + t * d[v];
                let m = F32_MARGIN * s + mt;
                if pu < min[0] - m || pu > max[0] + m || pv < min[1] - m || pv > max[1] + m {
                    return Verdict::Miss;
                }
                let inside =
                    pu > min[0] + m && pu < max[0] - m && pv > min[1] + m && pv < max[1] - m;
                if !inside || t <= epsilon + mt || da.abs() < 1e-3 {
                    return Verdict::Unsure;
                }
                Verdict::Hit(t, mt)
            }
            Fast::Triangle(FastTriangle {
                v0,
                e1,
                e2,
                len1,
                len2,
            }) => {
                let p = d.cross(e2);
                let det = e1.dot(p);
                let inv = 1.0 / det;
                let sv = o - v0;
                let a = sv.dot(p) * inv;
                let q = sv.cross(e1);
                let b = d.dot(q) * inv;
                let t = e2.dot(q) * inv;
                // |sv| ≤ ~2 scale inside the scene; the rounding of sv, p and q is a few f32
                // steps of scale·|e|, divided by |det| in the barycentrics and the distance.
                let bound = 3.0 * s * len1.max(len2) * inv.abs();
                let m = F32_MARGIN * (bound + 1.0);
                let mt = F32_MARGIN * (bound * len2 + t.abs() + s);
                let parallel = !(det.abs() > 1e-3 * len1 * len2);
                if !parallel
                    && (t < epsilon - mt
                        || t > far + mt
                        || a < -m
                        || a > 1.0 + m
                        || b < -m
                        || a + b > 1.0 + 2.0 * m)
                {
                    return Verdict::Miss;
                }
                if parallel || a < m || b < m || a + b > 1.0 - 2.0 * m || t <= epsilon + mt {
                    return Verdict::Unsure;
                }
                Verdict::Hit(t, mt)
            }
        }
    }

    pub fn primitives(&self) -> &[Primitive] {
        &self.primitives
    }

    /// Distance along the ray to `primitive`, if hit beyond epsilon and before `tmax`.
    fn intersect(&self, primitive: &Primitive, o: [f64; 3], d: [f64; 3], tmax: f64) -> Option<f64> {
        match primitive {
            Primitive::Rect {
                axis,
                coord,
                min,
                max,
                ..
            } => {
                if d[*axis] == 0.0 {
                    return None;
                }
                let t = (coord - o[*axis]) / d[*axis];
                if !(t > self.epsilon && t < tmax) {
                    return None;
                }
                let (u, v) = tangent_axes(*axis);
                let pu = o[u] + t * d[u];
                let pv = o[v] + t * d[v];
                let e = self.edge_epsilon;
                (pu >= min[0] - e && pu <= max[0] + e && pv >= min[1] - e && pv <= max[1] + e)
                    .then_some(t)
            }
            Primitive::Triangle { v, .. } => {
                let [v0, v1, v2] = v.map(DVec3::from);
                let d = DVec3::from(d);
                let e1 = v1 - v0;
                let e2 = v2 - v0;
                let p = d.cross(e2);
                let det = e1.dot(p);
                if det.abs() < 1e-300 {
                    return None;
                }
                let inv = 1.0 / det;
                let s = DVec3::from(o) - v0;
                let a = s.dot(p) * inv;
                if !(-1e-12..=1.0 + 1e-12).contains(&a) {
                    return None;
                }
                let q = s.cross(e1);
                let b = d.dot(q) * inv;
                if b < -1e-12 || a + b > 1.0 + 1e-12 {
                    return None;
                }
                let t = e2.dot(q) * inv;
                (t > self.epsilon && t < tmax).then_some(t)
            }
        }
    }

    /// Geometric normal of primitive `index` facing against the ray direction `d`.
    fn normal_facing(&self, index: u32, d: [f64; 3]) -> [f64; 3] {
        match &self.primitives[index as usize] {
            Primitive::Rect { axis, .. } => {
                let mut n = [0.0; 3];
                n[*axis] = if d[*axis] > 0.0 { -1.0 } else { 1.0 };
                n
            }
            Primitive::Triangle { .. } => {
                let [n, unit] = self.triangle_normals[index as usize];
                // −(n / |n|) is (−n) / |n| bit for bit: negation is exact.
                let unit = if n.dot(DVec3::from(d)) > 0.0 {
                    -unit
                } else {
                    unit
                };
                unit.to_array()
            }
        }
    }

    compiled_copies! {
        /// Closest hit along `o + t·d` (d unit) with `epsilon < t < tmax`. `lit_normal_sign`
        /// gives, for a rectangle with a surface, the sign of its lit normal along its axis; it
        /// is used to prefer the lit side when coincident rectangles tie.
        fn closest, closest_avx2, closest_avx512 = closest_portable(
            o: [f64; 3],
            d: [f64; 3],
            tmax: f64,
            lit_normal_sign: &dyn Fn(u32) -> f64,
        ) -> Option<Hit>
    }

    /// `closest`'s body, inlined into each compiled copy; `COPY` tells the copies apart, so
    /// each copy's closures are functions of their own, compiled for its instruction set
    /// (shared, a closure the inliner leaves out of line would run as the baseline's).
    #[inline(always)]
    fn closest_portable<const COPY: u8>(
        &self,
        o: [f64; 3],
        d: [f64; 3],
        tmax: f64,
        lit_normal_sign: &dyn Fn(u32) -> f64,
    ) -> Option<Hit> {
        let bvh = self.bvh.as_ref()?;
        let reach = tmax as f32 * (1.0 + 1e-6) + 1e-6;
        // 1. f32: the closest sure hit, unless a test was unsure.
        let (of, df) = (v3(o), v3(d));
        let (epsilon, limit) = (self.epsilon as f32, tmax as f32);
        let exact_value = |slot: usize| {
            self.exact_value(bvh.primitive_indices[slot], o, d, tmax, lit_normal_sign)
        };
        let mut unsure = false;
        let mut best: Option<SureHit> = None;
        // What one primitive's verdict does to the search: its distance for the traversal,
        // or -1 for an unsure test, which ends the traversal (f64 decides from the start).
        // (`identity` only so that the closure is an argument: an attribute on a `let`'s
        // expression is not stable Rust, one on a call's argument is.)
        let take = std::convert::identity(
            #[inline(always)]
            |id: usize, verdict: Verdict, best: &mut Option<SureHit>, unsure: &mut bool| {
                match verdict {
                    Verdict::Miss => f32::INFINITY,
                    Verdict::Unsure => {
                        *unsure = true;
                        -1.0
                    }
                    Verdict::Hit(t, m) if (t - limit).abs() <= m => {
                        *unsure = true; // at `tmax`: f64 decides
                        -1.0
                    }
                    Verdict::Hit(t, m) => match *best {
                        // A near tie (coincident walls): compared as f64's traversal does, the
                        // lower primitive index winning equal values.
                        Some((slot, bt, bm, value)) if (t - bt).abs() <= m + bm => {
                            let (Some(old), Some(new)) =
                                (value.or_else(|| exact_value(slot)), exact_value(id))
                            else {
                                *unsure = true;
                                return -1.0;
                            };
                            let lower = bvh.primitive_indices[id] < bvh.primitive_indices[slot];
                            *best = Some(if new < old || (new == old && lower) {
                                (id, t, m, Some(new))
                            } else {
                                (slot, bt, bm, Some(old))
                            });
                            t
                        }
                        Some((_, bt, _, _)) if t > bt => f32::INFINITY,
                        _ => {
                            *best = Some((id, t, m, None));
                            t
                        }
                    },
                }
            },
        );
        // Beyond the closest sure hit by more than both margins: a sure miss.
        let far_of = |best: &Option<SureHit>| best.map_or(limit, |(_, t, m, _)| t + m);
        bvh.traverse_leaves::<COPY>(
            of,
            df,
            reach,
            #[inline(always)]
            |first, count| {
                let mut nearest = f32::INFINITY;
                let leaf = self.leaves[first];
                let (begin, end) = leaf.packets;
                for packet in &self.packets[begin as usize..end as usize] {
                    let v = packet.classify(of, df, epsilon, far_of(&best), self.scale);
                    let mut lanes = packet.valid & !v.miss;
                    while lanes != 0 {
                        let lane = lanes.trailing_zeros() as usize;
                        lanes &= lanes - 1;
                        let (t, m) = (v.t[lane], v.margin[lane]);
                        // What the one-triangle test says at today's `far` (an earlier lane may
                        // have brought it nearer): beyond it, a sure miss.
                        if v.parallel & (1 << lane) == 0 && t > far_of(&best) + m {
                            continue;
                        }
                        let verdict = if v.unsure & (1 << lane) != 0 {
                            Verdict::Unsure
                        } else {
                            Verdict::Hit(t, m)
                        };
                        let r = take(packet.slots[lane] as usize, verdict, &mut best, &mut unsure);
                        if r < 0.0 {
                            return r;
                        }
                        nearest = nearest.min(r);
                    }
                }
                if leaf.rects {
                    for slot in first..first + count {
                        if let Fast::Rect { .. } = self.fast[slot] {
                            let verdict = self.classify(slot, of, df, epsilon, far_of(&best));
                            let r = take(slot, verdict, &mut best, &mut unsure);
                            if r < 0.0 {
                                return r;
                            }
                            nearest = nearest.min(r);
                        }
                    }
                }
                nearest
            },
        );
        if !unsure {
            let (slot, _, _, _) = best?;
            let index = bvh.primitive_indices[slot];
            if let Some(t) = self.intersect(&self.primitives[index as usize], o, d, tmax) {
                return Some(self.hit(index, o, d, t, lit_normal_sign));
            }
            // f64 disagrees with a sure hit (never expected): the f64 path decides.
        }
        // 2. f64 in the traversal: the exact answer.
        self.closest_exact(bvh, reach, o, d, tmax, lit_normal_sign)
    }

    /// [`Tracer::closest`] with the f64 test on every primitive the traversal reaches.
    fn closest_exact(
        &self,
        bvh: &Bvh8,
        reach: f32,
        o: [f64; 3],
        d: [f64; 3],
        tmax: f64,
        lit_normal_sign: &dyn Fn(u32) -> f64,
    ) -> Option<Hit> {
        // The closest so far: its value and primitive (the lower index wins equal values, so
        // the answer does not depend on the order the traversal visits leaves in).
        let mut best: Option<(f32, u32)> = None;
        bvh.traverse::<0>(v3(o), v3(d), reach, |id| {
            let index = bvh.primitive_indices[id];
            let Some(value) = self.exact_value(index, o, d, tmax, lit_normal_sign) else {
                return f32::INFINITY;
            };
            if best.is_none_or(|b| (value, index) < b) {
                best = Some((value, index));
            }
            value
        });
        let (_, index) = best?;
        let prim = &self.primitives[index as usize];
        let t = self.intersect(prim, o, d, tmax * (1.0 + 1e-9) + self.epsilon)?;
        Some(self.hit(index, o, d, t, lit_normal_sign))
    }

    /// What the f64 traversal compares for primitive `index`: its exact distance, plus
    /// `epsilon / 100` for a rectangle seen from behind its lit side (so of two coincident
    /// walls the one facing the ray wins), as f32; None when f64 finds no hit before `tmax`.
    fn exact_value(
        &self,
        index: u32,
        o: [f64; 3],
        d: [f64; 3],
        tmax: f64,
        lit_normal_sign: &dyn Fn(u32) -> f64,
    ) -> Option<f32> {
        let prim = &self.primitives[index as usize];
        let t = self.intersect(prim, o, d, tmax)?;
        let tie = self.epsilon * 1e-2;
        let back = Self::facing(prim, d, lit_normal_sign).is_some_and(|f| f > 0.0);
        Some((t + if back { tie } else { 0.0 }) as f32)
    }

    /// For a rectangle with a lit surface, the ray direction along its lit normal: negative
    /// when the ray arrives on the lit side, positive from behind.
    fn facing(prim: &Primitive, d: [f64; 3], lit_normal_sign: &dyn Fn(u32) -> f64) -> Option<f64> {
        match prim {
            Primitive::Rect {
                axis,
                surface: Some(s),
                ..
            } => Some(d[*axis] * lit_normal_sign(*s)),
            _ => None,
        }
    }

    /// The hit on primitive `index` at distance `t`.
    fn hit(
        &self,
        index: u32,
        o: [f64; 3],
        d: [f64; 3],
        t: f64,
        lit_normal_sign: &dyn Fn(u32) -> f64,
    ) -> Hit {
        let prim = &self.primitives[index as usize];
        let point = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
        let normal = self.normal_facing(index, d);
        let front = Self::facing(prim, d, lit_normal_sign).is_some_and(|f| f < 0.0);
        Hit {
            t,
            primitive: index,
            point,
            front,
            normal,
        }
    }

    compiled_copies! {
        /// True when anything lies strictly between `from` and `to` (both ends excluded by
        /// epsilon).
        fn occluded, occluded_avx2, occluded_avx512 = occluded_portable(
            from: [f64; 3],
            to: [f64; 3],
        ) -> bool
    }

    /// `occluded`'s body; `COPY` as in `closest_portable`.
    #[inline(always)]
    fn occluded_portable<const COPY: u8>(&self, from: [f64; 3], to: [f64; 3]) -> bool {
        let Some(bvh) = self.bvh.as_ref() else {
            return false;
        };
        let delta = DVec3::from(to) - DVec3::from(from);
        let len = delta.length();
        if len <= 2.0 * self.epsilon {
            return false;
        }
        let d = (delta / len).to_array();
        let tmax = len - self.epsilon;
        let (of, df) = (v3(from), v3(d));
        let (epsilon, limit) = (self.epsilon as f32, tmax as f32);
        // A hit returns -1, which ends the traversal.
        bvh.traverse::<COPY>(
            of,
            df,
            limit,
            #[inline(always)]
            |id| {
                match self.classify(id, of, df, epsilon, limit) {
                    Verdict::Miss => return f32::INFINITY,
                    Verdict::Hit(t, m) if t < limit - m => return -1.0,
                    _ => {}
                }
                let prim = &self.primitives[bvh.primitive_indices[id] as usize];
                match self.intersect(prim, from, d, tmax) {
                    Some(t) if (t as f32) < limit => -1.0,
                    _ => f32::INFINITY,
                }
            },
        ) < 0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::math::sampling::{sample_cosine_hemisphere, sobol_2d, to_world};
    use crate::bake::scene::geometry::Geometry;
    use lightfarm_proto::scene::Aabb;
    use lightfarm_proto::Face;

    /// The closest f64 hit over every primitive, no BVH: its distance and primitive (the
    /// first of equal distances).
    fn brute_closest(tracer: &Tracer, o: [f64; 3], d: [f64; 3]) -> Option<(f64, usize)> {
        tracer
            .primitives
            .iter()
            .enumerate()
            .filter_map(|(p, prim)| tracer.intersect(prim, o, d, f64::INFINITY).map(|t| (t, p)))
            .min_by(|a, b| a.0.total_cmp(&b.0))
    }

    /// What `occluded` must answer, by an f64 test of every primitive, no BVH.
    fn brute_occluded(tracer: &Tracer, from: [f64; 3], to: [f64; 3]) -> bool {
        let delta = DVec3::from(to) - DVec3::from(from);
        let len = delta.length();
        let d = (delta / len).to_array();
        len > 2.0 * tracer.epsilon
            && tracer
                .primitives
                .iter()
                .any(|p| tracer.intersect(p, from, d, len - tracer.epsilon).is_some())
    }

    #[test]
    fn closed_box_is_watertight_and_hits_match_brute_force() {
        let mut g = Geometry::default();
        let aabb = Aabb {
            min: [0.0, 0.0, 0.0],
            max: [3.0, 2.0, 5.0],
        };
        g.add_block(0, "a", &aabb, &Face::ALL, |_| [0.5; 3], 4);
        g.add_triangles(
            &[[[1.0, 0.5, 1.0], [2.0, 0.5, 1.0], [1.5, 1.5, 3.0]]],
            [0.5; 3],
        );
        let tracer = Tracer::new(g.primitives.clone(), g.scale());
        let signs: Vec<f64> = g.surfaces.iter().map(|s| s.normal_sign).collect();
        let sign = |s: u32| signs[s as usize];
        for (k, texel) in g.texels.iter().enumerate() {
            for i in 0..64 {
                let d = to_world(
                    sample_cosine_hemisphere(sobol_2d(k as u64, i)),
                    texel.normal,
                );
                let hit = tracer
                    .closest(texel.position, d, f64::INFINITY, &sign)
                    .expect("closed box leaks");
                let best = brute_closest(&tracer, texel.position, d).unwrap();
                assert!(
                    (best.0 - hit.t).abs() < 1e-9,
                    "bvh {} vs brute {}",
                    hit.t,
                    best.0
                );
            }
        }
    }

    /// Every packet lane's verdict is the one-triangle test's, bit for bit (distance and
    /// margin included), for rays from inside and outside a cloud of triangles, some of them
    /// slivers or nearly parallel to the rays, at several `far` limits.
    #[test]
    fn a_packets_lanes_say_what_the_one_triangle_test_says() {
        let mut state = 5u64;
        let mut rand = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut triangles: Vec<[[f64; 3]; 3]> = (0..300)
            .map(|_| {
                let c = [4.0 * rand(), 3.0 * rand(), 5.0 * rand()];
                [0, 1, 2].map(|_| [0, 1, 2].map(|a| c[a] + 0.8 * (rand() - 0.5)))
            })
            .collect();
        // Slivers (a vertex almost on the opposite edge) and axis-aligned ones.
        for k in 0..40 {
            let x = 0.1 * k as f64;
            triangles.push([[x, 0.0, 0.0], [x + 1.0, 0.0, 0.0], [x + 0.5, 1e-7, 0.0]]);
            triangles.push([[x, 1.0, 1.0], [x, 2.0, 1.0], [x, 1.0, 2.5]]);
        }
        let mut g = Geometry::default();
        g.add_triangles(&triangles, [0.5; 3]);
        let tracer = Tracer::new(g.primitives.clone(), g.scale());
        assert!(tracer.packets.iter().any(|p| p.valid == 0xF));
        let (mut lanes, mut hits, mut unsure) = (0, 0, 0);
        for i in 0..400 {
            let o = Vec3A::new(
                (6.0 * rand() - 1.0) as f32,
                (5.0 * rand() - 1.0) as f32,
                (7.0 * rand() - 1.0) as f32,
            );
            let mut d = Vec3A::new(
                (rand() - 0.5) as f32,
                (rand() - 0.5) as f32,
                (rand() - 0.5) as f32,
            );
            if i % 5 == 0 {
                d.z = 1e-6; // grazing the z = const slivers' plane
            }
            let d = d.normalize();
            for far in [f32::INFINITY, 3.0, 0.5] {
                for packet in &tracer.packets {
                    let v = packet.classify(o, d, tracer.epsilon as f32, far, tracer.scale);
                    for lane in 0..4 {
                        let bit = 1 << lane;
                        if packet.valid & bit == 0 {
                            assert_ne!(v.miss & bit, 0, "an empty lane is never reported");
                            continue;
                        }
                        lanes += 1;
                        let slot = packet.slots[lane] as usize;
                        let one = tracer.classify(slot, o, d, tracer.epsilon as f32, far);
                        let got = if v.miss & bit != 0 {
                            Verdict::Miss
                        } else if v.unsure & bit != 0 {
                            unsure += 1;
                            Verdict::Unsure
                        } else {
                            hits += 1;
                            Verdict::Hit(v.t[lane], v.margin[lane])
                        };
                        match (got, one) {
                            (Verdict::Hit(t, m), Verdict::Hit(t1, m1)) => {
                                assert_eq!((t.to_bits(), m.to_bits()), (t1.to_bits(), m1.to_bits()))
                            }
                            _ => assert_eq!(got, one, "ray {i}, far {far}, slot {slot}"),
                        }
                    }
                }
            }
        }
        assert!(
            hits > 100 && unsure > 0,
            "{lanes} lanes: {hits} hits, {unsure} unsure"
        );
    }

    /// A level of several rooms cluttered with 600 random triangles (a BVH many levels deep):
    /// the closest hit is brute force's closest, the same primitive unless two are hit at the
    /// same distance, and shadow rays agree with brute force.
    #[test]
    fn a_deep_tree_finds_what_brute_force_finds() {
        let mut g = Geometry::default();
        for k in 0..4 {
            let x = 4.0 * k as f64;
            let aabb = Aabb {
                min: [x, 0.0, 0.0],
                max: [x + 4.0, 3.0, 5.0],
            };
            g.add_block(k, "room", &aabb, &Face::ALL, |_| [0.5; 3], 3);
        }
        let mut state = 11u64;
        let mut rand = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let triangles: Vec<[[f64; 3]; 3]> = (0..600)
            .map(|_| {
                let c = [16.0 * rand(), 3.0 * rand(), 5.0 * rand()];
                [0, 1, 2].map(|_| [0, 1, 2].map(|a| c[a] + 0.6 * (rand() - 0.5)))
            })
            .collect();
        g.add_triangles(&triangles, [0.5; 3]);
        let tracer = Tracer::new(g.primitives.clone(), g.scale());
        assert!(tracer.bvh.as_ref().unwrap().stack_need() > 4);
        let signs: Vec<f64> = g.surfaces.iter().map(|s| s.normal_sign).collect();
        let sign = |s: u32| signs[s as usize];
        let (mut hits, mut shadowed) = (0, 0);
        for (k, texel) in g.texels.iter().enumerate().step_by(3) {
            for i in 0..16 {
                let d = to_world(
                    sample_cosine_hemisphere(sobol_2d(k as u64, i)),
                    texel.normal,
                );
                let o = texel.position;
                let brute = brute_closest(&tracer, o, d);
                let hit = tracer.closest(o, d, f64::INFINITY, &sign);
                match (hit, brute) {
                    (Some(h), Some((t, p))) => {
                        assert_eq!(h.t, t, "texel {k} ray {i}");
                        let ties = tracer
                            .primitives
                            .iter()
                            .filter(|q| tracer.intersect(q, o, d, f64::INFINITY) == Some(t))
                            .count();
                        assert!(h.primitive as usize == p || ties > 1, "texel {k} ray {i}");
                        hits += 1;
                        let to = [o[0] + 0.7 * t * d[0], o[1] + 0.7 * t * d[1], o[2]];
                        let expected = brute_occluded(&tracer, o, to);
                        assert_eq!(tracer.occluded(o, to), expected, "texel {k} ray {i}");
                        shadowed += usize::from(expected);
                    }
                    (None, None) => {}
                    (h, b) => panic!("texel {k} ray {i}: {h:?} against brute force {b:?}"),
                }
            }
        }
        assert!(
            hits > 1000 && shadowed > 30,
            "{hits} hits, {shadowed} shadowed"
        );
    }

    /// A ray found while checking the 4-wide BVH against the compressed one it replaced: from
    /// an opening's plane (a lightfield sample of a 2 × 3 × 3.5 m shape open at both ends of z),
    /// 2.9e-5 m from the x = 0 wall and heading into it, the hit lies 4.19e-5 m away, just
    /// beyond epsilon (3.5e-5 m). The compressed BVH's traversal missed it; brute force and
    /// this tracer find it.
    #[test]
    fn a_hit_just_beyond_epsilon_from_an_opening_is_found() {
        let mut g = Geometry::default();
        let aabb = Aabb {
            min: [0.0; 3],
            max: [2.0, 3.0, 3.5],
        };
        let closed = [Face::NegX, Face::PosX, Face::NegY, Face::PosY];
        g.add_block(0, "shape", &aabb, &closed, |_| [1.0; 3], 8);
        let tracer = Tracer::new(g.primitives.clone(), 3.5);
        let sign = |s: u32| g.surfaces[s as usize].normal_sign;
        let o = [2.9164133593440056e-5, 2.216426108730957, 3.5];
        let d = [-0.6963021641146796, 0.5441247677566559, -0.4680721454679601];
        let hit = tracer
            .closest(o, d, f64::INFINITY, &sign)
            .expect("the wall");
        assert!(hit.t > tracer.epsilon && hit.t < 4.2e-5, "{}", hit.t);
        assert_eq!(hit.point[0], 0.0);
        let exact = tracer.closest_exact(
            tracer.bvh.as_ref().unwrap(),
            f32::INFINITY,
            o,
            d,
            f64::INFINITY,
            &sign,
        );
        assert_eq!(Some(hit), exact);
    }

    /// The f32 path gives f64's hit, bit for bit, on the cases it must hand over or resolve:
    /// two blocks sharing a wall (coincident rectangles, lit sides opposite), one open to the
    /// outside (rays that miss), rectangles meeting at the boxes' edges, triangles (a small clutter mesh, one lying
    /// in a wall's plane), grazing rays, rays ending just at a wall (`tmax`) and shadow rays.
    #[test]
    fn the_f32_path_gives_the_f64_hit_bit_for_bit() {
        let mut g = Geometry::default();
        let a = Aabb {
            min: [0.0, 0.0, 0.0],
            max: [4.0, 3.0, 5.0],
        };
        let b = Aabb {
            min: [4.0, 0.0, 0.0],
            max: [9.0, 3.0, 5.0],
        };
        let b_closed: Vec<Face> = Face::ALL
            .iter()
            .copied()
            .filter(|f| *f != Face::PosX)
            .collect();
        g.add_block(0, "a", &a, &Face::ALL, |_| [0.5; 3], 4);
        g.add_block(1, "b", &b, &b_closed, |_| [0.6; 3], 4);
        g.add_triangles(
            &[
                [[1.0, 0.5, 1.0], [2.0, 0.5, 1.0], [1.5, 1.5, 3.0]],
                [[1.0, 1.5, 1.0], [2.0, 0.5, 1.0], [1.5, 1.5, 3.0]],
                // In the plane z = 5 (a wall of both blocks).
                [[6.0, 1.0, 5.0], [7.0, 1.0, 5.0], [6.5, 2.0, 5.0]],
            ],
            [0.5; 3],
        );
        let signs: Vec<f64> = g.surfaces.iter().map(|s| s.normal_sign).collect();
        let sign = |s: u32| signs[s as usize];
        // Every compiled copy this CPU runs (the others fall back to the detected one).
        for isa in [
            InstructionSet::Baseline,
            InstructionSet::Avx2,
            InstructionSet::Avx512,
        ] {
            let tracer = Tracer::new(g.primitives.clone(), g.scale()).with_instruction_set(isa);
            check_f32_path_against_f64(&g, &tracer, &sign);
        }
    }

    /// The checks of `the_f32_path_gives_the_f64_hit_bit_for_bit` for one tracer.
    fn check_f32_path_against_f64(g: &Geometry, tracer: &Tracer, sign: &dyn Fn(u32) -> f64) {
        let bvh = tracer.bvh.as_ref().unwrap();
        let (mut rays, mut hits) = (0, 0);
        for (k, texel) in g.texels.iter().enumerate() {
            for i in 0..48u32 {
                let mut d = to_world(
                    sample_cosine_hemisphere(sobol_2d(k as u64, i)),
                    texel.normal,
                );
                if i % 8 == 7 {
                    // Grazing: nearly in the texel's plane.
                    let n = texel.normal;
                    let dot = d[0] * n[0] + d[1] * n[1] + d[2] * n[2];
                    d = [0, 1, 2].map(|c| d[c] - n[c] * (dot - 1e-5));
                    let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                    d = d.map(|x| x / len);
                }
                let o = texel.position;
                let exact = tracer.closest_exact(bvh, f32::INFINITY, o, d, f64::INFINITY, sign);
                let fast = tracer.closest(o, d, f64::INFINITY, sign);
                assert_eq!(fast, exact, "texel {k} ray {i}");
                rays += 1;
                let Some(h) = exact else { continue };
                hits += 1;
                // A ray ending at its hit, just before it and just after it.
                for tmax in [h.t, h.t * (1.0 - 1e-7), h.t * (1.0 + 1e-7), 0.5 * h.t] {
                    let reach = tmax as f32 * (1.0 + 1e-6) + 1e-6;
                    let exact = tracer.closest_exact(bvh, reach, o, d, tmax, sign);
                    assert_eq!(tracer.closest(o, d, tmax, sign), exact, "texel {k} ray {i}");
                }
                // Shadow rays to the hit and to points beside it.
                for to in [h.point, [h.point[0], h.point[1] + 0.3, h.point[2]]] {
                    let exact = brute_occluded(tracer, o, to);
                    assert_eq!(tracer.occluded(o, to), exact, "texel {k} ray {i}");
                }
            }
        }
        assert!(
            hits > rays * 9 / 10,
            "{:?}: {hits} of {rays}",
            tracer.instruction_set()
        );
    }

    #[test]
    fn occlusion_between_points() {
        let mut g = Geometry::default();
        g.add_triangles(
            &[[[-1.0, -1.0, 1.0], [1.0, -1.0, 1.0], [0.0, 1.0, 1.0]]],
            [0.5; 3],
        );
        let tracer = Tracer::new(g.primitives.clone(), 2.0);
        assert!(tracer.occluded([0.0, 0.0, 0.0], [0.0, 0.0, 2.0]));
        assert!(!tracer.occluded([0.0, 0.0, 0.0], [0.0, 0.0, 0.9]));
        assert!(!tracer.occluded([5.0, 0.0, 0.0], [5.0, 0.0, 2.0]));
    }
}
