//! What `bench` sweeps: the two presets, per scene the methods and bake settings, and what is
//! left out and why (written into the report).

use lightfarm_proto::bounces::BounceCount;
use lightfarm_proto::scene::BundleCodec;
use serde::{Deserialize, Serialize};

use super::measure::{BakeSetting, BenchMethod};

/// Which sweep to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Preset {
    /// A few minutes on 2 cores: small scenes, few settings, low reference rays (CI).
    Quick,
    /// About 85 minutes cold on 2 cores (all-bounce references; about 70 with them cached):
    /// the four example scenes, 8 and 16 texels per face (32 on cornell).
    Full,
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
    /// Bounces of the main yardstick. Results written before bounces existed were one-bounce.
    #[serde(default = "one_bounce")]
    pub bounces: BounceCount,
    /// Whether every point is also measured at one bounce against one-bounce references (rows
    /// of their own); meaningless when `bounces` is one.
    #[serde(default)]
    pub one_bounce_rows: bool,
}

pub(super) fn one_bounce() -> BounceCount {
    BounceCount::ONE
}

impl SweepPlan {
    /// The bounce counts every point is measured at, the main one first.
    pub fn yardsticks(&self) -> Vec<BounceCount> {
        if self.one_bounce_rows && self.bounces != BounceCount::ONE {
            vec![self.bounces, BounceCount::ONE]
        } else {
            vec![self.bounces]
        }
    }
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

/// The sweep of a preset with `bounces` as the main yardstick.
pub fn plan(preset: Preset, bounces: BounceCount) -> SweepPlan {
    use BenchMethod::*;
    let static_methods = [Full, MrtLightfield, MrtTraced, Drt];
    let mut plan = match preset {
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
                "a high-ray reference above 1024 rays per texel (errors below ~1% at one bounce, \
                 ~3% at all bounces, are not resolved: longer paths are noisier)"
                    .into(),
            ],
            bounces,
            one_bounce_rows: true,
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
            bounces,
            one_bounce_rows: true,
        },
    };
    if plan.bounces != BounceCount::ONE {
        plan.left_out.push(
            "Feedback (one application per frame, the previous frame's indirect light fed back) \
             and Warm (Converged from the previous frame's answer) are not timed here: \
             `lightfarm frame-time --bounces 1,all,warm,feedback` times them, still and with a \
             moving light"
                .into(),
        );
    }
    plan
}
