//! `lightfarm bench [--quick] [--bounces N|all] --out DIR`: speed against error. Sweeps scenes ×
//! methods × bake settings, measures each point (`measure`), the reference path tracer at
//! equal error (`equal_error`) and ray throughput against Embree (`throughput`), and
//! writes `results.json`, plots (`plots`) and BENCHMARKS.md-ready markdown
//! (`report`).
//!
//! Yardsticks: every point is measured against references at `--bounces` (default all bounces,
//! what other bakers converge to) with the runtime at the matching bounce mode, and — unless
//! that count is already one — again against one-bounce references with the runtime at one
//! bounce (the papers' yardstick), as rows of their own. The path tracer at equal error runs at
//! each yardstick's bounce count.
//!
//! Owns the order of work.
//!
//! # Layout
//! - [`plan`](mod@plan): the two presets (what is swept, and what is left out and why).
//! - [`lights`]: seeded random light sets; [`reference_cache`]: references on disk by content.
//! - [`measure`]: one bake setting, every method's bytes, error and apply time.
//! - [`equal_error`]: the reference path tracer's error/time model at equal error.
//! - [`throughput`]: our tracer against Embree on the same rays.
//! - [`results`]: what a run measured (`results.json`); [`pareto`], [`plots`] and [`report`]
//!   read it.
//! - [`scale`]: `--scale`, the sweep over level sizes (`scale.json`, or `scale_tiled.json`
//!   with `--tile`); [`scale_report`] draws its figure and writes its sections of the markdown.
//!
//! Invariants:
//! - Everything random is seeded (`--seed`): light sets, the reference, the exported rays.
//! - References are read from / written to the content-keyed cache (`reference_cache`);
//!   only the timings of bakes, frames and tracing are measured afresh on every run.
//! - The engine and client run in-process; only Embree runs in a child process (Python).

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use lightfarm_proto::lights::LightSet;
use lightfarm_proto::result::{compare, ResultFile};
use lightfarm_proto::scene::{Aabb, Scene};

pub mod equal_error;
pub mod lights;
pub mod measure;
pub mod pareto;
pub mod plan;
pub mod plots;
pub mod reference_cache;
pub mod report;
pub mod results;
pub mod scale;
pub mod scale_report;
pub mod throughput;

pub use plan::{plan, Preset, ScenePlan, SweepPlan};
pub use results::{BenchResults, BruteForce, Machine, Row};

use super::bake::load_scene;
use super::write_json;
use crate::bake::reference::{reference, ReferenceSettings};
use crate::bake::scene::geometry::Geometry;
use equal_error::{BruteForceFit, BruteForceRun};
use lightfarm_proto::bounces::BounceCount;
use lights::random_light_set;
use measure::{
    bounces_label, drop_buried, measure_setting, BakeSetting, BenchPoint, BenchScene, Yardstick,
};
use reference_cache::{mesh_bytes, reference_key, CachedReference, ReferenceCache};
use throughput::{measure_throughput, Throughput};

/// Arguments of `bench`.
pub struct BenchArgs {
    pub preset: Preset,
    /// Output directory: results.json and the plots.
    pub out: PathBuf,
    /// Where the markdown goes (default OUT/BENCHMARKS.md).
    pub markdown: Option<PathBuf>,
    /// Reference cache directory.
    pub reference_cache: PathBuf,
    /// Directory holding the example scenes (`<name>/scene.json`).
    pub scenes: PathBuf,
    pub seed: u64,
    /// Python interpreter and script for Embree; None skips Embree.
    pub embree: Option<(String, PathBuf)>,
    /// The command line, for the report.
    pub command_line: String,
    /// Only rewrite the plots and markdown from OUT/results.json (no measuring).
    pub replot: bool,
    /// Bounces of the main yardstick (references, runtime mode, brute force).
    pub bounces: BounceCount,
    /// `--scale`: measure only the sweep over these level sizes (blocks), into OUT/scale.json.
    pub scale: Option<Vec<u32>>,
    /// `--tile`: the sweep's levels are copies of a level of this many blocks, into
    /// OUT/scale_tiled.json ([`scale`]).
    pub tile: Option<u32>,
    /// `--throughput`: measure only the ray throughput against Embree, into OUT/results.json's
    /// `throughput` (its other figures kept).
    pub throughput_only: bool,
    /// Python interpreter and the level generator of `--scale` (Embree's interpreter is in
    /// `embree`).
    pub python: String,
    pub generator: PathBuf,
}

fn load_bench_scene(
    scenes_dir: &Path,
    scene_plan: &ScenePlan,
    light_sets: usize,
    seed: u64,
) -> anyhow::Result<BenchScene> {
    let (scene, dir) = load_scene(&scenes_dir.join(&scene_plan.name).join("scene.json"))?;
    let light_sets: Vec<LightSet> = (0..light_sets as u64)
        .map(|k| random_light_set(&scene, seed, k))
        .collect();
    let methods = scene_plan
        .methods
        .iter()
        .copied()
        .filter(|m| m.applies_to(&scene))
        .collect();
    Ok(BenchScene {
        name: scene_plan.name.clone(),
        scene,
        dir,
        light_sets,
        methods,
    })
}

/// Seconds of reference runs read from the cache in this run (what a cold run adds).
static SECONDS_FROM_CACHE: std::sync::Mutex<f64> = std::sync::Mutex::new(0.0);

/// The reference of `lights` at `rays` and `bounces` (cached by content).
fn cached_reference(
    cache: &ReferenceCache,
    scene: &Scene,
    dir: &Path,
    lights: &LightSet,
    rays: u32,
    seed: u64,
    bounces: BounceCount,
) -> anyhow::Result<CachedReference> {
    let key = reference_key(scene, &mesh_bytes(scene, dir)?, lights, rays, seed, bounces);
    if let Some(hit) = cache.get(&key) {
        *SECONDS_FROM_CACHE.lock().expect("not poisoned") += hit.seconds;
        return Ok(hit);
    }
    let start = Instant::now();
    let mut geometry = Geometry::from_scene(scene, dir)?;
    geometry.add_posed_dynamic(scene, dir, &lights.poses)?;
    let settings = ReferenceSettings::new(rays, bounces, seed);
    let result = reference(&geometry, &lights.lights, &settings, &|_| {});
    let entry = CachedReference {
        seconds: start.elapsed().as_secs_f64(),
        result,
    };
    cache.put(&key, &entry)?;
    Ok(entry)
}

/// The references of one scene at one texel count and bounce count, and the fit of the path
/// tracer at equal error against them.
struct MeasuredYardstick {
    bounces: BounceCount,
    references: Vec<ResultFile>,
    fit: BruteForceFit,
    brute_force: BruteForce,
}

impl MeasuredYardstick {
    /// What a bake setting is measured against: the bounce count and its references.
    fn yardstick(&self) -> Yardstick<'_> {
        Yardstick {
            bounces: self.bounces,
            references: &self.references,
        }
    }
}

/// The bench's progress: an indicatif bar on a terminal, one timestamped line per step
/// otherwise (CI logs).
struct BenchProgress {
    bar: ProgressBar,
    terminal: bool,
    started: Instant,
}

impl BenchProgress {
    fn new(total: u64) -> BenchProgress {
        let bar = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr());
        bar.set_style(
            ProgressStyle::with_template(
                "{msg:>40} [{bar:30}] {pos}/{len} {elapsed_precise} ({eta})",
            )
            .expect("a valid template")
            .progress_chars("=> "),
        );
        BenchProgress {
            bar,
            terminal: std::io::stderr().is_terminal(),
            started: Instant::now(),
        }
    }

    fn message(&self, message: &str) {
        if !self.terminal {
            eprintln!(
                "[{:7.1}s {}/{}] {message}",
                self.started.elapsed().as_secs_f64(),
                self.bar.position(),
                self.bar.length().unwrap_or(0)
            );
        }
        self.bar.set_message(message.to_string());
    }

    fn inc(&self) {
        self.bar.inc(1);
    }

    fn finish(&self) {
        self.bar.finish();
    }
}

fn texel_counts(settings: &[BakeSetting]) -> Vec<u32> {
    let mut out: Vec<u32> = settings.iter().map(|s| s.texels_per_face).collect();
    out.sort_unstable();
    out.dedup();
    out
}

/// The high-ray references of every light set of `bench` at `scene_t`'s texel count and
/// `bounces`, and the path tracer's ladder at the same bounce count fitted against them.
fn measure_yardstick(
    cache: &ReferenceCache,
    bench: &BenchScene,
    scene_t: &Scene,
    plan: &SweepPlan,
    bounces: BounceCount,
    bar: &BenchProgress,
) -> anyhow::Result<MeasuredYardstick> {
    let boxes: Vec<Aabb> = bench.scene.clutter.iter().filter_map(|c| c.box_).collect();
    let t = scene_t.settings.texels_per_face;
    let seed = scene_t.settings.seed;
    let label = bounces_label(bounces);
    let mut references: Vec<ResultFile> = Vec::new();
    let mut reference_seconds = 0.0;
    let mut runs = Vec::new();
    for (k, lights) in bench.light_sets.iter().enumerate() {
        bar.message(&format!("{} T{t} reference {k}, {label}", bench.name));
        let high = cached_reference(
            cache,
            scene_t,
            &bench.dir,
            lights,
            plan.reference_rays,
            seed,
            bounces,
        )?;
        bar.inc();
        reference_seconds += high.seconds / bench.light_sets.len() as f64;
        for &rays in &plan.brute_force_rays {
            bar.message(&format!(
                "{} T{t} brute force {rays} rays, set {k}, {label}",
                bench.name
            ));
            // An independent seed, so the two estimators' errors add in quadrature.
            let low = cached_reference(
                cache,
                scene_t,
                &bench.dir,
                lights,
                rays,
                seed.wrapping_add(1),
                bounces,
            )?;
            let mut low_result = low.result;
            drop_buried(&mut low_result, &boxes);
            let c = compare(&low_result, &high.result);
            runs.push(BruteForceRun {
                rays,
                error: c.relative_l2,
                seconds: low.seconds,
            });
            bar.inc();
        }
        references.push(high.result);
    }
    let fit = BruteForceFit::fit(&runs, plan.reference_rays)
        .ok_or_else(|| anyhow::anyhow!("the brute-force fit needs two ray counts"))?;
    let brute_force = BruteForce {
        scene: bench.name.clone(),
        texels_per_face: t,
        bounces,
        runs: runs.iter().map(|r| (r.rays, r.error, r.seconds)).collect(),
        scale: fit.scale,
        exponent: fit.exponent,
        seconds_fixed: fit.seconds_fixed,
        seconds_per_ray: fit.seconds_per_ray,
        noise_floor: fit.noise_floor(),
        reference_seconds,
        texels: references[0].texels.len(),
    };
    Ok(MeasuredYardstick {
        bounces,
        references,
        fit,
        brute_force,
    })
}

/// The row of a measured point: the path tracer at its error, from the fit of its own bounce
/// count.
fn row_of(point: BenchPoint, yardsticks: &[MeasuredYardstick]) -> Row {
    let fit = yardsticks
        .iter()
        .find(|y| y.bounces == point.bounces)
        .map(|y| y.fit);
    let brute_force_rays = fit.and_then(|f| f.rays_for_error(point.relative_l2));
    Row {
        brute_force_seconds: fit
            .zip(brute_force_rays)
            .map(|(f, r)| f.seconds_for_rays(r)),
        brute_force_rays,
        point,
    }
}

pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    if args.replot {
        return write_outputs(&args);
    }
    if let Some(sizes) = &args.scale {
        return run_scale(&args, sizes);
    }
    if args.throughput_only {
        return run_throughput(&args);
    }
    let started = Instant::now();
    let plan = plan(args.preset, args.bounces);
    std::fs::create_dir_all(&args.out)?;
    let cache = ReferenceCache::open(&args.reference_cache)?;
    let scenes: Vec<BenchScene> = plan
        .scenes
        .iter()
        .map(|p| load_bench_scene(&args.scenes, p, plan.light_sets, args.seed))
        .collect::<anyhow::Result<_>>()?;
    let bounce_counts = plan.yardsticks();
    let reference_jobs: usize = plan
        .scenes
        .iter()
        .map(|p| {
            texel_counts(&p.settings).len()
                * bounce_counts.len()
                * plan.light_sets
                * (1 + plan.brute_force_rays.len())
        })
        .sum();
    let setting_jobs: usize = plan.scenes.iter().map(|p| p.settings.len()).sum();
    let bar = BenchProgress::new((reference_jobs + setting_jobs + 1) as u64);
    let mut rows = Vec::new();
    let mut brute_force = Vec::new();
    for (scene_plan, bench) in plan.scenes.iter().zip(&scenes) {
        for t in texel_counts(&scene_plan.settings) {
            let mut scene_t = bench.scene.clone();
            scene_t.settings.texels_per_face = t;
            let measured: Vec<MeasuredYardstick> = bounce_counts
                .iter()
                .map(|&b| measure_yardstick(&cache, bench, &scene_t, &plan, b, &bar))
                .collect::<anyhow::Result<_>>()?;
            brute_force.extend(measured.iter().map(|y| y.brute_force.clone()));
            let yardsticks: Vec<Yardstick> =
                measured.iter().map(MeasuredYardstick::yardstick).collect();
            for setting in scene_plan
                .settings
                .iter()
                .filter(|s| s.texels_per_face == t)
            {
                let points = measure_setting(bench, setting, &yardsticks, plan.frames, &|m| {
                    bar.message(m)
                })?;
                bar.inc();
                rows.extend(points.into_iter().map(|p| row_of(p, &measured)));
            }
        }
    }
    bar.message("ray throughput (ours, Embree)");
    let throughput = match scenes.iter().find(|s| s.name == plan.throughput_scene) {
        Some(bench) => Some(throughput_of(bench, &plan, &args)?),
        None => {
            let bench = geometry_only(&args.scenes, &plan.throughput_scene)?;
            Some(throughput_of(&bench, &plan, &args)?)
        }
    };
    bar.inc();
    bar.finish();
    let results = BenchResults {
        plan,
        machine: Machine::detect(),
        command_line: args.command_line.clone(),
        wall_seconds: started.elapsed().as_secs_f64(),
        reference_seconds_from_cache: *SECONDS_FROM_CACHE.lock().expect("not poisoned"),
        rows,
        brute_force,
        throughput,
    };
    write_json(&args.out.join("results.json"), &results)?;
    write_outputs(&args)
}

/// `--scale`: the sweep over level sizes ([`scale`]), into OUT/scale.json; the markdown is
/// then rewritten with it (and with OUT/results.json's sweep when there is one).
fn run_scale(args: &BenchArgs, sizes: &[u32]) -> anyhow::Result<()> {
    std::fs::create_dir_all(&args.out)?;
    let quick = args.preset == Preset::Quick;
    let scale_args = scale::ScaleArgs {
        sizes: sizes.to_vec(),
        python: args.python.clone(),
        generator: args.generator.clone(),
        settings: scale::ScaleSettings {
            seed: args.seed,
            texels_per_face: if quick { 4 } else { 8 },
            rays_per_texel: if quick { 128 } else { 1024 },
            tolerance: 0.001,
            reference_rays: if quick { 256 } else { 1024 },
            frames: if quick { 8 } else { 20 },
            tile: args.tile,
        },
        levels: std::env::temp_dir().join(format!("lightfarm-bench-levels-{}", std::process::id())),
        command_line: args.command_line.clone(),
    };
    let bar = BenchProgress::new(sizes.len() as u64 * 4);
    let sweep = scale::measure_scale(&scale_args, &|step| {
        bar.message(step);
        bar.inc();
    });
    bar.finish();
    let _ = std::fs::remove_dir_all(&scale_args.levels);
    let sweep = sweep?;
    let name = if args.tile.is_some() {
        "scale_tiled.json"
    } else {
        "scale.json"
    };
    write_json(&args.out.join(name), &sweep)?;
    write_outputs(args)
}

/// `--throughput`: the ray throughput alone, on the scene and ray count of OUT/results.json's
/// plan, replaces that file's `throughput` (marked with this command line, as the report says);
/// every other figure is kept, then the markdown is rewritten.
fn run_throughput(args: &BenchArgs) -> anyhow::Result<()> {
    let path = args.out.join("results.json");
    anyhow::ensure!(
        path.exists(),
        "{}: no results.json; run `lightfarm bench` first",
        args.out.display()
    );
    let mut results: BenchResults = serde_json::from_str(&super::read_text(&path)?)
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let bench = geometry_only(&args.scenes, &results.plan.throughput_scene)?;
    let mut measured = throughput_of(&bench, &results.plan, args)?;
    measured.measured_by = Some(args.command_line.clone());
    results.throughput = Some(measured);
    write_json(&path, &results)?;
    write_outputs(args)
}

/// Plots and markdown from OUT/results.json and OUT/scale.json (either may be missing, not
/// both).
fn write_outputs(args: &BenchArgs) -> anyhow::Result<()> {
    let markdown_path = args
        .markdown
        .clone()
        .unwrap_or_else(|| args.out.join("BENCHMARKS.md"));
    let read = |name: &str| -> anyhow::Result<Option<String>> {
        let path = args.out.join(name);
        if path.exists() {
            Ok(Some(super::read_text(&path)?))
        } else {
            Ok(None)
        }
    };
    let parse =
        |name: &str, text: &str| anyhow::anyhow!("{}: {text}", args.out.join(name).display());
    let results: Option<BenchResults> = read("results.json")?
        .map(|t| serde_json::from_str(&t).map_err(|e| parse("results.json", &e.to_string())))
        .transpose()?;
    let sweep_in = |name: &str| -> anyhow::Result<Option<scale::ScaleSweep>> {
        read(name)?
            .map(|t| serde_json::from_str(&t).map_err(|e| parse(name, &e.to_string())))
            .transpose()
    };
    let sweep = sweep_in("scale.json")?;
    let tiled = sweep_in("scale_tiled.json")?;
    anyhow::ensure!(
        results.is_some() || sweep.is_some() || tiled.is_some(),
        "{}: none of results.json, scale.json, scale_tiled.json; run `lightfarm bench` (or \
         `--scale`) first",
        args.out.display()
    );
    let mut markdown = match &results {
        Some(results) => {
            let plots = plots::write_plots(results, &args.out)?;
            report::markdown(results, &plots, &markdown_path)
        }
        None => report::header(),
    };
    if let Some(sweep) = &sweep {
        let (_, png) = scale_report::write_scale_plot(sweep, &args.out)?;
        let base = markdown_path.parent().unwrap_or(Path::new("."));
        if !markdown.ends_with("\n\n") {
            markdown.push('\n');
        }
        markdown.push_str(&scale_report::scale_markdown(sweep, &png, base));
    }
    if let Some(tiled) = &tiled {
        if !markdown.ends_with("\n\n") {
            markdown.push('\n');
        }
        markdown.push_str(&scale_report::tiled_markdown(tiled));
    }
    super::write_atomic(&markdown_path, markdown.as_bytes())?;
    if let Some(results) = &results {
        crate::say!("{}", report::summary(results));
    }
    crate::say!("markdown: {}", markdown_path.display());
    Ok(())
}

/// Scene `name` of `scenes_dir` with no light sets or methods: only its geometry is measured
/// (the ray throughput's scene when the sweep does not light it).
fn geometry_only(scenes_dir: &Path, name: &str) -> anyhow::Result<BenchScene> {
    let (scene, dir) = load_scene(&scenes_dir.join(name).join("scene.json"))?;
    Ok(BenchScene {
        name: name.to_string(),
        scene,
        dir,
        light_sets: vec![],
        methods: vec![],
    })
}

fn throughput_of(
    bench: &BenchScene,
    plan: &SweepPlan,
    args: &BenchArgs,
) -> anyhow::Result<Throughput> {
    let geometry = Geometry::from_scene(&bench.scene, &bench.dir)?;
    let embree = args
        .embree
        .as_ref()
        .map(|(python, script)| (python.as_str(), script.as_path()));
    // The exchange files (tens of MB of rays) live in a scratch directory, not in --out.
    let scratch =
        std::env::temp_dir().join(format!("lightfarm-bench-embree-{}", std::process::id()));
    let measured = measure_throughput(
        &bench.name,
        &geometry,
        plan.throughput_rays,
        args.seed,
        &scratch,
        embree,
    );
    let _ = std::fs::remove_dir_all(&scratch);
    measured
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfarm_proto::scene::BundleCodec;
    use measure::BenchMethod;

    #[test]
    fn yardsticks_follow_the_bounce_count() {
        use BounceCount::{All, Fixed};
        assert_eq!(plan(Preset::Quick, All).yardsticks(), vec![All, Fixed(1)]);
        assert_eq!(plan(Preset::Full, All).yardsticks(), vec![All, Fixed(1)]);
        assert_eq!(plan(Preset::Quick, Fixed(1)).yardsticks(), vec![Fixed(1)]);
        assert_eq!(
            plan(Preset::Full, Fixed(3)).yardsticks(),
            vec![Fixed(3), Fixed(1)]
        );
        // Without one-bounce rows only the main count is measured.
        let mut only_main = plan(Preset::Quick, All);
        only_main.one_bounce_rows = false;
        assert_eq!(only_main.yardsticks(), vec![All]);
    }

    fn point(method: BenchMethod, bounces: BounceCount, l2: f64, apply_ms: f64) -> BenchPoint {
        BenchPoint {
            scene: "cornell".into(),
            method,
            texels_per_face: 8,
            rays_per_texel: 256,
            tolerance: 1e-3,
            codec: "auto".into(),
            rank_max: 12,
            rank_mean: 7.5,
            bake_seconds: 3.0,
            bundle_bytes: 40_960,
            apply_ms,
            relative_l2: l2,
            p95: 2.0 * l2,
            relative_l2_per_set: vec![l2],
            bounces,
            iterations: if bounces == BounceCount::ONE { 1 } else { 14 },
        }
    }

    fn fit(scale: f64) -> BruteForceFit {
        BruteForceFit {
            scale,
            exponent: 0.5,
            reference_rays: 1024,
            seconds_fixed: 0.5,
            seconds_per_ray: 0.01,
        }
    }

    fn yardstick(bounces: BounceCount, scale: f64) -> MeasuredYardstick {
        let f = fit(scale);
        MeasuredYardstick {
            bounces,
            references: vec![],
            fit: f,
            brute_force: BruteForce {
                scene: "cornell".into(),
                texels_per_face: 8,
                bounces,
                runs: vec![(16, f.error_at(16.0), 0.66), (64, f.error_at(64.0), 1.14)],
                scale,
                exponent: 0.5,
                seconds_fixed: 0.5,
                seconds_per_ray: 0.01,
                noise_floor: f.noise_floor(),
                reference_seconds: 10.74,
                texels: 600,
            },
        }
    }

    /// A point's path-tracer cost comes from the fit of its own bounce count: the same error
    /// costs more rays against a noisier (all-bounce) path tracer.
    #[test]
    fn rows_take_the_path_tracer_of_their_own_bounce_count() {
        use BounceCount::All;
        // a = 0.4 at all bounces, 0.2 at one; R = 1024 (noise floors 0.0125 and 0.00625).
        let yardsticks = [yardstick(All, 0.4), yardstick(BounceCount::ONE, 0.2)];
        let all = row_of(point(BenchMethod::Full, All, 0.05, 0.5), &yardsticks);
        let one = row_of(
            point(BenchMethod::Full, BounceCount::ONE, 0.05, 0.5),
            &yardsticks,
        );
        // r = a² / (e² − a²/R): 0.16 / (0.0025 − 0.16/1024) = 68.27; 0.04 / (0.0025 − 0.04/1024).
        let r_all = 0.16 / (0.0025 - 0.16 / 1024.0);
        let r_one = 0.04 / (0.0025 - 0.04 / 1024.0);
        assert!((all.brute_force_rays.unwrap() - r_all).abs() < 1e-9);
        assert!((one.brute_force_rays.unwrap() - r_one).abs() < 1e-9);
        assert!((all.brute_force_seconds.unwrap() - (0.5 + 0.01 * r_all)).abs() < 1e-12);
        // One frame of 0.5 ms against 1.1827 s of path tracing: 2365× cheaper.
        let cheaper = all.times_cheaper_than_path_tracing().unwrap();
        assert!((cheaper - (0.5 + 0.01 * r_all) / 0.5e-3).abs() < 1e-6);
        assert!((cheaper - 2365.3).abs() < 0.1, "{cheaper}");
        // Below the all-bounce noise floor (0.0125) there is no path-tracer cost.
        let fine = row_of(point(BenchMethod::Full, All, 0.01, 0.5), &yardsticks);
        assert_eq!(fine.brute_force_rays, None);
        assert_eq!(fine.times_cheaper_than_path_tracing(), None);
        // A bounce count without a yardstick gets none either.
        let three = row_of(
            point(BenchMethod::Full, BounceCount::Fixed(3), 0.05, 0.5),
            &yardsticks,
        );
        assert_eq!(three.brute_force_seconds, None);
    }

    /// Results written before bounces existed were one-bounce and read as such.
    #[test]
    fn results_without_bounce_fields_read_as_one_bounce() {
        let row = serde_json::json!({
            "scene": "cornell", "method": "drt", "texels_per_face": 8, "rays_per_texel": 64,
            "tolerance": 0.001, "codec": "auto", "rank_max": 3, "rank_mean": 2.0,
            "bake_seconds": 1.0, "bundle_bytes": 100, "apply_ms": 0.25, "relative_l2": 0.1,
            "p95": 0.2, "relative_l2_per_set": [0.1],
            "brute_force_rays": 12.0, "brute_force_seconds": 0.75
        });
        let row: Row = serde_json::from_value(row).unwrap();
        assert_eq!(row.point.bounces, BounceCount::ONE);
        assert_eq!(row.point.iterations, 1);
        assert_eq!(row.times_cheaper_than_path_tracing(), Some(3000.0));
        let mut old_plan = serde_json::to_value(plan(Preset::Quick, BounceCount::All)).unwrap();
        let fields = old_plan.as_object_mut().unwrap();
        fields.remove("bounces");
        fields.remove("one_bounce_rows");
        let old_plan: SweepPlan = serde_json::from_value(old_plan).unwrap();
        assert_eq!(old_plan.yardsticks(), vec![BounceCount::ONE]);
    }

    fn results_with_both_yardsticks() -> BenchResults {
        use BounceCount::All;
        let yardsticks = [yardstick(All, 0.4), yardstick(BounceCount::ONE, 0.2)];
        let rows = [
            point(BenchMethod::Full, All, 0.05, 0.5),
            point(BenchMethod::Full, BounceCount::ONE, 0.03, 0.04),
            point(BenchMethod::Drt, All, 0.08, 0.2),
            point(BenchMethod::Drt, BounceCount::ONE, 0.04, 0.02),
        ]
        .into_iter()
        .map(|p| row_of(p, &yardsticks))
        .collect();
        BenchResults {
            plan: plan(Preset::Quick, All),
            machine: Machine {
                cpu: "test".into(),
                nproc: 2,
            },
            command_line: "lightfarm bench --quick".into(),
            wall_seconds: 60.0,
            reference_seconds_from_cache: 0.0,
            rows,
            brute_force: yardsticks.iter().map(|y| y.brute_force.clone()).collect(),
            throughput: None,
        }
    }

    /// The quick preset writing into `out`, measuring nothing on its own (no scenes, no
    /// Embree, no replot, scale or throughput): each test sets what it runs.
    fn quick_args(out: &Path) -> BenchArgs {
        BenchArgs {
            preset: Preset::Quick,
            out: out.to_path_buf(),
            markdown: None,
            reference_cache: out.join("refs"),
            scenes: PathBuf::from("unused"),
            seed: 1,
            embree: None,
            command_line: String::new(),
            replot: false,
            bounces: BounceCount::All,
            scale: None,
            tile: None,
            throughput_only: false,
            python: "python3".into(),
            generator: PathBuf::from("unused"),
        }
    }

    /// `bench --replot` reads the results.json the new code writes, and the report and plots
    /// it writes name every figure's bounce count.
    #[test]
    fn replot_reads_new_results_and_labels_every_figure_with_its_bounces() {
        let out = std::env::temp_dir().join(format!("lf-bench-replot-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        std::fs::create_dir_all(&out).unwrap();
        let written = results_with_both_yardsticks();
        write_json(&out.join("results.json"), &written).unwrap();
        let text = std::fs::read_to_string(out.join("results.json")).unwrap();
        assert!(text.contains(r#""bounces":"all""#) && text.contains(r#""bounces":1"#));
        assert!(text.contains(r#""iterations":14"#));
        run(BenchArgs {
            replot: true,
            ..quick_args(&out)
        })
        .unwrap();
        let md = std::fs::read_to_string(out.join("BENCHMARKS.md")).unwrap();
        // Rows labelled by bounces and iterations, side by side; × cheaper = path tracer s /
        // apply s: full all bounces 1.1827 s / 0.5 ms, full one bounce
        // (0.5 + 0.01·0.04/(0.0009 − 0.04/1024)) s / 0.04 ms. Pareto fronts are per bounce
        // count: mixed with the one-bounce rows (same bake, lower error) full at all bounces
        // would be off every front.
        assert!(
            md.contains("| full | 8 | 256 | 1e-3 | auto | 12/7.5 | 3.00 | 40.0 KiB | all | 14 | 0.500 | 0.0500 | 0.1000 | 68, 1.18 | 2.4k× | bas |"),
            "{md}"
        );
        let r_one: f64 = 0.04 / (0.0009 - 0.04 / 1024.0);
        let cheaper_one = (0.5 + 0.01 * r_one) / 0.04e-3;
        assert!((cheaper_one - 24_115.25).abs() < 0.01, "{cheaper_one}");
        assert!(
            md.contains("| full | 8 | 256 | 1e-3 | auto | 12/7.5 | 3.00 | 40.0 KiB | 1 | 1 | 0.040 | 0.0300 | 0.0600 | 46, 0.96 | 24k× | bas |"),
            "{md}"
        );
        assert!(md.contains("- **cornell, all bounces**: lowest error 0.0500"));
        assert!(md.contains("- **cornell, 1 bounce**: lowest error 0.0300"));
        assert!(md.contains("rows with bounces = all"));
        // Both path-tracer fits, each with its bounce count.
        assert!(md.contains("| cornell | 8 | all | 600 |"));
        assert!(md.contains("| cornell | 8 | 1 | 600 |"));
        for stem in ["cornell-all-bounces", "cornell-1-bounce"] {
            for axis in ["bake", "apply", "bytes"] {
                assert!(out.join(format!("{stem}-error-vs-{axis}.svg")).exists());
                assert!(md.contains(&format!("({stem}-error-vs-{axis}.png)")));
            }
        }
        let svg =
            std::fs::read_to_string(out.join("cornell-all-bounces-error-vs-bake.svg")).unwrap();
        assert!(svg.contains("cornell, all bounces: error vs bake time"));
        // And replot twice gives the same markdown (nothing measured, nothing lost).
        run(BenchArgs {
            markdown: Some(out.join("again.md")),
            replot: true,
            bounces: BounceCount::ONE,
            ..quick_args(&out)
        })
        .unwrap();
        assert_eq!(md, std::fs::read_to_string(out.join("again.md")).unwrap());
        std::fs::remove_dir_all(&out).unwrap();
    }

    /// `bench --throughput` measures the ray throughput alone on the plan's scene and ray
    /// count, replaces results.json's (none before) and keeps every other figure; the markdown
    /// says it was measured apart, by which command.
    #[test]
    fn the_throughput_alone_replaces_only_the_throughput() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let out = std::env::temp_dir().join(format!("lf-bench-rays-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        std::fs::create_dir_all(&out).unwrap();
        let written = results_with_both_yardsticks();
        assert!(written.throughput.is_none());
        write_json(&out.join("results.json"), &written).unwrap();
        run(BenchArgs {
            scenes: root.join("scenes"),
            command_line: "lightfarm bench --throughput".into(),
            throughput_only: true,
            ..quick_args(&out)
        })
        .unwrap();
        let read: BenchResults =
            serde_json::from_str(&std::fs::read_to_string(out.join("results.json")).unwrap())
                .unwrap();
        let t = read.throughput.as_ref().expect("measured");
        assert_eq!(t.scene, written.plan.throughput_scene);
        assert_eq!(t.rays, written.plan.throughput_rays);
        assert!(t.ours_triangles_rays_per_second > 0.0 && t.ours_native_rays_per_second > 0.0);
        assert_eq!(
            t.measured_by.as_deref(),
            Some("lightfarm bench --throughput")
        );
        assert_eq!(t.embree_missing.as_deref(), Some("skipped (--no-embree)"));
        // Everything else as it was (to JSON's round trip of f64, which may move a last digit).
        assert_eq!(read.command_line, written.command_line);
        assert_eq!(read.rows.len(), written.rows.len());
        for (a, b) in read.rows.iter().zip(&written.rows) {
            assert_eq!(
                (a.point.relative_l2, a.point.apply_ms),
                (b.point.relative_l2, b.point.apply_ms)
            );
        }
        assert_eq!(read.brute_force.len(), written.brute_force.len());
        let md = std::fs::read_to_string(out.join("BENCHMARKS.md")).unwrap();
        assert!(md.contains(
            "Measured apart from the rest of this page, by `lightfarm bench --throughput`."
        ));
        assert!(
            md.contains("| full | 8 | 256 | 1e-3 | auto | 12/7.5 |"),
            "{md}"
        );
        std::fs::remove_dir_all(&out).unwrap();
    }

    /// `bench --quick --scale 2,6`: generates, bakes and measures two small levels, writes
    /// scale.json, the figure and a markdown of the scale section alone; a replot next to a
    /// main sweep's results.json keeps both.
    #[test]
    fn the_scale_sweep_measures_every_level_and_reports_it() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let out = std::env::temp_dir().join(format!("lf-bench-scale-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        let args = |replot: bool| BenchArgs {
            scenes: root.join("scenes"),
            command_line: "lightfarm bench --quick --scale 2,6".into(),
            replot,
            scale: Some(vec![2, 6]),
            tile: None,
            generator: root.join("scripts/gen_level.py"),
            ..quick_args(&out)
        };
        run(args(false)).unwrap();
        let sweep: scale::ScaleSweep =
            serde_json::from_str(&std::fs::read_to_string(out.join("scale.json")).unwrap())
                .unwrap();
        assert_eq!(sweep.points.len(), 2);
        let (small, large) = (&sweep.points[0], &sweep.points[1]);
        assert_eq!((small.blocks, large.blocks), (2, 6));
        // 4 texels per face: 6 faces · 16 texels per block, fewer where faces are open.
        assert!(small.texels < large.texels && large.texels <= 6 * 96 + 96 * large.clutter);
        for p in &sweep.points {
            assert!(p.bake_seconds > 0.0 && p.stage_seconds.iter().any(|(n, _)| n == "encode"));
            assert!(p.peak_rss_bytes >= p.rss_before_bytes && p.rss_before_bytes > 0);
            let stored: u64 = p.sections.iter().map(|s| s.1).sum();
            assert!(
                stored > 0 && stored < p.bundle_bytes,
                "{stored} of {}",
                p.bundle_bytes
            );
            assert!(p.apply_one_ms > 0.0 && p.apply_converged_ms > 0.0);
            assert!(
                p.converged_applications >= 2,
                "{}",
                p.converged_applications
            );
            assert!(p.one_light.total_ms > 0.0 && p.relight_all.total_ms > 0.0);
            // One bounce: relighting by the change agrees with relighting everything to
            // float rounding.
            assert!(p.one_light_drift < 1e-4, "drift {}", p.one_light_drift);
            assert!(p.error_texels > 0);
            // All bounces against all bounces: a one-bounce answer would be ~0.6 off.
            assert!(p.relative_l2 < 0.3, "error {}", p.relative_l2);
            assert!(p.reference_noise > 0.0 && p.reference_noise < 0.2);
        }
        assert!(out.join("scale.svg").exists() && out.join("scale.png").exists());
        let md = std::fs::read_to_string(out.join("BENCHMARKS.md")).unwrap();
        assert!(md.starts_with("# Benchmarks"), "{md}");
        assert!(md.contains("## Scale: levels of 2, 6 blocks"), "{md}");
        assert!(md.contains("![scale sweep](scale.png)"), "{md}");
        assert!(md.contains(&format!("\n| 6 | {} | ", large.texels)), "{md}");
        // A replot next to the main sweep's results keeps both.
        write_json(&out.join("results.json"), &results_with_both_yardsticks()).unwrap();
        run(args(true)).unwrap();
        let md = std::fs::read_to_string(out.join("BENCHMARKS.md")).unwrap();
        assert!(md.contains("- **cornell, all bounces**") && md.contains("## Scale: levels"));

        // Tiled: copies of a 2-block level; a count off the tile is refused before any work.
        let tiled = |sizes: Vec<u32>| BenchArgs {
            scale: Some(sizes),
            tile: Some(2),
            ..args(false)
        };
        let refused = run(tiled(vec![2, 3])).unwrap_err().to_string();
        assert!(refused.contains("--tile 2"), "{refused}");
        run(tiled(vec![2, 4])).unwrap();
        let sweep: scale::ScaleSweep =
            serde_json::from_str(&std::fs::read_to_string(out.join("scale_tiled.json")).unwrap())
                .unwrap();
        assert_eq!(sweep.settings.tile, Some(2));
        let (one, two) = (&sweep.points[0], &sweep.points[1]);
        // Two copies: twice the lights and, less the two faces of the join, twice the texels.
        assert_eq!(two.lights, 2 * one.lights);
        assert!(two.texels < 2 * one.texels && two.texels + 2 * 16 >= 2 * one.texels);
        // The same lights moved (the first copy's) at both sizes.
        let moved = |p: &scale::ScalePoint| p.moved_lights.unwrap().lights;
        assert_eq!(moved(one), one.lights.min(scale::MOVED_LIGHTS));
        assert_eq!(moved(two), moved(one));
        let md = std::fs::read_to_string(out.join("BENCHMARKS.md")).unwrap();
        assert!(
            md.contains("## Scale: levels of 2, 6 blocks")
                && md.contains("## Scale, one neighbourhood: copies of a 2-block level, 2, 4"),
            "{md}"
        );
        std::fs::remove_dir_all(&out).unwrap();
    }

    /// The whole chain on cornell at 4 texels per face, one light set: all-bounce references
    /// carry the extra light of the later bounces, each point is measured against the
    /// reference of its own bounce count with the runtime at the matching mode, and the
    /// runtime's iterations are recorded.
    #[test]
    fn cornell_points_are_measured_against_the_reference_of_their_bounce_count() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let scene_plan = ScenePlan {
            name: "cornell".into(),
            methods: vec![BenchMethod::Full, BenchMethod::Drt],
            settings: vec![],
        };
        let bench = load_bench_scene(&root.join("scenes"), &scene_plan, 1, 1).unwrap();
        let mut plan = plan(Preset::Quick, BounceCount::All);
        plan.reference_rays = 256;
        plan.brute_force_rays = vec![16, 64];
        plan.light_sets = 1;
        let cache_dir =
            std::env::temp_dir().join(format!("lf-bench-yardsticks-{}", std::process::id()));
        let cache = ReferenceCache::open(&cache_dir).unwrap();
        let mut scene_t = bench.scene.clone();
        scene_t.settings.texels_per_face = 4;
        let bar = BenchProgress::new(100);
        let measured: Vec<MeasuredYardstick> = plan
            .yardsticks()
            .into_iter()
            .map(|b| measure_yardstick(&cache, &bench, &scene_t, &plan, b, &bar).unwrap())
            .collect();
        let energy = |r: &ResultFile| -> f64 {
            r.texels
                .iter()
                .map(|t| t.indirect.iter().sum::<f64>())
                .sum()
        };
        let ratio = energy(&measured[0].references[0]) / energy(&measured[1].references[0]);
        // Mitsuba puts cornell's all-bounce indirect energy at 2.45× one bounce (issue 18).
        assert!(
            ratio > 1.8 && ratio < 3.2,
            "all ÷ one bounce energy {ratio}"
        );
        // So the yardsticks are far apart: a perfect one-bounce answer is ~0.6 off all bounces.
        let apart = compare(&measured[1].references[0], &measured[0].references[0]).relative_l2;
        eprintln!("energy all ÷ one {ratio:.3}; one-bounce reference vs all-bounce {apart:.3}");
        assert!(apart > 0.4, "{apart}");
        assert_eq!(measured[0].brute_force.bounces, BounceCount::All);
        assert_eq!(measured[1].brute_force.bounces, BounceCount::ONE);
        let setting = BakeSetting {
            texels_per_face: 4,
            rays_per_texel: 64,
            tolerance: 1e-3,
            codecs: vec![BundleCodec::Auto],
        };
        let yardsticks: Vec<Yardstick> =
            measured.iter().map(MeasuredYardstick::yardstick).collect();
        let points = measure_setting(&bench, &setting, &yardsticks, 3, &|_| {}).unwrap();
        let labels: Vec<(BenchMethod, BounceCount)> =
            points.iter().map(|p| (p.method, p.bounces)).collect();
        use BenchMethod::{Drt, Full};
        use BounceCount::All;
        let one = BounceCount::ONE;
        assert_eq!(
            labels,
            vec![(Full, All), (Full, one), (Drt, All), (Drt, one)]
        );
        for p in &points {
            eprintln!(
                "{} {}: error {:.4}, iterations {}",
                p.method.label(),
                p.bounces,
                p.relative_l2,
                p.iterations
            );
            if p.bounces == one {
                assert_eq!(p.iterations, 1);
            } else {
                // Each bounce keeps about 0.6 of the light: summing bounces takes ~14 to 1e-3,
                // GMRES fewer; more than one either way.
                assert!((3..=40).contains(&p.iterations), "{}", p.iterations);
            }
            // Against the matching yardstick the operators are close (0.12–0.16 at T4 against a
            // 256-ray reference), far closer than the yardsticks are to each other.
            assert!(
                p.relative_l2 < 0.2,
                "{} {}: {}",
                p.method.label(),
                p.bounces,
                p.relative_l2
            );
        }
        std::fs::remove_dir_all(&cache_dir).unwrap();
    }
}
