//! The codecs' tests: every codec round-trips through the wire, reading any bytes never panics,
//! predicted forms decode to the bits of the plain ones and have the documented bytes, and a
//! budget picks the smallest codec that fits.

use super::predict::{add_residuals, predict, push_residuals, to_lines, ByteCounts};
use super::quantize::quantize_matrix;
use super::*;
use crate::wire::{Reader, Writer};
use proptest::prelude::*;

fn sample_matrix(rows: usize, cols: usize) -> Vec<f32> {
    // A smooth matrix with one large column, like a U_b with a dominant first mode.
    (0..rows * cols)
        .map(|k| {
            let (i, j) = (k / cols, k % cols);
            let base = ((i as f32 * 0.37 + j as f32 * 1.3).sin()) / (1.0 + j as f32);
            if j == 0 {
                10.0 + base
            } else {
                base
            }
        })
        .collect()
}

#[test]
fn f32_is_lossless_and_u8_error_is_within_half_a_step_per_value() {
    let (rows, cols) = (40, 7);
    let m = sample_matrix(rows, cols);
    assert_eq!(codec_error(&m, rows, cols, MatrixCodec::F32), 0.0);
    let back = round_trip(&m, rows, cols, MatrixCodec::U8Columns);
    for j in 0..cols {
        let col: Vec<f32> = (0..rows).map(|i| m[i * cols + j]).collect();
        let lo = col.iter().cloned().fold(f32::INFINITY, f32::min);
        let hi = col.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
        let half_step = (hi - lo) / 255.0 / 2.0;
        for i in 0..rows {
            let d = (back[i * cols + j] - m[i * cols + j]).abs();
            assert!(
                d <= half_step * 1.001 + 1e-6,
                "({i},{j}): {d} > {half_step}"
            );
        }
    }
    let e8 = codec_error(&m, rows, cols, MatrixCodec::U8Columns);
    let e16 = codec_error(&m, rows, cols, MatrixCodec::F16);
    assert!(e16 < e8, "f16 {e16} should beat u8 {e8}");
    assert!(e8 < 0.01 && e16 < 1e-3, "u8 {e8}, f16 {e16}");
}

#[test]
fn budget_picks_the_smallest_codec_that_fits() {
    let (rows, cols) = (64, 5);
    let m = sample_matrix(rows, cols);
    let e8 = codec_error(&m, rows, cols, MatrixCodec::U8Columns);
    let e16 = codec_error(&m, rows, cols, MatrixCodec::F16);
    assert_eq!(
        choose_codec(&m, rows, cols, CodecPolicy::Budget(e8 * 1.01)).0,
        MatrixCodec::U8Columns
    );
    assert_eq!(
        choose_codec(&m, rows, cols, CodecPolicy::Budget(e8 * 0.99)).0,
        MatrixCodec::F16
    );
    assert_eq!(
        choose_codec(&m, rows, cols, CodecPolicy::Budget(e16 * 0.5)).0,
        MatrixCodec::F32
    );
    // Wide matrices put their ranges on rows.
    assert_eq!(
        choose_codec(&m, cols, rows, CodecPolicy::Fixed(MatrixCodec::U8Columns)).0,
        MatrixCodec::U8Rows
    );
}

#[test]
fn a_wide_matrix_of_uneven_columns_takes_8_bits_with_a_pair_per_column() {
    // Like the compact transport's Z (k × Σ r_A): each row runs across source blocks of very
    // different strength, here one strong column and 299 weak ones.
    let (rows, cols) = (16, 300);
    let m: Vec<f32> = (0..rows * cols)
        .map(|k| {
            let (i, j) = (k / cols, k % cols);
            let amplitude = if j == 0 { 1.0 } else { 1e-3 };
            amplitude * ((i as f32 * 0.9 + j as f32 * 0.37).sin() + 0.1)
        })
        .collect();
    let budget = 0.02;
    let by_rows = codec_error(&m, rows, cols, MatrixCodec::U8Rows);
    let by_columns = codec_error(&m, rows, cols, MatrixCodec::U8Columns);
    assert!(
        by_rows > budget,
        "pairs per row fit ({by_rows}); the case is not uneven"
    );
    assert!(by_columns < budget / 4.0, "pairs per column: {by_columns}");
    assert!(
        MatrixCodec::U8Columns.value_bytes(rows, cols) < MatrixCodec::F16.value_bytes(rows, cols)
    );
    let (codec, grid, error) = choose_encoding(&m, rows, cols, CodecPolicy::Budget(budget));
    assert_eq!(codec, MatrixCodec::U8Columns);
    assert!(error <= budget);
    assert_eq!(error, codec_error_grid(&m, rows, cols, codec, grid));
    // The wire round trip gives back what the error was measured on.
    let mut w = Writer::default();
    write_matrix_smallest(&mut w, &m, rows, cols, codec, grid);
    let (_, _, back, _) = decode(&w.bytes);
    assert_eq!(
        bits(&back),
        bits(&round_trip_grid(&m, rows, cols, codec, grid))
    );
}

#[test]
fn f16_overflow_is_an_infinite_error_so_the_budget_refuses_it() {
    let m = vec![1.0e6f32, 2.0, 3.0, 4.0];
    assert!(codec_error(&m, 2, 2, MatrixCodec::F16).is_infinite());
    let (codec, _) = choose_codec(&m, 2, 2, CodecPolicy::Budget(0.01));
    assert_ne!(codec, MatrixCodec::F16);
}

#[test]
fn constant_and_zero_lines_quantise_exactly() {
    let m = vec![0.0, 2.5, 0.0, 2.5, 0.0, 2.5];
    for codec in [
        MatrixCodec::U8Columns,
        MatrixCodec::U8Rows,
        MatrixCodec::F16,
    ] {
        assert_eq!(round_trip(&m, 3, 2, codec), m, "{codec:?}");
    }
}

proptest! {
    #[test]
    fn every_codec_round_trips_through_the_wire(
        rows in 0usize..9, cols in 0usize..9,
        seed in proptest::collection::vec(-1.0e3f32..1.0e3, 81),
        tag in 0u8..6,
    ) {
        let data: Vec<f32> = seed[..rows * cols].to_vec();
        let codec = MatrixCodec::from_tag(tag).unwrap();
        let mut w = Writer::new();
        write_matrix(&mut w, &data, rows, cols, codec);
        prop_assert_eq!(w.bytes.len(), 9 + codec.value_bytes(rows, cols));
        let mut r = Reader::new(&w.bytes);
        let (r2, c2, back, codec2) = read_matrix(&mut r).unwrap();
        prop_assert_eq!((r2 as usize, c2 as usize, codec2), (rows, cols, codec));
        prop_assert_eq!(back, round_trip(&data, rows, cols, codec));
        prop_assert_eq!(r.remaining(), 0);
    }

    #[test]
    fn reading_arbitrary_bytes_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..128)) {
        let mut r = Reader::new(&bytes);
        let _ = read_matrix(&mut r);
    }

    /// Any bytes after a predicted header (small or huge sizes, any width) decode to `Ok`
    /// or `Err` without panicking, and `Ok` consumes exactly the matrix's bytes.
    #[test]
    fn reading_arbitrary_predicted_matrices_never_panics(
        rows in prop_oneof![0u32..7, any::<u32>()],
        cols in prop_oneof![0u32..7, any::<u32>()],
        tag in 4u8..6,
        rest in proptest::collection::vec(any::<u8>(), 0..160),
    ) {
        let mut bytes = rows.to_le_bytes().to_vec();
        bytes.extend_from_slice(&cols.to_le_bytes());
        bytes.push(tag);
        bytes.extend_from_slice(&rest);
        let mut r = Reader::new(&bytes);
        if let Ok((r2, c2, values, codec)) = read_matrix(&mut r) {
            prop_assert_eq!((r2, c2), (rows, cols));
            prop_assert_eq!(values.len(), rows as usize * cols as usize);
            let used = bytes.len() - r.remaining();
            prop_assert_eq!(used, 9 + codec.value_bytes(rows as usize, cols as usize));
        }
    }

    /// Tags 4/5 with any width decode to the bits of tags 2/3 for the same q.
    #[test]
    fn predicted_matrices_decode_like_plain_ones(
        rows in 0usize..12, cols in 0usize..12,
        seed in proptest::collection::vec(-1.0e3f32..1.0e3, 144),
        per_column in any::<bool>(),
        grid in proptest::sample::select(test_grids()),
        width in prop_oneof![0u16..20, any::<u16>()],
    ) {
        let data = &seed[..rows * cols];
        let plain = if per_column { MatrixCodec::U8Columns } else { MatrixCodec::U8Rows };
        let (back, predicted) = predicted_and_plain(data, rows, cols, plain, grid, width);
        prop_assert_eq!(bits(&back), bits(&predicted));
    }
}

/// Every coarser step, and floors from none to wider than the tests' values.
fn test_grids() -> Vec<U8Grid> {
    let steps = U8_STEPS.into_iter().map(U8Grid::Step);
    let floors = [0.0, 1e-3, 0.05, 0.7, 30.0, 5e3].map(U8Grid::Floor);
    steps.chain(floors).collect()
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn decode(bytes: &[u8]) -> DecodedMatrix {
    let mut r = Reader::new(bytes);
    let m = read_matrix(&mut r).unwrap();
    assert_eq!(r.remaining(), 0);
    m
}

/// Decoded values of `data` written in `plain` (tag 2/3) and in its predicted form with
/// `width`, after checking the predicted bytes' size and codec.
fn predicted_and_plain(
    data: &[f32],
    rows: usize,
    cols: usize,
    plain: MatrixCodec,
    grid: U8Grid,
    width: u16,
) -> (Vec<f32>, Vec<f32>) {
    let mut w = Writer::new();
    write_matrix_grid(&mut w, data, rows, cols, plain, grid);
    let (_, _, back, codec) = decode(&w.bytes);
    assert_eq!(codec, plain);
    let mut w = Writer::new();
    write_matrix_predicted(&mut w, data, rows, cols, plain, grid, width);
    let predicted = plain.predicted();
    assert_eq!(w.bytes.len(), 9 + predicted.value_bytes(rows, cols));
    assert_eq!(&w.bytes[9..11], &width.to_le_bytes());
    let (r2, c2, values, codec) = decode(&w.bytes);
    assert_eq!((r2 as usize, c2 as usize, codec), (rows, cols, predicted));
    (back, values)
}

/// Some pseudo-random values with a smooth trend, on every 8-bit line.
fn noisy_matrix(rows: usize, cols: usize, seed: u64) -> Vec<f32> {
    let mut s = seed;
    (0..rows * cols)
        .map(|k| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            let noise = (s >> 40) as f32 / (1u64 << 24) as f32;
            (k as f32 * 0.1).sin() + noise
        })
        .collect()
}

#[test]
fn predicted_forms_round_trip_on_every_shape_and_width() {
    // 1×1, lines of one value, a partial last image row, widths 0, 1, ≥ the line, u16::MAX.
    let shapes = [
        (1, 1),
        (1, 9),
        (9, 1),
        (13, 5),
        (5, 13),
        (64, 3),
        (3, 64),
        (0, 4),
        (4, 0),
        (0, 0),
    ];
    for (rows, cols) in shapes {
        let data = noisy_matrix(rows, cols, (rows * 100 + cols) as u64);
        for plain in [MatrixCodec::U8Columns, MatrixCodec::U8Rows] {
            for grid in test_grids() {
                for width in [0, 1, 2, 3, 5, 8, 12, 13, 64, 65, 1000, u16::MAX] {
                    let (back, predicted) =
                        predicted_and_plain(&data, rows, cols, plain, grid, width);
                    assert_eq!(
                        bits(&back),
                        bits(&predicted),
                        "{rows}×{cols} {plain:?} {grid:?} width {width}"
                    );
                    assert_eq!(
                        bits(&back),
                        bits(&round_trip_grid(&data, rows, cols, plain, grid)),
                    );
                }
            }
            // The encoder's own width choice decodes the same way too.
            let mut w = Writer::new();
            write_matrix(&mut w, &data, rows, cols, plain.predicted());
            assert_eq!(
                bits(&decode(&w.bytes).2),
                bits(&round_trip(&data, rows, cols, plain))
            );
        }
    }
}

/// The exact bytes of a small tag-4 matrix: one column of q
/// `[0, 255, 25, 20, 30, 40]` as an image 2 wide.
#[test]
fn predicted_wire_format_is_the_documented_one() {
    let q = [0.0f32, 255.0, 25.0, 20.0, 30.0, 40.0];
    let mut w = Writer::new();
    write_matrix_predicted(&mut w, &q, 6, 1, MatrixCodec::U8Columns, U8Grid::FULL, 2);
    let mut want = vec![6, 0, 0, 0, 1, 0, 0, 0, 4, 2, 0];
    want.extend_from_slice(&0.0f32.to_le_bytes());
    want.extend_from_slice(&1.0f32.to_le_bytes());
    // k0 no neighbour: 0; k1 left 0; k2 up 0; k3 median(25, 255, 25 + 255 − 0) = 255;
    // k4 up 25; k5 median(30, 20, 30 + 20 − 25) = 25.
    want.extend_from_slice(&[0, 255, 25, 20u8.wrapping_sub(255), 5, 15]);
    assert_eq!(w.bytes, want);
    assert_eq!(decode(&w.bytes).2, q);
    // 1D: the previous value.
    let mut w = Writer::new();
    write_matrix_predicted(&mut w, &q, 1, 6, MatrixCodec::U8Rows, U8Grid::FULL, 0);
    assert_eq!(&w.bytes[8..11], &[5, 0, 0]);
    assert_eq!(
        &w.bytes[19..],
        &[
            0,
            255,
            25u8.wrapping_sub(255),
            20u8.wrapping_sub(25),
            10,
            10
        ]
    );
    assert_eq!(decode(&w.bytes).2, q);
    // The median's three cases.
    let line = [10u8, 20, 30, 0, 10, 20, 15];
    assert_eq!(predict(&[30, 10, 20, 0], 3, 2), 10); // upleft ≥ both: min
    assert_eq!(predict(&[5, 10, 20, 0], 3, 2), 20); // upleft ≤ both: max
    assert_eq!(predict(&[15, 10, 20, 0], 3, 2), 15); // else left + up − upleft
    assert_eq!(predict(&line, 0, 3), 0);
    assert_eq!(predict(&line, 3, 3), 10); // first of an image row: up
    assert_eq!(predict(&line, 2, 3), 20); // first image row: left
}

/// Lighting-like data: smooth functions on the 8 × 8 texel grids of six box faces, as a
/// U_b (texels × r, per column) and a T_d→b (r × texels, per row).
#[test]
fn smooth_face_data_is_stored_predicted_and_smaller_after_zstd() {
    let (t, faces, r) = (8usize, 6usize, 12usize);
    let texels = t * t * faces;
    let u_b: Vec<f32> = (0..texels * r)
        .map(|k| {
            let (texel, mode) = (k / r, k % r);
            let (face, j, i) = (texel / (t * t), (texel % (t * t)) / t, texel % t);
            let (x, y) = (i as f32 / t as f32, j as f32 / t as f32);
            let f = mode as f32 + 1.0;
            ((x * f + face as f32).sin() * (y * 0.7 * f).cos() + x * y) / f
        })
        .collect();
    let t_db: Vec<f32> = (0..r * texels)
        .map(|k| u_b[(k % texels) * r + k / texels])
        .collect();
    for (data, rows, cols, plain) in [
        (&u_b, texels, r, MatrixCodec::U8Columns),
        (&t_db, r, texels, MatrixCodec::U8Rows),
    ] {
        for policy in [
            CodecPolicy::Budget(0.02),
            CodecPolicy::Fixed(MatrixCodec::U8Columns),
        ] {
            let (codec, grid, _) = choose_encoding(data, rows, cols, policy);
            assert_eq!(codec, plain);
            let chosen = write_matrix_smallest(&mut Writer::new(), data, rows, cols, codec, grid);
            assert_eq!(chosen, plain.predicted(), "{plain:?} {grid:?}");
            let (_, q) = quantize_matrix(data, rows, cols, plain.per_column(), grid);
            let lines = to_lines(&q, rows, cols, plain.per_column());
            assert_eq!(best_predictor_width(&lines, texels).0, t as u16);
            let size = |codec| {
                let mut w = Writer::new();
                write_matrix_grid(&mut w, data, rows, cols, codec, grid);
                let (.., values, _) = decode(&w.bytes);
                (zstd::bulk::compress(&w.bytes, 9).unwrap().len(), values)
            };
            let (plain_size, plain_values) = size(plain);
            let (predicted_size, values) = size(chosen);
            assert_eq!(bits(&values), bits(&plain_values));
            eprintln!("{plain:?} {grid:?}: zstd {plain_size} -> {predicted_size}");
            assert!(
                (predicted_size as f64) < 0.9 * plain_size as f64,
                "{plain:?} {grid:?}: {predicted_size} vs {plain_size}"
            );
        }
    }
}

#[test]
fn noise_keeps_the_plain_form() {
    let mut s = 99u64;
    let data: Vec<f32> = (0..64 * 8)
        .map(|_| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 40) as f32
        })
        .collect();
    for (rows, cols) in [(64, 8), (8, 64)] {
        let codec = MatrixCodec::u8_for(rows, cols);
        assert_eq!(
            write_matrix_smallest(&mut Writer::new(), &data, rows, cols, codec, U8Grid::FULL),
            codec
        );
    }
    // Non-8-bit codecs and empty matrices are left alone.
    assert_eq!(
        write_matrix_smallest(
            &mut Writer::new(),
            &data,
            64,
            8,
            MatrixCodec::F16,
            U8Grid::FULL
        ),
        MatrixCodec::F16
    );
    assert_eq!(
        write_matrix_smallest(
            &mut Writer::new(),
            &[],
            0,
            8,
            MatrixCodec::U8Columns,
            U8Grid::FULL
        ),
        MatrixCodec::U8Columns
    );
}

proptest! {
    /// The encoder's residuals (walked by image rows) and their histogram (counted in four
    /// tables) are exactly what [`predict`] gives element by element, for every width: 0, 1,
    /// inside the line, the line's length and beyond.
    #[test]
    fn residual_histogram_is_predict_element_by_element(
        line in proptest::collection::vec(any::<u8>(), 0..200),
        width in 0usize..40,
    ) {
        for w in [width, line.len(), line.len() + 3, u16::MAX as usize] {
            let mut want = [0u64; 256];
            for k in 0..line.len() {
                want[line[k].wrapping_sub(predict(&line, k, w)) as usize] += 1;
            }
            let mut got = ByteCounts::default();
            let mut scratch = vec![7u8; 3];
            add_residuals(&line, w, &mut got, &mut scratch);
            prop_assert_eq!(got.total(), want, "width {}", w);
            // And the residuals themselves, appended after what a buffer holds.
            let mut pushed = vec![1u8, 2];
            push_residuals(&line, w, &mut pushed);
            let each: Vec<u8> = (0..line.len())
                .map(|k| line[k].wrapping_sub(predict(&line, k, w)))
                .collect();
            prop_assert_eq!(&pushed[..2], &[1u8, 2][..]);
            prop_assert_eq!(&pushed[2..], &each[..], "width {}", w);
        }
    }
}

proptest! {
    /// The encoder's error (computed value by value) is, to the bit, the relative RMS error of
    /// the round-tripped matrix, for every codec and 8-bit grid.
    #[test]
    fn codec_error_is_that_of_the_round_trip_to_the_bit(
        rows in 1usize..12,
        cols in 1usize..12,
        seed in any::<u64>(),
        spread in 1e-6f32..1e5,
    ) {
        let mut x = seed | 1;
        let data: Vec<f32> = (0..rows * cols)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                ((x >> 40) as f32 / (1u64 << 24) as f32 - 0.3) * spread
            })
            .collect();
        for codec in [
            MatrixCodec::F32,
            MatrixCodec::F16,
            MatrixCodec::U8Columns,
            MatrixCodec::U8Rows,
        ] {
            for grid in test_grids() {
                let back = round_trip_grid(&data, rows, cols, codec, grid);
                let (mut diff, mut norm) = (0.0f64, 0.0f64);
                for (a, b) in data.iter().zip(&back) {
                    let d = *b as f64 - *a as f64;
                    diff += d * d;
                    norm += (*a as f64) * (*a as f64);
                }
                let want = if !diff.is_finite() {
                    f64::INFINITY
                } else if norm == 0.0 {
                    if diff == 0.0 { 0.0 } else { f64::INFINITY }
                } else {
                    (diff / norm).sqrt()
                };
                let got = codec_error_grid(&data, rows, cols, codec, grid);
                prop_assert_eq!(got.to_bits(), want.to_bits(), "{:?} {:?}", codec, grid);
            }
        }
    }
}

/// A truncated SVD's left factor `U_k Σ_k` (texels × k): smooth modes whose columns shrink
/// with σ_k from 1 to 1/100, with a little noise.
fn left_factor(texels: usize, k: usize) -> Vec<f32> {
    let noise = noisy_matrix(texels, k, 7);
    (0..texels * k)
        .map(|e| {
            let (i, j) = (e / k, e % k);
            let sigma = 0.01f32.powf(j as f32 / (k - 1) as f32);
            let x = i as f32 / texels as f32;
            sigma * ((x * (j + 1) as f32 * 3.1).sin() + 0.05 * noise[e])
        })
        .collect()
}

#[test]
fn a_floor_fits_the_budget_and_codes_a_left_factor_in_fewer_bytes() {
    let (rows, cols, budget) = (256, 40, 0.04);
    let m = left_factor(rows, cols);
    let stored = |policy| {
        let (codec, grid, error) = choose_encoding(&m, rows, cols, policy);
        assert_eq!(codec, MatrixCodec::U8Columns, "{policy:?}");
        assert!(error <= budget, "{policy:?}: {error}");
        assert_eq!(error, codec_error_grid(&m, rows, cols, codec, grid));
        let mut w = Writer::new();
        write_matrix_smallest(&mut w, &m, rows, cols, codec, grid);
        let (.., values, _) = decode(&w.bytes);
        assert_eq!(
            bits(&values),
            bits(&round_trip_grid(&m, rows, cols, codec, grid))
        );
        (grid, zstd::bulk::compress(&w.bytes, 9).unwrap().len())
    };
    let (step, step_bytes) = stored(CodecPolicy::Budget(budget));
    let (floor, floor_bytes) = stored(CodecPolicy::BudgetFloored(budget));
    eprintln!("{step:?}: {step_bytes} B; {floor:?}: {floor_bytes} B");
    let U8Grid::Floor(f) = floor else {
        panic!("a floored budget gave {floor:?}")
    };
    assert!(f > 0.0);
    // Measured: 5,914 → 2,346 B (Step(5) → Floor(0.0295)).
    assert!(
        (floor_bytes as f64) < 0.5 * step_bytes as f64,
        "{floor_bytes} vs {step_bytes}"
    );
    // Every column takes the one step, so the strong ones keep more levels than the weak.
    let (params, q) = quantize_matrix(&m, rows, cols, true, floor);
    let column_max = |j: usize| (0..rows).map(|i| q[i * cols + j]).max().unwrap();
    assert!(params.iter().all(|&(_, scale)| scale == f));
    assert!(column_max(0) > 30, "{}", column_max(0));
    assert!(column_max(cols - 1) < 2, "{}", column_max(cols - 1));
}

#[test]
fn a_line_narrower_than_half_a_floor_is_its_midpoint() {
    let m = vec![1.0f32, 1.05, 1.1, 50.0, 0.0, 100.0];
    // Rows: [1.0, 1.05, 1.1] and [50, 0, 100]; a floor of 0.3 is over twice the first row's
    // range and finer than the second's full-grid step (100 / 255).
    let floor = U8Grid::Floor(0.3);
    let back = round_trip_grid(&m, 2, 3, MatrixCodec::U8Rows, floor);
    let mid = 1.0f32 + 0.5 * (1.1 - 1.0);
    assert!((mid - 1.05).abs() < 1e-6);
    assert_eq!(&back[..3], &[mid, mid, mid]);
    let (params, q) = quantize_matrix(&m, 2, 3, false, floor);
    assert_eq!(params[0], (mid, 0.3));
    assert_eq!(params[1], (0.0, 100.0 / 255.0));
    assert_eq!(&q[..3], &[0, 0, 0]);
    assert_eq!(&q[3..], &[128, 0, 255]);
}

proptest! {
    /// Floor 0 is the full grid to the bit; any floor keeps every value within half its line's
    /// step, with q within the byte; the coarsest floor within a budget is within it.
    #[test]
    fn floors_stay_within_half_a_step_and_the_budget(
        rows in 1usize..10,
        cols in 1usize..10,
        seed in proptest::collection::vec(-1.0e3f32..1.0e3, 100),
        floor in 0.0f32..500.0,
        budget in 1e-4f64..0.5,
    ) {
        let data = &seed[..rows * cols];
        for codec in [MatrixCodec::U8Columns, MatrixCodec::U8Rows] {
            prop_assert_eq!(
                bits(&round_trip_grid(data, rows, cols, codec, U8Grid::Floor(0.0))),
                bits(&round_trip_grid(data, rows, cols, codec, U8Grid::FULL))
            );
            let per_column = codec.per_column();
            let (params, _) = quantize_matrix(data, rows, cols, per_column, U8Grid::Floor(floor));
            let back = round_trip_grid(data, rows, cols, codec, U8Grid::Floor(floor));
            for (k, (a, b)) in data.iter().zip(&back).enumerate() {
                let (_, scale) = params[if per_column { k % cols } else { k / cols }];
                prop_assert!(scale == 0.0 || scale >= floor);
                let slack = 1e-4 * (a.abs() + scale) + 1e-6;
                prop_assert!((a - b).abs() <= 0.5 * scale + slack, "{} {} {}", a, b, scale);
            }
            match coarsest_floor(data, rows, cols, codec, budget) {
                Some((grid, e)) => {
                    prop_assert!(e <= budget);
                    let measured = codec_error_grid(data, rows, cols, codec, grid);
                    prop_assert_eq!(e.to_bits(), measured.to_bits());
                }
                None => prop_assert!(codec_error(data, rows, cols, codec) > budget),
            }
        }
    }
}
