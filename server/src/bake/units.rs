//! PLACEHOLDER until the engine's real `units.rs` lands on main (same signatures): the whole
//! bake as one unit, whose outputs are every cache file it wrote. Replaced by the merge.

use std::path::{Path, PathBuf};

use lightfarm_proto::scene::Scene;

use super::pipeline::{bake, BakeError, BakeOptions};
use super::progress::Progress;
use super::shape_cache::ShapeCache;

/// One deterministic piece of a bake.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum BakeUnit {
    Shape { index: usize },
    Transport,
    DrtBlock { block: usize },
    DrtClutter { clutter: usize },
    Dnrt { object: usize },
}

impl BakeUnit {
    pub fn name(&self) -> String {
        match self {
            BakeUnit::Shape { index } => format!("shape/{index}"),
            BakeUnit::Transport => "transport".into(),
            BakeUnit::DrtBlock { block } => format!("drt-block/{block}"),
            BakeUnit::DrtClutter { clutter } => format!("drt-clutter/{clutter}"),
            BakeUnit::Dnrt { object } => format!("dnrt/{object}"),
        }
    }

    pub fn parse(name: &str) -> Option<BakeUnit> {
        (name == "transport").then_some(BakeUnit::Transport)
    }
}

pub fn plan(_scene: &Scene, _scene_dir: &Path) -> Result<Vec<Vec<BakeUnit>>, BakeError> {
    Ok(vec![vec![BakeUnit::Transport]])
}

pub fn unit_inputs(
    _scene: &Scene,
    _scene_dir: &Path,
    _unit: &BakeUnit,
) -> Result<Vec<PathBuf>, BakeError> {
    Ok(Vec::new())
}

fn files(dir: &Path, base: &Path, out: &mut Vec<PathBuf>) {
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                files(&p, base, out);
            } else if !p.to_string_lossy().ends_with(".tmp") {
                out.push(p.strip_prefix(base).unwrap().to_path_buf());
            }
        }
    }
}

pub fn run_unit(
    scene: &Scene,
    scene_dir: &Path,
    cache: &ShapeCache,
    _unit: &BakeUnit,
    progress: &dyn Progress,
) -> Result<Vec<PathBuf>, BakeError> {
    let options = BakeOptions {
        cache: Some(cache.clone()),
        ..BakeOptions::default()
    };
    bake(scene, scene_dir, &options, progress)?;
    let mut out = Vec::new();
    files(cache.dir(), cache.dir(), &mut out);
    Ok(out)
}
