//! `lightfarm reference SCENE.json --lights LIGHTS.json --rays N [--bounces N|all]
//! [--texel-stride K] -o RESULT.json`: brute-force indirect light (all bounces by default) on the
//! full geometry (blocks, clutter, posed dynamic objects).

use std::path::PathBuf;

use lightfarm_proto::bounces::BounceCount;
use lightfarm_proto::lights::LightSet;

use super::bake::load_scene;
use super::progress_bar::Bar;
use super::{read_text, write_json};
use crate::bake::progress::Progress;
use crate::bake::reference::{reference, ReferenceSettings};
use crate::bake::scene::geometry::Geometry;

/// Arguments of `reference`.
pub struct ReferenceArgs {
    pub scene: PathBuf,
    pub lights: PathBuf,
    pub rays: u32,
    pub bounces: BounceCount,
    /// Every K-th texel of each surface (1: all).
    pub texel_stride: u32,
    pub out: PathBuf,
}

pub fn run(args: ReferenceArgs) -> anyhow::Result<()> {
    let (scene, dir) = load_scene(&args.scene)?;
    let lights = LightSet::from_json(&read_text(&args.lights)?)
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.lights.display()))?;
    let mut geometry = Geometry::from_scene(&scene, &dir)?;
    geometry.add_posed_dynamic(&scene, &dir, &lights.poses)?;
    let bar = Bar::new();
    let stride = args.texel_stride.max(1);
    let selected = geometry.texels.iter().filter(|t| t.index % stride == 0);
    bar.stage("reference", selected.count() as u64);
    let settings = ReferenceSettings {
        rays: args.rays,
        bounces: args.bounces,
        seed: scene.settings.seed,
        texel_stride: args.texel_stride,
    };
    let result = reference(&geometry, &lights.lights, &settings, &|n| bar.advance(n));
    bar.finish();
    write_json(&args.out, &result)
}
