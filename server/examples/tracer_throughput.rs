//! Ray throughput of the bake's tracer against Embree on one scene's texel rays (the comparison
//! `lightfarm bench` runs, without the rest of the bench), and against obvhs alone: obvhs's
//! own triangle test inside its compressed wide BVH's traversal, on BVHs built by its presets.
//! The tracer traverses an 8-wide BVH of its own (`bake::tracer::bvh8`), so the obvhs-alone
//! lines say what that traversal and the f64-exact answer gain or cost against obvhs's.
//!
//! `cargo run --release -p lightfarm-server --example tracer_throughput -- SCENE.json [RAYS] [--obvhs-alone] [--instruction-sets]`
//!
//! One thread each, best of 3, the same rays and triangles for every line. `--instruction-sets`
//! instead times the tracer's compiled copies (`InstructionSet`) against each other on the
//! triangles, interleaved over seven rounds, and prints each one's median (and checks that
//! every copy finds the same hits, bit for bit).

use std::path::Path;
use std::time::{Duration, Instant};

use glam::Vec3A;
use lightfarm_server::bake::scene::geometry::Geometry;
use lightfarm_server::bake::tracer::{InstructionSet, Tracer};
use lightfarm_server::cli::bake::load_scene;
use lightfarm_server::cli::bench::throughput::{
    measure_throughput, texel_rays, triangle_soup, triangle_tracer,
};
use obvhs::{
    aabb::Aabb,
    cwbvh::builder::{build_cwbvh, build_cwbvh_from_tris},
    ray::{Ray, RayHit},
    rt_triangle::RtTriangle,
    triangle::Triangle,
    BvhBuildParams,
};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let path = args
        .get(1)
        .expect("usage: tracer_throughput SCENE.json [RAYS] [--obvhs-alone]");
    let rays: usize = match args.get(2).filter(|a| !a.starts_with("--")) {
        Some(n) => n.parse()?,
        None => 1_000_000,
    };
    let (scene, dir) = load_scene(Path::new(path))?;
    let geometry = Geometry::from_scene(&scene, &dir)?;
    if args.iter().any(|a| a == "--instruction-sets") {
        compare_instruction_sets(&geometry, rays);
        return Ok(());
    }
    if args.iter().any(|a| a == "--obvhs-alone") {
        let soup: Vec<Triangle> = triangle_soup(&geometry.primitives)
            .iter()
            .map(|t| {
                let v = |p: [f64; 3]| Vec3A::new(p[0] as f32, p[1] as f32, p[2] as f32);
                Triangle {
                    v0: v(t[0]),
                    v1: v(t[1]),
                    v2: v(t[2]),
                }
            })
            .collect();
        let boxes: Vec<Aabb> = soup.iter().map(|t| t.aabb()).collect();
        let mut time = Duration::default();
        let medium = BvhBuildParams::medium_build();
        for (label, bvh) in [
            ("boxes, medium", build_cwbvh(&boxes, medium, &mut time)),
            (
                "boxes, very_slow",
                build_cwbvh(&boxes, BvhBuildParams::very_slow_build(), &mut time),
            ),
            (
                "triangles, medium",
                build_cwbvh_from_tris(&soup, medium, &mut time),
            ),
            (
                "triangles, very_slow",
                build_cwbvh_from_tris(&soup, BvhBuildParams::very_slow_build(), &mut time),
            ),
        ] {
            let tests: Vec<RtTriangle> = bvh
                .primitive_indices
                .iter()
                .map(|&i| {
                    let t = &soup[i as usize];
                    RtTriangle::new(t.v0, t.v1, t.v2)
                })
                .collect();
            let rays = texel_rays(&geometry, rays, 1);
            let v = |p: [f64; 3]| Vec3A::new(p[0] as f32, p[1] as f32, p[2] as f32);
            let mut best = f64::INFINITY;
            for _ in 0..3 {
                let start = Instant::now();
                for (o, d) in &rays {
                    let ray = Ray::new(v(*o), v(*d), 0.0, f32::INFINITY);
                    let mut hit = RayHit::none();
                    bvh.ray_traverse(ray, &mut hit, |r, id| tests[id].intersect(r));
                }
                best = best.min(start.elapsed().as_secs_f64());
            }
            println!(
                "obvhs alone ({label}): {:.3} Mrays/s",
                rays.len() as f64 / best / 1e6
            );
        }
    }
    let scratch = std::env::temp_dir().join(format!("tracer-throughput-{}", std::process::id()));
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scripts/embree_throughput.py");
    let t = measure_throughput(
        &scene.name,
        &geometry,
        rays,
        1,
        &scratch,
        Some(("python3", &script)),
    );
    let _ = std::fs::remove_dir_all(&scratch);
    let t = t?;
    let embree = t.embree_rays_per_second;
    println!(
        "triangles={} rays={} ours_triangles_mrays={:.3} ours_native_mrays={:.3} embree_mrays={} ratio={} agreement={} {}",
        t.triangles,
        t.rays,
        t.ours_triangles_rays_per_second / 1e6,
        t.ours_native_rays_per_second / 1e6,
        embree.map_or("-".into(), |r| format!("{:.3}", r / 1e6)),
        t.ours_to_embree().map_or("-".into(), |r| format!("{r:.3}")),
        t.agreement.map_or("-".into(), |a| format!("{a}")),
        t.embree_missing.unwrap_or_default()
    );
    Ok(())
}

/// Times the tracer's compiled copies against each other on the scene's triangles (the bench's
/// triangle rays), interleaved, and checks they agree bit for bit.
fn compare_instruction_sets(geometry: &Geometry, rays: usize) {
    let soup = triangle_soup(&geometry.primitives);
    let rays = texel_rays(geometry, rays, 1);
    let tracer = |isa| triangle_tracer(&soup, geometry.scale()).with_instruction_set(isa);
    let mut sets: Vec<(Tracer, Vec<f64>)> = Vec::new();
    for isa in [
        InstructionSet::Baseline,
        InstructionSet::Avx2,
        InstructionSet::Avx512,
    ] {
        let t = tracer(isa);
        if sets
            .iter()
            .all(|(s, _)| s.instruction_set() != t.instruction_set())
        {
            sets.push((t, Vec::new()));
        }
    }
    let no_surfaces = |_: u32| 1.0;
    let mut answers: Vec<Vec<Option<(u64, u32)>>> = vec![Vec::new(); sets.len()];
    for round in 0..7 {
        for (k, (t, times)) in sets.iter_mut().enumerate() {
            let start = Instant::now();
            let hits: Vec<Option<(u64, u32)>> = rays
                .iter()
                .map(|(o, d)| {
                    t.closest(*o, *d, f64::INFINITY, &no_surfaces)
                        .map(|h| (h.t.to_bits(), h.primitive))
                })
                .collect();
            times.push(start.elapsed().as_secs_f64());
            if round == 0 {
                answers[k] = hits;
            }
        }
    }
    let first = sets[0].0.instruction_set();
    for (k, (t, times)) in sets.iter_mut().enumerate() {
        times.sort_by(f64::total_cmp);
        let same = answers[k] == answers[0];
        println!(
            "{:?}: median {:.3} Mrays/s (best {:.3}), same hits as {:?}: {same}",
            t.instruction_set(),
            rays.len() as f64 / times[3] / 1e6,
            rays.len() as f64 / times[0] / 1e6,
            first,
        );
    }
}
