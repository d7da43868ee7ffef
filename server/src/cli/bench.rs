//! `lightfarm bench [--quick] --out DIR`: speed against error. Sweeps scenes × methods × bake
//! settings, measures each point (`bench_measure`), the reference path tracer at equal error
//! (`bench_equal_error`) and ray throughput against Embree (`bench_throughput`), and writes
//! `results.json`, plots (`bench_plots`) and BENCHMARKS.md-ready markdown (`bench_report`).
//!
//! Owns the two presets (what is swept, and what is left out and why) and the order of work.
//!
//! Invariants:
//! - Everything random is seeded (`--seed`): light sets, the reference, the exported rays.
//! - References are read from / written to the content-keyed cache (`bench_reference_cache`);
//!   only the timings of bakes, frames and tracing are measured afresh on every run.
//! - The engine and client run in-process; only Embree runs in a child process (Python).

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::time::Instant;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use lightfarm_proto::lights::LightSet;
use lightfarm_proto::result::{compare, ResultFile};
use lightfarm_proto::scene::{Aabb, BundleCodec, Scene};
use serde::{Deserialize, Serialize};

use super::bake::load_scene;
use super::bench_equal_error::{BruteForceFit, BruteForceRun};
use super::bench_lights::random_light_set;
use super::bench_measure::{
    drop_buried, measure_setting, BakeSetting, BenchMethod, BenchPoint, BenchScene,
};
use super::bench_reference_cache::{mesh_bytes, reference_key, CachedReference, ReferenceCache};
use super::bench_throughput::{measure_throughput, Throughput};
use super::write_json;
use crate::bake::geometry::Geometry;
use crate::bake::reference::{reference, ReferenceSettings};
use lightfarm_proto::bounces::BounceCount;

/// Which sweep to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Preset {
    /// A few minutes on 2 cores: small scenes, few settings, low reference rays (CI).
    Quick,
    /// About half an hour on 2 cores: the four example scenes, 8 and 16 texels per face (32 on
    /// cornell).
    Full,
}

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
}

/// What one scene sweeps.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ScenePlan {
    pub name: String,
    pub methods: Vec<BenchMethod>,
    pub settings: Vec<BakeSetting>,
}

/// The whole sweep.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SweepPlan {
    pub preset: Preset,
    pub scenes: Vec<ScenePlan>,
    pub light_sets: usize,
    pub reference_rays: u32,
    /// Ray counts of the brute-force runs the equal-error fit uses.
    pub brute_force_rays: Vec<u32>,
    /// Timed frames per apply measurement.
    pub frames: usize,
    /// Scene and ray count of the throughput comparison.
    pub throughput_scene: String,
    pub throughput_rays: usize,
    /// What the preset leaves out, for the report.
    pub left_out: Vec<String>,
}

/// Every `(texels per face, rays per texel)` of `grid` at tolerance 1e-3 and codec `auto`;
/// at `base` also the codecs f32/f16/u8 (when `codecs`) and the extra `tolerances`.
fn sweep(
    grid: &[(u32, u32)],
    base: (u32, u32),
    tolerances: &[f64],
    codecs: bool,
) -> Vec<BakeSetting> {
    let mut out = Vec::new();
    for &(t, r) in grid {
        let mut codec_list = vec![BundleCodec::Auto];
        if codecs && (t, r) == base {
            codec_list.extend([BundleCodec::F32, BundleCodec::F16, BundleCodec::U8]);
        }
        out.push(BakeSetting {
            texels_per_face: t,
            rays_per_texel: r,
            tolerance: 1e-3,
            codecs: codec_list,
        });
    }
    for &tolerance in tolerances {
        out.push(BakeSetting {
            texels_per_face: base.0,
            rays_per_texel: base.1,
            tolerance,
            codecs: vec![BundleCodec::Auto],
        });
    }
    out
}

/// All pairs of `texels` × `rays`.
fn grid(texels: &[u32], rays: &[u32]) -> Vec<(u32, u32)> {
    texels
        .iter()
        .flat_map(|&t| rays.iter().map(move |&r| (t, r)))
        .collect()
}

fn plan_scene(name: &str, methods: &[BenchMethod], settings: Vec<BakeSetting>) -> ScenePlan {
    ScenePlan {
        name: name.to_string(),
        methods: methods.to_vec(),
        settings,
    }
}

/// The sweep of a preset.
pub fn plan(preset: Preset) -> SweepPlan {
    use BenchMethod::*;
    let static_methods = [Full, MrtLightfield, MrtTraced, Drt];
    match preset {
        Preset::Quick => SweepPlan {
            preset,
            scenes: vec![
                plan_scene(
                    "cornell",
                    &static_methods,
                    sweep(&grid(&[8], &[64, 256]), (8, 256), &[1e-2], true),
                ),
                plan_scene(
                    "corridor",
                    &[Full, MrtLightfield, MrtTraced],
                    sweep(&grid(&[8], &[64, 256]), (8, 256), &[], false),
                ),
                plan_scene(
                    "ball_corridor",
                    &[MrtLightfield, Dnrt],
                    sweep(&grid(&[8], &[64]), (8, 64), &[], false),
                ),
            ],
            light_sets: 2,
            reference_rays: 1024,
            brute_force_rays: vec![16, 64],
            frames: 200,
            throughput_scene: "maze".into(),
            throughput_rays: 200_000,
            left_out: vec![
                "the maze (only its geometry is used, for the ray throughput)".into(),
                "texels per face 16 and 32, rays per texel above 256, tolerance 1e-4".into(),
                "a high-ray reference above 1024 rays per texel (errors below ~1% are not \
                 resolved)"
                    .into(),
            ],
        },
        Preset::Full => SweepPlan {
            preset,
            scenes: vec![
                plan_scene(
                    "maze",
                    &static_methods,
                    sweep(
                        &grid(&[8, 16], &[64, 256, 1024]),
                        (16, 256),
                        &[1e-2, 1e-4],
                        true,
                    ),
                ),
                plan_scene(
                    "cornell",
                    &static_methods,
                    sweep(
                        &[grid(&[8, 16], &[64, 256, 1024, 4096]), grid(&[32], &[1024])].concat(),
                        (16, 1024),
                        &[1e-2, 1e-4],
                        true,
                    ),
                ),
                plan_scene(
                    "corridor",
                    &[Full, MrtLightfield, MrtTraced],
                    sweep(&grid(&[8, 16], &[64, 256, 1024]), (16, 256), &[1e-2], false),
                ),
                plan_scene(
                    "ball_corridor",
                    &[Full, MrtLightfield, Dnrt],
                    sweep(&grid(&[8, 16], &[64, 256, 1024]), (16, 256), &[], false),
                ),
            ],
            light_sets: 3,
            reference_rays: 4096,
            brute_force_rays: vec![16, 64, 256],
            frames: 200,
            throughput_scene: "maze".into(),
            throughput_rays: 1_000_000,
            left_out: vec![
                "the maze at 4096 rays per texel; 32 texels per face only for cornell at 1024 \
                 rays per texel (the maze's and the corridor's references at T32 would take \
                 most of the 40 minutes)"
                    .into(),
                "tolerance and codec variants only at one (T, rays) point per scene, not crossed \
                 with the whole grid"
                    .into(),
                "DNRT grid settings (resolution, SH order, codec) stay at their defaults; the \
                 client's multi-threaded apply path is not timed"
                    .into(),
            ],
        },
    }
}

/// The equal-error fit of one scene at one texel count.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BruteForce {
    pub scene: String,
    pub texels_per_face: u32,
    pub runs: Vec<(u32, f64, f64)>,
    /// `e(r) = scale · r^-exponent` (plus the reference's noise in quadrature).
    pub scale: f64,
    pub exponent: f64,
    pub seconds_fixed: f64,
    pub seconds_per_ray: f64,
    pub noise_floor: f64,
    /// Mean seconds of one high-ray reference (when it was computed).
    pub reference_seconds: f64,
    pub texels: usize,
}

/// A point with the brute-force cost at its error.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Row {
    #[serde(flatten)]
    pub point: BenchPoint,
    /// Rays per texel the reference solver needs for the same error (None: below its noise).
    pub brute_force_rays: Option<f64>,
    pub brute_force_seconds: Option<f64>,
}

/// The machine the numbers come from.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Machine {
    pub cpu: String,
    pub nproc: usize,
}

impl Machine {
    pub fn detect() -> Machine {
        let cpu = std::fs::read_to_string("/proc/cpuinfo")
            .ok()
            .and_then(|text| {
                text.lines()
                    .find(|l| l.starts_with("model name"))
                    .and_then(|l| l.split(':').nth(1))
                    .map(|s| s.trim().to_string())
            })
            .unwrap_or_else(|| "unknown".into());
        Machine {
            cpu,
            nproc: std::thread::available_parallelism().map_or(1, |n| n.get()),
        }
    }
}

/// Everything one run produced.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BenchResults {
    pub plan: SweepPlan,
    pub machine: Machine,
    pub command_line: String,
    pub wall_seconds: f64,
    /// Seconds the cached reference runs took when they were computed (a cold run adds them).
    #[serde(default)]
    pub reference_seconds_from_cache: f64,
    pub rows: Vec<Row>,
    pub brute_force: Vec<BruteForce>,
    pub throughput: Option<Throughput>,
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

/// The reference of `lights` at `rays` (cached by content).
/// Seconds of reference runs read from the cache in this run (what a cold run adds).
static SECONDS_FROM_CACHE: std::sync::Mutex<f64> = std::sync::Mutex::new(0.0);

fn cached_reference(
    cache: &ReferenceCache,
    scene: &Scene,
    dir: &Path,
    lights: &LightSet,
    rays: u32,
    seed: u64,
) -> anyhow::Result<CachedReference> {
    let key = reference_key(scene, &mesh_bytes(scene, dir)?, lights, rays, seed);
    if let Some(hit) = cache.get(&key) {
        *SECONDS_FROM_CACHE.lock().expect("not poisoned") += hit.seconds;
        return Ok(hit);
    }
    let start = Instant::now();
    let mut geometry = Geometry::from_scene(scene, dir)?;
    geometry.add_posed_dynamic(scene, dir, &lights.poses)?;
    let settings = ReferenceSettings::new(rays, BounceCount::ONE, seed);
    let result = reference(&geometry, &lights.lights, &settings, &|_| {});
    let entry = CachedReference {
        seconds: start.elapsed().as_secs_f64(),
        result,
    };
    cache.put(&key, &entry)?;
    Ok(entry)
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

pub fn run(args: BenchArgs) -> anyhow::Result<()> {
    if args.replot {
        let path = args.out.join("results.json");
        let results: BenchResults = serde_json::from_str(&super::read_text(&path)?)
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        return write_outputs(&results, &args);
    }
    let started = Instant::now();
    let plan = plan(args.preset);
    std::fs::create_dir_all(&args.out)?;
    let cache = ReferenceCache::open(&args.reference_cache)?;
    let scenes: Vec<BenchScene> = plan
        .scenes
        .iter()
        .map(|p| load_bench_scene(&args.scenes, p, plan.light_sets, args.seed))
        .collect::<anyhow::Result<_>>()?;
    let reference_jobs: usize = plan
        .scenes
        .iter()
        .map(|p| {
            texel_counts(&p.settings).len() * plan.light_sets * (1 + plan.brute_force_rays.len())
        })
        .sum();
    let setting_jobs: usize = plan.scenes.iter().map(|p| p.settings.len()).sum();
    let bar = BenchProgress::new((reference_jobs + setting_jobs + 1) as u64);
    let mut rows = Vec::new();
    let mut brute_force = Vec::new();
    for (scene_plan, bench) in plan.scenes.iter().zip(&scenes) {
        let boxes: Vec<Aabb> = bench.scene.clutter.iter().filter_map(|c| c.box_).collect();
        for t in texel_counts(&scene_plan.settings) {
            let mut scene_t = bench.scene.clone();
            scene_t.settings.texels_per_face = t;
            let seed = scene_t.settings.seed;
            let mut references: Vec<ResultFile> = Vec::new();
            let mut reference_seconds = 0.0;
            let mut runs = Vec::new();
            for (k, lights) in bench.light_sets.iter().enumerate() {
                bar.message(&format!("{} T{t} reference {k}", bench.name));
                let high = cached_reference(
                    &cache,
                    &scene_t,
                    &bench.dir,
                    lights,
                    plan.reference_rays,
                    seed,
                )?;
                bar.inc();
                reference_seconds += high.seconds / bench.light_sets.len() as f64;
                for &rays in &plan.brute_force_rays {
                    bar.message(&format!(
                        "{} T{t} brute force {rays} rays, set {k}",
                        bench.name
                    ));
                    // An independent seed, so the two estimators' errors add in quadrature.
                    let low = cached_reference(
                        &cache,
                        &scene_t,
                        &bench.dir,
                        lights,
                        rays,
                        seed.wrapping_add(1),
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
            brute_force.push(BruteForce {
                scene: bench.name.clone(),
                texels_per_face: t,
                runs: runs.iter().map(|r| (r.rays, r.error, r.seconds)).collect(),
                scale: fit.scale,
                exponent: fit.exponent,
                seconds_fixed: fit.seconds_fixed,
                seconds_per_ray: fit.seconds_per_ray,
                noise_floor: fit.noise_floor(),
                reference_seconds,
                texels: references[0].texels.len(),
            });
            for setting in scene_plan
                .settings
                .iter()
                .filter(|s| s.texels_per_face == t)
            {
                let points = measure_setting(bench, setting, &references, plan.frames, &|m| {
                    bar.message(m)
                })?;
                bar.inc();
                for point in points {
                    let brute_force_rays = fit.rays_for_error(point.relative_l2);
                    rows.push(Row {
                        brute_force_seconds: brute_force_rays.map(|r| fit.seconds_for_rays(r)),
                        brute_force_rays,
                        point,
                    });
                }
            }
        }
    }
    bar.message("ray throughput (obvhs, Embree)");
    let throughput = match scenes.iter().find(|s| s.name == plan.throughput_scene) {
        Some(bench) => Some(throughput_of(bench, &plan, &args)?),
        None => {
            let (scene, dir) =
                load_scene(&args.scenes.join(&plan.throughput_scene).join("scene.json"))?;
            let bench = BenchScene {
                name: plan.throughput_scene.clone(),
                scene,
                dir,
                light_sets: vec![],
                methods: vec![],
            };
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
    write_outputs(&results, &args)
}

/// Plots and markdown from the results.
fn write_outputs(results: &BenchResults, args: &BenchArgs) -> anyhow::Result<()> {
    let markdown_path = args
        .markdown
        .clone()
        .unwrap_or_else(|| args.out.join("BENCHMARKS.md"));
    let plots = super::bench_plots::write_plots(results, &args.out)?;
    let markdown = super::bench_report::markdown(results, &plots, &markdown_path);
    super::write_atomic(&markdown_path, markdown.as_bytes())?;
    println!("{}", super::bench_report::summary(results));
    println!("markdown: {}", markdown_path.display());
    Ok(())
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
