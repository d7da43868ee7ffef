//! The bundle writer gives a DRT delta entry's own matrix (dense, or a low-rank entry's left
//! factor `U_k Σ_k`) one floor on its 8-bit steps, and nothing else: not the entries' mixes,
//! the clutter's `T_d→c`, the shapes, the transport or the probes' deltas. Each matrix stays
//! within the budget, and the bytes decode like any 8-bit matrix.

use lightfarm_proto::bundle::{Bundle, EncodeOptions, Matrix};
use lightfarm_proto::codec::{choose_encoding, CodecPolicy, MatrixCodec, U8Grid};
use lightfarm_proto::testing::{drt_bundle, probe_bundle, Lcg};

const FLOORED: &str = "u8 (floored steps)";

fn options(budget: f64) -> EncodeOptions {
    EncodeOptions {
        codec: CodecPolicy::Budget(budget),
        transport_codec: Some(CodecPolicy::Budget(budget)),
        zstd_level: 3,
    }
}

/// `rows × k` with columns shrinking like singular values, 1 to 1/100.
fn left_factor(rng: &mut Lcg, rows: usize, k: usize) -> Matrix {
    let data = (0..rows * k)
        .map(|e| {
            let j = e % k;
            let sigma = 0.01f32.powf(j as f32 / (k.max(2) - 1) as f32);
            sigma * rng.range(-1.0, 1.0)
        })
        .collect();
    Matrix {
        rows: rows as u32,
        cols: k as u32,
        data,
    }
}

fn relative_error(a: &Matrix, b: &Matrix) -> f64 {
    let (mut d, mut n) = (0.0f64, 0.0f64);
    for (x, y) in a.data.iter().zip(&b.data) {
        d += (*x as f64 - *y as f64).powi(2);
        n += (*x as f64).powi(2);
    }
    if n == 0.0 {
        return d;
    }
    (d / n).sqrt()
}

#[test]
fn only_the_drt_entries_own_matrices_take_a_floor() {
    let mut rng = Lcg(5);
    let mut bundle = drt_bundle(&mut rng, false, true, false);
    let drt = bundle.drt.as_mut().expect("a DRT bundle");
    // Every matrix (entry, mix) of the same size as before, its columns shrinking like
    // singular values: what a floor coarsens.
    for e in &mut drt.entries {
        e.matrix = left_factor(&mut rng, e.matrix.rows as usize, e.matrix.cols as usize);
        if let Some(mix) = &mut e.mix {
            *mix = left_factor(&mut rng, mix.rows as usize, mix.cols as usize);
        }
    }
    let budget = 0.04;
    // The entries' own matrices that a floor above 0 fits, encoded alone.
    let want = drt
        .entries
        .iter()
        .filter(|e| {
            let (r, c) = (e.matrix.rows as usize, e.matrix.cols as usize);
            let (_, grid, _) =
                choose_encoding(&e.matrix.data, r, c, CodecPolicy::BudgetFloored(budget));
            matches!(grid, U8Grid::Floor(f) if f > 0.0)
        })
        .count() as u64;
    assert!(want >= 3, "{want}");
    let (bytes, report) = bundle.encode_with(&options(budget));
    let floored = report.codecs.get(FLOORED).map_or(0, |u| u.matrices);
    assert_eq!(floored, want, "{:?}", report.codecs);
    assert!(report.max_codec_error <= budget);
    let back = Bundle::decode(&bytes).expect("decodes");
    let (a, b) = (bundle.drt.as_ref().unwrap(), back.drt.as_ref().unwrap());
    for (e, f) in a.entries.iter().zip(&b.entries) {
        let error = relative_error(&e.matrix, &f.matrix);
        assert!(error <= budget * 1.0001, "{error}");
    }

    // The same matrices as probe deltas keep each line's own grid.
    let mut probes = probe_bundle(&mut rng, false);
    probes.probes.as_mut().unwrap().entries = a.entries.clone();
    let (_, report) = probes.encode_with(&options(budget));
    assert!(
        !report.codecs.contains_key(FLOORED),
        "{:?}",
        report.codecs.keys()
    );

    // A fixed codec stays fixed.
    let fixed = EncodeOptions {
        codec: CodecPolicy::Fixed(MatrixCodec::U8Columns),
        ..options(budget)
    };
    let (_, report) = bundle.encode_with(&fixed);
    assert!(!report.codecs.contains_key(FLOORED));
}
