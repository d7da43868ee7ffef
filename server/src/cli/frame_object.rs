//! `lightfarm frame-time BUNDLE --lights LIGHTS.json --update one-object`: the cost of relighting
//! when one dynamic object moves, against relighting everything.
//!
//! Pose `--object K` of the light set (default 0) moves on a horizontal circle of radius
//! `--radius` m around where the light set puts it, turning about the vertical axis as it goes,
//! one turn every [`PATH_FRAMES`] frames; the lights and the other poses stay. Every frame both
//! ways relight the level for the object's new pose, interleaved so the machine's noise falls on
//! both alike:
//! - **full**: every light's direct light with the posed objects' shadows (texel-averaged as
//!   `frame-time --update one-light` computes it: `ReachDirect::with_posed(…).all_lights`),
//!   `Runtime::apply`, the probe field from the light leaving the texels (`apply_probes`), the
//!   objects' light (`ObjectLight::update`) and its bounces (`ObjectLight::bounce`);
//! - **update**: the change of direct light where the object's shadows were and are
//!   (`ShadowChange::update`), `Runtime::apply_delta_in` of that change on a runtime of its own,
//!   the probe field by its change (`apply_probes_delta`, [`super::frame_probes`]), and the
//!   objects' light and its bounces as the full way makes them (`ObjectLight` already costs
//!   what the objects reach). The bounces of the objects' light are this frame's alone: they
//!   are kept apart from the runtime's indirect light (which follows the direct light's
//!   changes) and cleared where they were written before the next frame's.
//!
//! Each way is reported with its direct-light, operator and objects' times apart (medians),
//! then the update's total last (`median_ms=…`). After the last frame the update's direct light
//! (the first frame's plus every change) is compared with the full way's, and the light each
//! way adds to the lightmap (indirect light plus the objects' light and its bounces): relative
//! L2 over texels and channels, within float rounding for one or a fixed number of bounces and
//! within the tolerance for `all`. `feedback` and `warm` keep state between frames that this
//! comparison would mix in, and are refused.
//!
//! Units: milliseconds of wall time on this thread (the runtime single-threaded); metres.

use std::ops::Range;
use std::time::Instant;

use lightfarm_client::{
    direct_scale, relative_l2, Bounces, IndirectLight, Method, ObjectLight, Occluders, ProbeField,
    ReachDirect, Runtime, ShadowChange,
};
use lightfarm_proto::glam::DQuat;
use lightfarm_proto::lights::{LightSet, Pose};

use super::frame_probes::{ProbeTimes, ProbeWay};
use super::frame_update::{direct_of, median};
use crate::evaluate::{is_bounced, DIRECT_SAMPLES_PER_EDGE};

/// Frames of one turn of the path.
pub const PATH_FRAMES: usize = 120;

/// Medians (ms) of one way of relighting.
#[derive(Clone, Copy, Debug)]
pub struct ObjectWay {
    pub direct_ms: f64,
    pub operator_ms: f64,
    /// The probe field, the objects' light and its bounces.
    pub objects_ms: f64,
    pub total_ms: f64,
}

/// What [`time_object`] measured.
#[derive(Clone, Debug)]
pub struct ObjectTimes {
    pub object: String,
    pub full: ObjectWay,
    pub update: ObjectWay,
    /// Texels the change of direct light lay on and lights relit, medians over frames.
    pub texels_changed: usize,
    pub lights_relit: usize,
    /// Relative L2 after the last frame: the update's direct light against the full way's,
    /// and the light each adds to the lightmap (indirect plus the objects' light).
    pub direct_drift: f64,
    pub drift: f64,
    /// With a probe volume: keeping the probe field up to date both ways.
    pub probes: Option<ProbeTimes>,
    /// Whether the objects' own light (DNRT) was made: the bundle has a probe volume and a
    /// grid for every pose.
    pub object_light: bool,
}

/// Pose `pose` moved along the path to `frame`: its translation on a horizontal circle of
/// `radius` around where it was, its rotation turned about the vertical axis by the angle
/// travelled.
pub fn path_pose(pose: &Pose, radius: f64, frame: usize) -> Pose {
    let a = std::f64::consts::TAU * frame as f64 / PATH_FRAMES as f64;
    let [x, y, z] = pose.translation;
    let [qx, qy, qz, qw] = pose.rotation;
    let turned = DQuat::from_rotation_y(a) * DQuat::from_xyzw(qx, qy, qz, qw).normalize();
    Pose {
        id: pose.id.clone(),
        translation: [x + radius * a.cos(), y, z + radius * a.sin()],
        rotation: turned.to_array(),
    }
}

/// `a + b + c` per texel and channel (the light a way adds to the lightmap).
fn sum3(a: &[[f32; 3]], b: &[[f32; 3]], c: &[[f32; 3]]) -> Vec<[f32; 3]> {
    (a.iter().zip(b).zip(c))
        .map(|((a, b), c)| [0, 1, 2].map(|k| a[k] + b[k] + c[k]))
        .collect()
}

/// Times `frames` frames of pose `object` of `lights` moving along the path of `radius` m
/// (module doc), relit both ways with `method` and `bounces`.
#[allow(clippy::too_many_arguments)]
pub fn time_object(
    runtime: &mut Runtime,
    level: &Occluders,
    lights: &LightSet,
    object: usize,
    method: Method,
    bounces: Bounces,
    frames: usize,
    radius: f64,
) -> anyhow::Result<ObjectTimes> {
    anyhow::ensure!(
        object < lights.poses.len(),
        "--object {object}: the light set places {} dynamic objects",
        lights.poses.len()
    );
    anyhow::ensure!(
        !matches!(bounces, Bounces::Feedback | Bounces::Warm { .. }),
        "--update one-object times `1`, a fixed number of bounces or `all`, not {bounces:?}"
    );
    let bundle = runtime.bundle().clone();
    let layout = &bundle.layout;
    let n = layout.n_texels();
    let start_pose = lights.poses[object].clone();
    let mut poses = lights.poses.clone();
    let scale = direct_scale(layout, level);
    let bounced = is_bounced(bounces);
    let grids = bundle.dnrt.as_deref().unwrap_or(&[]);
    let object_light =
        runtime.has_probes() && poses.iter().all(|p| grids.iter().any(|g| g.object == p.id));
    let objects = || object_light.then(|| ObjectLight::new(&bundle)).transpose();
    let (mut full_objects, mut update_objects) = (objects()?, objects()?);

    // Frame 0, both ways from the same poses.
    poses[object] = path_pose(&start_pose, radius, 0);
    let mut full_reach = ReachDirect::new(&bundle, level);
    let direct0 = direct_of(
        &mut full_reach,
        &bundle,
        level,
        &lights.lights,
        &poses,
        scale,
    );
    let mut full_out = IndirectLight::default();
    runtime.apply(method, bounces, &direct0, &mut full_out)?;
    // The update way keeps frame 0's direct light and adds every change to it.
    let mut kept = direct0.clone();
    let m = DIRECT_SAMPLES_PER_EDGE;
    let mut shadows = ShadowChange::new(&bundle, level, &lights.lights, m, &poses);
    let mut by_change = runtime.clone();
    let mut update_out = IndirectLight::default();
    by_change.apply(method, bounces, &kept, &mut update_out)?;
    by_change.prepare_delta();
    let mut probe_way = ProbeWay::new(&mut by_change, &kept, &update_out, bounced)?;
    let mut full_field = ProbeField::default();
    // The update way's bounces of the objects' light, and where the last frame wrote them.
    let mut object_bounce = IndirectLight {
        radiance: vec![[0.0; 3]; n],
    };
    let mut bounce_written: Vec<Range<usize>> = Vec::new();

    let (mut full, mut update) = (vec![Vec::new(); 3], vec![Vec::new(); 3]);
    let (mut changed, mut relit) = (Vec::new(), Vec::new());
    let mut last_direct = direct0;
    for frame in 1..=frames {
        poses[object] = path_pose(&start_pose, radius, frame);
        // Full.
        let t0 = Instant::now();
        let direct = direct_of(
            &mut full_reach,
            &bundle,
            level,
            &lights.lights,
            &poses,
            scale,
        );
        let t1 = Instant::now();
        runtime.apply(method, bounces, &direct, &mut full_out)?;
        let t2 = Instant::now();
        if let Some(p) = probe_way.as_mut() {
            p.full_frame(runtime, &direct, &full_out, &mut full_field)?;
        }
        if let Some(o) = full_objects.as_mut() {
            o.update(&bundle, &full_field, bounced, level, &lights.lights, &poses)?;
            o.bounce(runtime, method, bounces, &mut full_out)?;
        }
        let t3 = Instant::now();
        for (times, (a, b)) in full.iter_mut().zip([(t0, t1), (t1, t2), (t2, t3)]) {
            times.push((b - a).as_secs_f64() * 1e3);
        }
        last_direct = direct;
        // Update.
        let t0 = Instant::now();
        shadows.update(&bundle, level, &poses)?;
        let change = shadows.change();
        for t in shadows.spans().iter().flat_map(Range::clone) {
            let (k, c) = (&mut kept.radiance[t], change.radiance[t]);
            *k = [k[0] + c[0], k[1] + c[1], k[2] + c[2]];
        }
        let t1 = Instant::now();
        by_change.apply_delta_in(method, bounces, change, shadows.spans(), &mut update_out)?;
        let t2 = Instant::now();
        if let Some(p) = probe_way.as_mut() {
            p.update_frame(&mut by_change, change, shadows.spans(), &update_out)?;
        }
        if let (Some(o), Some(p)) = (update_objects.as_mut(), probe_way.as_ref()) {
            o.update(&bundle, p.field(), bounced, level, &lights.lights, &poses)?;
            for r in bounce_written.drain(..) {
                object_bounce.radiance[r].fill([0.0; 3]);
            }
            if o.bounce(&mut by_change, method, bounces, &mut object_bounce)?
                .is_some()
            {
                match by_change.delta_written() {
                    Some(ranges) => bounce_written.extend(ranges),
                    None => bounce_written.push(0..n),
                }
            }
        }
        let t3 = Instant::now();
        for (times, (a, b)) in update.iter_mut().zip([(t0, t1), (t1, t2), (t2, t3)]) {
            times.push((b - a).as_secs_f64() * 1e3);
        }
        changed.push(shadows.spans().iter().map(|r| r.len()).sum::<usize>() as f64);
        relit.push(shadows.lights_relit() as f64);
    }
    let probes = match probe_way {
        Some(p) => Some(p.finish(&mut by_change, &kept, &update_out)?),
        None => None,
    };
    let zero = vec![[0.0f32; 3]; n];
    let light_of = |o: &Option<ObjectLight>| {
        o.as_ref()
            .map_or(zero.clone(), |o| o.light().radiance.clone())
    };
    let full_light = sum3(&full_out.radiance, &light_of(&full_objects), &zero);
    let update_light = sum3(
        &update_out.radiance,
        &light_of(&update_objects),
        &object_bounce.radiance,
    );
    let way = |[direct, operators, objects]: [Vec<f64>; 3]| {
        let sums: Vec<f64> = (direct.iter().zip(&operators).zip(&objects))
            .map(|((a, b), c)| a + b + c)
            .collect();
        ObjectWay {
            direct_ms: median(direct),
            operator_ms: median(operators),
            objects_ms: median(objects),
            total_ms: median(sums),
        }
    };
    let three = |v: Vec<Vec<f64>>| -> [Vec<f64>; 3] { v.try_into().expect("three stages") };
    Ok(ObjectTimes {
        object: start_pose.id.clone(),
        full: way(three(full)),
        update: way(three(update)),
        texels_changed: median(changed) as usize,
        lights_relit: median(relit) as usize,
        direct_drift: relative_l2(&kept.radiance, &last_direct.radiance),
        drift: relative_l2(&update_light, &full_light),
        probes,
        object_light,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfarm_proto::lights::{Light, LightKind};
    use lightfarm_proto::testing::ball_bundle;

    /// The ball of `ball_bundle` between its row of texels and a lamp, moving: relit by the
    /// change of its shadows, the direct light and the light added to the lightmap stay the
    /// full way's (float rounding at one and three bounces, the tolerance at all).
    #[test]
    fn relighting_by_the_change_of_a_moving_objects_shadow_agrees_with_relighting_everything() {
        let bundle = ball_bundle();
        let level = Occluders::from_layout(&bundle.layout);
        let lights = LightSet {
            lights: vec![Light {
                kind: LightKind::Point,
                position: [6.0, 0.5, 3.0],
                intensity: [20.0, 16.0, 12.0],
            }],
            poses: vec![Pose {
                id: "ball".into(),
                translation: [5.5, 0.5, 1.2],
                rotation: [0.0, 0.0, 0.0, 1.0],
            }],
        };
        for (bounces, tolerance) in [
            (Bounces::One, 1e-5),
            (Bounces::Fixed(3), 1e-5),
            (Bounces::Converged { tolerance: 1e-4 }, 1e-3),
        ] {
            let mut runtime = Runtime::try_new(bundle.clone()).unwrap();
            let t = time_object(
                &mut runtime,
                &level,
                &lights,
                0,
                Method::Mrt,
                bounces,
                12,
                1.0,
            )
            .unwrap();
            assert!(t.object_light, "the bundle has a grid and probes");
            assert_eq!(t.lights_relit, 1);
            assert!(
                t.texels_changed > 0 && t.texels_changed < bundle.layout.n_texels(),
                "{} texels changed",
                t.texels_changed
            );
            assert!(
                t.direct_drift < 1e-6,
                "{bounces:?}: direct {}",
                t.direct_drift
            );
            assert!(t.drift < tolerance, "{bounces:?}: drift {}", t.drift);
            assert!(t.probes.unwrap().drift < tolerance);
        }
        // Feedback and Warm keep state across frames; they are refused.
        let mut runtime = Runtime::try_new(bundle).unwrap();
        let refused = time_object(
            &mut runtime,
            &level,
            &lights,
            0,
            Method::Mrt,
            Bounces::Feedback,
            2,
            1.0,
        );
        assert!(refused.unwrap_err().to_string().contains("one-object"));
    }
}
