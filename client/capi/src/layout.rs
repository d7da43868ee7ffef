//! The bundle's texel layout and lightmap-atlas placement, for engines that compute direct light
//! themselves (on the GPU into the lightmap atlas, with their own shadows and light types) and
//! hand it to `lf_runtime_apply` instead of calling `lf_runtime_direct_from_point_lights`.
//!
//! Owns the C view of `Layout` (texel centres, normals, albedo, texel sizes, surfaces) and of
//! the runtime's `Atlas`. Units and frames: world frame (the scene's, y up), metres; normals are
//! unit vectors on the lit side; albedo is linear RGB in `[0, 1)`; atlas positions are integer
//! pixels of the lightmap image, `(0, 0)` top left, x to the right, y down.
//!
//! Invariants:
//! - Every per-texel buffer is in layout order (the order of `lf_runtime_apply`'s RGB vectors),
//!   texel-major, and its length must equal its per-texel count × texels exactly: 3 floats for
//!   positions, normals and albedo, 2 floats for sizes, 2 integers for atlas pixels.
//! - Surfaces cover the texels in order without gaps: surface `k + 1` starts where surface `k`
//!   ends, and the last ends at `lf_runtime_texel_count` (the bundle decoder checks it).
//! - Every texel's atlas pixel is inside `lf_runtime_atlas_size`. Block faces and boxes are cut
//!   into tiles, a pixel per texel; a mesh keeps its baked lightmap image, placed apart from the
//!   tiles and the other images, where each texel is one cell (the bundle decoder checks that
//!   those cells lie inside the image, not that they differ).
//! - The calls only copy what `lf_runtime_new` decoded and computed (the atlas too): they
//!   allocate nothing unless they fail (the last error message), and write their outputs only
//!   on success.

use std::ffi::c_char;

use crate::boundary::{size_call, slice_mut, status_call, value_call, write_c_string};
use crate::runtime::{check_len, LfRuntime};
use crate::status::CapiError;

/// Checks `out` (`len` elements, `per_texel` per texel) and copies `values`' flattened entries
/// into it.
///
/// # Safety
/// `out` must be NULL or point to `len` writable `T`s that nothing else reads or writes during
/// the call.
unsafe fn copy_per_texel<T: Copy, const N: usize>(
    rt: &LfRuntime,
    values: &[[T; N]],
    what: &'static str,
    unit: &'static str,
    out: *mut T,
    len: usize,
) -> Result<(), CapiError> {
    if out.is_null() && len > 0 {
        return Err(CapiError::NullPointer(what));
    }
    check_len(rt, what, unit, N, len)?;
    // SAFETY: `len` writable values, per the contract.
    let out = unsafe { slice_mut(out, len, what) }?;
    out.copy_from_slice(values.as_flattened());
    Ok(())
}

/// The shared body of the four per-texel float queries.
///
/// # Safety
/// As the entry points: `rt` NULL or live, `out` NULL or `len` writable floats.
unsafe fn texel_floats<const N: usize>(
    function: &'static str,
    rt: *const LfRuntime,
    field: fn(&LfRuntime) -> &[[f32; N]],
    out: *mut f32,
    len: usize,
) -> i32 {
    status_call(function, || {
        // SAFETY: NULL or live, per the contract.
        let rt = unsafe { rt.as_ref() }.ok_or(CapiError::NullPointer("rt"))?;
        // SAFETY: NULL or `len` writable floats, per the contract.
        unsafe { copy_per_texel(rt, field(rt), "out", "floats", out, len) }
    })
}

/// Writes the centre of every texel (world frame, metres) to `out`: `len` = `3 x texels` floats,
/// `x y z` per texel in layout order.
///
/// Returns `LF_STATUS_OK`, `LF_STATUS_NULL_POINTER` (`rt`, or `out` with `len > 0`),
/// `LF_STATUS_BAD_LENGTH` or `LF_STATUS_PANIC`. `out` is written only on success.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`. `out` must be NULL or point to
/// `len` writable floats that no other thread reads or writes during the call.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_texel_positions(
    rt: *const LfRuntime,
    out: *mut f32,
    len: usize,
) -> i32 {
    // SAFETY: the caller's contract is the helper's.
    unsafe {
        texel_floats(
            "lf_runtime_texel_positions",
            rt,
            |rt| &rt.runtime().bundle().layout.positions,
            out,
            len,
        )
    }
}

/// Writes the unit normal of every texel (world frame, on the lit side) to `out`:
/// `len` = `3 x texels` floats, `x y z` per texel in layout order.
///
/// Returns `LF_STATUS_OK`, `LF_STATUS_NULL_POINTER` (`rt`, or `out` with `len > 0`),
/// `LF_STATUS_BAD_LENGTH` or `LF_STATUS_PANIC`. `out` is written only on success.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`. `out` must be NULL or point to
/// `len` writable floats that no other thread reads or writes during the call.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_texel_normals(
    rt: *const LfRuntime,
    out: *mut f32,
    len: usize,
) -> i32 {
    // SAFETY: the caller's contract is the helper's.
    unsafe {
        texel_floats(
            "lf_runtime_texel_normals",
            rt,
            |rt| &rt.runtime().bundle().layout.normals,
            out,
            len,
        )
    }
}

/// Writes the diffuse albedo of every texel (linear RGB, each in `[0, 1)`) to `out`:
/// `len` = `3 x texels` floats, `r g b` per texel in layout order.
///
/// Direct light handed to `lf_runtime_apply` is outgoing radiance, so it includes this albedo:
/// for a point light of intensity `I` (W/sr) at distance `r`, `albedo / pi * I * cos / r^2`
/// (times visibility) per channel.
///
/// Returns `LF_STATUS_OK`, `LF_STATUS_NULL_POINTER` (`rt`, or `out` with `len > 0`),
/// `LF_STATUS_BAD_LENGTH` or `LF_STATUS_PANIC`. `out` is written only on success.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`. `out` must be NULL or point to
/// `len` writable floats that no other thread reads or writes during the call.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_texel_albedo(
    rt: *const LfRuntime,
    out: *mut f32,
    len: usize,
) -> i32 {
    // SAFETY: the caller's contract is the helper's.
    unsafe {
        texel_floats(
            "lf_runtime_texel_albedo",
            rt,
            |rt| &rt.runtime().bundle().layout.albedo,
            out,
            len,
        )
    }
}

/// Writes the size of every texel (metres) to `out`: `len` = `2 x texels` floats, `su sv` per
/// texel in layout order.
///
/// `su` and `sv` are the texel's extents along the two world axes other than its normal's
/// dominant axis (the axis of the largest `|n|` component, the lower one on a tie), in
/// ascending axis order: `(y, z)` for an x-dominant normal, `(x, z)` for y, `(x, y)` for z.
/// A slanted (mesh) texel's are the extents of its footprint projected along the dominant
/// axis. The texel covers `centre ± su/2, ± sv/2` along those axes (lifted onto its plane), the
/// area `lf_runtime_direct_from_point_lights` averages over.
///
/// Returns `LF_STATUS_OK`, `LF_STATUS_NULL_POINTER` (`rt`, or `out` with `len > 0`),
/// `LF_STATUS_BAD_LENGTH` or `LF_STATUS_PANIC`. `out` is written only on success.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`. `out` must be NULL or point to
/// `len` writable floats that no other thread reads or writes during the call.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_texel_sizes(
    rt: *const LfRuntime,
    out: *mut f32,
    len: usize,
) -> i32 {
    // SAFETY: the caller's contract is the helper's.
    unsafe {
        texel_floats(
            "lf_runtime_texel_sizes",
            rt,
            |rt| &rt.runtime().bundle().layout.texel_size,
            out,
            len,
        )
    }
}

/// Writes the lightmap atlas's size in pixels to `*width` and `*height`: the image every texel
/// has a pixel in (`lf_runtime_atlas_texels`), the same atlas as the lightmap files of
/// `lightfarm eval` (block faces and box clutter as tiles, mesh clutter as its own images below
/// them). Pixels no texel lands in are unused.
///
/// Returns `LF_STATUS_OK`, `LF_STATUS_NULL_POINTER` (`rt`, `width` or `height`) or
/// `LF_STATUS_PANIC`; the outputs are written only on success.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`; `width` and `height` must each be
/// NULL or point to a writable `uint32_t`.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_atlas_size(
    rt: *const LfRuntime,
    width: *mut u32,
    height: *mut u32,
) -> i32 {
    status_call("lf_runtime_atlas_size", || {
        // SAFETY: NULL or live, per the contract.
        let rt = unsafe { rt.as_ref() }.ok_or(CapiError::NullPointer("rt"))?;
        // SAFETY: NULL or writable, per the contract.
        let width = unsafe { width.as_mut() }.ok_or(CapiError::NullPointer("width"))?;
        // SAFETY: NULL or writable, per the contract.
        let height = unsafe { height.as_mut() }.ok_or(CapiError::NullPointer("height"))?;
        *width = rt.atlas().width;
        *height = rt.atlas().height;
        Ok(())
    })
}

/// Writes the atlas pixel of every texel to `xy`: `len` = `2 x texels` integers, `x y` per
/// texel in layout order (`0 <= x < width`, `0 <= y < height` of `lf_runtime_atlas_size`, origin
/// top left, y down). Tiles and mesh images do not overlap, so an engine can render direct
/// light into the atlas and gather it into `lf_runtime_apply`'s vector (`direct[3t + c] =
/// image[xy[2t + 1]][xy[2t]][c]`), or scatter the indirect light back into the image.
///
/// Returns `LF_STATUS_OK`, `LF_STATUS_NULL_POINTER` (`rt`, or `xy` with `len > 0`),
/// `LF_STATUS_BAD_LENGTH` or `LF_STATUS_PANIC`. `xy` is written only on success.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`. `xy` must be NULL or point to
/// `len` writable `uint32_t`s that no other thread reads or writes during the call.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_atlas_texels(
    rt: *const LfRuntime,
    xy: *mut u32,
    len: usize,
) -> i32 {
    status_call("lf_runtime_atlas_texels", || {
        // SAFETY: NULL or live, per the contract.
        let rt = unsafe { rt.as_ref() }.ok_or(CapiError::NullPointer("rt"))?;
        if xy.is_null() && len > 0 {
            return Err(CapiError::NullPointer("xy"));
        }
        check_len(rt, "xy", "integers", 2, len)?;
        // SAFETY: `len` writable integers, per the contract.
        let out = unsafe { slice_mut(xy, len, "xy") }?;
        for (o, &(x, y)) in out.chunks_exact_mut(2).zip(&rt.atlas().texel_xy) {
            o[0] = x;
            o[1] = y;
        }
        Ok(())
    })
}

/// Number of surfaces of the bundle's layout (`lf_runtime_surface` takes `0` to this minus 1);
/// 0 for NULL.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_surface_count(rt: *const LfRuntime) -> usize {
    value_call("lf_runtime_surface_count", 0, || {
        // SAFETY: NULL or live, per the contract.
        unsafe { rt.as_ref() }.map_or(0, |rt| rt.runtime().bundle().layout.surfaces.len())
    })
}

/// Describes surface `index`: its name, and the texels it owns, `texel_offset` to
/// `texel_offset + texel_count - 1` in layout order (surfaces are contiguous and in order).
///
/// The name (`block:<id>/<face>` for a block face, face one of `-x +x -y +y -z +z`, or
/// `clutter:<id>` for a clutter object) is copied into `name` as a NUL-terminated string, cut
/// to `cap - 1` bytes (at a UTF-8 character boundary) if it is longer, as `lf_last_error` does.
/// `name` may be NULL when `cap` is 0 (to ask for the size only); `texel_offset` and
/// `texel_count` may be NULL when not wanted.
///
/// Returns the buffer size the whole name needs, NUL included (at least 1; the copy is
/// complete when the result is <= `cap`), or a negative `LfStatus`: `LF_STATUS_NULL_POINTER`
/// (`rt`, or `name` with `cap > 0`), `LF_STATUS_BAD_INDEX` (`index` is not below
/// `lf_runtime_surface_count`) or `LF_STATUS_PANIC`. Nothing is written on failure.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`. `name` must be NULL or point to
/// `cap` writable bytes; `texel_offset` and `texel_count` must each be NULL or point to a
/// writable `uint32_t`; no other thread may read or write them during the call.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_surface(
    rt: *const LfRuntime,
    index: usize,
    name: *mut c_char,
    cap: usize,
    texel_offset: *mut u32,
    texel_count: *mut u32,
) -> i64 {
    size_call("lf_runtime_surface", || {
        // SAFETY: NULL or live, per the contract.
        let rt = unsafe { rt.as_ref() }.ok_or(CapiError::NullPointer("rt"))?;
        if name.is_null() && cap > 0 {
            return Err(CapiError::NullPointer("name"));
        }
        let surfaces = &rt.runtime().bundle().layout.surfaces;
        let surface = surfaces.get(index).ok_or(CapiError::BadIndex {
            what: "surface",
            index,
            count: surfaces.len(),
        })?;
        // SAFETY: each NULL or writable, per the contract.
        unsafe {
            if let Some(offset) = texel_offset.as_mut() {
                *offset = surface.texel_offset;
            }
            if let Some(count) = texel_count.as_mut() {
                *count = surface.texel_count;
            }
        }
        // SAFETY: NULL (then `cap` is 0) or `cap` writable bytes, per the contract.
        Ok(unsafe { write_c_string(&surface.name, name, cap) })
    })
}
