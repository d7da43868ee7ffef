//! Dynamic objects' own light on the lightmap, for C callers (DNRT, paper 003): what each object
//! placed with `lf_runtime_set_poses` adds to (reflection) and takes from (occlusion) the
//! texels around it this frame ([`lf_runtime_object_light`]), and that light's bounces through
//! the operators ([`lf_runtime_bounce_object_light`]), as `lightfarm eval` lights posed objects
//! (`lightfarm_client::ObjectLight`).
//!
//! An object's light-probe input is the point lights at its centre (shadowed by the level and
//! the other posed objects) and, with more than one bounce, the probe field's irradiance there;
//! it hides the probe field's radiance. So the field must be filled first
//! (`lf_runtime_apply_probes`) from the light leaving the texels: the direct light with
//! `LF_BOUNCES_ONE`, direct plus indirect light otherwise. The bounce mode is the runtime's
//! (`lf_runtime_set_bounces`).
//!
//! Units: radiance leaving the texels (W/m²/sr per channel), texel-major RGB in layout order.
//!
//! Invariants: the bundle's DNRT grids are decoded on the first call and kept; the light lies
//! on the surfaces within each object's reach only, and a call writes `out_rgb` on its spans
//! only; a refused call writes nothing and keeps the last light (the one
//! [`lf_runtime_bounce_object_light`] bounces).

use lightfarm_client::{Bounces, ObjectLight};

use crate::boundary::{slice_mut, status_call};
use crate::direct::LfPointLight;
use crate::reach::{lights_and_light_out, write_light_on_spans, LfTexelSpan};
use crate::runtime::LfRuntime;
use crate::status::CapiError;

/// Whether `bounces` feeds an object the walls' light too (its reflection of the point lights
/// is the first bounce).
fn bounced(bounces: Bounces) -> bool {
    !matches!(bounces, Bounces::One | Bounces::Fixed(1))
}

/// This frame's light of the dynamic objects placed with `lf_runtime_set_poses`, from the
/// `n_lights` point `lights` and the probe field (see the module doc): writes the texel spans
/// it lies in to `out_spans` (ascending, disjoint; their number to `*out_count`) and the light
/// on those spans to `out_rgb` (`out_len` = `3 x texels` floats; every other texel keeps its
/// value). Add it to the frame's indirect light; with more than one bounce, add its bounces
/// too (`lf_runtime_bounce_object_light`). No object placed: no span.
///
/// Returns `LF_STATUS_OK`, or: `LF_STATUS_NULL_POINTER` (`rt`, `out_count`, `lights` with
/// `n_lights > 0`, `out_rgb` with `out_len > 0`, or `out_spans` when spans are to be
/// written), `LF_STATUS_INVALID_LIGHT`, `LF_STATUS_BAD_LENGTH` (`out_len` is not `3 x texels`,
/// `capacity` is below the number of spans (`*out_count` then holds the number needed), or the
/// probe field is not filled yet), `LF_STATUS_MISSING_OPERATOR` (the bundle has no probe
/// volume, or no DNRT grid for a placed object) or `LF_STATUS_PANIC`. On an error neither
/// `out_spans` nor `out_rgb` is written. Allocates per object and call (its grid contracted
/// with the frame's light).
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`, used by no other thread during
/// the call. `lights` must be NULL or point to `n_lights` readable `LfPointLight`s; `out_spans`
/// NULL or `capacity` writable `LfTexelSpan`s; `out_count` NULL or writable; `out_rgb` NULL or
/// `out_len` writable floats; none overlapping another.
#[no_mangle]
#[allow(clippy::too_many_arguments)]
pub unsafe extern "C" fn lf_runtime_object_light(
    rt: *mut LfRuntime,
    lights: *const LfPointLight,
    n_lights: usize,
    out_spans: *mut LfTexelSpan,
    capacity: usize,
    out_count: *mut usize,
    out_rgb: *mut f32,
    out_len: usize,
) -> i32 {
    status_call("lf_runtime_object_light", || {
        // SAFETY: the arguments are as `lights_and_light_out` needs, per the contract.
        let (rt, count, lights, out) =
            unsafe { lights_and_light_out(rt, lights, n_lights, out_count, out_rgb, out_len) }?;
        let objects = rt.object_light(&lights)?;
        let (spans, light) = (objects.spans(), &objects.light().radiance);
        // SAFETY: `out_spans` NULL or `capacity` writable spans, per the contract.
        unsafe { write_light_on_spans(spans, light, out_spans, capacity, count, out) }
    })
}

/// Adds to `indirect_rgb` (`3 x texels` floats) the bounces of the last
/// `lf_runtime_object_light`'s light through the operators of `method`, in the runtime's
/// bounce mode less one (the objects' reflection is a bounce already): nothing with
/// `LF_BOUNCES_ONE`, else the light's own bounces converged to the mode's tolerance (the
/// default one with `LF_BOUNCES_FEEDBACK`: the light is the frame's whole light, not a change
/// to carry over frames). Only what the light reaches is computed and written (as
/// `lf_runtime_apply_delta_in_spans` on its spans); before any object light, nothing.
///
/// Returns `LF_STATUS_OK`, or the statuses of `lf_runtime_apply_delta_in_spans`.
/// `indirect_rgb` is changed only on success.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`, used by no other thread during
/// the call; `indirect_rgb` must be NULL or point to `indirect_len` readable and writable
/// floats no other thread writes during the call.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_bounce_object_light(
    rt: *mut LfRuntime,
    method: i32,
    indirect_rgb: *mut f32,
    indirect_len: usize,
) -> i32 {
    status_call("lf_runtime_bounce_object_light", || {
        // SAFETY: NULL or live and unshared, per the contract.
        let rt = unsafe { rt.as_mut() }.ok_or(CapiError::NullPointer("rt"))?;
        // SAFETY: readable and writable for its length, per the contract.
        let indirect = unsafe { slice_mut(indirect_rgb, indirect_len, "indirect_rgb") }?;
        rt.bounce_object_light(method, indirect)
    })
}

impl LfRuntime {
    /// The objects' light of this frame (`ObjectLight::update` on the runtime's poses, probe
    /// field and bounce mode), the grids decoded on the first call.
    fn object_light(
        &mut self,
        lights: &[lightfarm_client::Light],
    ) -> Result<&ObjectLight, CapiError> {
        let bundle = self.runtime.bundle();
        let objects = match &mut self.objects {
            Some(o) => o,
            slot => {
                slot.insert(ObjectLight::new(bundle).map_err(|e| CapiError::ObjectLight(e.into()))?)
            }
        };
        let bounced = bounced(self.bounces);
        objects.update(
            bundle,
            &self.probes,
            bounced,
            &self.level,
            lights,
            &self.poses,
        )?;
        Ok(objects)
    }
}
