//! The probe volume, for C callers that shade dynamic objects: the SH radiance of every probe
//! ([`lf_runtime_apply_probes`], from the light leaving the texels), kept up to date by a change
//! of that light ([`lf_runtime_apply_probes_delta_in_spans`]), read back for a GPU
//! ([`lf_runtime_probe_field`]) or as irradiance at a point ([`lf_runtime_probe_irradiance`]).
//! The field lives in the runtime, so no call allocates after the first.
//!
//! The light the probes read is what leaves the texels: the direct light at one bounce, direct
//! plus indirect light with more (as `lightfarm eval` feeds them). Only the blocks and clutter
//! objects the probe entries read are projected (`Runtime::apply_probes`), so the cost follows
//! the probe volume (the dynamic objects' regions), not the level.
//!
//! Units: radiance (W/m²/sr) per channel in, SH incident radiance (order 2, 9 coefficients per
//! channel) in the field, irradiance (W/m²) out of [`lf_runtime_probe_irradiance`]; positions in
//! world metres.
//!
//! Invariants: a failed call leaves the field as it was; before the first successful
//! [`lf_runtime_apply_probes`] the field is empty and a change cannot be added to it.

use lightfarm_client::irradiance_at;

use crate::boundary::{slice, slice_mut, status_call, value_call};
use crate::reach::{check_spans, LfTexelSpan};
use crate::runtime::{check_rgb_len, LfRuntime};
use crate::status::CapiError;

/// Floats per probe in `lf_runtime_probe_field`'s buffer: 3 channels × 9 SH coefficients.
pub const LF_PROBE_FLOATS: usize = 27;

/// Number of probes in the bundle's probe volume (0 without one, and for NULL). A bundle has a
/// probe volume when its scene has dynamic objects (or asks for one).
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_probe_count(rt: *const LfRuntime) -> usize {
    value_call("lf_runtime_probe_count", 0, || {
        // SAFETY: NULL or live, per the contract.
        unsafe { rt.as_ref() }.map_or(0, |rt| {
            rt.runtime()
                .probe_volume()
                .map_or(0, |v| v.n_probes as usize)
        })
    })
}

/// Fills the runtime's probe field from the light leaving the texels, `leaving_rgb` (`3 x
/// texels` floats, texel-major RGB in layout order).
///
/// Returns `LF_STATUS_OK`, `LF_STATUS_NULL_POINTER`, `LF_STATUS_BAD_LENGTH` or
/// `LF_STATUS_MISSING_OPERATOR` (the bundle has no probe volume).
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`, used by no other thread during
/// the call; `leaving_rgb` must be NULL or point to `leaving_len` readable floats.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_apply_probes(
    rt: *mut LfRuntime,
    leaving_rgb: *const f32,
    leaving_len: usize,
) -> i32 {
    status_call("lf_runtime_apply_probes", || {
        // SAFETY: NULL or live and unshared, per the contract.
        let rt = unsafe { rt.as_mut() }.ok_or(CapiError::NullPointer("rt"))?;
        // SAFETY: `leaving_len` readable floats, per the contract.
        let leaving = unsafe { slice(leaving_rgb, leaving_len, "leaving_rgb") }?;
        check_rgb_len(rt, "leaving_rgb", leaving.len())?;
        let (leaving, _) = leaving.as_chunks::<3>();
        rt.direct.radiance.copy_from_slice(leaving);
        let LfRuntime {
            runtime,
            direct,
            probes,
            ..
        } = rt;
        runtime.apply_probes(direct, probes)?;
        Ok(())
    })
}

/// Adds to the runtime's probe field the field of a change of leaving light, `change_rgb`
/// (`3 x texels` floats, new minus old), read on the texels of `spans` only (whatever it holds
/// elsewhere is taken as zero): e.g. a moved light's change of direct light on its reach before
/// and after (`lf_runtime_light_direct`), plus, with more than one bounce, the change of
/// indirect light `lf_runtime_apply_delta_in_spans` added. The field then equals
/// `lf_runtime_apply_probes` of the new light within float rounding, and only the probe
/// entries reading a texel of the spans run.
///
/// Returns `LF_STATUS_OK`, `LF_STATUS_NULL_POINTER`, `LF_STATUS_BAD_LENGTH` (also when no
/// `lf_runtime_apply_probes` has filled the field yet), `LF_STATUS_BAD_INDEX` (a span outside
/// the layout) or `LF_STATUS_MISSING_OPERATOR` (no probe volume).
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`, used by no other thread during
/// the call; `change_rgb` must be NULL or point to `change_len` readable floats, `spans` to
/// `n_spans` readable `LfTexelSpan`s.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_apply_probes_delta_in_spans(
    rt: *mut LfRuntime,
    change_rgb: *const f32,
    change_len: usize,
    spans: *const LfTexelSpan,
    n_spans: usize,
) -> i32 {
    status_call("lf_runtime_apply_probes_delta_in_spans", || {
        // SAFETY: NULL or live and unshared, per the contract.
        let rt = unsafe { rt.as_mut() }.ok_or(CapiError::NullPointer("rt"))?;
        // SAFETY: readable for their lengths, per the contract.
        let (change, spans) = unsafe {
            (
                slice(change_rgb, change_len, "change_rgb")?,
                slice(spans, n_spans, "spans")?,
            )
        };
        check_rgb_len(rt, "change_rgb", change.len())?;
        let texels = rt.runtime.n_texels();
        check_spans(spans, texels)?;
        // A field not filled yet is the runtime's `ProbeFieldSize` (status.rs: `not_filled`).
        rt.span_input(change, spans);
        let LfRuntime {
            runtime,
            span_delta,
            span_delta_at,
            probes,
            ..
        } = rt;
        runtime.apply_probes_delta(span_delta, span_delta_at, probes)?;
        Ok(())
    })
}

/// Copies the runtime's probe field into `out`: `LF_PROBE_FLOATS` floats per probe, value
/// `(probe * 3 + channel) * 9 + coefficient` (real SH to order 2, world frame, y up, in the
/// order of `lightfarm_proto::sh`: Y00, Y1-1, Y10, Y11, Y2-2, Y2-1, Y20, Y21, Y22), `len` =
/// `LF_PROBE_FLOATS x lf_runtime_probe_count` exactly.
///
/// Returns `LF_STATUS_OK`, `LF_STATUS_NULL_POINTER`, `LF_STATUS_BAD_LENGTH` (also before the
/// field is filled) or `LF_STATUS_MISSING_OPERATOR` (no probe volume).
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`; `out` must be NULL or point to
/// `len` writable floats; no other thread may use either during the call.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_probe_field(
    rt: *const LfRuntime,
    out: *mut f32,
    len: usize,
) -> i32 {
    status_call("lf_runtime_probe_field", || {
        // SAFETY: NULL or live, per the contract.
        let rt = unsafe { rt.as_ref() }.ok_or(CapiError::NullPointer("rt"))?;
        let volume = rt.runtime().probe_volume().ok_or_else(no_probes)?;
        let n = volume.n_probes as usize * LF_PROBE_FLOATS;
        let field = rt.probes.as_slice();
        if field.len() != n {
            return Err(not_filled(n, field.len()));
        }
        if len != n {
            return Err(CapiError::TooFew {
                what: "out (LF_PROBE_FLOATS x lf_runtime_probe_count floats exactly)",
                needed: n,
                got: len,
            });
        }
        // SAFETY: `len` writable floats, per the contract.
        let out = unsafe { slice_mut(out, len, "out") }?;
        out.copy_from_slice(field);
        Ok(())
    })
}

/// Irradiance (RGB, W/m²) from the runtime's probe field at `position` (3 floats, world
/// metres) on a surface of normal `normal` (3 floats, any length but zero): the probes around
/// the point interpolated, as `lightfarm eval` lights a dynamic object (the nearest probe
/// within three grid steps outside the volume, else zero). Written to `out_rgb` (3 floats).
///
/// Returns `LF_STATUS_OK`, `LF_STATUS_NULL_POINTER`, `LF_STATUS_BAD_LENGTH` (before the field
/// is filled) or `LF_STATUS_MISSING_OPERATOR` (no probe volume).
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`; `position` and `normal` must be
/// NULL or point to 3 readable floats, `out_rgb` to 3 writable floats.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_probe_irradiance(
    rt: *const LfRuntime,
    position: *const f32,
    normal: *const f32,
    out_rgb: *mut f32,
) -> i32 {
    status_call("lf_runtime_probe_irradiance", || {
        // SAFETY: NULL or live, per the contract.
        let rt = unsafe { rt.as_ref() }.ok_or(CapiError::NullPointer("rt"))?;
        // SAFETY: 3 readable floats each and 3 writable, per the contract.
        let (p, n, out) = unsafe {
            (
                slice(position, 3, "position")?,
                slice(normal, 3, "normal")?,
                slice_mut(out_rgb, 3, "out_rgb")?,
            )
        };
        let volume = rt.runtime().probe_volume().ok_or_else(no_probes)?;
        let needed = volume.n_probes as usize;
        if rt.probes.n_probes() != needed {
            return Err(not_filled(needed, rt.probes.n_probes()));
        }
        let e = irradiance_at(volume, &rt.probes, [p[0], p[1], p[2]], [n[0], n[1], n[2]]);
        out.copy_from_slice(&e);
        Ok(())
    })
}

/// The error of a call that needs the probe field before `lf_runtime_apply_probes` filled it
/// (`needed` and `got` in the call's unit: probes, or floats); `Runtime::apply_probes_delta`'s
/// `ProbeFieldSize` maps to it too.
pub(crate) fn not_filled(needed: usize, got: usize) -> CapiError {
    CapiError::TooFew {
        what: "the probe field (lf_runtime_apply_probes fills it)",
        needed,
        got,
    }
}

/// The error of a probe call on a bundle without a probe volume.
fn no_probes() -> CapiError {
    CapiError::MissingOperator(lightfarm_client::ApplyError::MissingProbes)
}
