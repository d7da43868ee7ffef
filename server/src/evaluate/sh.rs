//! SH incident radiance of every texel (bundle section `sh`) for a light set, through the
//! client exactly as a game would (`Runtime::apply_sh`, direct light averaged over each texel
//! as for `Runtime::apply`). With more than one bounce the SH responses are fed the radiance
//! leaving the texels, direct plus the runtime's bounced indirect light (DRT where the bundle
//! has it), so the incident radiance carries every bounce.
//!
//! Units: SH coefficients of `lightfarm_proto::sh` (world frame, y up; incident radiance, no
//! albedo). Texels the bake left without rows (buried) are 0.

use lightfarm_client::{Bounces, IndirectLight, Method, Occluders, Runtime, ShLight};
use lightfarm_proto::bundle::Bundle;
use lightfarm_proto::lights::LightSet;

use super::operator_direct;

/// The SH incident radiance of every texel for `lights`, carrying `bounces` bounces.
pub fn sh_incident(bundle: Bundle, lights: &LightSet, bounces: Bounces) -> anyhow::Result<ShLight> {
    let occluders = Occluders::from_layout(&bundle.layout);
    let mut light = operator_direct(&bundle, &occluders, lights);
    let mut runtime = Runtime::try_new(bundle)?;
    if !matches!(bounces, Bounces::One | Bounces::Fixed(1)) {
        let method = if runtime.has_drt() {
            Method::Drt
        } else {
            Method::Mrt
        };
        // Incident radiance of bounce k+1 is the radiance of bounce k leaving the texels: feed
        // the SH responses direct light plus every bounce but the last.
        let fewer = match bounces {
            Bounces::Fixed(n) => Bounces::Fixed(n - 1),
            other => other,
        };
        let mut indirect = IndirectLight::default();
        runtime.apply(method, fewer, &light, &mut indirect)?;
        for (l, i) in light.radiance.iter_mut().zip(&indirect.radiance) {
            *l = [l[0] + i[0], l[1] + i[1], l[2] + i[2]];
        }
    }
    let mut out = ShLight::default();
    runtime.apply_sh(&light, &mut out)?;
    Ok(out)
}
