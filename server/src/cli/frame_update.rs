//! `lightfarm frame-time BUNDLE --lights LIGHTS.json --update one-light`: the cost of relighting
//! when one light moves, against relighting everything.
//!
//! Light `--light K` (default 0) moves on a horizontal circle of radius `--radius` m (default
//! [`PATH_RADIUS`]) around its position, one turn every [`PATH_FRAMES`] frames. Every frame
//! both ways relight the level for the light's new position, interleaved so the machine's
//! noise falls on both alike (or, [`Ways::UpdateOnly`], the update alone: the full way's
//! passes over the level then leave no cold caches between its frames):
//! - **full**: every light's direct light (texel-averaged, shadows from the 4 × 4 samples `eval` feeds the
//!   operators, with shadow rays only where visibility changes across a texel:
//!   `direct_from_point_lights_adaptive`; with rooms each light is traced only where it reaches,
//!   against the occluders there, `ReachDirect::all_lights`, the same bits), then
//!   `Runtime::apply`;
//! - **update**: the moved light's direct light alone, on the texels it reaches from where it
//!   was and where it is now (`ReachDirect::light`: the portal walk over the bundle's rooms, and
//!   shadow rays against the reached rooms' occluders only; every texel against the level's
//!   occluders for a bundle without rooms), its change from the previous frame, and
//!   `Runtime::apply_delta_in` adding that change's indirect light to the previous frame's
//!   (told the spans the change lies in, so it reads nothing else), on a
//!   runtime of its own (a game relighting by the change does nothing else with it), made
//!   ready by `Runtime::prepare_delta` before the first frame and timed apart (`prepare_ms`,
//!   what a game pays at load instead of on the first light it moves). Both
//!   the walk and the direct light's bookkeeping touch the reached texels only. With `warm`
//!   (all bounces, which reach most of a level anyway) the change's direct light updates the
//!   level's direct light on the reached texels only and `Runtime::apply` relights it whole
//!   from the previous frame's answer, on a runtime of its own.
//!
//! The adaptive direct light's error against tracing every sample (each light where it
//! reaches, with rooms: `ReachDirect::all_lights_every_sample`), and that tracing's time,
//! are printed first. Each way is reported with its direct-light and operator times apart
//! (medians), then the
//! update's total last (`median_ms=…`, like the other `frame-time` lines). The update's drift
//! from the full relight after the last frame (relative L2 over texels and channels) says the
//! two agree: within float rounding for one or a fixed number of bounces, within the tolerance
//! per frame for `all`.
//!
//! With a probe volume (a scene with dynamic objects) both ways also keep the probe field up to
//! date, `apply_probes` of the whole leaving light against `apply_probes_delta` of its change
//! ([`super::frame_probes`], one more line: `probes=… full_ms=… update_ms=… drift_rel_l2=…`).
//!
//! With `feedback` both ways start from all bounces (the full way after `FEEDBACK_WARM_UP`
//! frames of whole-level feedback on the first frame's lights) and lag behind them while the
//! light moves: the update relights by the change with `Feedback` (one sparse bounce of the
//! change and of the light due, module `delta_feedback` of the client). After the last frame
//! both ways' lag against the all-bounce answer is printed, then the update settles (calls
//! with no change until nothing is due, timed) and its drift is against the all-bounce answer
//! ([`Settling`]), over the level and per lit surface. The all-bounce answers here are
//! `Converged` at `FEEDBACK_REFERENCE_TOLERANCE`.
//!
//! Units: milliseconds of wall time on this thread (the runtime single-threaded).

use std::time::Instant;

use std::ops::Range;

use lightfarm_client::{
    direct_from_point_lights_adaptive, direct_from_point_lights_adaptive_in, direct_scale,
    every_sample_by_reach, frame_occluders, occluders_with_poses, relative_l1, relative_l2,
    Bounces, Bundle, DirectLight, IndirectLight, Light, Method, Occluders, ProbeField, ReachDirect,
    Runtime, TexelSpan,
};
use lightfarm_proto::bundle::Layout;
use lightfarm_proto::lights::Pose;

use super::frame_probes::{ProbeTimes, ProbeWay};
use crate::evaluate::{is_bounced, DIRECT_SAMPLES_PER_EDGE};

/// Radius of the moving light's path by default, metres (5 mm a frame).
pub const PATH_RADIUS: f64 = 0.1;
/// Frames of one turn of the path.
pub const PATH_FRAMES: usize = 120;

/// Medians (ms) of one way of relighting.
#[derive(Clone, Copy, Debug)]
pub struct Way {
    pub direct_ms: f64,
    pub operator_ms: f64,
    pub total_ms: f64,
}

/// What [`time_update`] measured.
#[derive(Clone, Copy, Debug)]
pub struct UpdateTimes {
    pub full: Way,
    pub update: Way,
    /// Relative L2 between the update's and the full relight's indirect light after the last
    /// frame.
    pub drift: f64,
    /// Relative L2 of the adaptive direct light against tracing every sample (frame 0, every
    /// light), and the time of tracing every sample (ms).
    pub direct_error: f64,
    pub direct_every_sample_ms: f64,
    /// Block projections the update made per frame (median) and the level's blocks times the
    /// applications a full apply makes.
    pub blocks_projected: usize,
    pub blocks_total: usize,
    /// Texels the moved light reaches (median over frames; all of them without rooms) and
    /// rooms its walk reached.
    pub texels_reached: usize,
    pub rooms_reached: usize,
    /// Whether the bundle has rooms (else the update lights every texel).
    pub has_rooms: bool,
    /// [`Runtime::prepare_delta`] before the first frame (ms).
    pub prepare_ms: f64,
    /// `feedback` only ([`Settling`]): how far each way lagged behind all bounces after the
    /// last frame, and the update's settling once the light stops.
    pub settling: Option<Settling>,
    /// With a probe volume (not with `warm`): keeping the probe field up to date both ways
    /// ([`super::frame_probes`]).
    pub probes: Option<ProbeTimes>,
}

/// With [`Bounces::Feedback`] both ways lag behind all bounces while the light moves (the
/// light of a frame's change arrives bounce by bounce over the next frames); after the last
/// frame the update keeps calling with no change until nothing is due
/// ([`Runtime::feedback_due`]).
#[derive(Clone, Copy, Debug)]
pub struct Settling {
    /// Relative L2 against the all-bounce answer (`Converged` at
    /// `FEEDBACK_REFERENCE_TOLERANCE`) of the last frame's lights: the update's and the full
    /// way's (whole-level feedback; NaN with [`Ways::UpdateOnly`]).
    pub update_lag: f64,
    pub full_lag: f64,
    /// The update's lag in relative L1 (the norm of the feedback's tolerance) and what the
    /// runtime estimated it to be ([`Runtime::feedback_lag`], the last frame's
    /// `Applied::remaining_fraction`).
    pub update_lag_l1: f64,
    pub estimated_lag: f64,
    /// Calls with no change until nothing was due, their median time (ms), and the update's
    /// relative L2 and L1 against the all-bounce answer then, with the runtime's estimate.
    pub frames: usize,
    pub median_ms: f64,
    pub settled: f64,
    pub settled_l1: f64,
    pub estimated_settled: f64,
    /// Settled, per surface of the layout (relative L1 against the surface's all-bounce
    /// light; surfaces lit at least `LIT_SURFACE` of the mean texel's light): the 99th
    /// percentile and the largest.
    pub surface_p99: f64,
    pub surface_max: f64,
}

/// The least light per texel, relative to the level's mean, of the surfaces whose error
/// [`Settling`] reports.
const LIT_SURFACE: f64 = 1e-2;

/// Tolerance of the all-bounce answers the feedback is compared with (and starts from): well
/// under the feedback's own (the default, 1e-3), so the drift is the feedback's.
const FEEDBACK_REFERENCE_TOLERANCE: f32 = 1e-5;

/// Relative L1 error of each lit surface of `layout` (module doc of [`Settling`]): (99th
/// percentile, largest).
fn surface_errors(layout: &Layout, got: &[[f32; 3]], want: &[[f32; 3]]) -> (f64, f64) {
    let l1 = |v: &[[f32; 3]]| -> f64 { v.iter().flatten().map(|x| x.abs() as f64).sum() };
    let mean = l1(want) / want.len().max(1) as f64;
    let mut errors: Vec<f64> = layout
        .surfaces
        .iter()
        .filter_map(|s| {
            let r = s.texel_offset as usize..(s.texel_offset + s.texel_count) as usize;
            let light = l1(&want[r.clone()]);
            (s.texel_count > 0 && light >= LIT_SURFACE * mean * r.len() as f64)
                .then(|| relative_l1(&got[r.clone()], &want[r]))
        })
        .collect();
    if errors.is_empty() {
        return (0.0, 0.0);
    }
    errors.sort_by(f64::total_cmp);
    let p99 = errors[(errors.len() * 99 / 100).min(errors.len() - 1)];
    (p99, errors[errors.len() - 1])
}

/// Frames of whole-level feedback the full way makes on the first frame's lights before the
/// timed frames (so it starts from all bounces, as the update does: 0.65⁴⁰ ≈ 3e-8).
const FEEDBACK_WARM_UP: usize = 40;

/// Calls with no change the update makes at most to settle.
const MAX_SETTLE: usize = 1000;

/// The middle value of `v` (the upper of the two middle ones for an even count); `v` must not
/// be empty.
pub(crate) fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Every light's direct light with the dynamic objects at `poses` (none: the level alone), as
/// the full way relights it: texel-averaged with adaptive shadow rays
/// ([`DIRECT_SAMPLES_PER_EDGE`]), each light where it reaches against the occluders there
/// when the bundle has rooms (`reach`, the level's; `ReachDirect::with_posed` adds the
/// objects), every texel otherwise.
pub(crate) fn direct_of(
    reach: &mut Option<ReachDirect>,
    bundle: &Bundle,
    level: &Occluders,
    lights: &[Light],
    poses: &[Pose],
    scale: f64,
) -> DirectLight {
    let layout = &bundle.layout;
    let posed = occluders_with_poses(level, bundle, poses);
    let m = DIRECT_SAMPLES_PER_EDGE;
    match (reach.as_mut(), posed.as_ref()) {
        (Some(r), Some(p)) => r
            .with_posed(p)
            .all_lights(layout, &p.occluders, lights, m, scale),
        (Some(r), None) => r.all_lights(layout, level, lights, m, scale),
        (None, p) => {
            direct_from_point_lights_adaptive(layout, frame_occluders(level, p), lights, m)
        }
    }
}

/// The texels of two lists of ascending, disjoint spans (where the light was and where it is),
/// as ascending, disjoint ranges: each texel once, however much the two overlap.
fn union_of(a: &[TexelSpan], b: &[TexelSpan], out: &mut Vec<Range<usize>>) {
    out.clear();
    let (mut i, mut j) = (0, 0);
    while i < a.len() || j < b.len() {
        let next = if j == b.len() || (i < a.len() && a[i].texels.start <= b[j].texels.start) {
            i += 1;
            a[i - 1].texels.clone()
        } else {
            j += 1;
            b[j - 1].texels.clone()
        };
        match out.last_mut() {
            Some(last) if next.start <= last.end => last.end = last.end.max(next.end),
            _ => out.push(next),
        }
    }
}

/// The moved light's reach (every texel without rooms) into `spans`, and its direct light
/// there into `out`.
fn moved_direct(
    reach: &mut Option<ReachDirect>,
    layout: &Layout,
    occluders: &Occluders,
    light: &Light,
    scale: f64,
    spans: &mut Vec<TexelSpan>,
    out: &mut [[f32; 3]],
) {
    match reach {
        Some(r) => r.light(
            layout,
            occluders,
            light,
            DIRECT_SAMPLES_PER_EDGE,
            scale,
            spans,
            out,
        ),
        None => {
            spans.clear();
            spans.push(TexelSpan {
                texels: 0..layout.n_texels(),
                in_sight: false,
            });
            direct_from_point_lights_adaptive_in(
                layout,
                occluders,
                std::slice::from_ref(light),
                DIRECT_SAMPLES_PER_EDGE,
                scale,
                spans,
                out,
            )
        }
    }
}

/// Which ways [`time_update`] times.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ways {
    /// Relighting everything and relighting by the change, frame by frame, and tracing every
    /// sample once.
    Both,
    /// Relighting by the change alone: relighting everything runs once, after the last frame,
    /// for the drift; `full`, `direct_error` and `direct_every_sample_ms` are NaN.
    UpdateOnly,
}

/// Times `frames` frames of light `moved` of `lights` moving along the path of `radius` m
/// (module doc), relit both ways with `method` and `bounces` (or by the change only, see
/// [`Ways`]).
#[allow(clippy::too_many_arguments)]
pub fn time_update(
    runtime: &mut Runtime,
    occluders: &Occluders,
    lights: &[Light],
    moved: usize,
    method: Method,
    bounces: Bounces,
    frames: usize,
    ways: Ways,
    radius: f64,
) -> anyhow::Result<UpdateTimes> {
    anyhow::ensure!(
        moved < lights.len(),
        "--light {moved}: the light set has {} lights",
        lights.len()
    );
    let layout = runtime.bundle().layout.clone();
    let mut lights = lights.to_vec();
    let centre = lights[moved].position;
    let at = |frame: usize| {
        let a = std::f64::consts::TAU * frame as f64 / PATH_FRAMES as f64;
        [
            centre[0] + radius * a.cos(),
            centre[1],
            centre[2] + radius * a.sin(),
        ]
    };
    // Frame 0: both ways start from the same light.
    lights[moved].position = at(0);
    let scale = direct_scale(&layout, occluders);
    // Each way walks its lights' reaches with scratch of its own.
    let mut full_reach = ReachDirect::new(runtime.bundle(), occluders);
    let both = ways == Ways::Both;
    let direct0 = direct_of(
        &mut full_reach,
        runtime.bundle(),
        occluders,
        &lights,
        &[],
        scale,
    );
    let (mut direct_error, mut direct_every_sample_ms) = (f64::NAN, f64::NAN);
    if both {
        // Every sample traced (each light where it reaches, with rooms).
        let start = Instant::now();
        let every_sample = every_sample_by_reach(
            full_reach.as_mut(),
            &layout,
            occluders,
            &lights,
            DIRECT_SAMPLES_PER_EDGE,
            scale,
        );
        direct_every_sample_ms = start.elapsed().as_secs_f64() * 1e3;
        direct_error = relative_l2(&direct0.radiance, &every_sample.radiance);
    }
    let mut full_out = IndirectLight::default();
    let feedback = bounces == Bounces::Feedback;
    if feedback {
        // Both ways start from all bounces: the update from the converged answer, the full
        // way's feedback after as many frames on the same light.
        let reference = Bounces::Converged {
            tolerance: FEEDBACK_REFERENCE_TOLERANCE,
        };
        runtime.apply(method, reference, &direct0, &mut full_out)?;
        let mut warming = IndirectLight::default();
        for _ in 0..if both { FEEDBACK_WARM_UP } else { 0 } {
            runtime.apply(method, bounces, &direct0, &mut warming)?;
        }
    } else {
        runtime.apply(method, bounces, &direct0, &mut full_out)?;
    }
    let mut update_out = full_out.clone();
    // The update way relights on a runtime of its own, as a game relighting by the change
    // would: the full way's passes over the level leave nothing for it to clear.
    let mut by_change = (!matches!(bounces, Bounces::Warm { .. })).then(|| runtime.clone());
    // What the first relight by the change would make (a game does it at load), timed apart.
    let start = Instant::now();
    if let Some(rt) = by_change.as_mut() {
        rt.prepare_delta();
    }
    let prepare_ms = start.elapsed().as_secs_f64() * 1e3;
    // The update's direct light of the moved light: `previous` and `now` hold it on the spans
    // it reached (zero elsewhere); `change` is non-zero on `change_spans` only.
    let n = layout.n_texels();
    let mut reach = ReachDirect::new(runtime.bundle(), occluders);
    let has_rooms = reach.is_some();
    let (mut previous, mut now) = (vec![[0.0f32; 3]; n], vec![[0.0f32; 3]; n]);
    let (mut spans_before, mut spans_now) = (Vec::new(), Vec::new());
    let mut change_spans: Vec<Range<usize>> = Vec::new();
    let lit = |reach: &mut Option<ReachDirect>,
               light: &Light,
               spans: &mut Vec<TexelSpan>,
               out: &mut [[f32; 3]]| {
        moved_direct(reach, &layout, occluders, light, scale, spans, out)
    };
    lit(&mut reach, &lights[moved], &mut spans_before, &mut previous);
    let mut change = DirectLight {
        radiance: vec![[0.0; 3]; n],
    };
    // Warm: the update way keeps every light's direct light (the others' once, the moved
    // light's on its spans) and applies it whole on a runtime of its own, so neither way's
    // guess helps the other.
    let warm = matches!(bounces, Bounces::Warm { .. });
    let mut warm_way = warm.then(|| {
        let mut others = lights.clone();
        others.remove(moved);
        let others = direct_of(
            &mut full_reach,
            runtime.bundle(),
            occluders,
            &others,
            &[],
            scale,
        );
        let mut total = others.clone();
        for (t, p) in total.radiance.iter_mut().zip(&previous) {
            *t = [t[0] + p[0], t[1] + p[1], t[2] + p[2]];
        }
        (runtime.clone(), others, total)
    });
    if let Some((rt, _, total)) = warm_way.as_mut() {
        rt.apply(method, bounces, total, &mut update_out)?;
    }
    // The probe field both ways keep (the full way's in `full_field`), from frame 0's light.
    let mut probe_way = match by_change.as_mut() {
        Some(rt) => ProbeWay::new(rt, &direct0, &update_out, is_bounced(bounces))?,
        None => None,
    };
    let mut full_field = ProbeField::default();
    let (mut full, mut update) = ([Vec::new(), Vec::new()], [Vec::new(), Vec::new()]);
    let (mut projected, mut reached, mut rooms) = (Vec::new(), Vec::new(), Vec::new());
    let mut total = 0;
    // The full way's direct light of the last frame's lights.
    let mut last_direct = DirectLight::default();
    for frame in 1..=frames {
        lights[moved].position = at(frame);
        // Full: every light's direct light, then apply (every frame, or after the last).
        if both || frame == frames {
            let start = Instant::now();
            let direct = direct_of(
                &mut full_reach,
                runtime.bundle(),
                occluders,
                &lights,
                &[],
                scale,
            );
            let mid = Instant::now();
            runtime.apply(method, bounces, &direct, &mut full_out)?;
            full[0].push((mid - start).as_secs_f64() * 1e3);
            full[1].push(mid.elapsed().as_secs_f64() * 1e3);
            if let (true, Some(p)) = (both, probe_way.as_mut()) {
                p.full_frame(runtime, &direct, &full_out, &mut full_field)?;
            }
            last_direct = direct;
        }
        // Update: where the moved light reaches, its direct light there and the change from
        // the previous frame, then apply_delta.
        let start = Instant::now();
        lit(&mut reach, &lights[moved], &mut spans_now, &mut now);
        for span in &change_spans {
            change.radiance[span.clone()].as_flattened_mut().fill(0.0);
        }
        union_of(&spans_before, &spans_now, &mut change_spans);
        for span in &change_spans {
            // Channel by channel as runs of floats (the same values, in wide registers).
            let (l, p) = (
                now[span.clone()].as_flattened(),
                previous[span.clone()].as_flattened(),
            );
            match warm_way.as_mut() {
                Some((_, others, total)) => {
                    let o = others.radiance[span.clone()].as_flattened();
                    let t = total.radiance[span.clone()].as_flattened_mut();
                    for ((t, &o), &l) in t.iter_mut().zip(o).zip(l) {
                        *t = o + l;
                    }
                }
                None => {
                    let c = change.radiance[span.clone()].as_flattened_mut();
                    for ((c, &l), &p) in c.iter_mut().zip(l).zip(p) {
                        *c = l - p;
                    }
                }
            }
        }
        for span in &spans_before {
            previous[span.texels.clone()].as_flattened_mut().fill(0.0);
        }
        std::mem::swap(&mut previous, &mut now);
        std::mem::swap(&mut spans_before, &mut spans_now);
        let mid = Instant::now();
        let d = match warm_way.as_mut() {
            Some((rt, _, total)) => {
                let applied = rt.apply(method, bounces, total, &mut update_out)?;
                let blocks = rt.bundle().blocks.len() * applied.bounces as usize;
                lightfarm_client::DeltaApplied {
                    applied,
                    blocks_projected: blocks,
                    blocks_total: blocks,
                }
            }
            None => by_change
                .as_mut()
                .expect("made unless warm")
                .apply_delta_in(method, bounces, &change, &change_spans, &mut update_out)?,
        };
        update[0].push((mid - start).as_secs_f64() * 1e3);
        update[1].push(mid.elapsed().as_secs_f64() * 1e3);
        if let (Some(p), Some(rt)) = (probe_way.as_mut(), by_change.as_mut()) {
            p.update_frame(rt, &change, &change_spans, &update_out)?;
        }
        projected.push(d.blocks_projected as f64);
        reached.push(spans_before.iter().map(|s| s.texels.len()).sum::<usize>() as f64);
        rooms.push(reach.as_ref().map_or(0, |r| r.rooms_reached()) as f64);
        total = total.max(d.blocks_total);
    }
    // The update's probe field against the field of its own leaving light (the last frame's
    // direct light, every light, and the update's indirect light).
    let probes = match probe_way {
        Some(p) => Some(p.finish(runtime, &last_direct, &update_out)?),
        None => None,
    };
    // Feedback: how far both lag behind all bounces, then the update settling.
    let mut settling = None;
    let mut drift = relative_l2(&update_out.radiance, &full_out.radiance);
    if let (true, Some(rt)) = (feedback, by_change.as_mut()) {
        // The full way is done: its runtime makes the reference of the last frame's lights.
        let mut all = IndirectLight::default();
        let reference = Bounces::Converged {
            tolerance: FEEDBACK_REFERENCE_TOLERANCE,
        };
        runtime.apply(method, reference, &last_direct, &mut all)?;
        for span in &change_spans {
            change.radiance[span.clone()].fill([0.0; 3]);
        }
        let update_lag = relative_l2(&update_out.radiance, &all.radiance);
        let update_lag_l1 = relative_l1(&update_out.radiance, &all.radiance);
        let estimated_lag = rt.feedback_lag();
        let mut times = Vec::new();
        while rt.feedback_due() > 0 && times.len() < MAX_SETTLE {
            let start = Instant::now();
            rt.apply_delta_in(method, bounces, &change, &[], &mut update_out)?;
            times.push(start.elapsed().as_secs_f64() * 1e3);
        }
        let settled = relative_l2(&update_out.radiance, &all.radiance);
        let (surface_p99, surface_max) =
            surface_errors(&layout, &update_out.radiance, &all.radiance);
        settling = Some(Settling {
            update_lag,
            update_lag_l1,
            estimated_lag,
            settled_l1: relative_l1(&update_out.radiance, &all.radiance),
            estimated_settled: rt.feedback_lag(),
            full_lag: if both {
                relative_l2(&full_out.radiance, &all.radiance)
            } else {
                f64::NAN
            },
            frames: times.len(),
            median_ms: if times.is_empty() { 0.0 } else { median(times) },
            settled,
            surface_p99,
            surface_max,
        });
        drift = settled;
    }
    let way = |[direct, operators]: [Vec<f64>; 2]| {
        let sums: Vec<f64> = direct.iter().zip(&operators).map(|(a, b)| a + b).collect();
        Way {
            direct_ms: median(direct),
            operator_ms: median(operators),
            total_ms: median(sums),
        }
    };
    let full = if both {
        way(full)
    } else {
        Way {
            direct_ms: f64::NAN,
            operator_ms: f64::NAN,
            total_ms: f64::NAN,
        }
    };
    Ok(UpdateTimes {
        full,
        update: way(update),
        drift,
        direct_error,
        direct_every_sample_ms,
        blocks_projected: median(projected) as usize,
        blocks_total: total,
        texels_reached: median(reached) as usize,
        rooms_reached: median(rooms) as usize,
        has_rooms,
        prepare_ms,
        settling,
        probes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spans(ranges: &[Range<usize>]) -> Vec<TexelSpan> {
        ranges
            .iter()
            .map(|r| TexelSpan {
                texels: r.clone(),
                in_sight: false,
            })
            .collect()
    }

    #[test]
    fn the_union_of_two_span_lists_holds_every_texel_once() {
        let a = spans(&[0..4, 10..20, 30..31]);
        let b = spans(&[2..6, 6..8, 15..25, 40..41]);
        let mut out = vec![99..100];
        union_of(&a, &b, &mut out);
        assert_eq!(out, vec![0..8, 10..25, 30..31, 40..41]);
        union_of(&a, &[], &mut out);
        assert_eq!(out, vec![0..4, 10..20, 30..31]);
        union_of(&[], &[], &mut out);
        assert!(out.is_empty());
    }
}
