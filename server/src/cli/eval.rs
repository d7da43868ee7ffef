//! `lightfarm eval OUT.lfb --lights LIGHTS.json [--method full|mrt|drt] [--bounces N|all]
//! -o RESULT.json`: apply a bundle through the client crate, exactly as a game would
//! ([`crate::evaluate`]), and write per-texel radiance, optionally lightmaps and SH.

use std::path::PathBuf;

use anyhow::Context;
use lightfarm_client::{Bounces, Bundle, Method};
use lightfarm_proto::lights::LightSet;

use crate::evaluate::evaluate_with_report;
use crate::evaluate::sh::sh_incident;

use super::lightmap_files::{write_lightmaps, LightmapFiles};
use super::{read_text, write_json};

/// Arguments of `eval`.
pub struct EvalArgs {
    pub bundle: PathBuf,
    pub lights: PathBuf,
    pub method: Method,
    pub bounces: Bounces,
    pub out: PathBuf,
    pub lightmaps: LightmapFiles,
    /// Also write every texel's SH incident radiance (`eval_sh`); needs an `sh` section.
    pub sh_out: Option<PathBuf>,
}

pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    let bytes = std::fs::read(&args.bundle)
        .with_context(|| format!("cannot read {}", args.bundle.display()))?;
    let bundle = Bundle::decode(&bytes).with_context(|| format!("{}", args.bundle.display()))?;
    let lights = LightSet::from_json(&read_text(&args.lights)?)
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.lights.display()))?;
    let layout = bundle.layout.clone();
    if let Some(path) = &args.sh_out {
        let sh = sh_incident(bundle.clone(), &lights, args.bounces)?;
        super::eval_sh::write_sh_file(path, &sh)?;
    }
    let surface_atlases = bundle.surface_atlases.clone();
    let (result, applied) = evaluate_with_report(bundle, &lights, args.method, args.bounces)?;
    match lightfarm_client::Bounces::from(args.bounces) {
        lightfarm_client::Bounces::Converged { .. } => eprintln!(
            "bounces: all, {} applied (operator applications; estimated error {:.2e})",
            applied.bounces, applied.remaining_fraction
        ),
        _ => eprintln!("bounces: {} applied", applied.bounces),
    }
    write_json(&args.out, &result)?;
    if !args.lightmaps.is_empty() {
        eprintln!(
            "lightmaps: {}",
            write_lightmaps(&layout, &surface_atlases, &result, &args.lightmaps)?
        );
    }
    Ok(())
}
