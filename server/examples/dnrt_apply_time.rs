//! Times DNRT's G-buffer apply for one object on a 1366×768 frame, single thread and rayon.
//!
//! `cargo run --release -p lightfarm-server --example dnrt_apply_time -- BUNDLE.lfb [OBJECT]`
//!
//! The frame is a wall seen head-on: pixel (i, j) lies on the plane z = 0 at
//! x ∈ [0.2, 4.2], y ∈ [0, 2.5] (normal +z, albedo 0.7), with the object posed at
//! (2.2, 0.45, 0.5), so every pixel lies inside the object's outer volume (the worst case:
//! no pixel is skipped). Prints the median of 15 runs of the per-frame setup
//! ([`DnrtInstance::new`]) and of each apply path.

use std::time::Instant;

use lightfarm_client::{decode, DnrtInstance, DnrtVolume};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let path = args
        .get(1)
        .expect("usage: dnrt_apply_time BUNDLE.lfb [OBJECT]");
    let bundle = decode(&std::fs::read(path).expect("read bundle")).expect("decode");
    let grids = bundle.dnrt.as_ref().expect("the bundle has no DNRT grids");
    let grid = match args.get(2) {
        Some(id) => grids
            .iter()
            .find(|g| &g.object == id)
            .expect("no such object"),
        None => &grids[0],
    };
    let volume = DnrtVolume::new(grid).expect("valid grid");
    let mut c = [[0.0f32; 9]; 3];
    for (ch, cc) in c.iter_mut().enumerate() {
        for (k, x) in cc.iter_mut().enumerate() {
            *x = 1.0 / (1 + k + ch) as f32;
        }
    }
    let pose = ([2.2, 0.45, 0.5], [0.0, 0.383, 0.0, 0.924]);
    // Per-frame setup: SH rotation and contraction of the grid with c_j.
    let setup = median(
        (0..15)
            .map(|_| {
                let t = Instant::now();
                let i = DnrtInstance::new(&volume, pose.0, pose.1, c, c);
                std::hint::black_box(&i);
                t.elapsed().as_secs_f64() * 1e3
            })
            .collect(),
    );
    let instance = DnrtInstance::new(&volume, pose.0, pose.1, c, c);
    let (w, h) = (1366usize, 768usize);
    let mut positions = Vec::with_capacity(w * h);
    for j in 0..h {
        for i in 0..w {
            positions.push([
                0.2 + 4.0 * (i as f32 + 0.5) / w as f32,
                2.5 * (j as f32 + 0.5) / h as f32,
                0.0,
            ]);
        }
    }
    let normals = vec![[0.0f32, 0.0, 1.0]; w * h];
    let albedo = vec![[0.7f32; 3]; w * h];
    let mut out = vec![[0.0f32; 3]; w * h];
    let mut single = Vec::new();
    let mut parallel = Vec::new();
    for _ in 0..15 {
        let t = Instant::now();
        instance
            .apply_gbuffer(&positions, &normals, &albedo, &mut out)
            .unwrap();
        single.push(t.elapsed().as_secs_f64() * 1e3);
        let t = Instant::now();
        instance
            .apply_gbuffer_par(&positions, &normals, &albedo, &mut out)
            .unwrap();
        parallel.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let affected = positions
        .iter()
        .zip(&normals)
        .filter(|(p, n)| instance.shade(**p, **n, [1.0; 3]) != [0.0; 3])
        .count();
    println!(
        "object {} ({}³, {} SH, {} data bytes): 1366×768 G-buffer, {} pixels affected; \
         per-frame setup {:.3} ms; apply single thread {:.2} ms, rayon ({} threads) {:.2} ms \
         (medians of 15)",
        grid.object,
        grid.resolution,
        grid.n_sh,
        grid.data_bytes(),
        affected,
        setup,
        median(single),
        rayon::current_num_threads(),
        median(parallel)
    );
}
