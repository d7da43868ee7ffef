//! `lightfarm compare A.json B.json [--only PREFIX] [--scene S [--near-clutter M]]`: relative L2
//! error of A's indirect against B's over the texels both hold (optionally only surfaces whose
//! name starts with PREFIX, or only block texels within M metres of clutter), and the
//! 95th-percentile texel error. With `--scene`, block texels buried inside clutter boxes are left
//! out (as the Mitsuba check does). Last line: `relative_l2=<x> p95=<y>`.

use std::path::{Path, PathBuf};

use lightfarm_proto::result::{compare, ResultFile};
use lightfarm_proto::scene::Aabb;

use super::bake::load_scene;
use super::read_text;
use crate::bake::scene::mesh::load_mesh;

/// Arguments of `compare`.
pub struct CompareArgs {
    pub a: PathBuf,
    pub b: PathBuf,
    pub only: Option<String>,
    pub scene: Option<PathBuf>,
    pub near_clutter: Option<f64>,
}

/// Bounding boxes of every clutter object of a scene.
pub fn clutter_bounds(scene_path: &Path) -> anyhow::Result<Vec<Aabb>> {
    let (scene, dir) = load_scene(scene_path)?;
    let mut out = Vec::new();
    for c in &scene.clutter {
        if let Some(b) = c.box_ {
            out.push(b);
        } else if let Some(mesh) = &c.mesh {
            let m = load_mesh(
                &format!("clutter \"{}\"", c.id),
                &dir,
                mesh,
                &c.transform.unwrap_or_default(),
            )?;
            let mut b = Aabb {
                min: [f64::INFINITY; 3],
                max: [f64::NEG_INFINITY; 3],
            };
            for v in m.triangles.iter().flatten() {
                for k in 0..3 {
                    b.min[k] = b.min[k].min(v[k]);
                    b.max[k] = b.max[k].max(v[k]);
                }
            }
            out.push(b);
        }
    }
    Ok(out)
}

/// Distance from a point to a box (0 inside).
pub fn distance_to_box(p: [f64; 3], b: &Aabb) -> f64 {
    (0..3)
        .map(|k| (b.min[k] - p[k]).max(0.0).max(p[k] - b.max[k]).powi(2))
        .sum::<f64>()
        .sqrt()
}

pub fn run(args: CompareArgs) -> anyhow::Result<()> {
    let load = |p: &Path| -> anyhow::Result<ResultFile> {
        serde_json::from_str(&read_text(p)?).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))
    };
    let (mut ours, reference) = (load(&args.a)?, load(&args.b)?);
    if let Some(prefix) = &args.only {
        ours.texels
            .retain(|t| t.surface.starts_with(prefix.as_str()));
    }
    if let Some(scene) = &args.scene {
        // Texels buried in clutter boxes are never seen; their reference values are meaningless.
        let (scene, _) = load_scene(scene)?;
        let boxes: Vec<Aabb> = scene.clutter.iter().filter_map(|c| c.box_).collect();
        ours.texels.retain(|t| {
            !t.surface.starts_with("block:")
                || !boxes.iter().any(|b| {
                    (0..3).all(|k| {
                        t.position[k] >= b.min[k] - 1e-6 && t.position[k] <= b.max[k] + 1e-6
                    })
                })
        });
    }
    if let Some(m) = args.near_clutter {
        let Some(scene) = &args.scene else {
            anyhow::bail!("--near-clutter needs --scene")
        };
        let boxes = clutter_bounds(scene)?;
        ours.texels.retain(|t| {
            t.surface.starts_with("block:")
                && boxes.iter().any(|b| distance_to_box(t.position, b) <= m)
        });
    }
    let c = compare(&ours, &reference);
    if c.matched == 0 {
        anyhow::bail!(
            "{} and {} share no texels (after filters)",
            args.a.display(),
            args.b.display()
        );
    }
    crate::say!(
        "matched_texels={} unmatched_texels={}",
        c.matched,
        c.unmatched
    );
    crate::say!("relative_l2={:.6} p95={:.6}", c.relative_l2, c.p95);
    Ok(())
}
