//! `lightfarm frame-time … --bounces …,warm` (or `feedback`): the bounce modes while a light
//! moves, where a mode that keeps state between frames (`Warm`, `Feedback`) meets its hardest
//! case.
//!
//! Light `--light K` (default 0) moves on a horizontal circle of radius [`MOVING_RADIUS`] m
//! around its position, one turn every [`MOVING_FRAMES`] frames: 5 cm a frame, a torch carried
//! at a run at 60 Hz. Every frame's direct light (every light, texel-averaged as `eval` feeds
//! the operators) is computed before timing; each mode runs on its own copy of the runtime, so
//! one mode's state never helps another, and the modes take turns frame by frame so the
//! machine's noise falls on all alike. Each mode first relights frame 0 `SETTLE_FRAMES` times
//! untimed (a level that has been on screen with the light still, so Feedback has settled),
//! then the frames are timed.
//!
//! Per mode it reports the median frame (ms, one thread), the mean one-bounce applications per
//! frame, and the largest relative L2 (over texels and channels) of any frame's indirect light
//! against `Converged` at 1e-5 for that frame's light: Feedback's lag shows there, Warm's and
//! Converged's stay within their tolerance.

use std::time::Instant;

use lightfarm_client::{
    relative_l2, Bounces, DirectLight, IndirectLight, Method, Occluders, Runtime,
};
use lightfarm_proto::lights::LightSet;

use crate::evaluate::operator_direct;

/// Radius of the moving light's path, metres.
pub const MOVING_RADIUS: f64 = 0.5;
/// Frames of one turn of the path.
pub const MOVING_FRAMES: usize = 60;
/// Untimed frames at the path's start before the timed ones, so feedback has settled.
const SETTLE_FRAMES: usize = 50;

/// What one mode did while the light moved.
#[derive(Clone, Copy, Debug)]
pub struct MovingTimes {
    pub median_ms: f64,
    pub mean_applications: f64,
    /// Largest relative L2 against `Converged` at 1e-5 over the frames.
    pub worst_rel_l2: f64,
}

/// Position of the moving light at `frame` on its path around `centre`.
pub fn path_position(centre: [f64; 3], frame: usize) -> [f64; 3] {
    let a = std::f64::consts::TAU * frame as f64 / MOVING_FRAMES as f64;
    [
        centre[0] + MOVING_RADIUS * a.cos(),
        centre[1],
        centre[2] + MOVING_RADIUS * a.sin(),
    ]
}

/// Times `frames` frames of light `moved` moving (module doc) under each of `modes`, one
/// thread; one result per mode, in order. `runtime` makes the yardstick (its feedback and
/// warm state are then reset); each mode runs on a copy.
pub fn time_moving(
    runtime: &mut Runtime,
    occluders: &Occluders,
    lights: &LightSet,
    moved: usize,
    method: Method,
    modes: &[Bounces],
    frames: usize,
) -> anyhow::Result<Vec<MovingTimes>> {
    anyhow::ensure!(
        moved < lights.lights.len(),
        "--light {moved}: the light set has {} lights",
        lights.lights.len()
    );
    let centre = lights.lights[moved].position;
    let mut set = lights.clone();
    let direct: Vec<DirectLight> = (0..=frames)
        .map(|frame| {
            set.lights[moved].position = path_position(centre, frame);
            operator_direct(runtime.bundle(), occluders, &set)
        })
        .collect();
    // Every frame's all-bounce light, the yardstick.
    let truth = direct
        .iter()
        .map(|d| {
            let mut out = IndirectLight::default();
            runtime
                .apply(method, Bounces::Converged { tolerance: 1e-5 }, d, &mut out)
                .map(|_| out)
        })
        .collect::<Result<Vec<_>, _>>()?;
    runtime.reset_feedback();
    let mut runtimes: Vec<Runtime> = modes.iter().map(|_| runtime.clone()).collect();
    let mut outs = vec![IndirectLight::default(); modes.len()];
    for ((rt, out), &mode) in runtimes.iter_mut().zip(&mut outs).zip(modes) {
        rt.reset_feedback();
        rt.set_parallel(false);
        for _ in 0..SETTLE_FRAMES {
            rt.apply(method, mode, &direct[0], out)?;
        }
    }
    let mut times = vec![Vec::with_capacity(frames); modes.len()];
    let mut applications = vec![0u64; modes.len()];
    let mut worst = vec![0.0f64; modes.len()];
    for (frame, d) in direct.iter().enumerate().skip(1) {
        for (k, &mode) in modes.iter().enumerate() {
            let start = Instant::now();
            let applied = runtimes[k].apply(method, mode, d, &mut outs[k])?;
            times[k].push(start.elapsed().as_secs_f64() * 1e3);
            applications[k] += applied.bounces as u64;
            let err = relative_l2(&outs[k].radiance, &truth[frame].radiance);
            worst[k] = worst[k].max(err);
        }
    }
    Ok(times
        .into_iter()
        .zip(applications)
        .zip(worst)
        .map(|((mut t, apps), worst_rel_l2)| {
            t.sort_by(f64::total_cmp);
            MovingTimes {
                median_ms: t[t.len() / 2],
                mean_applications: apps as f64 / frames as f64,
                worst_rel_l2,
            }
        })
        .collect())
}
