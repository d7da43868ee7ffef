//! `lightfarm frame-time BUNDLE --lights LIGHTS.json [--bounces 1,all,feedback]`: how long one
//! frame of the client runtime takes (median over many frames), next to the memory-traffic
//! bound.
//!
//! Direct light is computed once (the engine's job, not timed); each timed frame is one
//! `Runtime::apply` with the bounce mode. Several modes are timed side by side: rounds of 10
//! frames of each mode in turn, so the machine's noise falls on all of them alike; one line per
//! mode, in the order given. The bound is the operator bytes one frame reads divided by the read
//! bandwidth measured here with a streaming sum over a buffer much larger than the caches: no
//! implementation that reads every operator value once per frame can beat it.
//!
//! With `--texel-bounces`, every `Converged` mode is timed a second time with its bounces over
//! texels (`Runtime::set_reduced_bounces(false)`; MRT runs them over the blocks' coefficients
//! by default, DRT over the blocks' and clutter objects'), in the same rounds.
//!
//! The direct light's own time (every light, texel-averaged as `eval` feeds the operators, one
//! thread) is printed first, apart from the operators'. With `--update one-light`, one light
//! moves instead and relighting by the change is timed against relighting everything
//! ([`super::frame_update`]; with `--update-alone`, relighting by the change alone, as a game
//! that only moves the light runs it); with `--update one-object`, one posed dynamic object moves
//! ([`super::frame_object`]).
//!
//! With `feedback` among the modes, it also prints how many feedback frames the light takes to
//! come within 1% (relative L2) of `Converged` at 1e-5 after the lights switch on from dark (the
//! largest jump a light can make), and within 0.1%.
//!
//! The frames above repeat one light set, which is where `Warm` (and `Feedback`) cost one
//! application. With `warm` or `feedback` among the modes, every mode is also timed while light
//! `--light K` moves ([`super::frame_moving`]): `moving … median_ms=… mean_applications=…
//! worst_rel_l2=…` lines.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use lightfarm_client::{Bounces, Bundle, IndirectLight, Method, Occluders, Runtime};
use lightfarm_proto::lights::LightSet;

use super::frame_moving::{time_moving, MOVING_FRAMES, MOVING_RADIUS};
use super::frame_object::time_object;
use super::frame_update::{time_update, Ways};
use super::read_text;
use crate::evaluate::operator_direct;

/// Arguments of `frame-time`.
pub struct FrameTimeArgs {
    pub bundle: PathBuf,
    pub lights: PathBuf,
    pub method: Method,
    /// Bounce modes, timed side by side.
    pub bounces: Vec<Bounces>,
    pub frames: usize,
    /// Threads of the runtime's rayon pool (1: the single-thread path).
    pub threads: usize,
    /// `--update one-light`: time moving light `light` ([`super::frame_update`]) instead.
    pub update_light: Option<usize>,
    /// `--update one-object`: time moving posed object `object` ([`super::frame_object`])
    /// instead.
    pub update_object: Option<usize>,
    /// The light the moving-light lines move ([`super::frame_moving`]).
    pub moving_light: usize,
    /// Radius (m) of the `--update one-light` light's circle ([`super::frame_update`]).
    pub radius: f64,
    /// `--update one-light` times relighting by the change alone ([`Ways::UpdateOnly`]).
    pub update_alone: bool,
    /// Texels of due units a `Feedback` call by the change shoots at most besides the
    /// change's (`Runtime::set_feedback_budget`; None: all due).
    pub feedback_budget: Option<usize>,
    /// Also time every `Converged` mode with its bounces over texels (`…-texels` lines), side
    /// by side with the coefficient-space paths MRT and DRT use by default.
    pub texel_bounces: bool,
}

/// One timed line: a bounce mode, and for MRT's `Converged` whether its bounces run over texels
/// instead of the blocks' coefficients (`Runtime::set_reduced_bounces(false)`, for comparing
/// the two in one run).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimedMode {
    pub bounces: Bounces,
    pub texel_bounces: bool,
}

impl From<Bounces> for TimedMode {
    fn from(bounces: Bounces) -> TimedMode {
        TimedMode {
            bounces,
            texel_bounces: false,
        }
    }
}

impl TimedMode {
    /// The mode's name in `frame-time`'s lines (`…-texels` on the texel path).
    pub fn name(&self) -> String {
        let name = mode_name(self.bounces);
        if self.texel_bounces {
            format!("{name}-texels")
        } else {
            name
        }
    }
}

/// Frame-time figures of one bounce mode.
#[derive(Clone, Debug)]
pub struct FrameTimes {
    pub median_ms: f64,
    pub p10_ms: f64,
    pub p90_ms: f64,
    pub operator_bytes: usize,
    /// One-bounce applications per frame (the last frame's; Converged's count).
    pub bounces: u32,
}

/// Frames of one mode per round when several modes are timed side by side.
const ROUND: usize = 10;

/// Times `frames` applications of `method` with each of `modes` on `threads` threads,
/// interleaved in rounds; one result per mode, in order.
pub fn time_frames(
    runtime: &mut Runtime,
    direct: &lightfarm_client::DirectLight,
    method: Method,
    modes: &[TimedMode],
    frames: usize,
    threads: usize,
) -> anyhow::Result<Vec<FrameTimes>> {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads.max(1))
        .build()?;
    runtime.set_parallel(threads > 1);
    let mut out = IndirectLight::default();
    let mut times = vec![Vec::with_capacity(frames); modes.len()];
    let mut bounces = vec![0u32; modes.len()];
    pool.install(|| -> anyhow::Result<()> {
        // Warm-up: caches, page faults, the output's allocation.
        for mode in modes {
            runtime.set_reduced_bounces(!mode.texel_bounces);
            for _ in 0..frames.min(20) {
                runtime.apply(method, mode.bounces, direct, &mut out)?;
            }
        }
        let mut done = 0;
        while done < frames {
            let round = ROUND.min(frames - done);
            for (k, mode) in modes.iter().enumerate() {
                runtime.set_reduced_bounces(!mode.texel_bounces);
                for _ in 0..round {
                    let start = Instant::now();
                    let applied = runtime.apply(method, mode.bounces, direct, &mut out)?;
                    times[k].push(start.elapsed().as_secs_f64() * 1e3);
                    bounces[k] = applied.bounces;
                }
            }
            done += round;
        }
        Ok(())
    })?;
    runtime.set_parallel(false);
    runtime.set_reduced_bounces(true);
    let operator_bytes = runtime.operator_bytes_per_frame(method);
    Ok(times
        .into_iter()
        .zip(bounces)
        .map(|(mut times, bounces)| {
            times.sort_by(f64::total_cmp);
            let at = |q: f64| times[((times.len() - 1) as f64 * q).round() as usize];
            FrameTimes {
                median_ms: at(0.5),
                p10_ms: at(0.1),
                p90_ms: at(0.9),
                operator_bytes,
                bounces,
            }
        })
        .collect())
}

/// The name of a bounce mode in `frame-time`'s lines.
pub fn mode_name(mode: Bounces) -> String {
    match mode {
        Bounces::One => "one".to_string(),
        Bounces::Fixed(n) => n.to_string(),
        Bounces::Converged { tolerance } => format!("converged({tolerance:e})"),
        Bounces::Feedback => "feedback".to_string(),
        Bounces::Warm { tolerance } => format!("warm({tolerance:e})"),
    }
}

/// Single-thread streaming read bandwidth (bytes/s) over a 256 MiB buffer, best of 5 passes.
pub fn read_bandwidth() -> f64 {
    let data = vec![1.0f32; 64 << 20];
    let mut best = f64::INFINITY;
    let mut sink = 0.0f32;
    for _ in 0..5 {
        let start = Instant::now();
        let mut acc = [0.0f32; 8];
        for chunk in data.chunks_exact(8) {
            for k in 0..8 {
                acc[k] += chunk[k];
            }
        }
        sink += acc.iter().sum::<f32>();
        best = best.min(start.elapsed().as_secs_f64());
    }
    std::hint::black_box(sink);
    (data.len() * 4) as f64 / best
}

pub fn run(args: FrameTimeArgs) -> anyhow::Result<()> {
    if args.update_alone && args.update_light.is_none() {
        anyhow::bail!("--update-alone times `--update one-light`, which was not given");
    }
    let bytes = std::fs::read(&args.bundle)
        .with_context(|| format!("cannot read {}", args.bundle.display()))?;
    let bundle = Bundle::decode(&bytes).with_context(|| format!("{}", args.bundle.display()))?;
    let lights = LightSet::from_json(&read_text(&args.lights)?)
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.lights.display()))?;
    let occluders = Occluders::from_layout(&bundle.layout);
    let start = Instant::now();
    let direct = operator_direct(&bundle, &occluders, &lights);
    let direct_ms = start.elapsed().as_secs_f64() * 1e3;
    let mut runtime = Runtime::try_new(bundle)?;
    if args.feedback_budget.is_some() {
        runtime.set_feedback_budget(args.feedback_budget);
    }
    let method = if args.method == Method::Drt && !runtime.has_drt() {
        Method::Mrt
    } else {
        args.method
    };
    let modes = if args.bounces.is_empty() {
        vec![Bounces::default()]
    } else {
        args.bounces.clone()
    };
    if let Some(object) = args.update_object {
        let mode = modes[0];
        let frames = args.frames;
        let t = time_object(
            &mut runtime,
            &occluders,
            &lights,
            object,
            method,
            mode,
            frames,
            args.radius,
        )?;
        let name = &t.object;
        for (way_name, way) in [("full", t.full), ("update", t.update)] {
            crate::say!(
                "update=one-object object={name} way={way_name} method={method:?} bounces={} \
                 frames={frames} direct_ms={:.4} operator_ms={:.4} objects_ms={:.4} \
                 total_ms={:.4}",
                mode_name(mode),
                way.direct_ms,
                way.operator_ms,
                way.objects_ms,
                way.total_ms
            );
        }
        if let Some(p) = t.probes {
            crate::say!(
                "update=one-object object={name} probes={} full_ms={:.4} update_ms={:.4} \
                 drift_rel_l2={:.2e}",
                p.probes,
                p.full_ms,
                p.update_ms,
                p.drift
            );
        }
        crate::say!(
            "update=one-object object={name} method={method:?} bounces={} frames={frames} \
             lights={} lights_relit={} texels_changed={}/{} object_light={} \
             direct_drift_rel_l2={:.2e} drift_rel_l2={:.2e} speedup={:.1} median_ms={:.4}",
            mode_name(mode),
            lights.lights.len(),
            t.lights_relit,
            t.texels_changed,
            runtime.n_texels(),
            t.object_light,
            t.direct_drift,
            t.drift,
            t.full.total_ms / t.update.total_ms,
            t.update.total_ms
        );
        return Ok(());
    }
    if let Some(moved) = args.update_light {
        let mode = modes[0];
        let frames = args.frames;
        let t = time_update(
            &mut runtime,
            &occluders,
            &lights.lights,
            moved,
            method,
            mode,
            frames,
            if args.update_alone {
                Ways::UpdateOnly
            } else {
                Ways::Both
            },
            args.radius,
        )?;
        if !args.update_alone {
            crate::say!(
                "update=one-light direct light: lights={} texels={} every_sample_ms={:.4} \
                 adaptive_rel_l2={:.2e}",
                lights.lights.len(),
                runtime.n_texels(),
                t.direct_every_sample_ms,
                t.direct_error
            );
        }
        let ways = [("full", t.full), ("update", t.update)];
        for (name, way) in ways.into_iter().skip(args.update_alone as usize) {
            crate::say!(
                "update=one-light light={moved} way={name} method={method:?} bounces={} \
                 frames={frames} direct_ms={:.4} operator_ms={:.4} total_ms={:.4}",
                mode_name(mode),
                way.direct_ms,
                way.operator_ms,
                way.total_ms
            );
        }
        crate::say!(
            "update=one-light light={moved} reach={} texels_reached={}/{} rooms_reached={} \
             prepare_ms={:.2}",
            if t.has_rooms {
                "rooms"
            } else {
                "everywhere (bundle without rooms)"
            },
            t.texels_reached,
            runtime.n_texels(),
            t.rooms_reached,
            t.prepare_ms
        );
        if let Some(p) = t.probes {
            crate::say!(
                "update=one-light light={moved} probes={} full_ms={:.4} update_ms={:.4} \
                 drift_rel_l2={:.2e}",
                p.probes,
                p.full_ms,
                p.update_ms,
                p.drift
            );
        }
        if let Some(s) = t.settling {
            crate::say!(
                "update=one-light light={moved} bounces=feedback budget={} lag_rel_l2: \
                 update={:.2e} full={:.2e}; update rel_l1={:.2e} estimated={:.2e}; settled \
                 after {} calls (median {:.4} ms) to rel_l2={:.2e} rel_l1={:.2e} \
                 estimated={:.2e}, per lit surface rel_l1 p99={:.2e} max={:.2e}",
                args.feedback_budget
                    .map_or("all".to_string(), |b| format!("{b}_texels")),
                s.update_lag,
                s.full_lag,
                s.update_lag_l1,
                s.estimated_lag,
                s.frames,
                s.median_ms,
                s.settled,
                s.settled_l1,
                s.estimated_settled,
                s.surface_p99,
                s.surface_max
            );
        }
        let speedup = if args.update_alone {
            String::new()
        } else {
            format!(" speedup={:.1}", t.full.total_ms / t.update.total_ms)
        };
        crate::say!(
            "update=one-light light={moved} method={method:?} bounces={} frames={frames} \
             blocks_projected={}/{} drift_rel_l2={:.2e}{speedup} median_ms={:.4}",
            mode_name(mode),
            t.blocks_projected,
            t.blocks_total,
            t.drift,
            t.update.total_ms
        );
        return Ok(());
    }
    // Direct light (every light, texel-averaged as `eval` feeds the operators), computed once
    // on this thread; the frames below time the operators alone.
    crate::say!(
        "direct light: lights={} texels={} direct_ms={direct_ms:.4}",
        lights.lights.len(),
        runtime.n_texels()
    );
    let mut timed: Vec<TimedMode> = modes.iter().map(|&b| b.into()).collect();
    if args.texel_bounces {
        timed.extend(
            modes
                .iter()
                .filter(|b| matches!(b, Bounces::Converged { .. }))
                .map(|&bounces| TimedMode {
                    bounces,
                    texel_bounces: true,
                }),
        );
    }
    let results = time_frames(
        &mut runtime,
        &direct,
        method,
        &timed,
        args.frames,
        args.threads,
    )?;
    let bandwidth = read_bandwidth();
    for (mode, t) in timed.iter().zip(&results) {
        // The bound: one pass over the operators per one-bounce application.
        let bound_ms = t.bounces as f64 * t.operator_bytes as f64 / bandwidth * 1e3;
        crate::say!(
            "method={method:?} bounces={} applications={} threads={} frames={} median_ms={:.4} \
             p10_ms={:.4} p90_ms={:.4} operator_bytes={} read_bandwidth_gbs={:.2} \
             bound_ms={bound_ms:.4}",
            mode.name(),
            t.bounces,
            args.threads,
            args.frames,
            t.median_ms,
            t.p10_ms,
            t.p90_ms,
            t.operator_bytes,
            bandwidth / 1e9
        );
    }
    if modes
        .iter()
        .any(|m| matches!(m, Bounces::Feedback | Bounces::Warm { .. }))
    {
        let frames = args.frames.clamp(2, MOVING_FRAMES);
        let moving = time_moving(
            &mut runtime,
            &occluders,
            &lights,
            args.moving_light,
            method,
            &modes,
            frames,
        )?;
        for (mode, t) in modes.iter().zip(&moving) {
            crate::say!(
                "moving light={} radius_m={MOVING_RADIUS} frames={frames} method={method:?} \
                 bounces={} threads=1 median_ms={:.4} mean_applications={:.2} \
                 worst_rel_l2={:.2e}",
                args.moving_light,
                mode_name(*mode),
                t.median_ms,
                t.mean_applications,
                t.worst_rel_l2
            );
        }
    }
    if modes.contains(&Bounces::Feedback) {
        let (to_1pct, to_01pct) = feedback_frames(&mut runtime, &direct, method)?;
        crate::say!(
            "method={method:?} feedback_frames_to_1pct={} feedback_frames_to_0.1pct={} \
             (after the lights switch on, against Converged at 1e-5)",
            fmt_frames(to_1pct),
            fmt_frames(to_01pct)
        );
    }
    Ok(())
}

fn fmt_frames(frames: Option<usize>) -> String {
    frames.map_or_else(|| format!(">{FEEDBACK_FRAMES}"), |f| f.to_string())
}

/// Frames [`feedback_frames`] runs at the most.
const FEEDBACK_FRAMES: usize = 500;

/// Feedback frames from dark until the output is within 1% and 0.1% (relative L2 over texels
/// and channels) of `Converged` at 1e-5 (None: not within `FEEDBACK_FRAMES`).
pub fn feedback_frames(
    runtime: &mut Runtime,
    direct: &lightfarm_client::DirectLight,
    method: Method,
) -> anyhow::Result<(Option<usize>, Option<usize>)> {
    let mut converged = IndirectLight::default();
    runtime.apply(
        method,
        Bounces::Converged { tolerance: 1e-5 },
        direct,
        &mut converged,
    )?;
    let norm: f64 = converged
        .radiance
        .iter()
        .flatten()
        .map(|&v| (v as f64).powi(2))
        .sum();
    runtime.reset_feedback();
    let mut out = IndirectLight::default();
    let (mut to_1pct, mut to_01pct) = (None, None);
    for frame in 1..=FEEDBACK_FRAMES {
        runtime.apply(method, Bounces::Feedback, direct, &mut out)?;
        let diff: f64 = out
            .radiance
            .iter()
            .flatten()
            .zip(converged.radiance.iter().flatten())
            .map(|(&a, &b)| (a as f64 - b as f64).powi(2))
            .sum();
        let rel = (diff / norm.max(f64::MIN_POSITIVE)).sqrt();
        if to_1pct.is_none() && rel <= 0.01 {
            to_1pct = Some(frame);
        }
        if rel <= 0.001 {
            to_01pct = Some(frame);
            break;
        }
    }
    runtime.reset_feedback();
    Ok((to_1pct, to_01pct))
}
