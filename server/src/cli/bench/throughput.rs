//! Ray throughput of our tracer (`bake::tracer::Tracer`: an 8-wide BVH built from obvhs's BVH2,
//! f32 tests, f64 where it decides) against Embree (`embreex`, through `scripts/embree_throughput.py`) on the same triangles
//! and the same rays.
//!
//! The scene's primitives are written as a triangle soup (each rectangle as two triangles) and
//! a seeded set of rays leaves the texels the way the reference solver's first bounce does
//! (cosine-distributed, from 1e-4 of the scene scale above the surface so that neither tracer
//! needs its own self-hit rule). Both sides trace closest hits on one thread; ours is timed on
//! the same triangles (the ratio) and on its native rectangles (what a bake actually uses).
//!
//! Invariant: both tracers read the very same f32 values (ours widens them to f64).

use std::path::Path;
use std::process::Command;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::bake::math::sampling::{
    sample_cosine_hemisphere, sobol_2d, stream_key, to_world, Purpose,
};
use crate::bake::scene::geometry::{Geometry, Primitive};
use lightfarm_proto::face::tangent_axes;

use crate::bake::tracer::Tracer;

/// One round of [`measure_throughput`].
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct ThroughputRound {
    pub ours_triangles_rays_per_second: f64,
    pub ours_native_rays_per_second: f64,
    pub embree_rays_per_second: Option<f64>,
    /// Embree traced before ours in this round (false in results written before the order
    /// alternated).
    #[serde(default)]
    pub embree_first: bool,
}

impl ThroughputRound {
    /// Ours : Embree in this round.
    pub fn ratio(&self) -> Option<f64> {
        self.embree_rays_per_second
            .map(|e| self.ours_triangles_rays_per_second / e)
    }
}

impl Throughput {
    /// Ours : Embree: the median of the rounds' ratios, or the rates' quotient for results
    /// written before the rounds.
    pub fn ours_to_embree(&self) -> Option<f64> {
        self.ratio.or_else(|| {
            self.embree_rays_per_second
                .map(|e| self.ours_triangles_rays_per_second / e)
        })
    }
}

/// Rays per second of both tracers (None where a side could not be measured, with why).
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Throughput {
    pub scene: String,
    pub triangles: usize,
    pub rays: usize,
    /// Ours on the triangle soup, one thread, the median of the rounds (named `obvhs_…` in
    /// results before the 4-wide BVH).
    #[serde(alias = "obvhs_triangles_rays_per_second")]
    pub ours_triangles_rays_per_second: f64,
    /// Ours on the native primitives (rectangles), one thread, the median of the rounds.
    #[serde(alias = "obvhs_native_rays_per_second")]
    pub ours_native_rays_per_second: f64,
    /// Embree, the median of the rounds.
    pub embree_rays_per_second: Option<f64>,
    pub embree_build_seconds: Option<f64>,
    /// Fraction of rays whose closest-hit distance agrees (1e-3 relative) between the two.
    pub agreement: Option<f64>,
    /// Why Embree was not measured.
    pub embree_missing: Option<String>,
    /// Ours : Embree, the median of the rounds' ratios (None: Embree not measured, or results
    /// from before the rounds, whose ratio is the two rates' quotient).
    #[serde(default)]
    pub ratio: Option<f64>,
    /// Each round side by side ([`ROUNDS`]); the rates above are their medians.
    #[serde(default)]
    pub rounds: Vec<ThroughputRound>,
    /// The tracer's compiled copy that ran (`bake::tracer::InstructionSet`).
    #[serde(default)]
    pub instruction_set: Option<String>,
    /// The command line of a `bench --throughput` run that measured this apart from the rest
    /// of results.json (None: measured with it).
    #[serde(default)]
    pub measured_by: Option<String>,
}

/// The geometry's primitives as triangles (a rectangle becomes two).
pub fn triangle_soup(primitives: &[Primitive]) -> Vec<[[f64; 3]; 3]> {
    let mut out = Vec::with_capacity(primitives.len() * 2);
    for p in primitives {
        match p {
            Primitive::Rect {
                axis,
                coord,
                min,
                max,
                ..
            } => {
                let (u, v) = tangent_axes(*axis);
                let corner = |a: f64, b: f64| {
                    let mut c = [0.0; 3];
                    c[*axis] = *coord;
                    c[u] = a;
                    c[v] = b;
                    c
                };
                let (c00, c10) = (corner(min[0], min[1]), corner(max[0], min[1]));
                let (c11, c01) = (corner(max[0], max[1]), corner(min[0], max[1]));
                out.push([c00, c10, c11]);
                out.push([c00, c11, c01]);
            }
            Primitive::Triangle { v, .. } => out.push(*v),
        }
    }
    out
}

/// Our tracer over `soup`'s triangles as f32 (what Embree reads), at the scene's `scale`.
pub fn triangle_tracer(soup: &[[[f64; 3]; 3]], scale: f64) -> Tracer {
    Tracer::new(
        soup.iter()
            .map(|v| Primitive::Triangle {
                v: v.map(|p| p.map(|x| x as f32 as f64)),
                albedo: [0.5; 3],
                lightmap: None,
            })
            .collect(),
        scale,
    )
}

/// `n_rays` seeded cosine-distributed rays from the texels (cycled), origins lifted off the
/// surface; each value is rounded to f32 (what both tracers read).
pub fn texel_rays(g: &Geometry, n_rays: usize, seed: u64) -> Vec<([f64; 3], [f64; 3])> {
    let lift = 1e-4 * g.scale();
    (0..n_rays)
        .map(|i| {
            let texel = &g.texels[i % g.texels.len()];
            let round = (i / g.texels.len()) as u32;
            let key = stream_key(seed, Purpose::Throughput, (i % g.texels.len()) as u64);
            let d = to_world(sample_cosine_hemisphere(sobol_2d(key, round)), texel.normal);
            let o = [0, 1, 2].map(|k| texel.position[k] + lift * texel.normal[k]);
            let f = |x: f64| x as f32 as f64;
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            (o.map(f), d.map(|x| f(x / len)))
        })
        .collect()
}

/// Closest-hit distance of every ray (inf on a miss) and the best-of-3 rays per second.
fn trace_all(tracer: &Tracer, rays: &[([f64; 3], [f64; 3])]) -> (Vec<f32>, f64) {
    let no_surfaces = |_: u32| 1.0;
    let mut distances = vec![f32::INFINITY; rays.len()];
    let mut best = f64::INFINITY;
    for _ in 0..3 {
        let start = Instant::now();
        for (slot, (o, d)) in distances.iter_mut().zip(rays) {
            *slot = tracer
                .closest(*o, *d, f64::INFINITY, &no_surfaces)
                .map_or(f32::INFINITY, |h| h.t as f32);
        }
        best = best.min(start.elapsed().as_secs_f64());
    }
    (distances, rays.len() as f64 / best)
}

fn write_f32(path: &Path, values: impl Iterator<Item = f32>) -> anyhow::Result<()> {
    let bytes: Vec<u8> = values.flat_map(f32::to_le_bytes).collect();
    crate::cli::write_atomic(path, &bytes)
}

/// Rounds of the comparison: each traces the rays with ours (best of 3) and Embree (its
/// script's best of 3), so both sides of a round's ratio share the machine's state of the
/// moment; the ratio reported is the median of the rounds' ratios. Which goes first
/// alternates (ours in round 0, whose distances Embree's agreement is checked against), so
/// neither side always runs second: bakes timed side by side on this shared machine ran
/// slower second.
pub const ROUNDS: usize = 9;

/// Measures both tracers on `g`, [`ROUNDS`] rounds side by side; exports to `dir` and runs
/// `python script dir` each round for Embree unless `python_and_script` is None.
pub fn measure_throughput(
    scene_name: &str,
    g: &Geometry,
    n_rays: usize,
    seed: u64,
    dir: &Path,
    python_and_script: Option<(&str, &Path)>,
) -> anyhow::Result<Throughput> {
    let soup = triangle_soup(&g.primitives);
    let rays = texel_rays(g, n_rays, seed);
    let triangle_tracer = triangle_tracer(&soup, g.scale());
    let native_tracer = Tracer::new(g.primitives.clone(), g.scale());
    let mut out = Throughput {
        scene: scene_name.to_string(),
        triangles: soup.len(),
        rays: rays.len(),
        instruction_set: Some(format!("{:?}", triangle_tracer.instruction_set())),
        ..Throughput::default()
    };
    let mut embree = match python_and_script {
        None => {
            out.embree_missing = Some("skipped (--no-embree)".into());
            None
        }
        Some(python_and_script) => {
            std::fs::create_dir_all(dir)?;
            write_f32(
                &dir.join("triangles.f32"),
                soup.iter().flatten().flatten().map(|&x| x as f32),
            )?;
            write_f32(
                &dir.join("rays.f32"),
                rays.iter()
                    .flat_map(|(o, d)| o.iter().chain(d).map(|&x| x as f32).collect::<Vec<_>>()),
            )?;
            Some(python_and_script)
        }
    };
    for round in 0..ROUNDS {
        let embree_first = round % 2 == 1 && embree.is_some();
        let early = match embree {
            Some((python, script)) if embree_first => Some(run_embree(python, script, dir)),
            _ => None,
        };
        let (distances, ours_triangles) = trace_all(&triangle_tracer, &rays);
        let (_, ours_native) = trace_all(&native_tracer, &rays);
        let mut measured = ThroughputRound {
            ours_triangles_rays_per_second: ours_triangles,
            ours_native_rays_per_second: ours_native,
            embree_rays_per_second: None,
            embree_first,
        };
        if let Some((python, script)) = embree {
            if round == 0 {
                write_f32(&dir.join("obvhs_t.f32"), distances.into_iter())?;
            }
            match early.unwrap_or_else(|| run_embree(python, script, dir)) {
                Ok(v) => {
                    measured.embree_rays_per_second = v["rays_per_second"].as_f64();
                    out.embree_build_seconds = v["build_seconds"].as_f64();
                    out.agreement = v["agreement"].as_f64();
                }
                Err(why) => {
                    out.embree_missing = Some(why);
                    embree = None;
                }
            }
        }
        out.rounds.push(measured);
    }
    let median = |f: &dyn Fn(&ThroughputRound) -> Option<f64>| {
        let mut v: Vec<f64> = out.rounds.iter().filter_map(f).collect();
        v.sort_by(f64::total_cmp);
        (!v.is_empty()).then(|| v[v.len() / 2])
    };
    out.ours_triangles_rays_per_second =
        median(&|r| Some(r.ours_triangles_rays_per_second)).unwrap_or(0.0);
    out.ours_native_rays_per_second =
        median(&|r| Some(r.ours_native_rays_per_second)).unwrap_or(0.0);
    if out.embree_missing.is_none() {
        out.embree_rays_per_second = median(&|r| r.embree_rays_per_second);
        out.ratio = median(&|r| r.ratio());
    }
    Ok(out)
}

/// One run of the Embree script: its JSON line, or why there is none.
fn run_embree(python: &str, script: &Path, dir: &Path) -> Result<serde_json::Value, String> {
    let output = Command::new(python)
        .arg(script)
        .arg(dir)
        .output()
        .map_err(|e| format!("cannot run {python}: {e}"))?;
    let stdout = String::from_utf8_lossy(&output.stdout);
    let parsed: Option<serde_json::Value> = stdout
        .lines()
        .last()
        .and_then(|l| serde_json::from_str(l).ok());
    match parsed {
        Some(v) if output.status.success() && v["rays_per_second"].is_number() => Ok(v),
        Some(v) if v["error"].is_string() => Err(v["error"].as_str().unwrap_or("").to_string()),
        _ => Err(format!(
            "{} failed ({}): {}",
            script.display(),
            output.status,
            String::from_utf8_lossy(&output.stderr).trim()
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use lightfarm_proto::scene::Aabb;
    use lightfarm_proto::Face;

    /// Rays from inside a closed box hit it at the same distance on the triangle soup as on
    /// the rectangles.
    #[test]
    fn triangle_soup_traces_like_the_rectangles() {
        let mut g = Geometry::default();
        let aabb = Aabb {
            min: [0.0; 3],
            max: [2.0, 1.0, 3.0],
        };
        g.add_block(0, "b", &aabb, &Face::ALL, |_| [0.5; 3], 4);
        let soup = triangle_soup(&g.primitives);
        assert_eq!(soup.len(), 12);
        let triangles = Tracer::new(
            soup.iter()
                .map(|&v| Primitive::Triangle {
                    v,
                    albedo: [0.5; 3],
                    lightmap: None,
                })
                .collect(),
            g.scale(),
        );
        let rects = Tracer::new(g.primitives.clone(), g.scale());
        let sign = |_: u32| 1.0;
        for (o, d) in texel_rays(&g, 500, 3) {
            let a = triangles.closest(o, d, f64::INFINITY, &sign).unwrap();
            let b = rects.closest(o, d, f64::INFINITY, &sign).unwrap();
            assert!((a.t - b.t).abs() < 1e-6, "{} vs {}", a.t, b.t);
        }
    }
}
