//! Dynamic objects' direct shadows, for C callers that take direct light from the library:
//! [`lf_runtime_set_poses`] places the bundle's dynamic objects (their shapes, bundle section
//! `dynamic shapes`, format 2.4) for every later direct-light call, so the light fed to the
//! operators is dark where an object hides a light, as in `lightfarm eval`.
//!
//! Frames and units: a pose maps the object frame to the world, `x_world = R x_obj + t`, `R`
//! from the quaternion `[x, y, z, w]` (normalised; a zero quaternion is the identity), metres.
//!
//! Invariants: poses are checked whole before any is used, so a refused call leaves the
//! previous poses in force; with no pose set (or after `n_poses = 0`) direct light is exactly
//! the level's.

use std::ffi::{c_char, CStr};

use lightfarm_proto::lights::Pose;

use crate::boundary::{slice, status_call};
use crate::runtime::LfRuntime;
use crate::status::CapiError;

/// Where a dynamic object is this frame: its id (NUL-terminated UTF-8, the scene's
/// `dynamic[].id`), translation (world metres) and rotation quaternion `[x, y, z, w]`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct LfPose {
    pub id: *const c_char,
    pub translation: [f32; 3],
    pub rotation: [f32; 4],
}

/// The client's poses for C's, or the first refused (by its index).
///
/// # Safety
/// Every `id` must be NULL (refused) or a readable NUL-terminated string.
unsafe fn client_poses(rt: &LfRuntime, poses: &[LfPose]) -> Result<Vec<Pose>, CapiError> {
    let shapes = &rt.runtime().bundle().dynamic_shapes;
    let mut out = Vec::with_capacity(poses.len());
    for (index, p) in poses.iter().enumerate() {
        let bad = |reason: String| CapiError::InvalidPose { index, reason };
        if p.id.is_null() {
            return Err(bad("id is NULL".into()));
        }
        // SAFETY: a readable NUL-terminated string, per the contract.
        let id = unsafe { CStr::from_ptr(p.id) }
            .to_str()
            .map_err(|_| bad("id is not UTF-8".into()))?;
        if !shapes.iter().any(|s| s.object == id) {
            return Err(bad(format!(
                "\"{id}\" is no dynamic object of this bundle (it has {})",
                match shapes.len() {
                    0 => "none: bundles before format 2.4 carry no shapes".to_string(),
                    _ => shapes
                        .iter()
                        .map(|s| format!("\"{}\"", s.object))
                        .collect::<Vec<_>>()
                        .join(", "),
                }
            )));
        }
        if !p
            .translation
            .iter()
            .chain(&p.rotation)
            .all(|x| x.is_finite())
        {
            return Err(bad(format!(
                "\"{id}\": translation or rotation is not finite"
            )));
        }
        out.push(Pose {
            id: id.to_string(),
            translation: p.translation.map(f64::from),
            rotation: p.rotation.map(f64::from),
        });
    }
    Ok(out)
}

/// Places the bundle's dynamic objects: from now on `lf_runtime_direct_from_point_lights`,
/// `lf_runtime_light_direct`, `lf_runtime_direct_in_spans` and `lf_runtime_light_reach`
/// shadow direct light with the posed objects' shapes (and no longer take a room holding one
/// to be empty). `n_poses = 0` removes every object. Objects not listed cast no shadow.
///
/// Direct light computed before the call does not change: after moving an object, recompute
/// the direct light of the lights that reach it (or all) and apply it, or its change. Spans
/// passed to `lf_runtime_direct_in_spans` must come from `lf_runtime_light_reach` after the
/// poses were set (their `in_sight` flag depends on them). Costs a shadow-ray hierarchy over
/// the objects' triangles (the level's is kept) and a copy of the rooms' occluder lists with
/// the objects added to the rooms they touch; allocates.
///
/// Returns `LF_STATUS_OK`, or: `LF_STATUS_NULL_POINTER` (`rt`, or `poses` with
/// `n_poses > 0`), `LF_STATUS_INVALID_POSE` (an id that is NULL, not UTF-8 or not a dynamic
/// object of the bundle, or a non-finite translation or rotation; nothing changes) or
/// `LF_STATUS_PANIC`.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`. `poses` must be NULL or point to
/// `n_poses` readable `LfPose`s whose `id`s are NULL or readable NUL-terminated strings; no
/// other thread may use `rt` or write them during the call.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_set_poses(
    rt: *mut LfRuntime,
    poses: *const LfPose,
    n_poses: usize,
) -> i32 {
    status_call("lf_runtime_set_poses", || {
        // SAFETY: NULL or live and not shared, per the contract.
        let rt = unsafe { rt.as_mut() }.ok_or(CapiError::NullPointer("rt"))?;
        // SAFETY: `n_poses` readable poses, per the contract.
        let poses = unsafe { slice(poses, n_poses, "poses") }?;
        // SAFETY: ids NULL or readable strings, per the contract.
        let poses = unsafe { client_poses(rt, poses) }?;
        rt.set_poses(&poses);
        Ok(())
    })
}
