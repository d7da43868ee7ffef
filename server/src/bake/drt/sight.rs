//! Which block texels could see clutter at all, decided before any ray (issue 19: DRT's cost
//! follows the props, not the level). A texel that cannot see any clutter object gets no DRT
//! row whatever its rays do, so it is not traced.
//!
//! The test is conservative and exact in what it rules out. Blocks are closed boxes whose only
//! way out is their open faces (whole faces, coincident with a neighbour's open face, or
//! leading out of the level: `Opening::Void`); closed faces stop rays from either side. A
//! segment from a point of face `F` to a point of clutter box `C` lies in the convex hull
//! `H = conv(F ∪ C)` (the *shaft*), starts in `F`'s block and crosses from block to block only
//! through open faces, each crossing point inside `H`. So if a walk (a graph search) from `F`'s
//! block, through the open faces that meet `H`, never reaches a block that `C` overlaps (or the
//! outside, when `C` is not inside one block), no segment joins them: nothing of `F` sees `C`.
//! Clutter is ignored as an occluder (it only hides more). A face also cannot see a box that
//! lies wholly behind its plane.
//!
//! Whether an open face (a flat box) meets `H`, the hull of two axis-aligned boxes, is a
//! separating-axis test: the coordinate axes and `e_k × (c_i − f_i)` for corresponding corners
//! `f_i`, `c_i` (the hull's side facets contain an edge of each box, parallel, at the same
//! corner). An axis separates only by more than `margin`, so touching counts as meeting.
//!
//! Three levels, each only for what the last one kept: per block and clutter object one walk
//! with the block's box as `F` (ruling most pairs out at once), then one per face with the box
//! around its texel centres, then one per texel centre (a point; DRT's rays start there).
//!
//! Frames: world, metres. Cost: a walk only enters blocks inside the shaft.

use glam::DVec3;

use lightfarm_proto::face::Face;
use lightfarm_proto::scene::{Opening, Scene};

use crate::bake::scene::geometry::{Geometry, SurfaceOwner};

/// An axis-aligned box (possibly flat), world metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Box3 {
    pub min: DVec3,
    pub max: DVec3,
}

impl Box3 {
    pub fn new(min: [f64; 3], max: [f64; 3]) -> Box3 {
        Box3 {
            min: DVec3::from(min),
            max: DVec3::from(max),
        }
    }

    fn grown(&self, m: f64) -> Box3 {
        Box3 {
            min: self.min - DVec3::splat(m),
            max: self.max + DVec3::splat(m),
        }
    }

    fn corner(&self, i: usize) -> DVec3 {
        DVec3::new(
            if i & 1 == 1 { self.max.x } else { self.min.x },
            if i & 2 == 2 { self.max.y } else { self.min.y },
            if i & 4 == 4 { self.max.z } else { self.min.z },
        )
    }

    /// The projection onto unit axis `n`.
    fn interval(&self, n: DVec3) -> (f64, f64) {
        let c = (self.min + self.max).dot(n) * 0.5;
        let r = (self.max - self.min).dot(n.abs()) * 0.5;
        (c - r, c + r)
    }

    /// The flat box of one of its faces.
    fn face(&self, face: Face) -> Box3 {
        let k = face.axis();
        let c = if face.is_max_side() {
            self.max[k]
        } else {
            self.min[k]
        };
        let mut out = *self;
        (out.min[k], out.max[k]) = (c, c);
        out
    }

    fn meets(&self, other: &Box3, margin: f64) -> bool {
        (0..3).all(|k| self.min[k] <= other.max[k] + margin && other.min[k] <= self.max[k] + margin)
    }

    fn contains(&self, other: &Box3) -> bool {
        (0..3).all(|k| self.min[k] <= other.min[k] && other.max[k] <= self.max[k])
    }
}

/// Whether box `p` may meet the convex hull of boxes `a` and `b`: false only when one of the
/// hull's candidate separating axes (see the module doc) separates them by more than `margin`.
pub fn may_meet_hull(p: &Box3, a: &Box3, b: &Box3, margin: f64) -> bool {
    let separates = |n: DVec3| {
        let len = n.length();
        if !(len > 1e-12) {
            return false;
        }
        let n = n / len;
        let (p0, p1) = p.interval(n);
        let (a0, a1) = a.interval(n);
        let (b0, b1) = b.interval(n);
        p0 > a1.max(b1) + margin || a0.min(b0) > p1 + margin
    };
    if [DVec3::X, DVec3::Y, DVec3::Z].into_iter().any(separates) {
        return false;
    }
    for i in 0..8 {
        let d = b.corner(i) - a.corner(i);
        if [DVec3::X, DVec3::Y, DVec3::Z]
            .into_iter()
            .any(|e| separates(e.cross(d)))
        {
            return false;
        }
    }
    true
}

/// One open face: where it leads, and its rectangle (a flat box).
#[derive(Clone, Copy, Debug)]
struct Portal {
    /// The block beyond, or `None` for the outside of the level.
    to: Option<usize>,
    rect: Box3,
}

/// A clutter object as a walk's goal.
struct Goal {
    bounds: Box3,
    /// Blocks the (grown) box overlaps.
    blocks: Vec<usize>,
    /// Whether part of it may lie outside every block (then reaching the outside is enough).
    outside: bool,
}

/// The blocks and their open faces, as a graph the walks run on.
struct Portals {
    boxes: Vec<Box3>,
    /// Per block, its open faces.
    open: Vec<Vec<Portal>>,
    /// Every open face leading out of the level: (its block, its rectangle).
    to_outside: Vec<(usize, Box3)>,
    margin: f64,
}

impl Portals {
    /// Whether some segment from `from` (inside block `start`) to `goal` could exist.
    fn walk(&self, from: &Box3, start: usize, goal: &Goal) -> bool {
        let n = self.boxes.len();
        let outside = n;
        let mut seen = vec![false; n + 1];
        let mut queue = vec![start];
        seen[start] = true;
        while let Some(node) = queue.pop() {
            if node == outside {
                if goal.outside {
                    return true;
                }
                for (block, rect) in &self.to_outside {
                    if !seen[*block] && may_meet_hull(rect, from, &goal.bounds, self.margin) {
                        seen[*block] = true;
                        queue.push(*block);
                    }
                }
                continue;
            }
            if goal.blocks.contains(&node) {
                return true;
            }
            for portal in &self.open[node] {
                let next = portal.to.unwrap_or(outside);
                if !seen[next] && may_meet_hull(&portal.rect, from, &goal.bounds, self.margin) {
                    seen[next] = true;
                    queue.push(next);
                }
            }
        }
        false
    }
}

/// The level's blocks, open faces and clutter, ready to answer per block which of its faces
/// could see some clutter object (see the module doc).
pub struct ClutterSight<'a> {
    portals: Portals,
    goals: Vec<Goal>,
    /// The full geometry: its block texels' centres bound each face (per block, when asked).
    g: &'a Geometry,
}

impl<'a> ClutterSight<'a> {
    /// `g` is the full geometry: its clutter shapes' bounds are the goals, and its block
    /// texels' centres (where the DRT rays start) bound each face. The margin is
    /// `1e-6 · g.scale()`, as the tracer's own tolerances.
    pub fn new(
        scene: &Scene,
        openings: &[[Option<Opening>; 6]],
        g: &'a Geometry,
    ) -> ClutterSight<'a> {
        let margin = 1e-6 * g.scale();
        let boxes: Vec<Box3> = scene
            .blocks
            .iter()
            .map(|b| Box3::new(b.min, b.max))
            .collect();
        let mut open = vec![Vec::new(); boxes.len()];
        let mut to_outside = Vec::new();
        for (b, by_face) in openings.iter().enumerate() {
            for face in Face::ALL {
                let Some(o) = by_face[face.index()] else {
                    continue;
                };
                let rect = boxes[b].face(face);
                let to = match o {
                    Opening::Neighbour { block, .. } => Some(block),
                    Opening::Void => {
                        to_outside.push((b, rect));
                        None
                    }
                };
                open[b].push(Portal { to, rect });
            }
        }
        let goals: Vec<Goal> = g
            .clutter_shapes
            .iter()
            .map(|c| {
                let bounds = Box3::new(c.bounds[0], c.bounds[1]).grown(margin);
                let blocks: Vec<usize> = (0..boxes.len())
                    .filter(|&b| boxes[b].meets(&bounds, 0.0))
                    .collect();
                let outside = !blocks.iter().any(|&b| boxes[b].contains(&bounds));
                Goal {
                    bounds,
                    blocks,
                    outside,
                }
            })
            .collect();
        ClutterSight {
            portals: Portals {
                boxes,
                open,
                to_outside,
                margin,
            },
            goals,
            g,
        }
    }

    /// Per face of block `b`: the box around its texel centres (None: no texels).
    fn face_boxes(&self, b: usize) -> [Option<Box3>; 6] {
        let g = self.g;
        let mut faces = [None; 6];
        for texel in &g.texels[g.block_texels[b].clone()] {
            let SurfaceOwner::Block { face, .. } = g.surfaces[texel.surface as usize].owner else {
                continue;
            };
            let p = DVec3::from(texel.position);
            let slot: &mut Option<Box3> = &mut faces[face.index()];
            *slot = Some(slot.map_or(Box3 { min: p, max: p }, |b| Box3 {
                min: b.min.min(p),
                max: b.max.max(p),
            }));
        }
        faces
    }

    /// Whether anything in block `b` could see some clutter object (what
    /// [`ClutterSight::block_faces`] narrows per face).
    pub fn block_may_see(&self, b: usize) -> bool {
        let from = &self.portals.boxes[b];
        self.goals
            .iter()
            .any(|goal| self.portals.walk(from, b, goal))
    }

    /// Per face of block `b` (in [`Face::ALL`] order): the clutter objects (scene clutter
    /// indices, ascending) it could see. Faces without texels (open ones) see none.
    pub fn block_faces(&self, b: usize) -> [Vec<u32>; 6] {
        let mut sees: [Vec<u32>; 6] = Default::default();
        let faces = self.face_boxes(b);
        for (c, goal) in self.goals.iter().enumerate() {
            if !self.portals.walk(&self.portals.boxes[b], b, goal) {
                continue;
            }
            for face in Face::ALL {
                let Some(rect) = faces[face.index()] else {
                    continue;
                };
                if !goal.behind(face, &rect) && self.portals.walk(&rect, b, goal) {
                    sees[face.index()].push(c as u32);
                }
            }
        }
        sees
    }

    /// Whether the texel centre `p` on face `face` of block `b` could see one of `clutter`
    /// (the face's list from [`ClutterSight::block_faces`]).
    pub fn texel_sees(&self, b: usize, face: Face, p: [f64; 3], clutter: &[u32]) -> bool {
        let point = Box3::new(p, p);
        clutter.iter().any(|&c| {
            let goal = &self.goals[c as usize];
            !goal.behind(face, &point) && self.portals.walk(&point, b, goal)
        })
    }
}

impl Goal {
    /// Whether the goal lies wholly behind the plane of `face` (whose texels, within `rect`,
    /// light the block's inside): out of sight of everything on it.
    fn behind(&self, face: Face, rect: &Box3) -> bool {
        let (k, c) = (face.axis(), rect.min[face.axis()]);
        if face.is_max_side() {
            self.bounds.min[k] > c
        } else {
            self.bounds.max[k] < c
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::drt::rays::{trace_block_unit, BlockTexelRays, RayPass};
    use crate::bake::tracer::Tracer;

    /// A small deterministic generator (xorshift).
    struct Rng(u64);
    impl Rng {
        fn unit(&mut self) -> f64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
        fn boxed(&mut self, flat: Option<usize>) -> Box3 {
            let c = DVec3::new(self.unit(), self.unit(), self.unit()) * 8.0;
            let mut h = DVec3::new(self.unit(), self.unit(), self.unit()) * 1.5;
            if let Some(k) = flat {
                h[k] = 0.0;
            }
            Box3 {
                min: c - h,
                max: c + h,
            }
        }
        fn point_in(&mut self, b: &Box3) -> DVec3 {
            let t = DVec3::new(self.unit(), self.unit(), self.unit());
            b.min + (b.max - b.min) * t
        }
    }

    /// Whether segment `a → b` crosses the flat box `p` (flat along `axis`).
    fn crosses(a: DVec3, b: DVec3, p: &Box3, axis: usize) -> bool {
        let (da, db) = (a[axis] - p.min[axis], b[axis] - p.min[axis]);
        if da * db > 0.0 || da == db {
            return false;
        }
        let x = a + (b - a) * (da / (da - db));
        (0..3).all(|k| k == axis || (x[k] >= p.min[k] && x[k] <= p.max[k]))
    }

    /// Random boxes and flat portals: whenever some sampled segment between the two boxes
    /// crosses the portal, the hull test says it may; and it does rule portals out.
    #[test]
    fn the_hull_test_never_rules_out_a_portal_a_segment_crosses() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        let (mut crossed, mut ruled_out) = (0, 0);
        for i in 0..3000 {
            let axis = i % 3;
            let a = rng.boxed((i % 7 == 0).then_some((i / 7) % 3));
            let b = rng.boxed(None);
            let mut p = rng.boxed(Some(axis));
            if i % 2 == 0 {
                // Half the portals sit between the boxes, where crossings are common.
                let mid = (a.min + a.max + b.min + b.max) * 0.25 - (p.min + p.max) * 0.5;
                (p.min, p.max) = (p.min + mid, p.max + mid);
            }
            let said = may_meet_hull(&p, &a, &b, 1e-9);
            let truly = (0..400).any(|_| {
                let (x, y) = (rng.point_in(&a), rng.point_in(&b));
                crosses(x, y, &p, axis)
            });
            assert!(
                !truly || said,
                "case {i}: a segment crosses {p:?} but it was ruled out"
            );
            crossed += usize::from(truly);
            ruled_out += usize::from(!said);
        }
        assert!(
            crossed > 300 && ruled_out > 300,
            "{crossed} crossed, {ruled_out} ruled out"
        );
    }

    /// A level from (min, max, open faces) blocks and (min, max) clutter boxes, at `t` texels
    /// per face and `rays` rays.
    fn level(
        blocks: &[([f64; 3], [f64; 3], &[&str])],
        clutter: &[([f64; 3], [f64; 3])],
        rays: u32,
    ) -> Scene {
        let blocks: Vec<_> = blocks
            .iter()
            .enumerate()
            .map(|(i, (min, max, open))| {
                serde_json::json!({"id": format!("b{i}"), "min": min, "max": max, "open": open, "albedo": [0.6, 0.6, 0.6]})
            })
            .collect();
        let clutter: Vec<_> = clutter
            .iter()
            .enumerate()
            .map(|(i, (min, max))| {
                serde_json::json!({"id": format!("c{i}"), "box": {"min": min, "max": max}, "albedo": [0.5, 0.5, 0.5]})
            })
            .collect();
        let doc = serde_json::json!({
            "format": "lightfarm.scene/1",
            "name": "sight",
            "settings": {"texels_per_face": 4, "rays_per_texel": rays, "tolerance": 0.001},
            "blocks": blocks,
            "clutter": clutter,
        });
        Scene::from_json(&doc.to_string()).expect("test level")
    }

    /// Four rooms round two corners (A → B → C → D, D beside A): no straight line leaves A,
    /// passes B and C and comes back beside it, so a box in D is out of A's sight.
    fn round_two_corners() -> Scene {
        level(
            &[
                ([0.0, 0.0, 0.0], [2.0, 2.0, 2.0], &["+x"]),
                ([2.0, 0.0, 0.0], [4.0, 2.0, 2.0], &["-x", "+y"]),
                ([2.0, 2.0, 0.0], [4.0, 4.0, 2.0], &["-y", "-x"]),
                ([0.0, 2.0, 0.0], [2.0, 4.0, 2.0], &["+x", "+z"]),
            ],
            &[([0.5, 3.0, 0.0], [1.0, 3.5, 0.5])],
            64,
        )
    }

    #[test]
    fn a_room_round_two_corners_is_out_of_sight() {
        let scene = round_two_corners();
        let g = Geometry::from_scene(&scene, std::path::Path::new(".")).unwrap();
        let sight = ClutterSight::new(&scene, &scene.openings().unwrap(), &g);
        assert!(sight.block_faces(0).iter().all(|f| f.is_empty()), "room A");
        // D holds the box: its floor sees it; its open faces have no texels.
        let d = sight.block_faces(3);
        assert_eq!(d[Face::NegZ.index()], [0]);
        assert!(d[Face::PosX.index()].is_empty());
        // C looks straight into D.
        assert!(sight.block_faces(2).iter().any(|f| !f.is_empty()));
    }

    /// Every texel the sight rules out, traced anyway, sees no clutter at all; every other texel
    /// gets exactly what tracing it alone gives. On the four rooms and on a 3 × 3 grid with
    /// pillars, loops and a face open to the outside.
    #[test]
    fn texels_out_of_sight_would_have_seen_no_clutter() {
        let mut grid = Vec::new();
        // Rooms 3 m wide; openings: a fixed tree with one loop, (2, 1) open to the void on +x
        // and (2, 2) on +z. Each entry: (i, j, open faces).
        let open: [[&[&str]; 3]; 3] = [
            [&["+x"], &["-x", "+y"], &["+y"]],
            [&["+y", "+x"], &["-y", "-x", "+y"], &["-y", "+x"]],
            [&["-y", "+x"], &["-y", "-x", "+x"], &["-x", "+z"]],
        ];
        // open[j][i]: room (i, j) at x = 3i, y = 3j; "+y" of row j meets "-y" of row j + 1.
        for (j, row) in open.iter().enumerate() {
            for (i, faces) in row.iter().enumerate() {
                let (x, y) = (3.0 * i as f64, 3.0 * j as f64);
                grid.push(([x, y, 0.0], [x + 3.0, y + 3.0, 2.5], *faces));
            }
        }
        let grid = level(
            &grid,
            &[
                ([1.2, 1.2, 0.0], [1.7, 1.7, 2.0]),
                ([7.0, 7.3, 0.0], [7.4, 7.7, 1.0]),
            ],
            128,
        );
        let mut culled_total = 0;
        for scene in [round_two_corners(), grid] {
            let g = Geometry::from_scene(&scene, std::path::Path::new(".")).unwrap();
            let gb = Geometry::blocks_only(&scene);
            let openings = scene.openings().unwrap();
            let tracer = Tracer::new(g.primitives.clone(), g.scale());
            let block_tracer = Tracer::new(gb.primitives.clone(), gb.scale());
            let pass = RayPass::new(&scene, &openings, &g, &gb, &tracer, &block_tracer);
            for b in 0..scene.blocks.len() {
                let (texels, counts) = trace_block_unit(&pass, b, None, &|_| {}).unwrap();
                culled_total += counts.culled;
                for (x, unit) in g.block_texels[b].clone().zip(&texels) {
                    let alone = pass.trace_block_texel(x);
                    if unit.reach == crate::bake::drt::reach::RayReach::everywhere() {
                        assert_eq!(
                            alone.clutter_hits, 0.0,
                            "texel {x} of block {b} sees clutter"
                        );
                        assert_eq!(
                            BlockTexelRays {
                                reach: unit.reach.clone(),
                                ..alone
                            },
                            *unit
                        );
                    } else {
                        assert_eq!(alone, *unit, "texel {x} of block {b}");
                    }
                }
            }
        }
        assert!(culled_total > 150, "only {culled_total} texels ruled out");
    }
}
