//! The opaque `LfRuntime` and its lifecycle: load a bundle, query it, apply it every frame,
//! free it.
//!
//! Invariants:
//! - An [`LfRuntime`] exists only for bytes `Bundle::decode` and `Runtime::try_new` accepted.
//! - Its direct and indirect scratch always hold exactly `texels` entries (sized in
//!   [`lf_runtime_new`]), so [`lf_runtime_apply`] allocates nothing: it copies the caller's
//!   direct light in, applies, and copies the indirect light out.
//! - The scratch of `LfRuntime::apply_delta_in_spans` is sized on its first call and holds
//!   zeros outside the spans of its last call (the change) and everywhere between calls (the
//!   change's light).
//! - Its lightmap atlas is computed once, in [`lf_runtime_new`], from the bundle it applies, so
//!   the layout queries of [`crate::layout`] only copy.
//! - C only ever sees `LfRuntime*` from [`lf_runtime_new`] (a leaked `Box`), and
//!   [`lf_runtime_free`] is the only place that box is dropped.

use lightfarm_client::{
    direct_from_point_lights_adaptive_in, direct_scale, frame_occluders, occluders_with_poses,
    Applied, Atlas, Bounces, DirectLight, IndirectLight, Light, ObjectLight, Occluders,
    PosedObjects, ProbeField, ReachDirect, Runtime, ShadowChange, TexelSpan,
};
use lightfarm_proto::bundle::Bundle;
use lightfarm_proto::lights::Pose;
use std::ops::Range;

use crate::bounces::LfBounces;
use crate::boundary::{pointer_call, slice, slice_mut, status_call, value_call};
use crate::method::LfMethod;
use crate::reach::{check_spans, LfTexelSpan};
use crate::status::CapiError;

/// A loaded bundle ready to apply every frame (opaque to C).
pub struct LfRuntime {
    pub(crate) runtime: Runtime,
    /// Shadow-ray geometry of the bundle, for direct light from point lights.
    pub(crate) level: Occluders,
    /// The level's occluders with the dynamic objects at their poses (`lf_runtime_set_poses`;
    /// None: no object placed).
    posed: Option<PosedObjects>,
    /// Where each texel lands in the lightmap atlas (`Atlas::from_layout_with` the bundle's
    /// surface atlases: the image `lightfarm eval` writes).
    atlas: Atlas,
    /// Scratch: the caller's direct light, one RGB value per texel.
    pub(crate) direct: DirectLight,
    /// Scratch: the indirect light `apply` writes, one RGB value per texel.
    indirect: IndirectLight,
    /// The bounce mode of `lf_runtime_apply` (all bounces until `lf_runtime_set_bounces`).
    pub(crate) bounces: Bounces,
    /// What the last successful application (`lf_runtime_apply`, or a delta call) did.
    last: Applied,
    /// A point light's reach over the bundle's rooms, with the occluders of each room (None:
    /// the bundle has no rooms section); over the posed objects too when there are some.
    reach: Option<ReachDirect>,
    /// The same over the level alone, made at load: each `lf_runtime_set_poses` derives
    /// `reach` from it ([`ReachDirect::with_posed`]) instead of searching the level again.
    level_reach: Option<ReachDirect>,
    /// Scratch: the spans of the last `lf_runtime_light_reach` or `lf_runtime_light_direct`.
    reach_spans: Vec<TexelSpan>,
    /// The direct light's clamp scale (`direct_scale`: a pass over every texel, made once).
    direct_scale: f64,
    /// Scratch of `lf_runtime_apply_delta_in_spans` and `lf_runtime_apply_probes_delta_in_spans`
    /// (sized on the first such call, `span_input`): the change of light, zero outside
    /// `span_delta_at` (the last call's spans), and the change's indirect light, zero everywhere
    /// between calls.
    pub(crate) span_delta: DirectLight,
    pub(crate) span_delta_at: Vec<Range<usize>>,
    span_change: IndirectLight,
    /// The probe field of `lf_runtime_apply_probes` (empty until its first call).
    pub(crate) probes: ProbeField,
    /// The poses of the last successful `lf_runtime_set_poses` (none at load).
    pub(crate) poses: Vec<Pose>,
    /// The posed objects' light (`lf_runtime_object_light`; None until its first call, which
    /// decodes the bundle's DNRT grids).
    pub(crate) objects: Option<ObjectLight>,
    /// The change of direct light as objects move (`lf_runtime_shadow_change`; None until its
    /// first call), the poses the next change starts from (those of the last change handed
    /// over; before the first, the poses before the last `lf_runtime_set_poses`), and the
    /// poses of a change computed but not handed over yet.
    pub(crate) shadows: Option<ShadowChange>,
    pub(crate) shadow_from: Vec<Pose>,
    pub(crate) shadow_pending: Option<Vec<Pose>>,
}

impl LfRuntime {
    /// Decodes and validates `bytes` and sizes the per-frame scratch.
    fn load(bytes: &[u8]) -> Result<LfRuntime, CapiError> {
        let bundle = Bundle::decode(bytes)?;
        let occluders = Occluders::from_layout(&bundle.layout);
        let atlas = Atlas::from_layout_with(&bundle.layout, &bundle.surface_atlases);
        let level_reach = ReachDirect::new(&bundle, &occluders);
        let direct_scale = direct_scale(&bundle.layout, &occluders);
        let runtime = Runtime::try_new(bundle)?;
        let n = runtime.n_texels();
        Ok(LfRuntime {
            reach: level_reach.clone(),
            level_reach,
            reach_spans: Vec::new(),
            direct_scale,
            runtime,
            level: occluders,
            posed: None,
            atlas,
            direct: DirectLight {
                radiance: vec![[0.0; 3]; n],
            },
            indirect: IndirectLight {
                radiance: vec![[0.0; 3]; n],
            },
            bounces: Bounces::default(),
            last: Applied::default(),
            span_delta: DirectLight::default(),
            span_delta_at: Vec::new(),
            span_change: IndirectLight::default(),
            probes: ProbeField::default(),
            poses: Vec::new(),
            objects: None,
            shadows: None,
            shadow_from: Vec::new(),
            shadow_pending: None,
        })
    }

    /// `lf_runtime_apply_delta_in_spans` once its pointers are slices: `delta` and `indirect`
    /// hold `3 x texels` floats (checked), the change is read on `spans` only and its indirect
    /// light added to `indirect` only where the runtime wrote it (`Runtime::delta_written`;
    /// everywhere when it answered by whole-level applications). On an error `indirect` is
    /// unchanged.
    pub(crate) fn apply_delta_in_spans(
        &mut self,
        method: i32,
        delta: &[f32],
        spans: &[LfTexelSpan],
        indirect: &mut [f32],
    ) -> Result<(), CapiError> {
        let method = LfMethod::from_raw(method)?.method();
        check_rgb_len(self, "delta_rgb", delta.len())?;
        check_rgb_len(self, "indirect_rgb", indirect.len())?;
        let texels = self.runtime.n_texels();
        check_spans(spans, texels)?;
        self.span_input(delta, spans);
        let applied = self.runtime.apply_delta_in(
            method,
            self.bounces,
            &self.span_delta,
            &self.span_delta_at,
            &mut self.span_change,
        )?;
        self.last = applied.applied;
        self.add_span_change(indirect);
        Ok(())
    }

    /// `lf_runtime_bounce_object_light` once its pointer is a slice (`indirect`: `3 x texels`
    /// floats, checked): the last object light's bounces (`ObjectLight::bounce`, the runtime's
    /// bounce mode) added where the runtime wrote them. On an error `indirect` is unchanged.
    pub(crate) fn bounce_object_light(
        &mut self,
        method: i32,
        indirect: &mut [f32],
    ) -> Result<(), CapiError> {
        let method = LfMethod::from_raw(method)?.method();
        check_rgb_len(self, "indirect_rgb", indirect.len())?;
        self.size_span_scratch();
        let Some(objects) = &self.objects else {
            return Ok(());
        };
        let bounced = objects.bounce(
            &mut self.runtime,
            method,
            self.bounces,
            &mut self.span_change,
        );
        if let Some(applied) = bounced? {
            self.last = applied.applied;
            self.add_span_change(indirect);
        }
        Ok(())
    }

    /// Adds the indirect light of the last delta application (`span_change`, zero where the
    /// runtime did not write) to C's `indirect` (`3 x texels` floats) where it was written, and
    /// zeroes it again there.
    fn add_span_change(&mut self, indirect: &mut [f32]) {
        let texels = self.runtime.n_texels();
        let (indirect, _) = indirect.as_chunks_mut::<3>();
        let change = &mut self.span_change.radiance;
        let mut add = |r: Range<usize>| {
            for (o, c) in indirect[r.clone()].iter_mut().zip(&mut change[r]) {
                *o = [o[0] + c[0], o[1] + c[1], o[2] + c[2]];
                *c = [0.0; 3];
            }
        };
        match self.runtime.delta_written() {
            Some(ranges) => ranges.for_each(add),
            None => add(0..texels),
        }
    }

    /// Sizes the span scratch (`span_delta`, `span_change`: zeros) on its first use.
    fn size_span_scratch(&mut self) {
        let texels = self.runtime.n_texels();
        if self.span_delta.radiance.len() != texels {
            self.span_delta.radiance = vec![[0.0; 3]; texels];
            self.span_change.radiance = vec![[0.0; 3]; texels];
        }
    }

    /// Copies a change of light (`3 x texels` floats, checked) on the texels of `spans` (checked)
    /// into `span_delta`, which is zero elsewhere, and lists them in `span_delta_at`.
    pub(crate) fn span_input(&mut self, delta: &[f32], spans: &[LfTexelSpan]) {
        self.size_span_scratch();
        for r in self.span_delta_at.drain(..) {
            self.span_delta.radiance[r].fill([0.0; 3]);
        }
        let (delta, _) = delta.as_chunks::<3>();
        for s in spans {
            let r = s.start as usize..s.end as usize;
            self.span_delta.radiance[r.clone()].copy_from_slice(&delta[r.clone()]);
            self.span_delta_at.push(r);
        }
    }

    /// The client runtime (its bundle holds the layout direct light is computed on).
    pub(crate) fn runtime(&self) -> &Runtime {
        &self.runtime
    }

    /// The shadow-ray geometry of the bundle, with the posed dynamic objects.
    pub(crate) fn occluders(&self) -> &Occluders {
        frame_occluders(&self.level, self.posed.as_ref())
    }

    /// A fresh light reach over [`LfRuntime::occluders`] (None without rooms), as the one
    /// `lf_runtime_light_reach` walks.
    pub(crate) fn new_reach(&self) -> Option<ReachDirect> {
        let level = self.level_reach.as_ref()?;
        Some(match &self.posed {
            Some(posed) => level.with_posed(posed),
            None => level.clone(),
        })
    }

    /// Places the dynamic objects (ids checked by the caller): the objects' own hierarchy over
    /// their posed triangles beside the level's (`Occluders::with_triangles`), and the reach
    /// with them in the rooms they touch; no pose, the level's alone. The clamp scale stays
    /// the level's.
    pub(crate) fn set_poses(&mut self, poses: &[Pose]) {
        let before = std::mem::replace(&mut self.poses, poses.to_vec());
        if self.shadows.is_none() {
            self.shadow_from = before;
        }
        self.posed = occluders_with_poses(&self.level, self.runtime.bundle(), poses);
        self.reach = self.new_reach();
    }

    /// `direct_scale` of the bundle's layout and occluders.
    pub(crate) fn direct_scale(&self) -> f64 {
        self.direct_scale
    }

    /// The texel spans a point light at `light` can reach (every texel without rooms).
    pub(crate) fn light_reach(&mut self, light: [f64; 3]) -> &[TexelSpan] {
        let layout = &self.runtime.bundle().layout;
        match &mut self.reach {
            Some(reach) => reach.texels(layout, light, &mut self.reach_spans),
            None => {
                self.reach_spans.clear();
                self.reach_spans.push(TexelSpan {
                    texels: 0..layout.n_texels(),
                    in_sight: false,
                });
            }
        }
        &self.reach_spans
    }

    /// `light`'s direct light on the spans it reaches ([`LfRuntime::light_reach`]) into `out`
    /// (one RGB per texel; other texels untouched), with shadow rays against the occluders of
    /// the rooms it reached only (`ReachDirect::light`); the same values as
    /// `direct_from_point_lights_adaptive_in` with the level's occluders on those spans.
    /// Returns the spans.
    pub(crate) fn light_direct(&mut self, light: &Light, out: &mut [[f32; 3]]) -> &[TexelSpan] {
        let layout = &self.runtime.bundle().layout;
        match &mut self.reach {
            Some(reach) => reach.light(
                layout,
                frame_occluders(&self.level, self.posed.as_ref()),
                light,
                crate::direct::LF_DIRECT_SAMPLES_PER_EDGE,
                self.direct_scale,
                &mut self.reach_spans,
                out,
            ),
            None => {
                self.reach_spans.clear();
                self.reach_spans.push(TexelSpan {
                    texels: 0..layout.n_texels(),
                    in_sight: false,
                });
                direct_from_point_lights_adaptive_in(
                    layout,
                    frame_occluders(&self.level, self.posed.as_ref()),
                    std::slice::from_ref(light),
                    crate::direct::LF_DIRECT_SAMPLES_PER_EDGE,
                    self.direct_scale,
                    &self.reach_spans,
                    out,
                );
            }
        }
        &self.reach_spans
    }

    /// Where each texel lands in the lightmap atlas.
    pub(crate) fn atlas(&self) -> &Atlas {
        &self.atlas
    }
}

/// Fails unless `got` is `per_texel x texels` of the runtime; `unit` names the elements
/// (`floats`, `integers`) in the error.
pub(crate) fn check_len(
    rt: &LfRuntime,
    what: &'static str,
    unit: &'static str,
    per_texel: usize,
    got: usize,
) -> Result<(), CapiError> {
    let expected = per_texel * rt.runtime.n_texels();
    if got == expected {
        Ok(())
    } else {
        Err(CapiError::BadLength {
            what,
            unit,
            per_texel,
            expected,
            got,
        })
    }
}

/// The arguments every RGB-in, RGB-out call checks, in this order: no NULL buffer with a
/// non-zero length, a known method, and both lengths `3 x texels`. The method on success.
fn check_rgb_call(
    rt: &LfRuntime,
    method: i32,
    buffers: [(*const f32, usize, &'static str); 2],
) -> Result<lightfarm_client::Method, CapiError> {
    for (ptr, len, what) in buffers {
        if ptr.is_null() && len > 0 {
            return Err(CapiError::NullPointer(what));
        }
    }
    let method = LfMethod::from_raw(method)?.method();
    for (_, len, what) in buffers {
        check_rgb_len(rt, what, len)?;
    }
    Ok(method)
}

/// Fails unless `got` is the runtime's `3 x texels` floats (one RGB vector).
pub(crate) fn check_rgb_len(
    rt: &LfRuntime,
    what: &'static str,
    got: usize,
) -> Result<(), CapiError> {
    check_len(rt, what, "floats", 3, got)
}

/// Loads a bundle (the bytes of an `.lfb` file; they are copied, so the caller may free them
/// on return).
///
/// Returns a runtime to free with `lf_runtime_free`, or NULL when the bytes are not a usable
/// bundle or `bytes` is NULL with `len > 0` (then `lf_last_error` says why).
///
/// # Safety
/// `bytes` must be NULL or point to `len` readable bytes.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_new(bytes: *const u8, len: usize) -> *mut LfRuntime {
    pointer_call("lf_runtime_new", || {
        // SAFETY: the caller guarantees `len` readable bytes at a non-NULL `bytes`.
        let bytes = unsafe { slice(bytes, len, "bytes") }?;
        Ok(Box::into_raw(Box::new(LfRuntime::load(bytes)?)))
    })
}

/// Frees a runtime; does nothing for NULL.
///
/// # Safety
/// `rt` must be NULL or a pointer from `lf_runtime_new` not yet freed; it must not be used
/// after this call.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_free(rt: *mut LfRuntime) {
    value_call("lf_runtime_free", (), || {
        if !rt.is_null() {
            // SAFETY: `rt` came from `Box::into_raw` in `lf_runtime_new` and is freed once.
            drop(unsafe { Box::from_raw(rt) });
        }
    })
}

/// Number of texels of the bundle's layout (an RGB vector is 3 x this many floats); 0 for NULL.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_texel_count(rt: *const LfRuntime) -> usize {
    value_call("lf_runtime_texel_count", 0, || {
        // SAFETY: NULL or live, per the contract.
        unsafe { rt.as_ref() }.map_or(0, |rt| rt.runtime.n_texels())
    })
}

/// Whether the bundle has DRT operators (a scene with clutter), so `LF_METHOD_DRT` applies;
/// false for NULL.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_has_drt(rt: *const LfRuntime) -> bool {
    value_call("lf_runtime_has_drt", false, || {
        // SAFETY: NULL or live, per the contract.
        unsafe { rt.as_ref() }.is_some_and(|rt| rt.runtime.has_drt())
    })
}

/// Whether the bundle has the dense operator (baked with `--full`), so `LF_METHOD_FULL`
/// applies; false for NULL.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_has_full(rt: *const LfRuntime) -> bool {
    value_call("lf_runtime_has_full", false, || {
        // SAFETY: NULL or live, per the contract.
        unsafe { rt.as_ref() }.is_some_and(|rt| rt.runtime.has_full())
    })
}

/// Picks how many bounces `lf_runtime_apply` sums: `mode` is an `LfBounces`; `tolerance` is
/// `LF_BOUNCES_CONVERGED`'s and `LF_BOUNCES_WARM`'s (stop when a bounce adds less than this
/// fraction of the light so far; 0 for the default 1e-3), for `LF_BOUNCES_FEEDBACK` the one
/// relighting by the change settles to (relative to the level's light), and ignored by
/// `LF_BOUNCES_ONE`. A new runtime
/// starts at `LF_BOUNCES_CONVERGED` with the default. Choosing a mode (again) starts
/// `LF_BOUNCES_FEEDBACK`'s feedback from zero and `LF_BOUNCES_WARM` from a cold solve.
///
/// Returns `LF_STATUS_OK`, `LF_STATUS_NULL_POINTER`, `LF_STATUS_BAD_BOUNCES` (unknown mode, or
/// a tolerance outside `[0, 1)`: the mode is then unchanged) or `LF_STATUS_PANIC`.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`, used by no other thread during
/// the call.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_set_bounces(
    rt: *mut LfRuntime,
    mode: i32,
    tolerance: f32,
) -> i32 {
    status_call("lf_runtime_set_bounces", || {
        // SAFETY: NULL or live and unshared, per the contract.
        let rt = unsafe { rt.as_mut() }.ok_or(CapiError::NullPointer("rt"))?;
        let mode = LfBounces::from_raw(mode)?;
        let (bounces, tolerance) = mode.bounces(tolerance)?;
        if let (LfBounces::Feedback, Some(tolerance)) = (mode, tolerance) {
            rt.runtime.set_feedback_tolerance(tolerance)?;
        }
        rt.bounces = bounces;
        rt.runtime.reset_feedback();
        Ok(())
    })
}

/// Units (blocks, clutter objects, other texel runs) whose light is due to bounce on the next
/// `lf_runtime_apply_delta` or `lf_runtime_apply_delta_in_spans` in `LF_BOUNCES_FEEDBACK`: 0
/// once the light relit by the change holds all bounces within the tolerance (a game calls
/// with a zero change, or an empty span list, until then; such a call costs the due units
/// alone). 0 for NULL.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_feedback_due(rt: *const LfRuntime) -> usize {
    value_call("lf_runtime_feedback_due", 0, || {
        // SAFETY: NULL or live, per the contract.
        unsafe { rt.as_ref() }.map_or(0, |rt| rt.runtime.feedback_due())
    })
}

/// Caps the texels of due blocks and clutter objects one `lf_runtime_apply_delta` or
/// `lf_runtime_apply_delta_in_spans` in `LF_BOUNCES_FEEDBACK` shoots besides the change's: the
/// most urgent first, at least one a call, the rest on the next calls. A frame then costs about
/// one bounce of its change while the later bounces arrive over more frames (the maze, a light
/// moving 5 cm a frame: 1.1 ms of operators at 0 against 2.0 ms with every due unit, lagging
/// 6e-3 behind all bounces against 9e-4). `SIZE_MAX` (the default) shoots every due unit.
/// Returns `LF_STATUS_OK`, `LF_STATUS_NULL_POINTER` or `LF_STATUS_PANIC`.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`, used by no other thread during
/// the call.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_set_feedback_budget(rt: *mut LfRuntime, texels: usize) -> i32 {
    status_call("lf_runtime_set_feedback_budget", || {
        // SAFETY: NULL or live and unshared, per the contract.
        let rt = unsafe { rt.as_mut() }.ok_or(CapiError::NullPointer("rt"))?;
        rt.runtime
            .set_feedback_budget((texels != usize::MAX).then_some(texels));
        Ok(())
    })
}

/// One-bounce operator applications the last successful `lf_runtime_apply` on `rt` made (the
/// bounces `LF_BOUNCES_CONVERGED` or `LF_BOUNCES_WARM` needed; 1 for the other modes); 0 before
/// any, or for NULL.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_last_bounces(rt: *const LfRuntime) -> u32 {
    value_call("lf_runtime_last_bounces", 0, || {
        // SAFETY: NULL or live, per the contract.
        unsafe { rt.as_ref() }.map_or(0, |rt| rt.last.bounces)
    })
}

/// How far the last successful application on `rt` is estimated to be from all bounces,
/// relative: in `LF_BOUNCES_CONVERGED` and `LF_BOUNCES_WARM`, the solve's remaining error
/// relative to the light; in `LF_BOUNCES_FEEDBACK` relit by the change
/// (`lf_runtime_apply_delta`, `lf_runtime_apply_delta_in_spans`), the light still to arrive
/// over the next calls relative to the level's (at most the tolerance once
/// `lf_runtime_feedback_due` is 0); 0 for a fixed number of bounces, before any application,
/// or for NULL. An estimate, as the tolerance is.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_last_remaining(rt: *const LfRuntime) -> f32 {
    value_call("lf_runtime_last_remaining", 0.0, || {
        // SAFETY: NULL or live, per the contract.
        unsafe { rt.as_ref() }.map_or(0.0, |rt| rt.last.remaining_fraction)
    })
}

/// Turns direct light into indirect light with `method` (an `LfMethod`), summing the bounces
/// `lf_runtime_set_bounces` chose (all, by default); allocates nothing.
///
/// `direct_rgb` and `out_rgb` hold `3 x texels` floats each (`direct_len`, `out_len` must be
/// exactly that), texel-major RGB in layout order; direct light is outgoing radiance, as
/// `lf_runtime_direct_from_point_lights` computes it. They may be the same buffer
/// (direct light is read in full before anything is written).
///
/// Returns `LF_STATUS_OK`, or: `LF_STATUS_NULL_POINTER` (`rt`, or a buffer with a non-zero
/// length, is NULL), `LF_STATUS_BAD_METHOD`, `LF_STATUS_BAD_LENGTH`,
/// `LF_STATUS_MISSING_OPERATOR` (see `lf_runtime_has_drt`, `lf_runtime_has_full`),
/// `LF_STATUS_NOT_CONVERGING` (the bounces do not converge: an albedo near 1 in a closed room)
/// or `LF_STATUS_PANIC`. `out_rgb` is written only on success.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`, used by no other thread
/// during the call. `direct_rgb` must be NULL or point to `direct_len` readable floats;
/// `out_rgb` must be NULL or point to `out_len` writable floats; no other thread may write
/// either during the call.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_apply(
    rt: *mut LfRuntime,
    method: i32,
    direct_rgb: *const f32,
    direct_len: usize,
    out_rgb: *mut f32,
    out_len: usize,
) -> i32 {
    status_call("lf_runtime_apply", || {
        // SAFETY: NULL or live and unshared, per the contract.
        let rt = unsafe { rt.as_mut() }.ok_or(CapiError::NullPointer("rt"))?;
        let method = check_rgb_call(
            rt,
            method,
            [
                (direct_rgb, direct_len, "direct_rgb"),
                (out_rgb.cast_const(), out_len, "out_rgb"),
            ],
        )?;
        {
            // SAFETY: `direct_len` readable floats, per the contract. The slice ends before
            // `out_rgb` (which may be the same memory) is touched.
            let direct = unsafe { slice(direct_rgb, direct_len, "direct_rgb") }?;
            for (d, v) in rt.direct.radiance.iter_mut().zip(direct.chunks_exact(3)) {
                *d = [v[0], v[1], v[2]];
            }
        }
        let applied = rt
            .runtime
            .apply(method, rt.bounces, &rt.direct, &mut rt.indirect)?;
        rt.last = applied;
        // SAFETY: `out_len` writable floats, per the contract; no other slice is alive.
        let out = unsafe { slice_mut(out_rgb, out_len, "out_rgb") }?;
        for (o, v) in out.chunks_exact_mut(3).zip(&rt.indirect.radiance) {
            o.copy_from_slice(v);
        }
        Ok(())
    })
}

/// Makes now what `lf_runtime_apply_delta` and `lf_runtime_apply_delta_in_spans` otherwise
/// make on their first call (the exact gather by column, the one-bounce update's scratch), so
/// the first light moved costs a frame like the later ones (on grid1000 the first call took
/// 91 ms, the later ones 0.4 ms): call it at level load. Changes no result; calling it again
/// does nothing. Returns `LF_STATUS_OK`, `LF_STATUS_NULL_POINTER` or `LF_STATUS_PANIC`.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`, used by no other thread during
/// the call.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_prepare_delta(rt: *mut LfRuntime) -> i32 {
    status_call("lf_runtime_prepare_delta", || {
        // SAFETY: NULL or live and unshared, per the contract.
        let rt = unsafe { rt.as_mut() }.ok_or(CapiError::NullPointer("rt"))?;
        rt.runtime.prepare_delta();
        Ok(())
    })
}

/// Relights after a change of direct light, doing work only where the change reaches:
/// `indirect_rgb` holds what `lf_runtime_apply` returned with `method` and the current bounce
/// mode for some direct light L; `delta_rgb` is the change of direct light (the new light minus
/// L: e.g. a moved light's direct light at its new place minus at its old, zero wherever nothing
/// changed). On success `indirect_rgb` holds the indirect light of L + delta: the same as
/// `lf_runtime_apply` on the new light within float rounding (`LF_BOUNCES_ONE`) or within the
/// tolerance (`LF_BOUNCES_CONVERGED`), while only the blocks and clutter objects the change
/// lights, and what their light reaches bounce by bounce, are computed. In
/// `LF_BOUNCES_FEEDBACK` it adds one bounce of the change and of the light earlier calls added
/// but did not bounce yet (where that matters): all bounces arrive over the next calls, each
/// costing one bounce where the light is (`lf_runtime_feedback_due`). Allocates nothing after
/// its first call.
///
/// Both buffers hold `3 x texels` floats, texel-major RGB in layout order, and must not
/// overlap. Returns `LF_STATUS_OK`, or the statuses of `lf_runtime_apply`, or
/// `LF_STATUS_BAD_BOUNCES` in `LF_BOUNCES_FEEDBACK` with `LF_METHOD_FULL` (feedback by the
/// change shoots the light of blocks and clutter objects). `indirect_rgb` is changed only on
/// success.
///
/// # Safety
/// `rt` must be NULL or a live pointer from `lf_runtime_new`, used by no other thread during
/// the call. `delta_rgb` must be NULL or point to `delta_len` readable floats; `indirect_rgb`
/// must be NULL or point to `indirect_len` readable and writable floats, not overlapping
/// `delta_rgb`; no other thread may write either during the call.
#[no_mangle]
pub unsafe extern "C" fn lf_runtime_apply_delta(
    rt: *mut LfRuntime,
    method: i32,
    delta_rgb: *const f32,
    delta_len: usize,
    indirect_rgb: *mut f32,
    indirect_len: usize,
) -> i32 {
    status_call("lf_runtime_apply_delta", || {
        // SAFETY: NULL or live and unshared, per the contract.
        let rt = unsafe { rt.as_mut() }.ok_or(CapiError::NullPointer("rt"))?;
        let method = check_rgb_call(
            rt,
            method,
            [
                (delta_rgb, delta_len, "delta_rgb"),
                (indirect_rgb.cast_const(), indirect_len, "indirect_rgb"),
            ],
        )?;
        // SAFETY: `delta_len` readable floats, per the contract; not overlapping `indirect_rgb`.
        let delta = unsafe { slice(delta_rgb, delta_len, "delta_rgb") }?;
        for (d, v) in rt.direct.radiance.iter_mut().zip(delta.chunks_exact(3)) {
            *d = [v[0], v[1], v[2]];
        }
        // SAFETY: `indirect_len` readable and writable floats, per the contract.
        let indirect = unsafe { slice_mut(indirect_rgb, indirect_len, "indirect_rgb") }?;
        for (o, v) in rt
            .indirect
            .radiance
            .iter_mut()
            .zip(indirect.chunks_exact(3))
        {
            *o = [v[0], v[1], v[2]];
        }
        let applied = rt
            .runtime
            .apply_delta(method, rt.bounces, &rt.direct, &mut rt.indirect)?;
        rt.last = applied.applied;
        for (o, v) in indirect.chunks_exact_mut(3).zip(&rt.indirect.radiance) {
            o.copy_from_slice(v);
        }
        Ok(())
    })
}
