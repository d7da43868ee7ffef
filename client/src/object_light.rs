//! Posed dynamic objects' light on the lightmap, per frame (DNRT, paper 003): what each object
//! adds to (reflection) and takes from (occlusion) the texels around it, fed by the probe
//! volume, and the bounces of that light ([`ObjectLight`]).
//!
//! One bounce (`bounced` false, the probe field filled from the direct light): an object
//! reflects the point lights' direct light (their irradiance lobe at its centre,
//! [`point_light_irradiance_sh`]) and hides the radiance of the direct-lit surfaces behind it
//! (the probe volume's radiance SH at its centre, Appendix B.2); light it would reflect from
//! the walls is a second bounce. All bounces (`bounced`, the field filled from direct plus
//! indirect light): the object also reflects the walls' light (the probes' irradiance at its
//! centre, the full light-probe input the paper assumes) and hides their bounced light too. A
//! point light an object hides is its direct shadow ([`crate::occluders_with_poses`]), never
//! this light. The point lights reach an object's centre past the level and the other posed
//! objects, not its own triangles (which enclose the centre): a ball under another gets none
//! of the lamp the upper one hides.
//!
//! With more than one bounce the objects' light bounces on through the operators like a change
//! of direct light ([`ObjectLight::bounce`]): in a bright room a red ball darkens the whole
//! room's green, not only its surroundings (ball_corridor at all bounces against Mitsuba:
//! 0.0523 without it, 0.0264 with it). The reflection is a bounce already, so `Fixed(n)`
//! bounces it `n − 1` more times and one bounce adds nothing (the papers' DNRT).
//!
//! Units: radiance leaving the texels (W/m²/sr per channel), metres, world frame; poses map the
//! object frame to the world (`x_world = R x_obj + t`).
//!
//! Invariants: the grids are decoded once ([`ObjectLight::new`]); [`ObjectLight::update`]
//! writes only the surfaces within each object's reach (`SurfaceBounds::near`), clears only
//! what its last call wrote, and keeps [`ObjectLight::light`] zero outside
//! [`ObjectLight::spans`] (ascending, disjoint); a refused call leaves the light of the last
//! successful one.

use std::ops::Range;

use lightfarm_proto::bundle::Bundle;
use lightfarm_proto::lights::{Light, Pose};
use lightfarm_proto::sh::SH_COEFFS;

use crate::direct::DirectLight;
use crate::dnrt::{DnrtError, DnrtNear, DnrtVolume};
use crate::dynamic_shadows::{frame_occluders, occluders_with_poses, shadowing_poses};
use crate::light_sh::{point_light_irradiance_sh, point_light_irradiance_sh_with};
use crate::occluders::Occluders;
use crate::probes::{irradiance_sh_at, radiance_sh_at, ProbeField};
use crate::runtime::{
    merge_spans, ApplyError, Bounces, DeltaApplied, IndirectLight, Method, Runtime,
    DEFAULT_TOLERANCE,
};
use crate::surface_bounds::SurfaceBounds;

/// Why the objects' light could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ObjectLightError {
    #[error("posed objects need the bundle's probe volume, and it has none")]
    NoProbeVolume,
    #[error("pose \"{0}\": the bundle has no DNRT grid for it")]
    NoGrid(String),
    #[error(
        "the probe field has {got} probes, the bundle's volume {expected}: fill it first \
         (Runtime::apply_probes)"
    )]
    FieldSize { expected: usize, got: usize },
    #[error(
        "this ObjectLight was made for a bundle of {texels} texels and {grids} DNRT grids, \
         not this one"
    )]
    OtherBundle { texels: usize, grids: usize },
    #[error(transparent)]
    Dnrt(#[from] DnrtError),
}

/// The per-frame light of posed dynamic objects on a bundle's texels (see the module doc).
#[derive(Clone, Debug)]
pub struct ObjectLight {
    /// The bundle's DNRT grids, decoded (bundle order).
    volumes: Vec<DnrtVolume>,
    bounds: SurfaceBounds,
    /// One RGB value per texel: the last update's light, zero outside `spans`.
    light: DirectLight,
    spans: Vec<Range<usize>>,
    /// Scratch: one object's surfaces.
    ranges: Vec<Range<usize>>,
}

impl ObjectLight {
    /// Decodes `bundle`'s DNRT grids and bounds its surfaces (once per bundle, at load).
    pub fn new(bundle: &Bundle) -> Result<ObjectLight, DnrtError> {
        let volumes = (bundle.dnrt.as_deref().unwrap_or(&[]).iter())
            .map(DnrtVolume::new)
            .collect::<Result<_, _>>()?;
        Ok(ObjectLight {
            volumes,
            bounds: SurfaceBounds::new(&bundle.layout),
            light: DirectLight {
                radiance: vec![[0.0; 3]; bundle.layout.n_texels()],
            },
            spans: Vec::new(),
            ranges: Vec::new(),
        })
    }

    /// This frame's light of the objects at `poses` (each must have a grid in `bundle`, the
    /// bundle this was made for): `field` is the bundle's probe field, filled from the light
    /// leaving the texels (`Runtime::apply_probes` of the direct light at one bounce, of direct
    /// plus indirect light when `bounced`); `level` the bundle's occluders
    /// (`Occluders::from_layout`), which with the other posed objects shadow each object's
    /// light-probe input from `lights`. No poses: no light. Allocates per object (room for its
    /// grid contracted with this frame's light, and with several objects the others'
    /// occluders).
    pub fn update(
        &mut self,
        bundle: &Bundle,
        field: &ProbeField,
        bounced: bool,
        level: &Occluders,
        lights: &[Light],
        poses: &[Pose],
    ) -> Result<(), ObjectLightError> {
        // Check everything before the last light is cleared.
        let grids = bundle.dnrt.as_deref().unwrap_or(&[]);
        let texels = self.light.radiance.len();
        if bundle.layout.n_texels() != texels || grids.len() != self.volumes.len() {
            let grids = self.volumes.len();
            return Err(ObjectLightError::OtherBundle { texels, grids });
        }
        let mut which = Vec::with_capacity(poses.len());
        for pose in poses {
            let g = grids.iter().position(|g| g.object == pose.id);
            which.push(g.ok_or_else(|| ObjectLightError::NoGrid(pose.id.clone()))?);
        }
        let volume = match (poses.is_empty(), bundle.probes.as_ref()) {
            (true, _) => None,
            (false, None) => return Err(ObjectLightError::NoProbeVolume),
            (false, Some(v)) if field.n_probes() != v.n_probes as usize => {
                return Err(ObjectLightError::FieldSize {
                    expected: v.n_probes as usize,
                    got: field.n_probes(),
                })
            }
            (false, Some(v)) => Some(v),
        };
        for r in self.spans.drain(..) {
            self.light.radiance[r].fill([0.0; 3]);
        }
        let Some(volume) = volume else {
            return Ok(());
        };
        // Every object posed once, each numbered by its place among the shadowing poses.
        let posed = occluders_with_poses(level, bundle, poses);
        let occluders = frame_occluders(level, posed.as_ref());
        let mut placed = 0u32;
        for (pose, &g) in poses.iter().zip(&which) {
            let casts = shadowing_poses(bundle, std::slice::from_ref(pose)).next();
            let own = casts.map(|_| {
                placed += 1;
                placed - 1
            });
            let dnrt = &self.volumes[g];
            let centre = dnrt.centre_world(pose.translation, pose.rotation);
            let mut lit = lights_at_object(occluders, own, lights, centre);
            if bounced {
                let walls = irradiance_sh_at(volume, field, centre);
                for (l, w) in lit.iter_mut().zip(walls) {
                    for (a, b) in l.iter_mut().zip(w) {
                        *a += b;
                    }
                }
            }
            let hidden = radiance_sh_at(volume, field, centre);
            let mut instance = DnrtNear::new(dnrt, pose.translation, pose.rotation, lit, hidden);
            let out = &mut self.light.radiance;
            instance.apply_texels_near(&bundle.layout, &self.bounds, &mut self.ranges, out)?;
            self.spans.extend_from_slice(&self.ranges);
        }
        merge_spans(&mut self.spans);
        Ok(())
    }

    /// The last update's light leaving each texel (zero outside [`ObjectLight::spans`]): add it
    /// to the indirect light of the frame.
    pub fn light(&self) -> &DirectLight {
        &self.light
    }

    /// The texel ranges the last update's light lies in (ascending, disjoint).
    pub fn spans(&self) -> &[Range<usize>] {
        &self.spans
    }

    /// Adds the bounces of the last update's light to `indirect` (the runtime's answer for the
    /// direct light, with `bounces`): `Fixed(n)` bounces it `n − 1` times, `One` and
    /// `Fixed(0 | 1)` not at all (`None`), `Converged` and `Warm` to their tolerance, and
    /// `Feedback` converged to [`DEFAULT_TOLERANCE`]: the objects' light is this frame's whole
    /// light, not a change to carry over frames (`Runtime::apply_delta_in` on
    /// [`ObjectLight::spans`], which computes only what the light reaches).
    pub fn bounce(
        &self,
        runtime: &mut Runtime,
        method: Method,
        bounces: Bounces,
        indirect: &mut IndirectLight,
    ) -> Result<Option<DeltaApplied>, ApplyError> {
        let rest = match bounces {
            Bounces::One | Bounces::Fixed(0 | 1) => return Ok(None),
            Bounces::Fixed(n) => Bounces::Fixed(n - 1),
            Bounces::Feedback => Bounces::Converged {
                tolerance: DEFAULT_TOLERANCE,
            },
            other => other,
        };
        runtime
            .apply_delta_in(method, rest, &self.light, &self.spans, indirect)
            .map(Some)
    }
}

/// The point lights' irradiance SH at a posed object's centre `centre` (its light-probe
/// input): shadowed by the frame's `occluders` (the level's with every posed object in,
/// [`occluders_with_poses`]) but for the object's own triangles (`own`, its number there;
/// `None` when it casts no shadow), which enclose its centre. With one pose, the level's
/// answer. One hierarchy over every object serves all of them: the objects' light costs a
/// build over their triangles once a frame, not once per object.
fn lights_at_object(
    occluders: &Occluders,
    own: Option<u32>,
    lights: &[Light],
    centre: [f32; 3],
) -> [[f32; SH_COEFFS]; 3] {
    let scale = occluders.scale();
    match own {
        Some(own) => point_light_irradiance_sh_with(
            |a, b| occluders.occluded_except(a, b, own),
            scale,
            lights,
            centre,
        ),
        None => point_light_irradiance_sh(occluders, lights, centre),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dnrt::DnrtInstance;
    use lightfarm_proto::lights::LightKind;
    use lightfarm_proto::testing::{ball_bundle, cube};

    fn lamp(position: [f64; 3]) -> Light {
        Light {
            kind: LightKind::Point,
            position,
            intensity: [10.0, 8.0, 6.0],
        }
    }

    fn pose(id: &str, translation: [f64; 3]) -> Pose {
        Pose {
            id: id.into(),
            translation,
            rotation: [0.0, 0.0, 0.0, 1.0],
        }
    }

    /// The bundle's runtime with its probe field filled from some direct light.
    fn lit(bundle: &Bundle) -> (Runtime, ProbeField, DirectLight) {
        let mut runtime = Runtime::try_new(bundle.clone()).unwrap();
        let n = bundle.layout.n_texels();
        let direct = DirectLight {
            radiance: (0..n).map(|t| [0.5 + 0.1 * t as f32, 0.4, 0.3]).collect(),
        };
        let mut field = ProbeField::default();
        runtime.apply_probes(&direct, &mut field).unwrap();
        (runtime, field, direct)
    }

    #[test]
    fn the_light_lies_in_its_spans_and_follows_the_object() {
        let bundle = ball_bundle();
        let level = Occluders::from_layout(&bundle.layout);
        let (_, field, _) = lit(&bundle);
        let lights = [lamp([3.0, 0.0, 3.0])];
        let mut objects = ObjectLight::new(&bundle).unwrap();
        let volume = bundle.probes.as_ref().unwrap();
        for bounced in [false, true] {
            for at in [[3.0, 0.0, 0.8], [10.0, 0.2, 1.0], [3.5, 0.0, 0.7]] {
                let poses = [pose("ball", at)];
                objects
                    .update(&bundle, &field, bounced, &level, &lights, &poses)
                    .unwrap();
                // What DNRT gives every texel, the light probe made by hand.
                let dnrt = DnrtVolume::new(&bundle.dnrt.as_ref().unwrap()[0]).unwrap();
                let zero = [[0.0; 9]; 3];
                let (t, r) = (at, [0.0, 0.0, 0.0, 1.0]);
                let centre = DnrtInstance::new(&dnrt, t, r, zero, zero).centre_world();
                let mut probe = point_light_irradiance_sh(&level, &lights, centre);
                if bounced {
                    let walls = irradiance_sh_at(volume, &field, centre);
                    for (p, w) in probe.iter_mut().flatten().zip(walls.iter().flatten()) {
                        *p += w;
                    }
                }
                let hidden = radiance_sh_at(volume, &field, centre);
                let mut want = vec![[0.0f32; 3]; bundle.layout.n_texels()];
                DnrtInstance::new(&dnrt, t, r, probe, hidden)
                    .apply_texels(&bundle.layout, &mut want)
                    .unwrap();
                assert_eq!(
                    objects.light().radiance,
                    want,
                    "at {at:?}, bounced {bounced}"
                );
                assert!(
                    want.iter().any(|v| v[0] != 0.0),
                    "the ball lights something"
                );
                let spans = objects.spans();
                assert!(spans.windows(2).all(|w| w[0].end < w[1].start), "{spans:?}");
                for (t, v) in want.iter().enumerate() {
                    if !spans.iter().any(|r| r.contains(&t)) {
                        assert_eq!(*v, [0.0; 3], "texel {t} outside {spans:?}");
                    }
                }
                // Far from the first spot: texel 3 is out of the second one's reach.
                if at[0] == 10.0 {
                    assert!(!spans.iter().any(|r| r.contains(&3)), "{spans:?}");
                }
            }
        }
        // No poses: no light.
        objects
            .update(&bundle, &field, false, &level, &lights, &[])
            .unwrap();
        assert!(objects.spans().is_empty());
        assert!(objects.light().radiance.iter().all(|v| *v == [0.0; 3]));
    }

    #[test]
    fn refused_updates_name_the_cause_and_keep_the_last_light() {
        let bundle = ball_bundle();
        let level = Occluders::from_layout(&bundle.layout);
        let (_, field, _) = lit(&bundle);
        let lights = [lamp([3.0, 0.0, 3.0])];
        let mut objects = ObjectLight::new(&bundle).unwrap();
        let ball = [pose("ball", [3.0, 0.0, 0.8])];
        objects
            .update(&bundle, &field, false, &level, &lights, &ball)
            .unwrap();
        let kept = (objects.light().clone(), objects.spans().to_vec());
        let unknown = [pose("ball", [3.0, 0.0, 0.8]), pose("crate", [1.0; 3])];
        let err = objects
            .update(&bundle, &field, false, &level, &lights, &unknown)
            .unwrap_err();
        assert_eq!(err, ObjectLightError::NoGrid("crate".into()));
        assert!(err.to_string().contains("\"crate\""), "{err}");
        let empty = ProbeField::default();
        let err = objects
            .update(&bundle, &empty, false, &level, &lights, &ball)
            .unwrap_err();
        assert_eq!(
            err,
            ObjectLightError::FieldSize {
                expected: bundle.probes.as_ref().unwrap().n_probes as usize,
                got: 0
            }
        );
        let mut no_volume = bundle.clone();
        no_volume.probes = None;
        let err = objects
            .update(&no_volume, &field, false, &level, &lights, &ball)
            .unwrap_err();
        assert_eq!(err, ObjectLightError::NoProbeVolume);
        let other =
            lightfarm_proto::testing::probe_bundle(&mut lightfarm_proto::testing::Lcg(3), true);
        let err = objects
            .update(&other, &field, false, &level, &lights, &ball)
            .unwrap_err();
        assert_eq!(
            err,
            ObjectLightError::OtherBundle {
                texels: bundle.layout.n_texels(),
                grids: 1
            }
        );
        assert_eq!((objects.light().clone(), objects.spans().to_vec()), kept);
    }

    #[test]
    fn the_reflection_is_a_bounce_already() {
        let bundle = ball_bundle();
        let level = Occluders::from_layout(&bundle.layout);
        let (mut runtime, field, direct) = lit(&bundle);
        let mut objects = ObjectLight::new(&bundle).unwrap();
        let ball = [pose("ball", [3.0, 0.0, 0.8])];
        objects
            .update(
                &bundle,
                &field,
                true,
                &level,
                &[lamp([3.0, 0.0, 3.0])],
                &ball,
            )
            .unwrap();
        let mut answer = IndirectLight::default();
        runtime
            .apply(Method::Mrt, Bounces::Fixed(3), &direct, &mut answer)
            .unwrap();
        // One bounce adds nothing.
        let mut one = answer.clone();
        let none = objects.bounce(&mut runtime, Method::Mrt, Bounces::One, &mut one);
        assert!(none.unwrap().is_none());
        assert_eq!(one, answer);
        // Three bounces: the light bounces twice more.
        let mut three = answer.clone();
        let mut twice = answer.clone();
        objects
            .bounce(&mut runtime, Method::Mrt, Bounces::Fixed(3), &mut three)
            .unwrap()
            .unwrap();
        let (light, spans) = (objects.light(), objects.spans());
        runtime
            .apply_delta_in(Method::Mrt, Bounces::Fixed(2), light, spans, &mut twice)
            .unwrap();
        assert_eq!(three, twice);
        assert_ne!(three, answer);
        // Feedback: the light's converged bounces, twice the same (nothing carried over).
        let converged = Bounces::Converged {
            tolerance: DEFAULT_TOLERANCE,
        };
        let mut want = answer.clone();
        runtime
            .apply_delta_in(Method::Mrt, converged, light, spans, &mut want)
            .unwrap();
        for _ in 0..2 {
            let mut got = answer.clone();
            objects
                .bounce(&mut runtime, Method::Mrt, Bounces::Feedback, &mut got)
                .unwrap()
                .unwrap();
            assert_eq!(got, want);
        }
    }

    /// A lamp above two stacked cubes: the lower one's light-probe input gets none of the lamp
    /// (the upper cube hides it), and alone it gets the lamp's unshadowed lobe; the upper one
    /// gets the lamp either way, and no object's own triangles hide its centre.
    #[test]
    fn an_object_hides_a_lamp_from_the_object_under_it() {
        let bundle = Bundle {
            dynamic_shapes: vec![cube("upper", 0.3), cube("lower", 0.3)],
            ..Bundle::default()
        };
        let level = Occluders::from_layout(&bundle.layout);
        let lamp = lamp([0.0, 3.0, 0.0]);
        let both = [
            pose("upper", [0.0, 2.0, 0.0]),
            pose("lower", [0.0, 0.5, 0.0]),
        ];
        let lamp = std::slice::from_ref(&lamp);
        let energy = |sh: [[f32; 9]; 3]| sh.iter().flatten().map(|c| c.abs()).sum::<f32>();
        let at = |poses: &[Pose], own: u32, centre: [f32; 3]| {
            let posed = occluders_with_poses(&level, &bundle, poses);
            lights_at_object(
                frame_occluders(&level, posed.as_ref()),
                Some(own),
                lamp,
                centre,
            )
        };
        let lower_alone = at(&both[1..], 0, [0.0, 0.5, 0.0]);
        let lower = at(&both, 1, [0.0, 0.5, 0.0]);
        let upper = at(&both, 0, [0.0, 2.0, 0.0]);
        // 10 W/sr at 2.5 m: the DC term of the lobe is Â₀ · 1.6 · Y₀₀ > 0.
        assert!(energy(lower_alone) > 0.5, "{lower_alone:?}");
        assert_eq!(energy(lower), 0.0, "{lower:?}");
        assert!(energy(upper) > 4.0 * energy(lower_alone), "{upper:?}");
        // One pose: the level's answer, bit for bit.
        assert_eq!(
            lower_alone,
            point_light_irradiance_sh(&level, lamp, [0.0, 0.5, 0.0])
        );
    }
}
