//! DNRT at evaluation: the light posed dynamic objects add to and take from the texels, fed
//! by the probe volume (see [`dnrt_delta`]).

use lightfarm_client::{
    irradiance_sh_at, point_light_irradiance_sh, radiance_sh_at, Bounces, Bundle, DirectLight,
    DnrtInstance, DnrtVolume, IndirectLight, Method, Occluders, ProbeField, Runtime,
};
use lightfarm_proto::lights::{LightSet, Pose};

/// DNRT (paper 003) for every posed dynamic object: per texel, the light the objects add and
/// take away. `field` is the probe volume fed the radiance leaving the texels
/// (`Runtime::apply_probes`), made once per frame by the caller.
/// One bounce (`bounced` false, `leaving` the direct light), consistent with the one-bounce
/// solution: an object reflects the point lights' direct light (their irradiance lobe at its
/// centre) and hides the radiance of the direct-lit surfaces behind it (the probe volume's
/// radiance SH at its centre, Appendix B.2); light the object would reflect from the walls is a
/// second bounce. All bounces (`bounced`, `leaving` direct plus indirect): the object also
/// reflects the walls' light (the probes' irradiance at its centre, the full light-probe input
/// the paper assumes) and hides their bounced light too. A point light it hides is its direct
/// shadow, never indirect light.
/// `None` when there are no poses; an error when a pose names an object without a grid or the
/// bundle has no probe volume.
pub fn dnrt_delta(
    bundle: &Bundle,
    field: &ProbeField,
    bounced: bool,
    occluders: &Occluders,
    lights: &LightSet,
) -> anyhow::Result<Option<DirectLight>> {
    let poses: &[Pose] = &lights.poses;
    if poses.is_empty() {
        return Ok(None);
    }
    let volume = bundle
        .probes
        .as_ref()
        .ok_or_else(|| anyhow::anyhow!("posed objects need the bundle's probe volume"))?;
    let grids = bundle.dnrt.as_deref().unwrap_or(&[]);
    let mut out = vec![[0.0f32; 3]; bundle.layout.n_texels()];
    for pose in poses {
        let grid = grids.iter().find(|g| g.object == pose.id).ok_or_else(|| {
            anyhow::anyhow!("pose \"{}\": the bundle has no DNRT grid for it", pose.id)
        })?;
        let dnrt = DnrtVolume::new(grid)?;
        let zero = [[0.0; 9]; 3];
        let at = DnrtInstance::new(&dnrt, pose.translation, pose.rotation, zero, zero);
        let centre = at.centre_world();
        let mut lit = point_light_irradiance_sh(occluders, &lights.lights, centre);
        if bounced {
            let walls = irradiance_sh_at(volume, field, centre);
            for (l, w) in lit.iter_mut().zip(walls) {
                for (a, b) in l.iter_mut().zip(w) {
                    *a += b;
                }
            }
        }
        let hidden = radiance_sh_at(volume, field, centre);
        let instance = DnrtInstance::new(&dnrt, pose.translation, pose.rotation, lit, hidden);
        instance.apply_texels(&bundle.layout, &mut out)?;
    }
    Ok(Some(DirectLight { radiance: out }))
}

/// With more than one bounce, the light the posed objects add and take away ([`dnrt_delta`]'s
/// `change`, radiance leaving the texels) bounces on: it goes through the operators like a
/// change of direct light (`Runtime::apply_delta`), its bounces added to `indirect`, which
/// holds the runtime's answer for the direct light. In a bright room a red ball darkens the
/// whole room's green, not only its surroundings: ball_corridor at all bounces against
/// Mitsuba, 0.0523 without this, 0.0264 with it. The object's reflection is a bounce already,
/// so `Fixed(n)` bounces the change `n − 1` more times; at one bounce nothing is added (the
/// papers' DNRT).
pub fn bounce_object_light(
    runtime: &mut Runtime,
    method: Method,
    bounces: Bounces,
    change: &DirectLight,
    indirect: &mut IndirectLight,
) -> anyhow::Result<()> {
    let rest = match bounces {
        Bounces::One | Bounces::Fixed(0 | 1) => return Ok(()),
        Bounces::Fixed(n) => Bounces::Fixed(n - 1),
        other => other,
    };
    runtime.apply_delta(method, rest, change, indirect)?;
    Ok(())
}
