//! Ray casting against a [`Geometry`](crate::bake::scene::geometry::Geometry)'s primitives through an `obvhs` compressed wide BVH.
//!
//! Intersections are computed in f64 inside the traversal callback (obvhs traverses in f32);
//! rectangles are closed at their edges so a closed box is watertight. Where two coincident
//! rectangles are hit at the same distance (back-to-back walls of neighbouring blocks), the one
//! whose lit side faces the ray wins.
//!
//! Invariant: `closest` only reports hits with `t > epsilon`, where epsilon is relative to the
//! scene's scale, so rays leaving a surface never hit that surface again.

use std::time::Duration;

use glam::{DVec3, Vec3A};
use obvhs::{
    aabb::Aabb,
    cwbvh::builder::build_cwbvh,
    cwbvh::CwBvh,
    ray::{Ray, RayHit},
    Boundable, BvhBuildParams,
};

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

struct Bounded {
    aabb: Aabb,
}

impl Boundable for Bounded {
    fn aabb(&self) -> Aabb {
        self.aabb
    }
}

/// A BVH over primitives.
pub struct Tracer {
    bvh: Option<CwBvh>,
    primitives: Vec<Primitive>,
    /// Smallest accepted hit distance.
    pub epsilon: f64,
    edge_epsilon: f64,
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
            let (u, v) = tangents(*axis);
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

pub(crate) fn tangents(axis: usize) -> (usize, usize) {
    match axis {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    }
}

impl Tracer {
    /// Builds the BVH. `scale` is the scene's largest coordinate magnitude.
    pub fn new(primitives: Vec<Primitive>, scale: f64) -> Tracer {
        let epsilon = 1e-5 * scale.max(1e-3);
        let bounded: Vec<Bounded> = primitives
            .iter()
            .map(|p| {
                let (lo, hi) = primitive_bounds(p, epsilon);
                Bounded {
                    aabb: Aabb::new(v3(lo), v3(hi)),
                }
            })
            .collect();
        let bvh = if bounded.is_empty() {
            None
        } else {
            Some(build_cwbvh(
                &bounded,
                BvhBuildParams::medium_build(),
                &mut Duration::default(),
            ))
        };
        Tracer {
            bvh,
            primitives,
            epsilon,
            edge_epsilon: 1e-9 * scale.max(1e-3),
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
                let (u, v) = tangents(*axis);
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

    /// Geometric normal of `primitive` facing against the ray direction `d`.
    fn normal_facing(primitive: &Primitive, d: [f64; 3]) -> [f64; 3] {
        match primitive {
            Primitive::Rect { axis, .. } => {
                let mut n = [0.0; 3];
                n[*axis] = if d[*axis] > 0.0 { -1.0 } else { 1.0 };
                n
            }
            Primitive::Triangle { v, .. } => {
                let [v0, v1, v2] = v.map(DVec3::from);
                let n = (v1 - v0).cross(v2 - v0);
                let len = n.length();
                let sign = if n.dot(DVec3::from(d)) > 0.0 {
                    -1.0
                } else {
                    1.0
                };
                (sign * n / len).to_array()
            }
        }
    }

    /// Closest hit along `o + t·d` (d unit) with `epsilon < t < tmax`. `lit_normal_sign` gives,
    /// for a rectangle with a surface, the sign of its lit normal along its axis; it is used to
    /// prefer the lit side when coincident rectangles tie.
    pub fn closest(
        &self,
        o: [f64; 3],
        d: [f64; 3],
        tmax: f64,
        lit_normal_sign: &dyn Fn(u32) -> f64,
    ) -> Option<Hit> {
        let bvh = self.bvh.as_ref()?;
        let ray = Ray::new(v3(o), v3(d), 0.0, tmax as f32 * (1.0 + 1e-6) + 1e-6);
        let tie = self.epsilon * 1e-2;
        let mut hit = RayHit::none();
        let found = bvh.ray_traverse(ray, &mut hit, |_ray, id| {
            let index = bvh.primitive_indices[id];
            let prim = &self.primitives[index as usize];
            match self.intersect(prim, o, d, tmax) {
                Some(t) => {
                    // Back-facing coincident rectangles lose ties.
                    let back = match prim {
                        Primitive::Rect {
                            axis,
                            surface: Some(s),
                            ..
                        } => d[*axis] * lit_normal_sign(*s) > 0.0,
                        _ => false,
                    };
                    (t + if back { tie } else { 0.0 }) as f32
                }
                None => f32::INFINITY,
            }
        });
        if !found {
            return None;
        }
        let index = bvh.primitive_indices[hit.primitive_id as usize];
        let prim = &self.primitives[index as usize];
        let t = self.intersect(prim, o, d, tmax * (1.0 + 1e-9) + self.epsilon)?;
        let point = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
        let normal = Self::normal_facing(prim, d);
        let front = match prim {
            Primitive::Rect {
                axis,
                surface: Some(s),
                ..
            } => d[*axis] * lit_normal_sign(*s) < 0.0,
            _ => false,
        };
        Some(Hit {
            t,
            primitive: index,
            point,
            front,
            normal,
        })
    }

    /// True when anything lies strictly between `from` and `to` (both ends excluded by epsilon).
    pub fn occluded(&self, from: [f64; 3], to: [f64; 3]) -> bool {
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
        let ray = Ray::new(v3(from), v3(d), 0.0, tmax as f32);
        !bvh.ray_traverse_miss(ray, |_ray, id| {
            let prim = &self.primitives[bvh.primitive_indices[id] as usize];
            match self.intersect(prim, from, d, tmax) {
                Some(t) => t as f32,
                None => f32::INFINITY,
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bake::math::sampling::{sample_cosine_hemisphere, sobol_2d, to_world};
    use crate::bake::scene::geometry::Geometry;
    use lightfarm_proto::scene::Aabb;
    use lightfarm_proto::Face;

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
                // Brute force over all primitives.
                let best = g
                    .primitives
                    .iter()
                    .enumerate()
                    .filter_map(|(p, prim)| {
                        tracer
                            .intersect(prim, texel.position, d, f64::INFINITY)
                            .map(|t| (t, p))
                    })
                    .min_by(|a, b| a.0.total_cmp(&b.0))
                    .unwrap();
                assert!(
                    (best.0 - hit.t).abs() < 1e-9,
                    "bvh {} vs brute {}",
                    hit.t,
                    best.0
                );
            }
        }
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
