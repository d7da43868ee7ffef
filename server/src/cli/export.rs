//! `lightfarm export BUNDLE --lights LIGHTS.json -o level.glb [--bounces N|all]
//! [--lit|--direct|--indirect]`: the bundle lit by the light set as a binary glTF file
//! (meshes with their lightmaps, point lights) for any glTF viewer; see [`crate::export`].

use std::path::PathBuf;

use anyhow::Context;
use lightfarm_client::Bundle;
use lightfarm_proto::lights::LightSet;

use super::{read_text, write_atomic};
use crate::export::{export_glb, ExportOptions};

/// Arguments of `export`.
pub struct ExportArgs {
    pub bundle: PathBuf,
    pub lights: PathBuf,
    pub out: PathBuf,
    pub options: ExportOptions,
}

pub fn run(args: ExportArgs) -> anyhow::Result<()> {
    let bytes = std::fs::read(&args.bundle)
        .with_context(|| format!("cannot read {}", args.bundle.display()))?;
    let bundle = Bundle::decode(&bytes).with_context(|| format!("{}", args.bundle.display()))?;
    let lights = LightSet::from_json(&read_text(&args.lights)?)
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.lights.display()))?;
    let (glb, exposure) = export_glb(bundle, &lights, args.options)?;
    write_atomic(&args.out, &glb)?;
    eprintln!(
        "{}: {} bytes ({} light, {} bounces, exposure {exposure:.3})",
        args.out.display(),
        glb.len(),
        args.options.mode.name(),
        args.options.bounces
    );
    Ok(())
}
