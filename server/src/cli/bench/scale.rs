//! `lightfarm bench --scale 20,80,320,1000`: how a level's costs grow with its size. For each
//! block count the level generator (`scripts/gen_level.py`, the same seeded grid levels as
//! `scenes/grid1000`, whose 1,000-block level it is at the default seed) writes a level; the
//! point then measures, in this process:
//! - the cold bake (no shape cache): seconds per engine stage plus the encoding, and the
//!   process's peak resident memory during it (Linux: the high-water mark is reset before the
//!   bake through `/proc/self/clear_refs` and read from `/proc/self/status` after the encoding;
//!   freed pages are handed back first, so earlier levels do not count);
//! - stored bytes per bundle section;
//! - frame times on one thread with every light of the level (texel-averaged direct light
//!   with adaptive shadow rays, as `frame-time --update` feeds it): the full DRT apply at one
//!   bounce and converged, side by side; relighting everything (direct light included) against
//!   moving one light and relighting by its change (`frame-time --update one-light`, one
//!   bounce), with the two ways' drift;
//! - error: DRT at all bounces (as `eval` computes it) against the reference path tracer at
//!   all bounces, on a sample of texels around [`ERROR_LIGHTS`] of the level's lights (those
//!   lights alone): the block and clutter texels within [`ERROR_RADIUS`] m of one of them,
//!   thinned to at most [`ERROR_TEXELS`] (block texels buried in clutter left out, as the
//!   bench's other points do). The reference's own noise is measured with a second
//!   seed, so the error can be read against it.
//!
//! With `--tile B` (`ScaleSettings::tile`) every level is copies of one B-block level
//! (`gen_level.py --tile`), and the lights moved one at a time are spread over the first
//! copy's instead of the whole list: every size moves the same lights through the same rooms,
//! so the moved lights' frames grow with the level's size alone.
//!
//! Units: seconds, bytes, milliseconds of wall time; errors are relative L2 over the sampled
//! texels' indirect radiance (every channel).
//!
//! Invariant: everything random is seeded (the generator's `--seed`, the reference's seed);
//! only times and memory are measured afresh.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use lightfarm_client::{
    direct_from_point_lights_adaptive, direct_scale, Bounces, Method, Occluders, ReachDirect,
    Runtime, DEFAULT_TOLERANCE,
};
use lightfarm_proto::bounces::BounceCount;
use lightfarm_proto::lights::LightSet;
use lightfarm_proto::result::{compare, ResultFile};
use lightfarm_proto::scene::Aabb;
use serde::{Deserialize, Serialize};

use super::measure::drop_buried;
use super::results::Machine;
use crate::bake::memory::release_freed;
use crate::bake::pipeline::encoding::encode_options;
use crate::bake::progress::NoProgress;
use crate::bake::reference::{reference_at, ReferenceSettings};
use crate::bake::scene::geometry::Geometry;
use crate::bake::{bake, BakeOptions};
use crate::cli::bake::load_scene;
use crate::cli::frame_time::time_frames;
use crate::cli::frame_update::{median, time_update, Ways, PATH_RADIUS};
use crate::evaluate::{evaluate, DIRECT_SAMPLES_PER_EDGE};

/// Lights of the level the error is measured with (spread evenly over its light list).
pub const ERROR_LIGHTS: usize = 4;
/// Metres around those lights whose texels are sampled for the error.
pub const ERROR_RADIUS: f64 = 6.0;
/// Most texels sampled for the error.
pub const ERROR_TEXELS: usize = 1500;

/// What `bench --scale` is asked for.
#[derive(Clone, Debug)]
pub struct ScaleArgs {
    /// Block counts, ascending.
    pub sizes: Vec<u32>,
    /// Python interpreter and the level generator.
    pub python: String,
    pub generator: PathBuf,
    pub settings: ScaleSettings,
    /// Scratch directory of the generated levels (the caller removes it; the generator's
    /// command writes any of them again, byte for byte).
    pub levels: PathBuf,
    pub command_line: String,
}

/// The settings every level of a sweep is generated, baked and measured with.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct ScaleSettings {
    pub seed: u64,
    pub texels_per_face: u32,
    pub rays_per_texel: u32,
    pub tolerance: f64,
    /// Paths per texel of the error's references.
    pub reference_rays: u32,
    /// Timed frames of each apply and of the one-light comparison (whose medians a first
    /// frame's setup, e.g. indexing the exact gather by change, would sway with fewer).
    pub frames: usize,
    /// Every level is copies of a level of this many blocks (`gen_level.py --tile`), and the
    /// lights moved are the first copy's (absent: levels of their own, lights spread over the
    /// whole list).
    #[serde(default)]
    pub tile: Option<u32>,
}

/// Median milliseconds of one way of relighting, direct light and operators apart.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize)]
pub struct WayMs {
    pub direct_ms: f64,
    pub operator_ms: f64,
    pub total_ms: f64,
}

/// One level size.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ScalePoint {
    pub blocks: usize,
    pub texels: usize,
    pub clutter: usize,
    pub lights: usize,
    /// Engine stages (name, seconds), then `encode`.
    pub stage_seconds: Vec<(String, f64)>,
    /// The stages and the encoding.
    pub bake_seconds: f64,
    /// The process's peak resident bytes during the bake and the encoding, and its resident
    /// bytes just before (what the bench itself holds).
    pub peak_rss_bytes: u64,
    pub rss_before_bytes: u64,
    /// Stored bytes per bundle section, in file order.
    pub sections: Vec<(String, u64)>,
    pub bundle_bytes: u64,
    /// Median ms of the full DRT apply (operators only) at one bounce and converged, and the
    /// one-bounce applications converging took.
    pub apply_one_ms: f64,
    pub apply_converged_ms: f64,
    pub converged_applications: u32,
    /// One light moving (one bounce): relighting everything against relighting by its change,
    /// both with their direct light; the two ways' drift (relative L2) after the last frame.
    pub relight_all: WayMs,
    pub one_light: WayMs,
    pub one_light_drift: f64,
    /// Texels the moved light reaches (median over frames).
    pub one_light_texels: usize,
    /// Up to [`MOVED_LIGHTS`] lights spread over the level's list, each moved alone and
    /// relit by its change (absent in sweeps from before it was measured).
    #[serde(default)]
    pub moved_lights: Option<MovedLights>,
    /// The same lights moved at all bounces (`Converged`), relit by their change (absent in
    /// sweeps from before it was measured).
    #[serde(default)]
    pub moved_lights_all: Option<MovedLights>,
    /// The same lights moved with `Feedback` by the change (all bounces over the next frames,
    /// module `delta_feedback` of the client), and the largest over them of the lag behind all
    /// bounces after the last frame and of the error once settled (relative L2); absent in
    /// sweeps from before it was measured.
    #[serde(default)]
    pub moved_lights_feedback: Option<MovedLights>,
    #[serde(default)]
    pub feedback_lag: Option<f64>,
    #[serde(default)]
    pub feedback_settled: Option<f64>,
    /// Texels sampled for the error, DRT all bounces against the reference at all bounces
    /// there, and the reference's noise (two seeds' relative L2 over √2).
    pub error_texels: usize,
    pub relative_l2: f64,
    pub reference_noise: f64,
    pub reference_seconds: f64,
}

/// Lights moved one at a time, each relit by its change (direct light included): how the cost
/// of moving a light spreads over a level's lights.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct MovedLights {
    pub lights: usize,
    /// Median and largest of the lights' median frame (ms).
    pub median_ms: f64,
    pub max_ms: f64,
    /// Median of the texels each light reaches.
    pub median_texels: usize,
    /// Median over the lights of their frame per texel reached (µs).
    pub us_per_texel: f64,
}

/// Lights [`MovedLights`] moves at most (spread over the level's light list).
pub const MOVED_LIGHTS: usize = 8;

/// Each moved light's frames, as a multiple of the sweep's `frames`: a moved light's frame is
/// about a millisecond, and its median over 20 frames swayed by 10-50% between two runs of a
/// tiled sweep (feedback's 0.99 and 1.51 ms at 1,000 blocks).
pub const MOVED_FRAMES_FACTOR: usize = 3;

/// A whole sweep, as `OUT/scale.json` holds it.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ScaleSweep {
    pub machine: Machine,
    pub command_line: String,
    pub wall_seconds: f64,
    #[serde(flatten)]
    pub settings: ScaleSettings,
    pub points: Vec<ScalePoint>,
}

/// The process's resident set now and its high-water mark, bytes (0 where `/proc` has none).
fn resident() -> (u64, u64) {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let field = |name: &str| {
        status
            .lines()
            .find(|l| l.starts_with(name))
            .and_then(|l| l.split_whitespace().nth(1))
            .and_then(|kb| kb.parse::<u64>().ok())
            .map_or(0, |kb| kb * 1024)
    };
    (field("VmRSS:"), field("VmHWM:"))
}

/// Resets the high-water mark to the current resident set (Linux ≥ 4.0; elsewhere the peak
/// then covers the process's whole life, which the report would overstate, never understate).
fn reset_peak() {
    let _ = std::fs::write("/proc/self/clear_refs", "5");
}

/// Writes the level of `blocks` blocks into `dir` with the generator.
fn generate(args: &ScaleArgs, blocks: u32, dir: &Path) -> anyhow::Result<()> {
    let output = Command::new(&args.python)
        .arg(&args.generator)
        .arg(dir)
        .args(["--blocks", &blocks.to_string()])
        .args(["--seed", &args.settings.seed.to_string()])
        .args(["--texels", &args.settings.texels_per_face.to_string()])
        .args(["--rays", &args.settings.rays_per_texel.to_string()])
        .args(["--tolerance", &args.settings.tolerance.to_string()])
        .args(["--dynamic", "0"])
        .args(
            args.settings
                .tile
                .iter()
                .flat_map(|t| ["--tile".to_string(), t.to_string()]),
        )
        .output()
        .map_err(|e| {
            anyhow::anyhow!(
                "cannot run {} {}: {e}",
                args.python,
                args.generator.display()
            )
        })?;
    anyhow::ensure!(
        output.status.success(),
        "{} failed: {}",
        args.generator.display(),
        String::from_utf8_lossy(&output.stderr)
    );
    Ok(())
}

/// `count` of `lights`, spread evenly over the list.
fn spread(lights: &LightSet, count: usize) -> LightSet {
    let n = lights.lights.len();
    let picked = (0..count.min(n)).map(|k| lights.lights[k * n / count.min(n)].clone());
    LightSet {
        lights: picked.collect(),
        poses: Vec::new(),
    }
}

/// [`MovedLights`] of each light's (median frame ms, texels reached); `None` without lights.
fn moved_lights(moved: &[(f64, usize)]) -> Option<MovedLights> {
    (!moved.is_empty()).then(|| MovedLights {
        lights: moved.len(),
        median_ms: median(moved.iter().map(|m| m.0).collect()),
        max_ms: moved.iter().map(|m| m.0).fold(0.0, f64::max),
        median_texels: median(moved.iter().map(|m| m.1 as f64).collect()) as usize,
        us_per_texel: median(
            moved
                .iter()
                .map(|&(ms, texels)| 1e3 * ms / texels.max(1) as f64)
                .collect(),
        ),
    })
}

/// Texels of `g` within `radius` of a light, every k-th so at most `most` remain.
fn texels_near(g: &Geometry, lights: &LightSet, radius: f64, most: usize) -> Vec<usize> {
    let near: Vec<usize> = (0..g.texels.len())
        .filter(|&x| {
            let p = g.texels[x].position;
            lights.lights.iter().any(|l| {
                let d = [0, 1, 2].map(|k| p[k] - l.position[k]);
                d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= radius * radius
            })
        })
        .collect();
    let step = near.len().div_ceil(most.max(1)).max(1);
    near.into_iter().step_by(step).collect()
}

/// Records of `all` that `sample` also holds (same surface and index).
fn matching(all: ResultFile, sample: &ResultFile) -> ResultFile {
    let keys: std::collections::HashSet<(&str, u32)> = sample
        .texels
        .iter()
        .map(|t| (t.surface.as_str(), t.index))
        .collect();
    ResultFile {
        texels: all
            .texels
            .into_iter()
            .filter(|t| keys.contains(&(t.surface.as_str(), t.index)))
            .collect(),
    }
}

/// Measures one level (module doc); `step` is told what runs.
fn measure_point(args: &ScaleArgs, blocks: u32, step: &dyn Fn(&str)) -> anyhow::Result<ScalePoint> {
    let dir = args.levels.join(format!("grid{blocks}"));
    step(&format!("{blocks} blocks: generate"));
    generate(args, blocks, &dir)?;
    let (scene, scene_dir) = load_scene(&dir.join("scene.json"))?;
    let lights = LightSet::from_json(&crate::cli::read_text(&dir.join("lights.json"))?)
        .map_err(|e| anyhow::anyhow!("{}: {e}", dir.join("lights.json").display()))?;

    step(&format!("{blocks} blocks: bake"));
    release_freed();
    reset_peak();
    let (rss_before_bytes, _) = resident();
    let options = BakeOptions {
        cache: None,
        full: false,
        transport: None,
    };
    let (bundle, report) = bake(&scene, &scene_dir, &options, &NoProgress)?;
    let start = Instant::now();
    let (bytes, encoded) = bundle.encode_with(&encode_options(&scene.settings, None));
    let encode_seconds = start.elapsed().as_secs_f64();
    let (_, peak_rss_bytes) = resident();
    drop(bundle);
    let mut stage_seconds = report.stage_seconds.clone();
    stage_seconds.push(("encode".to_string(), encode_seconds));
    let bake_seconds = stage_seconds.iter().map(|(_, s)| s).sum();
    let sections = encoded
        .sections
        .iter()
        .map(|(name, info)| (name.to_string(), info.stored_len))
        .collect();
    let decoded = lightfarm_client::decode(&bytes)?;
    drop(bytes);

    step(&format!("{blocks} blocks: frames"));
    let texels = decoded.layout.n_texels();
    let method = if decoded.drt.is_some() {
        Method::Drt
    } else {
        Method::Mrt
    };
    let mut runtime = Runtime::try_new(decoded.clone())?;
    let occluders = Occluders::from_layout(&decoded.layout);
    let client_lights = &lights.lights;
    // Every light lit where it reaches (the same bits as lighting every texel).
    let direct = match ReachDirect::new(&decoded, &occluders) {
        Some(mut reach) => reach.all_lights(
            &decoded.layout,
            &occluders,
            client_lights,
            DIRECT_SAMPLES_PER_EDGE,
            direct_scale(&decoded.layout, &occluders),
        ),
        None => direct_from_point_lights_adaptive(
            &decoded.layout,
            &occluders,
            client_lights,
            DIRECT_SAMPLES_PER_EDGE,
        ),
    };
    let converged = Bounces::Converged {
        tolerance: DEFAULT_TOLERANCE,
    };
    let applied = time_frames(
        &mut runtime,
        &direct,
        method,
        &[Bounces::One.into(), converged.into()],
        args.settings.frames,
        1,
    )?;
    let update = time_update(
        &mut runtime,
        &occluders,
        client_lights,
        0,
        method,
        Bounces::One,
        args.settings.frames,
        Ways::Both,
        PATH_RADIUS,
    )?;
    step(&format!(
        "{blocks} blocks: moving each of {MOVED_LIGHTS} lights"
    ));
    // Tiled, the first copy's lights (the generator lists them copy by copy).
    let n_lights = match args.settings.tile {
        Some(tile) => client_lights.len() / (blocks / tile.max(1)).max(1) as usize,
        None => client_lights.len(),
    };
    let (mut moved, mut moved_all, mut moved_feedback) = (Vec::new(), Vec::new(), Vec::new());
    let (mut feedback_lag, mut feedback_settled) = (None::<f64>, None::<f64>);
    for k in 0..MOVED_LIGHTS.min(n_lights) {
        for (bounces, times) in [
            (Bounces::One, &mut moved),
            (converged, &mut moved_all),
            (Bounces::Feedback, &mut moved_feedback),
        ] {
            let t = time_update(
                &mut runtime,
                &occluders,
                client_lights,
                k * n_lights / MOVED_LIGHTS.min(n_lights),
                method,
                bounces,
                MOVED_FRAMES_FACTOR * args.settings.frames,
                Ways::UpdateOnly,
                PATH_RADIUS,
            )?;
            times.push((t.update.total_ms, t.texels_reached));
            if let Some(s) = t.settling {
                feedback_lag = Some(feedback_lag.map_or(s.update_lag, |m| m.max(s.update_lag)));
                feedback_settled = Some(feedback_settled.map_or(s.settled, |m| m.max(s.settled)));
            }
        }
    }
    let (moved_lights, moved_lights_all, moved_lights_feedback) = (
        moved_lights(&moved),
        moved_lights(&moved_all),
        moved_lights(&moved_feedback),
    );
    drop(runtime);
    let way = |w: crate::cli::frame_update::Way| WayMs {
        direct_ms: w.direct_ms,
        operator_ms: w.operator_ms,
        total_ms: w.total_ms,
    };

    step(&format!("{blocks} blocks: error against the reference"));
    let error_lights = spread(&lights, ERROR_LIGHTS);
    let geometry = Geometry::from_scene(&scene, &scene_dir)?;
    let sample = texels_near(&geometry, &error_lights, ERROR_RADIUS, ERROR_TEXELS);
    let start = Instant::now();
    let reference_of = |seed: u64| {
        let settings = ReferenceSettings::new(args.settings.reference_rays, BounceCount::All, seed);
        reference_at(
            &geometry,
            &error_lights.lights,
            &settings,
            sample.clone(),
            &|_| {},
        )
    };
    let reference = reference_of(args.settings.seed);
    let reference_seconds = start.elapsed().as_secs_f64();
    let second = reference_of(args.settings.seed + 1);
    let mut ours = matching(
        evaluate(decoded, &error_lights, method, converged)?,
        &reference,
    );
    let boxes: Vec<Aabb> = scene.clutter.iter().filter_map(|c| c.box_).collect();
    drop_buried(&mut ours, &boxes);
    let error = compare(&ours, &reference);
    anyhow::ensure!(
        error.matched > 0,
        "{blocks} blocks: no sampled texel to compare"
    );
    Ok(ScalePoint {
        blocks: scene.blocks.len(),
        texels,
        clutter: scene.clutter.len(),
        lights: lights.lights.len(),
        stage_seconds,
        bake_seconds,
        peak_rss_bytes,
        rss_before_bytes,
        sections,
        bundle_bytes: encoded.total_bytes,
        apply_one_ms: applied[0].median_ms,
        apply_converged_ms: applied[1].median_ms,
        converged_applications: applied[1].bounces,
        relight_all: way(update.full),
        one_light: way(update.update),
        one_light_drift: update.drift,
        one_light_texels: update.texels_reached,
        moved_lights,
        moved_lights_all,
        moved_lights_feedback,
        feedback_lag,
        feedback_settled,
        error_texels: error.matched,
        relative_l2: error.relative_l2,
        reference_noise: compare(&second, &reference).relative_l2 / std::f64::consts::SQRT_2,
        reference_seconds,
    })
}

/// Runs the sweep (module doc); `step` is told what runs.
pub fn measure_scale(args: &ScaleArgs, step: &dyn Fn(&str)) -> anyhow::Result<ScaleSweep> {
    anyhow::ensure!(!args.sizes.is_empty(), "--scale: no block count given");
    anyhow::ensure!(
        args.sizes.iter().all(|&n| n >= 1),
        "--scale: a level needs at least one block"
    );
    if let Some(tile) = args.settings.tile {
        anyhow::ensure!(
            tile >= 1 && args.sizes.iter().all(|&n| n % tile == 0),
            "--tile {tile}: every --scale count must be a positive multiple of it"
        );
    }
    let started = Instant::now();
    let points = args
        .sizes
        .iter()
        .map(|&blocks| measure_point(args, blocks, step))
        .collect::<anyhow::Result<_>>()?;
    Ok(ScaleSweep {
        machine: Machine::detect(),
        command_line: args.command_line.clone(),
        wall_seconds: started.elapsed().as_secs_f64(),
        settings: args.settings,
        points,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moved_lights_take_medians_and_the_slowest() {
        assert!(moved_lights(&[]).is_none());
        let m = moved_lights(&[(1.0, 1000), (3.0, 1000), (2.0, 4000)]).expect("three lights");
        assert_eq!(m.lights, 3);
        assert_eq!((m.median_ms, m.max_ms), (2.0, 3.0));
        assert_eq!(m.median_texels, 1000);
        // 1.0, 3.0 and 0.5 µs per texel.
        assert_eq!(m.us_per_texel, 1.0);
    }
}
