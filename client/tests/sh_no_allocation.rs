//! `Runtime::apply_sh` allocates nothing per frame once its output is sized, computes
//! `Y · (Z · b)` per texel, and `ShLight::shade` follows the lightmap's radiometric convention.
//! Its own test binary, because it replaces the global allocator with one that counts the
//! current thread's allocations.

use lightfarm_client::{DirectLight, Runtime, ShLight};
use lightfarm_proto::bundle::{Bundle, DeltaSource, Matrix, ShEntry, ShResponses};
use lightfarm_proto::sh::SH_COEFFS;
use lightfarm_proto::testing::{allocs, one_block_bundle, strip_layout, CountingAlloc};

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

fn m(rows: usize, cols: usize, salt: f32) -> Matrix {
    Matrix {
        rows: rows as u32,
        cols: cols as u32,
        data: (0..rows * cols)
            .map(|k| salt / (1 + k) as f32 - 0.01 * (k % 3) as f32)
            .collect(),
    }
}

/// One block of `n` texels (rank 2) whose texels all have an SH entry of rank 2.
fn bundle(n: usize) -> Bundle {
    let mut b = one_block_bundle(
        strip_layout(n),
        "strip",
        "strip",
        m(n, 2, 1.0),
        m(2, n, 0.5),
    );
    b.sh = Some(ShResponses {
        entries: vec![ShEntry {
            texels: (0..n as u32).collect(),
            source: DeltaSource::Block(0),
            y: m(SH_COEFFS * n, 2, 2.0),
            z: m(2, 2, 3.0),
        }],
    });
    b
}

#[test]
fn apply_sh_allocates_nothing_and_computes_y_z_b() {
    let n = 12;
    let b = bundle(n);
    let (y, z, t_db) = {
        let e = &b.sh.as_ref().unwrap().entries[0];
        (e.y.clone(), e.z.clone(), b.shapes[0].t_db.clone())
    };
    let bytes = b.encode();
    let mut rt = Runtime::new(Bundle::decode(&bytes).unwrap());
    let direct = DirectLight {
        radiance: (0..n)
            .map(|k| [(k % 5) as f32 * 0.25, 0.5, (k % 3) as f32])
            .collect(),
    };
    let (mut first, mut second) = (ShLight::default(), ShLight::default());
    rt.apply_sh(&direct, &mut first).unwrap();
    rt.apply_sh(&direct, &mut second).unwrap();

    let before = allocs();
    let _counter_works = std::hint::black_box(Box::new(0u8));
    assert_eq!(allocs(), before + 1, "the allocation counter works");
    let before = allocs();
    rt.apply_sh(&direct, &mut first).unwrap();
    rt.apply_sh(&direct, &mut second).unwrap();
    assert_eq!(allocs(), before, "apply_sh allocated once sized");
    assert_eq!(first, second);

    // Y · (Z · (T_d→b · l_d)) in f64, per channel.
    for c in 0..3 {
        let b: Vec<f64> = (0..2)
            .map(|r| {
                (0..n)
                    .map(|t| t_db.row(r)[t] as f64 * direct.radiance[t][c] as f64)
                    .sum()
            })
            .collect();
        let s: Vec<f64> = (0..2)
            .map(|k| (0..2).map(|j| z.row(k)[j] as f64 * b[j]).sum())
            .collect();
        for t in 0..n {
            for lm in 0..SH_COEFFS {
                let row = y.row(SH_COEFFS * t + lm);
                let want: f64 = (0..2).map(|k| row[k] as f64 * s[k]).sum();
                let got = first.coefficients[t][c][lm] as f64;
                assert!(
                    (got - want).abs() <= 1e-5 * (1.0 + want.abs()),
                    "texel {t} channel {c} lm {lm}: {got} vs {want}"
                );
            }
        }
    }
}

#[test]
fn shading_constant_radiance_gives_albedo_times_radiance() {
    // A constant field L = 1 has L_00 = √(4π) and E(n) = π at any normal, so the outgoing
    // radiance is ρ · L, the scalar lightmap's `ρ ⊙ (F l)` with F's rows summing to 1.
    let mut sh = ShLight::default();
    let l00 = (4.0 * std::f64::consts::PI).sqrt() as f32;
    sh.coefficients = vec![[[l00, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]; 3]];
    let out = sh.shade(0, [0.6, 0.8, 0.0], [0.5, 0.25, 1.0]);
    for (o, want) in out.iter().zip([0.5, 0.25, 1.0]) {
        assert!((o - want).abs() < 1e-5, "{out:?}");
    }
}
