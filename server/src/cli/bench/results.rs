//! What one `bench` run measured, as `results.json` holds it: the rows (one per scene, method,
//! bake setting and yardstick), the equal-error fits of the reference path tracer, the ray
//! throughput and the machine. The report and the plots read it; nothing here measures.

use lightfarm_proto::bounces::BounceCount;
use serde::{Deserialize, Serialize};

use super::measure::BenchPoint;
use super::plan::{one_bounce, SweepPlan};
use super::throughput::Throughput;

/// The equal-error fit of one scene at one texel count and bounce count.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BruteForce {
    pub scene: String,
    pub texels_per_face: u32,
    /// Bounces the path tracer (the ladder and the high-ray reference) sums.
    #[serde(default = "one_bounce")]
    pub bounces: BounceCount,
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

impl Row {
    /// How many times cheaper one relight by the operators (one frame, `apply_ms`) is than
    /// path tracing the same light set to the same error at the same bounce count (None when
    /// the path tracer cannot be fitted there).
    pub fn times_cheaper_than_path_tracing(&self) -> Option<f64> {
        let seconds = self.brute_force_seconds?;
        (self.point.apply_ms > 0.0).then(|| seconds / (self.point.apply_ms * 1e-3))
    }
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
