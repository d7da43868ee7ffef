//! Direct shadows of posed dynamic objects: each object's triangles (bundle section `dynamic
//! shapes`, in its own frame) moved to this frame's pose and added to the level's occluders,
//! so that the direct light the operators are fed is dark where an object hides a light, as
//! in a path tracer. The light an object reflects and the bounced light it hides are DNRT's
//! ([`crate::dnrt`]); a point light it hides is direct light, which only its geometry can
//! shadow.
//!
//! Frames and units: a pose maps the object frame to the world, `x_world = R x_obj + t`, with
//! `R` from the quaternion `[x, y, z, w]` normalised ([`quaternion_matrix`], as DNRT and the
//! reference pose objects); metres; posed in f64, stored in f32 like every occluder.
//!
//! Invariants: the posed occluders keep the level's scale, so their margins are the level's:
//! a segment no posed triangle crosses gets exactly the level's answer, and direct light on a
//! texel no object shadows is bit-identical to the level's. A pose whose object has no shape
//! (a bundle before format 2.4, or an object the bundle does not list) casts no shadow.

use lightfarm_proto::bundle::{Bundle, DynamicShape};
use lightfarm_proto::glam::{DMat3, DVec3};
use lightfarm_proto::lights::Pose;
use lightfarm_proto::sh_rotation::quaternion_matrix;

use crate::occluders::Occluders;

/// `shape`'s triangles at `pose`, world frame.
pub fn posed_triangles(shape: &DynamicShape, pose: &Pose) -> Vec<[[f32; 3]; 3]> {
    // quaternion_matrix gives rows; glam builds from columns.
    let rotation = DMat3::from_cols_array_2d(&quaternion_matrix(pose.rotation)).transpose();
    let translation = DVec3::from_array(pose.translation);
    shape
        .triangles
        .iter()
        .map(|tri| {
            tri.map(|v| {
                let world = rotation * DVec3::from_array(v.map(f64::from)) + translation;
                world.as_vec3().to_array()
            })
        })
        .collect()
}

/// This frame's posed objects: the occluders to shadow direct light with, and the boxes the
/// objects occupy (for the light reach, [`crate::ReachDirect::with_posed`], which must not take
/// a room holding one to hold nothing but walls).
#[derive(Clone, Debug)]
pub struct PosedObjects {
    /// The level's occluders plus every posed object's triangles, with the level's margins
    /// ([`Occluders::with_objects_triangles`]: the level's hierarchy shared, the objects' in
    /// one of their own, numbered after the level's, each triangle's object numbered by its
    /// place in [`shadowing_poses`], for [`Occluders::occluded_except`]).
    pub occluders: Occluders,
    /// Per posed object, the bounds `(min, max)` of its posed triangles (metres), in the order
    /// of [`shadowing_poses`].
    pub boxes: Vec<([f64; 3], [f64; 3])>,
}

/// The poses of `poses` that cast shadows (their object has a shape with triangles in
/// `bundle`), in order, each with its shape: what [`occluders_with_poses`] places.
pub fn shadowing_poses<'a>(
    bundle: &'a Bundle,
    poses: &'a [Pose],
) -> impl Iterator<Item = (&'a Pose, &'a DynamicShape)> + 'a {
    poses.iter().filter_map(|pose| {
        let shape = bundle.dynamic_shapes.iter().find(|s| s.object == pose.id)?;
        (!shape.triangles.is_empty()).then_some((pose, shape))
    })
}

/// The occluders this frame's direct light is shadowed with: the level's with the posed objects
/// in when some are placed (`posed`), else the level's.
pub fn frame_occluders<'a>(level: &'a Occluders, posed: Option<&'a PosedObjects>) -> &'a Occluders {
    posed.map_or(level, |p| &p.occluders)
}

/// The level's occluders with every posed object's triangles ([`posed_triangles`]) added;
/// `None` when no pose has a shape in the bundle (the level's occluders stand as they are).
pub fn occluders_with_poses(
    level: &Occluders,
    bundle: &Bundle,
    poses: &[Pose],
) -> Option<PosedObjects> {
    let (mut triangles, mut owners, mut boxes) = (Vec::new(), Vec::new(), Vec::new());
    for (pose, shape) in shadowing_poses(bundle, poses) {
        let posed = posed_triangles(shape, pose);
        let mut bounds: Option<(DVec3, DVec3)> = None;
        for v in posed.iter().flatten() {
            let v = DVec3::from_array(v.map(f64::from));
            bounds = Some(bounds.map_or((v, v), |(lo, hi)| (lo.min(v), hi.max(v))));
        }
        if let Some((lo, hi)) = bounds {
            owners.resize(owners.len() + posed.len(), boxes.len() as u32);
            boxes.push((lo.to_array(), hi.to_array()));
            triangles.extend(posed);
        }
    }
    (!triangles.is_empty()).then(|| PosedObjects {
        occluders: level.with_objects_triangles(&triangles, &owners),
        boxes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::direct::tests::floor;

    /// A square lid of half-size `half` in the plane z = `z` (object frame).
    fn square(half: f32, z: f32) -> DynamicShape {
        DynamicShape {
            object: "lid".into(),
            albedo: [0.5; 3],
            triangles: vec![
                [[-half, -half, z], [half, -half, z], [half, half, z]],
                [[-half, -half, z], [half, half, z], [-half, half, z]],
            ],
        }
    }

    #[test]
    fn a_pose_rotates_then_translates() {
        let shape = square(1.0, 0.0);
        // 90° about +z: x → y, y → −x.
        let s = std::f64::consts::FRAC_1_SQRT_2;
        let pose = Pose {
            id: "lid".into(),
            translation: [10.0, 20.0, 30.0],
            rotation: [0.0, 0.0, s, s],
        };
        let posed = posed_triangles(&shape, &pose);
        for (tri, src) in posed.iter().zip(&shape.triangles) {
            for (v, o) in tri.iter().zip(src) {
                let expected = [10.0 - o[1], 20.0 + o[0], 30.0 + o[2]];
                for k in 0..3 {
                    assert!((v[k] - expected[k]).abs() < 1e-5, "{v:?} vs {expected:?}");
                }
            }
        }
        // An unnormalised quaternion is the same rotation.
        let doubled = Pose {
            rotation: [0.0, 0.0, 2.0 * s, 2.0 * s],
            ..pose.clone()
        };
        assert_eq!(posed_triangles(&shape, &doubled), posed);
    }

    #[test]
    fn a_posed_object_shadows_only_what_it_hides() {
        let mut bundle = Bundle::default();
        bundle.layout = floor(&[[1.2, 0.9, 0.0], [3.0, 3.0, 0.0]]);
        bundle.dynamic_shapes = vec![square(0.5, 0.0)];
        let level = Occluders::from_layout(&bundle.layout);
        let pose = |id: &str| Pose {
            id: id.into(),
            translation: [1.0, 1.0, 1.0],
            rotation: [0.0, 0.0, 0.0, 1.0],
        };
        assert!(occluders_with_poses(&level, &bundle, &[pose("other")]).is_none());
        let objects = occluders_with_poses(&level, &bundle, &[pose("lid")]).unwrap();
        assert_eq!(objects.boxes, vec![([0.5, 0.5, 1.0], [1.5, 1.5, 1.0])]);
        let posed = &objects.occluders;
        assert_eq!(posed.len(), level.len() + 2);
        assert_eq!(posed.scale(), level.scale());
        let light = [1.0, 1.0, 3.0];
        // Under the lid, hidden; beside it, lit as the level alone says.
        assert!(posed.occluded([1.2, 0.9, 0.0], light));
        assert!(!posed.occluded([3.0, 0.0, 3.0], light));
        assert!(!level.occluded([1.2, 0.9, 0.0], light));
    }
}
