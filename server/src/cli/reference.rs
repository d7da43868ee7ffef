//! `lightfarm reference SCENE.json --lights LIGHTS.json --rays N -o RESULT.json`: brute-force
//! one-bounce indirect on the full geometry (blocks, clutter, posed dynamic objects).

use std::path::PathBuf;

use lightfarm_proto::lights::LightSet;

use super::bake::load_scene;
use super::progress_bar::Bar;
use super::{read_text, write_json};
use crate::bake::geometry::Geometry;
use crate::bake::progress::Progress;
use crate::bake::reference::reference;

/// Arguments of `reference`.
pub struct ReferenceArgs {
    pub scene: PathBuf,
    pub lights: PathBuf,
    pub rays: u32,
    pub out: PathBuf,
}

pub fn run(args: ReferenceArgs) -> anyhow::Result<()> {
    let (scene, dir) = load_scene(&args.scene)?;
    let lights = LightSet::from_json(&read_text(&args.lights)?)
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.lights.display()))?;
    let mut geometry = Geometry::from_scene(&scene, &dir)?;
    geometry.add_posed_dynamic(&scene, &dir, &lights.poses)?;
    let bar = Bar::new();
    bar.stage("reference", geometry.texels.len() as u64);
    let result = reference(
        &geometry,
        &lights.lights,
        args.rays,
        scene.settings.seed,
        &|n| bar.advance(n),
    );
    bar.finish();
    write_json(&args.out, &result)
}
