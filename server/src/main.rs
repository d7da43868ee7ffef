//! The `lightfarm` binary: parses arguments and calls [`lightfarm_server::cli`].

use std::path::PathBuf;

use clap::{Parser, Subcommand, ValueEnum};
use lightfarm_client::{Bounces, Method};
use lightfarm_proto::bounces::BounceCount;
use lightfarm_proto::scene::{BundleCodec, Transport};
use lightfarm_server::cli;

#[derive(Parser)]
#[command(
    name = "lightfarm",
    version,
    about = "Bakes precomputed indirect lighting (MRT/DRT/DNRT) and applies it."
)]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Clone, Copy, ValueEnum)]
enum UpdateArg {
    /// One light moves; the others stay.
    OneLight,
    /// One posed dynamic object moves; the lights and the other objects stay.
    OneObject,
}

#[derive(Clone, Copy, ValueEnum)]
enum MethodArg {
    Full,
    Mrt,
    Drt,
}

#[derive(Clone, Copy, ValueEnum)]
enum TransportArg {
    Lightfield,
    Traced,
}

#[derive(Clone, Copy, ValueEnum)]
enum CodecArg {
    Auto,
    F32,
    F16,
    U8,
}

impl From<CodecArg> for BundleCodec {
    fn from(c: CodecArg) -> BundleCodec {
        match c {
            CodecArg::Auto => BundleCodec::Auto,
            CodecArg::F32 => BundleCodec::F32,
            CodecArg::F16 => BundleCodec::F16,
            CodecArg::U8 => BundleCodec::U8,
        }
    }
}

/// `--bounces` of `frame-time`: a bounce count, Enlighten-style feedback or warm-started
/// Converged.
#[derive(Clone, Copy, Debug)]
struct BouncesArg(Bounces);

impl std::str::FromStr for BouncesArg {
    type Err = String;

    fn from_str(s: &str) -> Result<BouncesArg, String> {
        if s.trim().eq_ignore_ascii_case("feedback") {
            return Ok(BouncesArg(Bounces::Feedback));
        }
        if s.trim().eq_ignore_ascii_case("warm") {
            return Ok(BouncesArg(Bounces::Warm {
                tolerance: lightfarm_client::DEFAULT_TOLERANCE,
            }));
        }
        let count: BounceCount = s
            .parse()
            .map_err(|e| format!("{e}, \"feedback\" or \"warm\""))?;
        Ok(BouncesArg(count.into()))
    }
}

impl From<MethodArg> for Method {
    fn from(m: MethodArg) -> Method {
        match m {
            MethodArg::Full => Method::Full,
            MethodArg::Mrt => Method::Mrt,
            MethodArg::Drt => Method::Drt,
        }
    }
}

#[derive(Subcommand)]
enum Command {
    /// Bake a scene into an operator bundle.
    Bake {
        scene: PathBuf,
        #[arg(short, long)]
        out: PathBuf,
        /// Shape-operator cache directory.
        #[arg(long, default_value = "lightfarm-data/shapes")]
        cache: PathBuf,
        /// Do not use the shape-operator cache.
        #[arg(long)]
        no_cache: bool,
        /// Also bake the dense per-texel operator (needed by `eval --method full`).
        #[arg(long)]
        full: bool,
        /// Override the scene's inter-block transport.
        #[arg(long, value_enum)]
        transport: Option<TransportArg>,
        /// Override the scene's bundle codec (auto: per operator from `codec_error`).
        #[arg(long, value_enum)]
        codec: Option<CodecArg>,
        #[arg(short, long)]
        quiet: bool,
    },
    /// Time the client runtime: median frame of `--frames` applications, and the
    /// memory-traffic bound.
    FrameTime {
        bundle: PathBuf,
        #[arg(long)]
        lights: PathBuf,
        #[arg(long, value_enum, default_value = "drt")]
        method: MethodArg,
        /// Bounces: a whole number ≥ 1, `all` (Converged), `feedback` (one application per
        /// frame, the previous frame's indirect light fed back) or `warm` (Converged from the
        /// previous frame's answer); several, comma-separated, are timed side by side in
        /// interleaved rounds (one line each). With `feedback` or `warm`, every mode is also
        /// timed while light `--light` moves.
        #[arg(long, default_value = "all", value_delimiter = ',')]
        bounces: Vec<BouncesArg>,
        #[arg(long, default_value_t = 1000)]
        frames: usize,
        /// Runtime threads (1: the single-thread path; more: the rayon path).
        #[arg(long, default_value_t = 1)]
        threads: usize,
        /// `one-light`: move one light (`--light`) along a small circle and time relighting by
        /// its change (its direct light alone, then `Runtime::apply_delta`) against relighting
        /// everything, direct light included (uses the first `--bounces` mode). `one-object`:
        /// move one posed dynamic object (`--object`) the same way and time relighting by the
        /// change of its shadows (`ShadowChange`), its probes and its own light against
        /// relighting everything.
        #[arg(long, value_enum)]
        update: Option<UpdateArg>,
        /// The light `--update one-light` and the moving-light lines move (index in the light
        /// set).
        #[arg(long, default_value_t = 0)]
        light: usize,
        /// The dynamic object `--update one-object` moves (index in the light set's poses).
        #[arg(long, default_value_t = 0)]
        object: usize,
        /// Radius (m) of the circle `--update one-light` moves the light on (and `one-object`
        /// the object), one turn every 120 frames (0.1: 5 mm a frame; 1: 5 cm a frame, a
        /// walking torch at 60 Hz).
        #[arg(long, default_value_t = cli::frame_update::PATH_RADIUS)]
        radius: f64,
        /// With `--update one-light`: time relighting by the change alone, frame after frame,
        /// as a game that only moves the light runs it (relighting everything runs once, after
        /// the last frame, for the drift; its line and the speedup are left out). Without it
        /// the two ways alternate frame by frame, and the full way's passes over the level
        /// leave the caches cold for each update.
        #[arg(long)]
        update_alone: bool,
        /// With `--bounces feedback`: texels of due blocks and clutter objects a frame shoots
        /// at most besides the change's (`Runtime::set_feedback_budget`; default: all due).
        #[arg(long)]
        feedback_budget: Option<usize>,
        /// Also time every `all` mode with its bounces over texels (`converged(…)-texels`
        /// lines), side by side with the coefficient-space paths MRT and DRT use by default.
        #[arg(long)]
        texel_bounces: bool,
    },
    /// Show what a bundle holds: sections, operators, ranks, values.
    Inspect { bundle: PathBuf },
    /// Apply a bundle to a light set, as a game would.
    Eval {
        bundle: PathBuf,
        #[arg(long)]
        lights: PathBuf,
        #[arg(long, value_enum, default_value = "drt")]
        method: MethodArg,
        /// Bounces of indirect light: a whole number ≥ 1 or `all` (iterated until converged).
        #[arg(long, default_value = "all")]
        bounces: BounceCount,
        #[arg(short, long)]
        out: PathBuf,
        /// Also write the indirect lightmap atlas as PNG (8-bit sRGB, auto exposure).
        #[arg(long)]
        png: Option<PathBuf>,
        /// Also write the lit (direct + indirect) lightmap atlas as PNG.
        #[arg(long)]
        png_lit: Option<PathBuf>,
        /// Also write the indirect lightmap atlas as raw f16 RGB (for engines).
        #[arg(long)]
        f16: Option<PathBuf>,
        /// Also write every texel's SH incident radiance (27 little-endian f32 per texel:
        /// R, G, B × 9 coefficients); needs a bundle baked with `settings.sh_responses`.
        #[arg(long)]
        sh_out: Option<PathBuf>,
    },
    /// Write the bundle lit by a light set as binary glTF (meshes with their lightmaps on
    /// their own UVs, point lights as KHR_lights_punctual) for any glTF viewer.
    Export {
        bundle: PathBuf,
        #[arg(long)]
        lights: PathBuf,
        #[arg(short, long)]
        out: PathBuf,
        /// Bounces of indirect light: a whole number ≥ 1 or `all` (iterated until converged).
        #[arg(long, default_value = "all")]
        bounces: BounceCount,
        /// Textures hold direct + indirect light (the default).
        #[arg(long, conflicts_with_all = ["direct", "indirect"])]
        lit: bool,
        /// Textures hold direct light only.
        #[arg(long, conflicts_with = "indirect")]
        direct: bool,
        /// Textures hold indirect light only.
        #[arg(long)]
        indirect: bool,
    },
    /// Brute-force reference: path tracing with next-event estimation on the full geometry.
    Reference {
        scene: PathBuf,
        #[arg(long)]
        lights: PathBuf,
        #[arg(long, default_value_t = 4096)]
        rays: u32,
        /// Bounces of indirect light: a whole number ≥ 1 or `all`.
        #[arg(long, default_value = "all")]
        bounces: BounceCount,
        /// Trace every K-th texel of each surface only (K = 1: all); the others are left out
        /// of RESULT.json, and `compare` matches the ones present.
        #[arg(long, default_value_t = 1)]
        texel_stride: u32,
        #[arg(short, long)]
        out: PathBuf,
    },
    /// Relative L2 and p95 error of A against B.
    Compare {
        a: PathBuf,
        b: PathBuf,
        /// Only surfaces whose name starts with this (e.g. `clutter:` or `block:`).
        #[arg(long)]
        only: Option<String>,
        /// The scene (for --near-clutter).
        #[arg(long)]
        scene: Option<PathBuf>,
        /// Only block texels within this many metres of clutter.
        #[arg(long)]
        near_clutter: Option<f64>,
    },
    /// Speed against error: sweep scenes × methods × bake settings against a cached high-ray
    /// reference; write results.json, plots and BENCHMARKS.md-ready markdown.
    Bench {
        /// A few minutes on 2 cores (small scenes, few settings, low reference rays).
        #[arg(long)]
        quick: bool,
        /// Output directory (results.json and the plots).
        #[arg(long, default_value = "bench-out")]
        out: PathBuf,
        /// Where to write the markdown [default: OUT/BENCHMARKS.md].
        #[arg(long)]
        markdown: Option<PathBuf>,
        /// Cache of reference results (keyed by content; reused across runs).
        #[arg(long, default_value = "lightfarm-data/bench-references")]
        reference_cache: PathBuf,
        /// Directory of the example scenes.
        #[arg(long, default_value = "scenes")]
        scenes: PathBuf,
        /// Seed of the light sets and the exported rays.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Skip the Embree throughput comparison.
        #[arg(long)]
        no_embree: bool,
        /// Python interpreter with embreex installed.
        #[arg(long, default_value = "python3")]
        python: String,
        /// The Embree side of the throughput comparison.
        #[arg(long, default_value = "scripts/embree_throughput.py")]
        embree_script: PathBuf,
        /// Only rewrite the plots and markdown from OUT/results.json (no measuring).
        #[arg(long)]
        replot: bool,
        /// Bounces of the references, the runtime's mode and the path tracer at equal error: a
        /// whole number ≥ 1 or `all` (the runtime converges). Unless 1, every point is also
        /// measured at one bounce against one-bounce references, as rows of their own.
        #[arg(long, default_value = "all")]
        bounces: BounceCount,
        /// Measure only how costs grow with the level: generated levels of these block counts
        /// (comma-separated, e.g. 20,80,320,1000): bake stages, peak memory, bytes per section,
        /// frame times, error. Writes OUT/scale.json and the markdown's scale section (keeping
        /// OUT/results.json's). With --quick: 4 texels per face and 128 rays instead of 8 and
        /// 1,024.
        #[arg(long, value_delimiter = ',')]
        scale: Option<Vec<u32>>,
        /// With --scale: every level is copies of one level of this many blocks, joined in a
        /// row (`gen_level.py --tile`; each count a multiple of it), and the lights moved are
        /// the first copy's, the same neighbourhood at every size: how relighting a light
        /// grows with the level alone. Writes OUT/scale_tiled.json and its own section.
        #[arg(long, requires = "scale")]
        tile: Option<u32>,
        /// Measure only the ray throughput against Embree (on the scene and ray count of
        /// OUT/results.json's plan), replace results.json's throughput with it (keeping every
        /// other figure) and rewrite the markdown.
        #[arg(long, conflicts_with_all = ["scale", "replot"])]
        throughput: bool,
        /// The level generator of --scale.
        #[arg(long, default_value = "scripts/gen_level.py")]
        generator: PathBuf,
    },
    /// Print the JSON Schema of the scene description.
    Schema,
    /// Run the bake service (HTTP API; in-process workers, on-disk store under --data; with
    /// --farm, a stateless replica of a bake farm on NATS JetStream).
    Serve {
        /// Listen address [default: 127.0.0.1:8080, or the config file's `addr`]. Without
        /// --config only loopback addresses are accepted.
        #[arg(long)]
        addr: Option<std::net::SocketAddr>,
        /// Data directory [default: ./lightfarm-data, or the config file's `data`].
        #[arg(long)]
        data: Option<PathBuf>,
        /// TOML file with `[[teams]]` tokens and `[limits]`.
        #[arg(long)]
        config: Option<PathBuf>,
        /// NATS server of a bake farm (`nats://HOST:PORT`): jobs and blobs live in JetStream and
        /// bakes run on `lightfarm worker`s.
        #[arg(long)]
        farm: Option<String>,
    },
    /// Run a bake-farm worker: pulls bake units from NATS JetStream and runs them.
    Worker {
        /// NATS server of the farm (`nats://HOST:PORT`).
        #[arg(long)]
        farm: String,
        /// Local operator cache and scratch directory.
        #[arg(long, default_value = "lightfarm-worker")]
        cache: PathBuf,
        /// Threads for unit work (0: one per core).
        #[arg(long, default_value_t = 0)]
        threads: usize,
        /// Byte budget of the local operator cache, trimmed least-recently-used after each unit
        /// and bake (the service's own default: 10 GiB).
        #[arg(long, default_value_t = lightfarm_server::service::config::DEFAULT_OPERATOR_CACHE_BYTES)]
        cache_bytes: u64,
    },
}

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| "warn,lightfarm_server::service=info".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    match Args::parse().command {
        Command::Inspect { bundle } => cli::inspect::run(bundle),
        Command::FrameTime {
            bundle,
            lights,
            method,
            bounces,
            frames,
            threads,
            update,
            light,
            object,
            radius,
            update_alone,
            feedback_budget,
            texel_bounces,
        } => cli::frame_time::run(cli::frame_time::FrameTimeArgs {
            bundle,
            lights,
            method: method.into(),
            bounces: bounces.into_iter().map(|b| b.0).collect(),
            frames,
            threads,
            update_light: update
                .filter(|u| matches!(u, UpdateArg::OneLight))
                .map(|_| light),
            update_object: update
                .filter(|u| matches!(u, UpdateArg::OneObject))
                .map(|_| object),
            moving_light: light,
            radius,
            update_alone,
            feedback_budget,
            texel_bounces,
        }),
        Command::Bake {
            scene,
            out,
            cache,
            no_cache,
            full,
            transport,
            codec,
            quiet,
        } => cli::bake::run(cli::bake::BakeArgs {
            codec: codec.map(Into::into),
            scene,
            out,
            cache: (!no_cache).then_some(cache),
            full,
            transport: transport.map(|t| match t {
                TransportArg::Lightfield => Transport::Lightfield,
                TransportArg::Traced => Transport::Traced,
            }),
            quiet,
        }),
        Command::Export {
            bundle,
            lights,
            out,
            bounces,
            lit: _,
            direct,
            indirect,
        } => cli::export::run(cli::export::ExportArgs {
            bundle,
            lights,
            out,
            options: lightfarm_server::export::ExportOptions {
                mode: if direct {
                    lightfarm_server::export::LightMode::Direct
                } else if indirect {
                    lightfarm_server::export::LightMode::Indirect
                } else {
                    lightfarm_server::export::LightMode::Lit
                },
                bounces,
            },
        }),
        Command::Eval {
            bundle,
            lights,
            method,
            bounces,
            out,
            png,
            png_lit,
            f16,
            sh_out,
        } => cli::eval::run(cli::eval::EvalArgs {
            bundle,
            lights,
            method: method.into(),
            bounces: bounces.into(),
            out,
            lightmaps: cli::lightmap_files::LightmapFiles {
                png_indirect: png,
                png_lit,
                f16_indirect: f16,
            },
            sh_out,
        }),
        Command::Reference {
            scene,
            lights,
            rays,
            bounces,
            texel_stride,
            out,
        } => cli::reference::run(cli::reference::ReferenceArgs {
            scene,
            lights,
            rays,
            bounces,
            texel_stride,
            out,
        }),
        Command::Compare {
            a,
            b,
            only,
            scene,
            near_clutter,
        } => cli::compare::run(cli::compare::CompareArgs {
            a,
            b,
            only,
            scene,
            near_clutter,
        }),
        Command::Serve {
            addr,
            data,
            config,
            farm,
        } => cli::serve::run(cli::serve::ServeArgs {
            addr,
            data,
            config,
            farm,
        }),
        Command::Worker {
            farm,
            cache,
            threads,
            cache_bytes,
        } => cli::worker::run(cli::worker::WorkerArgs {
            farm,
            cache,
            threads,
            cache_bytes,
        }),
        Command::Bench {
            quick,
            out,
            markdown,
            reference_cache,
            scenes,
            seed,
            no_embree,
            python,
            embree_script,
            replot,
            bounces,
            scale,
            tile,
            throughput,
            generator,
        } => cli::bench::run(cli::bench::BenchArgs {
            preset: if quick {
                cli::bench::Preset::Quick
            } else {
                cli::bench::Preset::Full
            },
            out,
            markdown,
            reference_cache,
            scenes,
            seed,
            embree: (!no_embree).then_some((python.clone(), embree_script)),
            command_line: std::env::args().collect::<Vec<_>>().join(" "),
            replot,
            bounces,
            scale,
            tile,
            throughput_only: throughput,
            python,
            generator,
        }),
        Command::Schema => {
            lightfarm_server::say!(
                "{}",
                serde_json::to_string_pretty(&lightfarm_proto::scene::scene_schema())?
            );
            Ok(())
        }
    }
}
