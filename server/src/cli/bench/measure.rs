//! One sweep point of `lightfarm bench`: bake a scene at one (texels per face, rays per texel,
//! tolerance), encode it with each codec, and measure every method on it — bake seconds,
//! bundle bytes, apply time per frame and error against the high-ray reference — once per
//! yardstick (bounce count): the runtime runs at the bounce mode matching the reference's
//! count (`all` → `Bounces::default()`, i.e. Converged; `N` → `Fixed(N)`; `1` → `One`).
//!
//! Invariants:
//! - Errors are measured on the *decoded* bundle, through the client crate (`eval`'s
//!   `evaluate`), as a game would see it; block texels buried inside clutter boxes are left out
//!   (as `compare --scene` does), since nothing ever sees them.
//! - Bakes run without the shape cache (cold), so bake seconds are what a first bake costs.
//! - A point's error is only ever against the reference of its own bounce count, and its apply
//!   time and iterations are of the same bounce mode.
//! - One bake serves several methods and yardsticks: a method's bake seconds are the engine's stages it needs
//!   (`BakeReport::stage_seconds`) plus the encode, and its bytes are the stored sections it
//!   reads plus the container's own bytes.

use std::collections::HashMap;
use std::time::Instant;

use lightfarm_client::{
    Bounces, Bundle, IndirectLight, Method, ObjectLight, Occluders, ProbeField, Runtime,
};
use lightfarm_proto::bounces::BounceCount;
use lightfarm_proto::lights::LightSet;
use lightfarm_proto::result::{compare, ResultFile};
use lightfarm_proto::scene::{Aabb, BundleCodec, Scene, Transport};
use serde::{Deserialize, Serialize};

use crate::bake::pipeline::encoding::encode_options;
use crate::bake::progress::NoProgress;
use crate::bake::{bake, BakeOptions, BakeReport};
use crate::cli::frame_time::time_frames;
use crate::cli::frame_update::median;
use crate::evaluate::{evaluate, is_bounced, leaving_light, operator_direct};

/// A method as the bench names it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum BenchMethod {
    /// The dense direct-to-indirect operator (Hašan et al. 2006 style; the paper's baseline).
    Full,
    MrtLightfield,
    MrtTraced,
    /// DRT on the default (traced) bake (clutter scenes).
    Drt,
    /// MRT plus the DNRT grids of the posed dynamic objects (scenes with dynamic objects).
    Dnrt,
}

impl BenchMethod {
    pub const ALL: [BenchMethod; 5] = [
        BenchMethod::Full,
        BenchMethod::MrtLightfield,
        BenchMethod::MrtTraced,
        BenchMethod::Drt,
        BenchMethod::Dnrt,
    ];

    pub fn label(self) -> &'static str {
        match self {
            BenchMethod::Full => "full",
            BenchMethod::MrtLightfield => "mrt-lightfield",
            BenchMethod::MrtTraced => "mrt-traced",
            BenchMethod::Drt => "drt",
            BenchMethod::Dnrt => "dnrt",
        }
    }

    fn client_method(self) -> Method {
        match self {
            BenchMethod::Full => Method::Full,
            BenchMethod::Drt => Method::Drt,
            _ => Method::Mrt,
        }
    }

    /// The transport of the bake this method reads: DRT and DNRT on the default (traced), the
    /// dense operator on the lightfield bake (it reads no transport).
    fn transport(self) -> Transport {
        match self {
            BenchMethod::MrtTraced | BenchMethod::Drt | BenchMethod::Dnrt => Transport::Traced,
            BenchMethod::Full | BenchMethod::MrtLightfield => Transport::Lightfield,
        }
    }

    /// Bundle sections the client reads for this method.
    fn sections(self) -> &'static [&'static str] {
        match self {
            BenchMethod::Full => &["layout", "full"],
            BenchMethod::MrtLightfield | BenchMethod::MrtTraced => {
                &["layout", "shapes", "blocks", "transport", "probes"]
            }
            BenchMethod::Drt => &["layout", "shapes", "blocks", "transport", "drt", "probes"],
            BenchMethod::Dnrt => &["layout", "shapes", "blocks", "transport", "probes", "dnrt"],
        }
    }

    /// Bake stages this method needs.
    fn stages(self) -> &'static [&'static str] {
        match self {
            BenchMethod::Full => &["geometry", "dense operator", "bundle"],
            BenchMethod::MrtLightfield | BenchMethod::MrtTraced => &[
                "geometry",
                "shape operators",
                "transport",
                "probe volume",
                "bundle",
            ],
            BenchMethod::Drt => &[
                "geometry",
                "shape operators",
                "transport",
                "clutter operators",
                "probe volume",
                "bundle",
            ],
            BenchMethod::Dnrt => &[
                "geometry",
                "shape operators",
                "transport",
                "probe volume",
                "dnrt grids",
                "bundle",
            ],
        }
    }

    /// Whether the method means anything on `scene`.
    pub fn applies_to(self, scene: &Scene) -> bool {
        match self {
            BenchMethod::Drt => !scene.clutter.is_empty(),
            BenchMethod::Dnrt => !scene.dynamic.is_empty(),
            _ => true,
        }
    }
}

/// The bake settings of one sweep point (codecs share the bake).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BakeSetting {
    pub texels_per_face: u32,
    pub rays_per_texel: u32,
    pub tolerance: f64,
    pub codecs: Vec<BundleCodec>,
}

/// A measured point.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct BenchPoint {
    pub scene: String,
    pub method: BenchMethod,
    pub texels_per_face: u32,
    pub rays_per_texel: u32,
    pub tolerance: f64,
    pub codec: String,
    /// Largest and mean shape-operator rank (from the tolerance).
    pub rank_max: usize,
    pub rank_mean: f64,
    pub bake_seconds: f64,
    pub bundle_bytes: u64,
    /// Median of the timed frames of `Runtime::apply` (plus the DNRT pass for `dnrt`), one
    /// thread.
    pub apply_ms: f64,
    /// Mean over light sets.
    pub relative_l2: f64,
    pub p95: f64,
    pub relative_l2_per_set: Vec<f64>,
    /// Bounces of the reference this point is measured against, and of the runtime's mode.
    /// Results written before bounces existed were one-bounce, hence the default.
    #[serde(default = "one_bounce")]
    pub bounces: BounceCount,
    /// One-bounce applications per timed frame (`Applied::bounces`): 1 for one bounce, N for
    /// `Fixed(N)`, the iterations Converged needed for `all`.
    #[serde(default = "one_iteration")]
    pub iterations: u32,
}

fn one_bounce() -> BounceCount {
    BounceCount::ONE
}

fn one_iteration() -> u32 {
    1
}

/// "1 bounce", "3 bounces", "all bounces": how reports and plots name a yardstick.
pub fn bounces_label(bounces: BounceCount) -> String {
    match bounces {
        BounceCount::Fixed(1) => "1 bounce".to_string(),
        other => format!("{other} bounces"),
    }
}

/// The references one point is measured against: a bounce count and, per light set, the
/// reference at that count and the point's texel count.
pub struct Yardstick<'a> {
    pub bounces: BounceCount,
    pub references: &'a [ResultFile],
}

impl BenchPoint {
    /// "T16 r1024 tol1e-3 auto": the setting in a few characters.
    pub fn setting_label(&self) -> String {
        format!(
            "T{} r{} tol{:.0e} {}",
            self.texels_per_face, self.rays_per_texel, self.tolerance, self.codec
        )
    }
}

/// A scene with its light sets and, per texels-per-face, the reference result of each set.
pub struct BenchScene {
    pub name: String,
    pub scene: Scene,
    pub dir: std::path::PathBuf,
    pub light_sets: Vec<LightSet>,
    pub methods: Vec<BenchMethod>,
}

pub fn codec_name(codec: BundleCodec) -> &'static str {
    match codec {
        BundleCodec::Auto => "auto",
        BundleCodec::F32 => "f32",
        BundleCodec::F16 => "f16",
        BundleCodec::U8 => "u8",
    }
}

/// Block texels inside a clutter box: never seen, their reference values mean nothing.
pub fn drop_buried(result: &mut ResultFile, boxes: &[Aabb]) {
    result.texels.retain(|t| {
        !t.surface.starts_with("block:")
            || !boxes.iter().any(|b| {
                (0..3).all(|k| t.position[k] >= b.min[k] - 1e-6 && t.position[k] <= b.max[k] + 1e-6)
            })
    });
}

/// The scene with the setting's bake parameters.
pub fn scene_at(scene: &Scene, setting: &BakeSetting) -> Scene {
    let mut s = scene.clone();
    s.settings.texels_per_face = setting.texels_per_face;
    s.settings.rays_per_texel = setting.rays_per_texel;
    s.settings.tolerance = setting.tolerance;
    s
}

/// Measures every method of `bench` at `setting` against each yardstick (one point per method,
/// codec and yardstick, the yardsticks of a method next to each other); a yardstick's
/// `references[k]` is the reference of light set k at this texel count.
pub fn measure_setting(
    bench: &BenchScene,
    setting: &BakeSetting,
    yardsticks: &[Yardstick],
    frames: usize,
    on_method: &dyn Fn(&str),
) -> anyhow::Result<Vec<BenchPoint>> {
    let scene = scene_at(&bench.scene, setting);
    let boxes: Vec<Aabb> = scene.clutter.iter().filter_map(|c| c.box_).collect();
    let mut points = Vec::new();
    // One bake per transport; the lightfield bake also carries the dense operator if needed.
    let mut transports: Vec<Transport> = Vec::new();
    for method in &bench.methods {
        if !transports.contains(&method.transport()) {
            transports.push(method.transport());
        }
    }
    for transport in transports {
        let methods: Vec<BenchMethod> = bench
            .methods
            .iter()
            .copied()
            .filter(|m| m.transport() == transport)
            .collect();
        on_method(&format!(
            "{} T{} r{} bake {transport:?}",
            bench.name, setting.texels_per_face, setting.rays_per_texel
        ));
        let options = BakeOptions {
            cache: None,
            full: methods.contains(&BenchMethod::Full),
            transport: Some(transport),
        };
        let (bundle, report) = bake(&scene, &bench.dir, &options, &NoProgress)?;
        let stage_seconds: HashMap<&str, f64> = report
            .stage_seconds
            .iter()
            .map(|(n, s)| (n.as_str(), *s))
            .collect();
        for &codec in &setting.codecs {
            let start = Instant::now();
            let (bytes, encoded) =
                bundle.encode_with(&encode_options(&scene.settings, Some(codec)));
            let encode_seconds = start.elapsed().as_secs_f64();
            let decoded = lightfarm_client::decode(&bytes)?;
            let section_total: u64 = encoded.sections.iter().map(|(_, i)| i.stored_len).sum();
            let container_bytes = bytes.len() as u64 - section_total;
            for &method in &methods {
                on_method(&format!(
                    "{} {} T{} r{} {}",
                    bench.name,
                    method.label(),
                    setting.texels_per_face,
                    setting.rays_per_texel,
                    codec_name(codec)
                ));
                let bake_seconds = method
                    .stages()
                    .iter()
                    .map(|s| stage_seconds.get(s).copied().unwrap_or(0.0))
                    .sum::<f64>()
                    + encode_seconds;
                let bundle_bytes = container_bytes
                    + encoded
                        .sections
                        .iter()
                        .filter(|(n, _)| method.sections().contains(n))
                        .map(|(_, i)| i.stored_len)
                        .sum::<u64>();
                for yardstick in yardsticks {
                    let bounces = Bounces::from(yardstick.bounces);
                    let mut l2 = Vec::new();
                    let mut p95 = Vec::new();
                    for (lights, reference) in bench.light_sets.iter().zip(yardstick.references) {
                        let lights = lights_for(method, lights);
                        let mut ours =
                            evaluate(decoded.clone(), &lights, method.client_method(), bounces)?;
                        drop_buried(&mut ours, &boxes);
                        let c = compare(&ours, reference);
                        anyhow::ensure!(c.matched > 0, "{}: no texels to compare", method.label());
                        l2.push(c.relative_l2);
                        p95.push(c.p95);
                    }
                    let timed =
                        time_apply(&decoded, method, &bench.light_sets[0], bounces, frames)?;
                    points.push(BenchPoint {
                        scene: bench.name.clone(),
                        method,
                        texels_per_face: setting.texels_per_face,
                        rays_per_texel: setting.rays_per_texel,
                        tolerance: setting.tolerance,
                        codec: codec_name(codec).to_string(),
                        rank_max: report.ranks.iter().copied().max().unwrap_or(0),
                        rank_mean: mean_rank(&report),
                        bake_seconds,
                        bundle_bytes,
                        apply_ms: timed.median_ms,
                        relative_l2: l2.iter().sum::<f64>() / l2.len() as f64,
                        p95: p95.iter().sum::<f64>() / p95.len() as f64,
                        relative_l2_per_set: l2,
                        bounces: yardstick.bounces,
                        iterations: timed.iterations,
                    });
                }
            }
        }
    }
    Ok(points)
}

fn mean_rank(report: &BakeReport) -> f64 {
    if report.ranks.is_empty() {
        0.0
    } else {
        report.ranks.iter().sum::<usize>() as f64 / report.ranks.len() as f64
    }
}

/// The light set a method is evaluated with: only `dnrt` sees the poses (the others ignore the
/// dynamic objects, which the reference still contains).
fn lights_for(method: BenchMethod, lights: &LightSet) -> LightSet {
    let mut lights = lights.clone();
    if method != BenchMethod::Dnrt {
        lights.poses.clear();
    }
    lights
}

/// One point's timed frames.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimedApply {
    /// Median milliseconds of one frame.
    pub median_ms: f64,
    /// One-bounce applications per frame (`Applied::bounces` of the timed frames).
    pub iterations: u32,
}

/// Median milliseconds of one frame: `Runtime::apply` at `bounces` as `frame-time` times it,
/// plus for `dnrt` the median of the DNRT pass (probe field, SH at each object, per-texel grid
/// lookups and, past one bounce, the bounces of the light the objects change), fed the light
/// leaving the texels at that bounce mode as `eval` feeds it.
fn time_apply(
    bundle: &Bundle,
    method: BenchMethod,
    lights: &LightSet,
    bounces: Bounces,
    frames: usize,
) -> anyhow::Result<TimedApply> {
    let occluders = Occluders::from_layout(&bundle.layout);
    let direct = operator_direct(bundle, &occluders, lights);
    let mut runtime = Runtime::try_new(bundle.clone())?;
    let apply = time_frames(
        &mut runtime,
        &direct,
        method.client_method(),
        &[bounces.into()],
        frames,
        1,
    )?
    .remove(0);
    let timed = TimedApply {
        median_ms: apply.median_ms,
        iterations: apply.bounces,
    };
    if method != BenchMethod::Dnrt {
        return Ok(timed);
    }
    let bounced = is_bounced(bounces);
    let mut answer = IndirectLight::default();
    let leaving = if bounced {
        runtime.apply(method.client_method(), bounces, &direct, &mut answer)?;
        leaving_light(&direct, &answer)
    } else {
        direct
    };
    let mut times = Vec::new();
    let mut sink = IndirectLight::default();
    let mut field = ProbeField::default();
    // Made at load, like the runtime: the grids decoded, the surfaces bounded.
    let mut objects = ObjectLight::new(runtime.bundle())?;
    for _ in 0..frames.clamp(3, 50) {
        // The answer the objects' bounced light is added to, as eval adds it (not timed).
        sink.radiance.clone_from(&answer.radiance);
        let start = Instant::now();
        runtime.apply_probes(&leaving, &mut field)?;
        if !lights.poses.is_empty() {
            let bundle = runtime.bundle();
            let (l, p) = (&lights.lights, &lights.poses);
            objects.update(bundle, &field, bounced, &occluders, l, p)?;
            let method = method.client_method();
            objects.bounce(&mut runtime, method, bounces, &mut sink)?;
        }
        times.push(start.elapsed().as_secs_f64() * 1e3);
    }
    std::hint::black_box(&sink);
    Ok(TimedApply {
        median_ms: timed.median_ms + median(times),
        ..timed
    })
}
