//! Direct light from point lights at every texel, for C callers that do not compute direct
//! light in their own engine.
//!
//! Invariants: the result is exactly what `lightfarm eval` feeds the operators
//! (`direct_from_point_lights_by_reach` with [`LF_DIRECT_SAMPLES_PER_EDGE`] samples per texel
//! edge, shadow rays against the bundle's occluders and the dynamic objects placed with
//! `lf_runtime_set_poses`, each light traced where it reaches);
//! lights are checked before use, so every output value is finite and non-negative.

use lightfarm_client::every_sample_by_reach;
use lightfarm_proto::lights::{Light, LightKind};

use crate::boundary::{slice, slice_mut, status_call};
use crate::runtime::{check_rgb_len, LfRuntime};
use crate::status::CapiError;

/// Direct light is each texel's average, its shadows from an `N x N` grid of samples (the
/// value `lightfarm eval` uses).
pub const LF_DIRECT_SAMPLES_PER_EDGE: u32 = 4;

/// A point light: world position (metres) and radiant intensity (W/sr per RGB channel).
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LfPointLight {
    pub position: [f32; 3],
    pub intensity: [f32; 3],
}

impl LfPointLight {
    /// The client's light, or why this one is refused.
    fn to_light(self) -> Result<Light, &'static str> {
        if !self.position.iter().all(|x| x.is_finite()) {
            return Err("position is not finite");
        }
        if !self.intensity.iter().all(|x| x.is_finite() && *x >= 0.0) {
            return Err("intensity must be finite and non-negative");
        }
        Ok(Light {
            kind: LightKind::Point,
            position: self.position.map(f64::from),
            intensity: self.intensity.map(f64::from),
        })
    }
}

/// The client's lights for C's, or the first refused (by its index).
pub(crate) fn client_lights(lights: &[LfPointLight]) -> Result<Vec<Light>, CapiError> {
    lights
        .iter()
        .enumerate()
        .map(|(index, l)| {
            l.to_light()
                .map_err(|reason| CapiError::InvalidLight { index, reason })
        })
        .collect()
}

/// Computes direct outgoing radiance at every texel from `n_lights` point lights, with shadow
/// rays against the bundle's geometry, averaged over each texel as `lightfarm eval` does.
///
/// Writes `out_len` = `3 x texels` floats (texel-major RGB, layout order) to `out_rgb`, ready
/// for `lf_runtime_apply`. Unlike `lf_runtime_apply` it allocates (lights and a
/// result vector) and costs a shadow ray per light and sample where the light reaches;
/// engines that have their own direct light skip it.
///
/// Returns `LF_STATUS_OK`, or: `LF_STATUS_NULL_POINTER` (`rt`, or `lights` with
/// `n_lights > 0`, or `out_rgb` with `out_len > 0`, is NULL), `LF_STATUS_BAD_LENGTH`,
/// `LF_STATUS_INVALID_LIGHT` (a non-finite position, or an intensity that is negative or not
/// finite) or `LF_STATUS_PANIC`. `out_rgb` is written only on success.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`. `lights` must be NULL or
/// point to `n_lights` readable `LfPointLight`s; `out_rgb` must be NULL or point to `out_len`
/// writable floats not overlapping `lights`; no other thread may write any of them during the
/// call.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_direct_from_point_lights(
    rt: *const LfRuntime,
    lights: *const LfPointLight,
    n_lights: usize,
    out_rgb: *mut f32,
    out_len: usize,
) -> i32 {
    status_call("lf_runtime_direct_from_point_lights", || {
        // SAFETY: NULL or live, per the contract.
        let rt = unsafe { rt.as_ref() }.ok_or(CapiError::NullPointer("rt"))?;
        // SAFETY: `n_lights` readable lights, per the contract.
        let lights = unsafe { slice(lights, n_lights, "lights") }?;
        if out_rgb.is_null() && out_len > 0 {
            return Err(CapiError::NullPointer("out_rgb"));
        }
        check_rgb_len(rt, "out_rgb", out_len)?;
        let lights = client_lights(lights)?;
        // The reach over the posed objects too (`lf_runtime_set_poses`); without poses this is
        // `direct_from_point_lights_by_reach`.
        let direct = every_sample_by_reach(
            rt.new_reach().as_mut(),
            &rt.runtime().bundle().layout,
            rt.occluders(),
            &lights,
            LF_DIRECT_SAMPLES_PER_EDGE,
            rt.direct_scale(),
        );
        // SAFETY: `out_len` writable floats, per the contract, not overlapping `lights`.
        let out = unsafe { slice_mut(out_rgb, out_len, "out_rgb") }?;
        for (o, v) in out.chunks_exact_mut(3).zip(&direct.radiance) {
            o.copy_from_slice(v);
        }
        Ok(())
    })
}
