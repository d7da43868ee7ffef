//! The change of direct light when dynamic objects move, for C callers that take direct light
//! from the library ([`lf_runtime_shadow_change`], `lightfarm_client::ShadowChange`): only the
//! texels whose shadow rays a moved object can cross, where it was or where it is now, are
//! relit, for the lights whose reach it stands in, so a frame in which an object moves costs
//! what its shadows touch; `lf_runtime_apply_delta_in_spans` then relights by the change.
//!
//! Units: radiance leaving the texels (W/m²/sr per channel), texel-major RGB in layout order;
//! direct light texel-averaged adaptively (`LF_DIRECT_SAMPLES_PER_EDGE` samples per edge where
//! a texel's corners disagree about visibility), as `lf_runtime_light_direct` averages.
//!
//! Invariants: the change is between the poses of the last change handed over (before the
//! first: the poses before the last `lf_runtime_set_poses`, none at load) and the runtime's
//! poses now, for the lights of the call; the tracker is made on the first call (a walk of
//! each light's reach) and made again, from those poses, when the lights differ from the last
//! call's. A call writes `out_rgb` on its spans only and a refused call writes nothing; a
//! change refused for want of span room is kept and handed over by the next call (with the
//! same lights) as it was, so no change is lost.

use lightfarm_client::ShadowChange;

use crate::boundary::status_call;
use crate::direct::{LfPointLight, LF_DIRECT_SAMPLES_PER_EDGE};
use crate::reach::{lights_and_light_out, write_light_on_spans, LfTexelSpan};
use crate::runtime::LfRuntime;

/// The change of the `n_lights` point `lights`' direct light that the dynamic objects made by
/// moving since the last call (see the module doc): writes the texel spans it lies in to
/// `out_spans` (ascending, disjoint; their number to `*out_count`) and the change on those
/// spans to `out_rgb` (`out_len` = `3 x texels` floats; every other texel keeps its value).
/// Add it to the direct light, and relight by it with `lf_runtime_apply_delta_in_spans` on
/// the same spans. No object moved: no span.
///
/// Returns `LF_STATUS_OK`, or: `LF_STATUS_NULL_POINTER` (`rt`, `out_count`, `lights` with
/// `n_lights > 0`, `out_rgb` with `out_len > 0`, or `out_spans` when spans are to be
/// written), `LF_STATUS_INVALID_LIGHT`, `LF_STATUS_BAD_LENGTH` (`out_len` is not `3 x
/// texels`, or `capacity` is below the number of spans: `*out_count` then holds the number
/// needed, and the next call returns that change) or `LF_STATUS_PANIC`. On an
/// error neither `out_spans` nor `out_rgb` is written. Allocates when the tracker is made and
/// per call (the moved objects' shadow-ray hierarchy).
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`, used by no other thread during
/// the call. `lights` must be NULL or point to `n_lights` readable `LfPointLight`s; `out_spans`
/// NULL or `capacity` writable `LfTexelSpan`s; `out_count` NULL or writable; `out_rgb` NULL or
/// `out_len` writable floats; none overlapping another.
#[no_mangle]
#[allow(clippy::too_many_arguments)]
pub unsafe extern "C" fn lf_runtime_shadow_change(
    rt: *mut LfRuntime,
    lights: *const LfPointLight,
    n_lights: usize,
    out_spans: *mut LfTexelSpan,
    capacity: usize,
    out_count: *mut usize,
    out_rgb: *mut f32,
    out_len: usize,
) -> i32 {
    status_call("lf_runtime_shadow_change", || {
        // SAFETY: the arguments are as `lights_and_light_out` needs, per the contract.
        let (rt, count, lights, out) =
            unsafe { lights_and_light_out(rt, lights, n_lights, out_count, out_rgb, out_len) }?;
        // Made (again) from the poses of the last change handed over; a change computed but
        // not handed over (too few spans) is one of the old lights', and is dropped.
        if rt.shadows.as_ref().is_none_or(|s| s.lights() != lights) {
            let bundle = rt.runtime.bundle();
            let (from, m) = (&rt.shadow_from, LF_DIRECT_SAMPLES_PER_EDGE);
            rt.shadows = Some(ShadowChange::new(bundle, &rt.level, &lights, m, from));
            rt.shadow_pending = None;
        }
        let shadows = rt.shadows.as_mut().expect("made above");
        // A change computed but not handed over is handed over as it is.
        if rt.shadow_pending.is_none() {
            let bundle = rt.runtime.bundle();
            shadows
                .update(bundle, &rt.level, &rt.poses)
                .expect("the tracker was made for this runtime's bundle");
            rt.shadow_pending = Some(rt.poses.clone());
        }
        let (spans, change) = (shadows.spans(), &shadows.change().radiance);
        // SAFETY: `out_spans` NULL or `capacity` writable spans, per the contract.
        unsafe { write_light_on_spans(spans, change, out_spans, capacity, count, out) }?;
        rt.shadow_from = rt.shadow_pending.take().expect("computed above");
        Ok(())
    })
}
