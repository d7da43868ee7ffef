//! The `lightfarm` binary: parses arguments and calls [`lightfarm_server::cli`].

use std::path::PathBuf;

use clap::{Parser, Subcommand, ValueEnum};
use lightfarm_client::Method;
use lightfarm_proto::scene::Transport;
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
        #[arg(short, long)]
        quiet: bool,
    },
    /// Apply a bundle to a light set, as a game would.
    Eval {
        bundle: PathBuf,
        #[arg(long)]
        lights: PathBuf,
        #[arg(long, value_enum, default_value = "drt")]
        method: MethodArg,
        #[arg(short, long)]
        out: PathBuf,
    },
    /// Brute-force one-bounce reference.
    Reference {
        scene: PathBuf,
        #[arg(long)]
        lights: PathBuf,
        #[arg(long, default_value_t = 4096)]
        rays: u32,
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
    /// Print the JSON Schema of the scene description.
    Schema,
}

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_writer(std::io::stderr)
        .init();
    match Args::parse().command {
        Command::Bake {
            scene,
            out,
            cache,
            no_cache,
            full,
            transport,
            quiet,
        } => cli::bake::run(cli::bake::BakeArgs {
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
        Command::Eval {
            bundle,
            lights,
            method,
            out,
        } => {
            let method = match method {
                MethodArg::Full => Method::Full,
                MethodArg::Mrt => Method::Mrt,
                MethodArg::Drt => Method::Drt,
            };
            cli::eval::run(cli::eval::EvalArgs {
                bundle,
                lights,
                method,
                out,
            })
        }
        Command::Reference {
            scene,
            lights,
            rays,
            out,
        } => cli::reference::run(cli::reference::ReferenceArgs {
            scene,
            lights,
            rays,
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
        Command::Schema => {
            println!(
                "{}",
                serde_json::to_string_pretty(&lightfarm_proto::scene::scene_schema())?
            );
            Ok(())
        }
    }
}
