//! One moving light at a time, for C callers: where a point light can reach
//! ([`lf_runtime_light_reach`]) and direct light computed only there
//! ([`lf_runtime_direct_in_spans`]), or both in one call with shadow rays against only the
//! reached rooms' occluders ([`lf_runtime_light_direct`]), so that a game relights by the
//! change of direct light (`lf_runtime_apply_delta_in_spans`) without lighting the whole level
//! every frame.
//!
//! The spans are those of `lightfarm_client::LightReach` (the bundle's rooms and the windows
//! between them): a texel outside them has no straight segment to the light, so the light's
//! direct light there is exactly 0. The direct light in spans is the client's adaptive texel
//! average (`direct_from_point_lights_adaptive_in`, [`crate::LF_DIRECT_SAMPLES_PER_EDGE`]
//! samples per edge where a texel's corners disagree about visibility), bit-identical on the
//! spans to computing it for every texel.
//!
//! Invariants: spans come out ascending, disjoint and inside the layout; a bundle without a
//! rooms section (format before 2.1) reaches everything (one span over every texel). Texels
//! outside the spans are never written.

use std::ops::Range;

use lightfarm_client::{direct_from_point_lights_adaptive_in, Light, TexelSpan};

use crate::boundary::{slice, slice_mut, status_call};
use crate::direct::{client_lights, LfPointLight, LF_DIRECT_SAMPLES_PER_EDGE};
use crate::runtime::{check_rgb_len, LfRuntime};
use crate::status::CapiError;

/// A run of texels in layout order: `start` (inclusive) to `end` (exclusive).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LfTexelSpan {
    pub start: u32,
    pub end: u32,
    /// 1 when the light whose reach this is sees every point of these texels unoccluded (its
    /// own room, holding nothing but its walls): `lf_runtime_direct_in_spans` traces no shadow
    /// rays there. Set it only on spans passed together with that one light; 0 otherwise.
    pub in_sight: u8,
}

/// Fails unless every span is a range of the layout's `texels` texels (`start <= end <=
/// texels`), naming the first that is not.
pub(crate) fn check_spans(spans: &[LfTexelSpan], texels: usize) -> Result<(), CapiError> {
    for (index, s) in spans.iter().enumerate() {
        let (start, end) = (s.start as usize, s.end as usize);
        if start > end || end > texels {
            return Err(CapiError::BadSpan {
                index,
                start,
                end,
                texels,
            });
        }
    }
    Ok(())
}

/// Sets `*count` to the `needed` spans and fails unless they fit C's `out_spans` (`capacity`
/// entries; NULL only when none is needed): `TooFew` names the room needed, so the caller can
/// ask again with enough.
pub(crate) fn spans_fit(
    needed: usize,
    out_spans: *const LfTexelSpan,
    capacity: usize,
    count: &mut usize,
) -> Result<(), CapiError> {
    *count = needed;
    if needed > capacity {
        return Err(CapiError::TooFew {
            what: "out_spans",
            needed,
            got: capacity,
        });
    }
    if out_spans.is_null() && needed > 0 {
        return Err(CapiError::NullPointer("out_spans"));
    }
    Ok(())
}

/// Copies `spans` to C's `out`.
///
/// # Safety
/// `out` must be NULL (refused unless `spans` is empty) or point to `spans.len()` writable
/// `LfTexelSpan`s.
unsafe fn write_spans(spans: &[TexelSpan], out: *mut LfTexelSpan) -> Result<(), CapiError> {
    // SAFETY: per this function's contract.
    let out = unsafe { slice_mut(out, spans.len(), "out_spans") }?;
    for (o, s) in out.iter_mut().zip(spans) {
        *o = LfTexelSpan {
            start: s.texels.start as u32,
            end: s.texels.end as u32,
            in_sight: u8::from(s.in_sight),
        };
    }
    Ok(())
}

/// What a call taking the point lights and handing a light over on spans reads from its
/// arguments (`lf_runtime_object_light`, `lf_runtime_shadow_change`), checked in this order:
/// the runtime, the count to write, the lights, the RGB output (the runtime's `3 x texels`
/// floats), then each light's values.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`, used by no other thread during
/// the call; `lights` NULL or `n_lights` readable `LfPointLight`s; `out_count` NULL or
/// writable; `out_rgb` NULL or `out_len` writable floats; none overlapping another.
pub(crate) unsafe fn lights_and_light_out<'a>(
    rt: *mut LfRuntime,
    lights: *const LfPointLight,
    n_lights: usize,
    out_count: *mut usize,
    out_rgb: *mut f32,
    out_len: usize,
) -> Result<LightsAndLightOut<'a>, CapiError> {
    // SAFETY: NULL or live and unshared, per the contract.
    let rt = unsafe { rt.as_mut() }.ok_or(CapiError::NullPointer("rt"))?;
    // SAFETY: NULL or writable, per the contract.
    let count = unsafe { out_count.as_mut() }.ok_or(CapiError::NullPointer("out_count"))?;
    // SAFETY: readable and writable for their lengths, per the contract.
    let (lights, out) = unsafe {
        (
            slice(lights, n_lights, "lights")?,
            slice_mut(out_rgb, out_len, "out_rgb")?,
        )
    };
    check_rgb_len(rt, "out_rgb", out.len())?;
    let lights = client_lights(lights)?;
    Ok((rt, count, lights, out))
}

/// [`lights_and_light_out`]'s result: the runtime, the count to write, the lights, the RGB
/// output.
pub(crate) type LightsAndLightOut<'a> =
    (&'a mut LfRuntime, &'a mut usize, Vec<Light>, &'a mut [f32]);

/// Hands a light that lies on `spans` (ascending, disjoint texel ranges) over to C: the spans
/// to `out_spans` (their number to `*count`; see [`spans_fit`], which refuses before anything is
/// written) and `light`'s values on them to `out` (`3 x texels` floats, texel-major; every other
/// texel keeps its value).
///
/// # Safety
/// `out_spans` must be NULL or point to `capacity` writable `LfTexelSpan`s.
pub(crate) unsafe fn write_light_on_spans(
    spans: &[Range<usize>],
    light: &[[f32; 3]],
    out_spans: *mut LfTexelSpan,
    capacity: usize,
    count: &mut usize,
    out: &mut [f32],
) -> Result<(), CapiError> {
    spans_fit(spans.len(), out_spans, capacity, count)?;
    // SAFETY: `capacity` >= spans.len() writable spans, per the contract.
    let out_spans = unsafe { slice_mut(out_spans, spans.len(), "out_spans") }?;
    let (out, _) = out.as_chunks_mut::<3>();
    for (o, r) in out_spans.iter_mut().zip(spans) {
        *o = LfTexelSpan {
            start: r.start as u32,
            end: r.end as u32,
            in_sight: 0,
        };
        out[r.clone()].copy_from_slice(&light[r.clone()]);
    }
    Ok(())
}

/// Writes the texel spans the point light at `position` (3 floats, world metres) can reach to
/// `out_spans`, and their number to `*out_count`.
///
/// Returns `LF_STATUS_OK`, or: `LF_STATUS_NULL_POINTER` (`rt`, `position` or `out_count`, or
/// `out_spans` when spans are to be written), `LF_STATUS_INVALID_LIGHT` (a non-finite
/// position), `LF_STATUS_BAD_LENGTH` (`capacity` is below the number of spans: `*out_count`
/// then holds the number needed and nothing is written to `out_spans`) or `LF_STATUS_PANIC`.
/// Allocates only while a walk reaches more than any before it.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`, used by no other thread during
/// the call. `position` must be NULL or point to 3 readable floats; `out_spans` must be NULL or
/// point to `capacity` writable `LfTexelSpan`s; `out_count` must be NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_light_reach(
    rt: *mut LfRuntime,
    position: *const f32,
    out_spans: *mut LfTexelSpan,
    capacity: usize,
    out_count: *mut usize,
) -> i32 {
    status_call("lf_runtime_light_reach", || {
        // SAFETY: NULL or live and unshared, per the contract.
        let rt = unsafe { rt.as_mut() }.ok_or(CapiError::NullPointer("rt"))?;
        // SAFETY: 3 readable floats, per the contract.
        let position = unsafe { slice(position, 3, "position") }?;
        // SAFETY: NULL or writable, per the contract.
        let count = unsafe { out_count.as_mut() }.ok_or(CapiError::NullPointer("out_count"))?;
        if !position.iter().all(|x| x.is_finite()) {
            return Err(CapiError::InvalidLight {
                index: 0,
                reason: "position is not finite",
            });
        }
        let spans = rt.light_reach([0, 1, 2].map(|k| f64::from(position[k])));
        spans_fit(spans.len(), out_spans, capacity, count)?;
        // SAFETY: `capacity` >= spans.len() writable spans, per the contract.
        unsafe { write_spans(spans, out_spans) }
    })
}

/// One point light's reach and its direct light there, in one call: writes the texel spans
/// `light` reaches to `out_spans` (as `lf_runtime_light_reach`; their number to `*out_count`)
/// and the light's direct outgoing radiance on those spans to `out_rgb` (`out_len` = `3 x
/// texels` floats, texel-major RGB; every other texel keeps its value): the values
/// `lf_runtime_direct_in_spans` gives for this light on these spans, bit for bit, at the cost
/// of what the light reaches: its shadow rays are tested against the occluders of the rooms the
/// light reached only (the whole level's when the bundle has no rooms section, or the walk
/// gives up or leaves the level), where `lf_runtime_direct_in_spans` prepares the whole level's
/// occluders for every call.
///
/// Returns `LF_STATUS_OK`, or: `LF_STATUS_NULL_POINTER` (`rt`, `light`, `out_count`, `out_rgb`
/// with `out_len > 0`, or `out_spans` when spans are to be written), `LF_STATUS_INVALID_LIGHT`,
/// `LF_STATUS_BAD_LENGTH` (`out_len` is not `3 x texels`, or `capacity` is below the number of
/// spans: `*out_count` then holds the number needed) or `LF_STATUS_PANIC`. On an error neither
/// `out_spans` nor `out_rgb` is written. Allocates only while a walk reaches more than any
/// before it.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`, used by no other thread during
/// the call. `light` must be NULL or readable; `out_spans` must be NULL or point to `capacity`
/// writable `LfTexelSpan`s, `out_count` NULL or writable, `out_rgb` NULL or `out_len` writable
/// floats, none overlapping another.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_light_direct(
    rt: *mut LfRuntime,
    light: *const LfPointLight,
    out_spans: *mut LfTexelSpan,
    capacity: usize,
    out_count: *mut usize,
    out_rgb: *mut f32,
    out_len: usize,
) -> i32 {
    status_call("lf_runtime_light_direct", || {
        // SAFETY: NULL or live and unshared, per the contract.
        let rt = unsafe { rt.as_mut() }.ok_or(CapiError::NullPointer("rt"))?;
        // SAFETY: NULL or readable, per the contract.
        let light = unsafe { light.as_ref() }.ok_or(CapiError::NullPointer("light"))?;
        // SAFETY: NULL or writable, per the contract.
        let count = unsafe { out_count.as_mut() }.ok_or(CapiError::NullPointer("out_count"))?;
        let light = client_lights(std::slice::from_ref(light))?.remove(0);
        if out_rgb.is_null() && out_len > 0 {
            return Err(CapiError::NullPointer("out_rgb"));
        }
        check_rgb_len(rt, "out_rgb", out_len)?;
        // The walk alone first: nothing is written unless the spans fit.
        let needed = rt.light_reach(light.position).len();
        spans_fit(needed, out_spans, capacity, count)?;
        // SAFETY: `out_len` writable floats, per the contract, overlapping no input.
        let out = unsafe { slice_mut(out_rgb, out_len, "out_rgb") }?;
        let (out, _) = out.as_chunks_mut::<3>();
        let spans = rt.light_direct(&light, out);
        debug_assert_eq!(spans.len(), needed, "the same walk twice");
        // SAFETY: `capacity` >= spans.len() writable spans, per the contract.
        unsafe { write_spans(spans, out_spans) }
    })
}

/// Computes direct outgoing radiance from `n_lights` point lights on the texels of `spans`
/// only (e.g. where a moved light reaches, before and after the move), with shadow rays against
/// the bundle's geometry, averaged over each texel adaptively; every other texel of `out_rgb`
/// keeps its value.
///
/// `out_rgb` holds `out_len` = `3 x texels` floats (texel-major RGB, layout order): e.g. one
/// light's direct light, updated in place where it moved, to take the change from.
///
/// Returns `LF_STATUS_OK`, or: `LF_STATUS_NULL_POINTER`, `LF_STATUS_BAD_LENGTH`,
/// `LF_STATUS_INVALID_LIGHT`, `LF_STATUS_BAD_INDEX` (a span that is not a range of the
/// layout's texels: `start > end` or `end > texels`) or `LF_STATUS_PANIC`. `out_rgb` is
/// written only on success. Allocates a copy of the lights and spans; costs shadow rays only on
/// the spans' texels.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`. `lights` must be NULL or point
/// to `n_lights` readable `LfPointLight`s, `spans` to
/// `n_spans` readable `LfTexelSpan`s; `out_rgb` must be NULL or point to `out_len` writable
/// floats overlapping neither; no other thread may write any of them during the call.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_direct_in_spans(
    rt: *const LfRuntime,
    lights: *const LfPointLight,
    n_lights: usize,
    spans: *const LfTexelSpan,
    n_spans: usize,
    out_rgb: *mut f32,
    out_len: usize,
) -> i32 {
    status_call("lf_runtime_direct_in_spans", || {
        // SAFETY: NULL or live, per the contract.
        let rt = unsafe { rt.as_ref() }.ok_or(CapiError::NullPointer("rt"))?;
        // SAFETY: `n_lights` readable lights and `n_spans` readable spans, per the contract.
        let (lights, spans) = unsafe {
            (
                slice(lights, n_lights, "lights")?,
                slice(spans, n_spans, "spans")?,
            )
        };
        if out_rgb.is_null() && out_len > 0 {
            return Err(CapiError::NullPointer("out_rgb"));
        }
        check_rgb_len(rt, "out_rgb", out_len)?;
        let lights = client_lights(lights)?;
        check_spans(spans, rt.runtime().n_texels())?;
        let spans: Vec<TexelSpan> = spans
            .iter()
            .map(|s| TexelSpan {
                texels: s.start as usize..s.end as usize,
                in_sight: s.in_sight != 0,
            })
            .collect();
        // SAFETY: `out_len` writable floats, per the contract, overlapping no input.
        let out = unsafe { slice_mut(out_rgb, out_len, "out_rgb") }?;
        let (out, _) = out.as_chunks_mut::<3>();
        direct_from_point_lights_adaptive_in(
            &rt.runtime().bundle().layout,
            rt.occluders(),
            &lights,
            LF_DIRECT_SAMPLES_PER_EDGE,
            rt.direct_scale(),
            &spans,
            out,
        );
        Ok(())
    })
}

/// `lf_runtime_apply_delta` for a change of direct light that is zero outside `spans` (e.g.
/// one moved light: the spans of `lf_runtime_light_reach` where it was and where it is now,
/// its direct light before and after from `lf_runtime_direct_in_spans`): `delta_rgb` is read
/// on the spans' texels only (whatever it holds elsewhere is taken as zero), and
/// `indirect_rgb` is read and written only on the blocks and clutter objects the change's
/// light reaches (at one bounce; with more, those its bounces reach while their light
/// matters), so the call costs what the change reaches, not the level (every texel is updated
/// when whole-level applications cost less, for a change whose light fills the level). The same values as `lf_runtime_apply_delta`
/// with that change (up to the sign of zeros). Allocates only on its first call and when it is
/// given more spans than before.
///
/// Both buffers hold `3 x texels` floats, texel-major RGB in layout order, and must not
/// overlap. Returns `LF_STATUS_OK`, or the statuses of `lf_runtime_apply_delta`, or
/// `LF_STATUS_BAD_INDEX` (a span that is not a range of the layout's texels). `indirect_rgb`
/// is changed only on success.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`, used by no other thread during
/// the call. `delta_rgb` must be NULL or point to `delta_len` readable floats, `spans` to
/// `n_spans` readable `LfTexelSpan`s; `indirect_rgb` must be NULL or point to `indirect_len`
/// readable and writable floats overlapping neither; no other thread may write any of them
/// during the call.
#[no_mangle]
#[allow(clippy::too_many_arguments)]
pub unsafe extern "C" fn lf_runtime_apply_delta_in_spans(
    rt: *mut LfRuntime,
    method: i32,
    delta_rgb: *const f32,
    delta_len: usize,
    spans: *const LfTexelSpan,
    n_spans: usize,
    indirect_rgb: *mut f32,
    indirect_len: usize,
) -> i32 {
    status_call("lf_runtime_apply_delta_in_spans", || {
        // SAFETY: NULL or live and unshared, per the contract.
        let rt = unsafe { rt.as_mut() }.ok_or(CapiError::NullPointer("rt"))?;
        // SAFETY: readable for their lengths, per the contract; `indirect_rgb` overlaps
        // neither input.
        let (delta, spans, indirect) = unsafe {
            (
                slice(delta_rgb, delta_len, "delta_rgb")?,
                slice(spans, n_spans, "spans")?,
                slice_mut(indirect_rgb, indirect_len, "indirect_rgb")?,
            )
        };
        rt.apply_delta_in_spans(method, delta, spans, indirect)
    })
}
