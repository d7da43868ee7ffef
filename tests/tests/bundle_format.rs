//! The bundle on a real bake (the Cornell box with its clutter): every codec round-trips with
//! the error it reports, a bundle cut anywhere lights the scene from the sections that arrived,
//! the runtime's rayon path is bit-identical to the single-thread path, and mutated bundles
//! never make the decoder or runtime panic.

use lightfarm_client::{relative_l2, Bounces, DirectLight, IndirectLight, Method, Runtime};
use lightfarm_proto::bundle::{Bundle, EncodeOptions, Matrix, TransportOps};
use lightfarm_proto::codec::{CodecPolicy, MatrixCodec};
use lightfarm_proto::result::compare;
use lightfarm_proto::scene::Transport;
use lightfarm_server::bake::progress::NoProgress;
use lightfarm_server::bake::{bake, BakeOptions};
use lightfarm_tests::*;

fn cornell() -> (Bundle, lightfarm_proto::lights::LightSet) {
    let (scene, lights) = load_scene("cornell", 8, 256);
    let options = BakeOptions {
        cache: None,
        full: false,
        transport: Some(Transport::Lightfield),
    };
    let (bundle, _) = bake(&scene, &scene_dir("cornell"), &options, &NoProgress).unwrap();
    (bundle, lights)
}

/// Deterministic direct light with structure (a gradient and a hot spot).
fn direct_for(rt: &Runtime) -> DirectLight {
    let layout = &rt.bundle().layout;
    DirectLight {
        radiance: layout
            .positions
            .iter()
            .map(|p| {
                let hot = (-((p[0] - 1.0).powi(2) + (p[2] - 2.0).powi(2))).exp();
                [0.2 + hot, 0.1 + 0.5 * hot, 0.3 + 0.05 * p[1]]
            })
            .collect(),
    }
}

fn indirect(bundle: Bundle, method: Method) -> Vec<[f32; 3]> {
    let mut rt = Runtime::try_new(bundle).unwrap();
    let direct = direct_for(&rt);
    let mut out = IndirectLight::default();
    rt.apply(method, Bounces::One, &direct, &mut out).unwrap();
    out.radiance
}

#[test]
fn every_codec_round_trips_with_the_error_it_reports_and_shrinks_the_bundle() {
    let (bundle, _) = cornell();
    let exact = indirect(bundle.clone(), Method::Drt);
    let lossless = bundle.encode();
    assert_eq!(
        Bundle::decode(&lossless).unwrap(),
        bundle,
        "f32 is lossless"
    );
    let mut sizes = Vec::new();
    for (codec, max_matrix_error, max_output_error) in [
        (MatrixCodec::F16, 2e-3, 1e-3),
        (MatrixCodec::U8Columns, 0.06, 0.02),
    ] {
        let (bytes, report) = bundle.encode_with(&EncodeOptions {
            codec: CodecPolicy::Fixed(codec),
            transport_codec: None,
            zstd_level: 9,
        });
        let decoded = Bundle::decode(&bytes).unwrap();
        assert!(
            report.max_codec_error > 0.0 && report.max_codec_error < max_matrix_error,
            "{codec:?}: largest matrix error {}",
            report.max_codec_error
        );
        assert_eq!(report.codecs.len(), 1, "{codec:?}: {:?}", report.codecs);
        let e = relative_l2(&indirect(decoded, Method::Drt), &exact);
        eprintln!(
            "{codec:?}: {} bytes (f32 {}), output error {e:.2e}",
            bytes.len(),
            lossless.len()
        );
        assert!(
            e > 0.0 && e < max_output_error,
            "{codec:?}: output error {e}"
        );
        sizes.push(bytes.len());
    }
    assert!(
        sizes[0] < lossless.len() && sizes[1] < sizes[0],
        "{sizes:?}"
    );
    // The budget picks per matrix: a budget between the u8 and f16 errors mixes codecs.
    let (_, report) = bundle.encode_with(&EncodeOptions {
        codec: CodecPolicy::Budget(0.01),
        transport_codec: None,
        zstd_level: 9,
    });
    assert!(report.max_codec_error <= 0.01, "{report:?}");
}

/// Relative Frobenius error of `decoded` against `exact`, per matrix pair.
fn matrix_errors<'a>(pairs: impl Iterator<Item = (&'a Matrix, &'a Matrix)>) -> Vec<f64> {
    pairs
        .map(|(decoded, exact)| {
            let (mut d, mut n) = (0.0f64, 0.0f64);
            for (a, b) in decoded.data.iter().zip(&exact.data) {
                d += (*a as f64 - *b as f64).powi(2);
                n += (*b as f64).powi(2);
            }
            if n == 0.0 {
                0.0
            } else {
                (d / n).sqrt()
            }
        })
        .collect()
}

fn transport_matrices(bundle: &Bundle) -> Vec<&Matrix> {
    match bundle
        .transport
        .as_ref()
        .expect("the corridor has transport")
    {
        TransportOps::Compact(e) => e.iter().flat_map(|e| [&e.y, &e.z]).collect(),
        TransportOps::Lightfield(e) => e.iter().map(|e| &e.matrix).collect(),
        TransportOps::Traced(e) => e.iter().map(|e| &e.matrix).collect(),
        TransportOps::Factored(f) => f
            .bases
            .iter()
            .map(|b| &b.q)
            .chain(f.entries.iter().flat_map(|e| [&e.y, &e.z]))
            .collect(),
    }
}

fn shape_matrices(bundle: &Bundle) -> Vec<&Matrix> {
    bundle
        .shapes
        .iter()
        .flat_map(|s| [&s.u_b, &s.t_db])
        .collect()
}

/// Transport matrices are coded within their own budget (`EncodeOptions::transport_codec`),
/// every other matrix within the general one; the scene settings give transport the smaller.
#[test]
fn transport_matrices_are_coded_within_their_own_budget() {
    let (scene, _) = load_scene("corridor", 4, 128);
    let options = BakeOptions {
        cache: None,
        full: false,
        transport: None,
    };
    let (bundle, _) = bake(&scene, &scene_dir("corridor"), &options, &NoProgress).unwrap();
    let encode = |transport_budget: f64| {
        let (bytes, _) = bundle.encode_with(&EncodeOptions {
            codec: CodecPolicy::Budget(0.05),
            transport_codec: Some(CodecPolicy::Budget(transport_budget)),
            zstd_level: 3,
        });
        let decoded = Bundle::decode(&bytes).unwrap();
        let largest = |of: fn(&Bundle) -> Vec<&Matrix>| {
            matrix_errors(of(&decoded).into_iter().zip(of(&bundle)))
                .into_iter()
                .fold(0.0, f64::max)
        };
        (
            largest(transport_matrices),
            largest(shape_matrices),
            bytes.len(),
        )
    };
    let (tight_transport, tight_shapes, tight_bytes) = encode(0.005);
    let (loose_transport, loose_shapes, loose_bytes) = encode(0.05);
    eprintln!(
        "transport budget 0.005: transport {tight_transport:.2e}, shapes {tight_shapes:.2e}, {tight_bytes} B; \
         0.05: transport {loose_transport:.2e}, shapes {loose_shapes:.2e}, {loose_bytes} B"
    );
    assert!(
        tight_transport > 0.0 && tight_transport <= 0.005,
        "{tight_transport}"
    );
    assert!(
        loose_transport > 0.005 && loose_transport <= 0.05,
        "{loose_transport}"
    );
    // The shapes follow the general budget whatever the transport's.
    assert!(
        tight_shapes > 0.005 && tight_shapes <= 0.05,
        "{tight_shapes}"
    );
    assert_eq!(tight_shapes, loose_shapes);
    assert!(tight_bytes > loose_bytes, "{tight_bytes} vs {loose_bytes}");

    // From the settings: `transport_codec_error` caps transport below `codec_error`.
    let mut settings = scene.settings.clone();
    settings.codec_error = 0.05;
    settings.transport_codec_error = 0.005;
    let options = lightfarm_server::bake::pipeline::encoding::encode_options(&settings, None);
    assert_eq!(options.codec, CodecPolicy::Budget(0.05));
    assert_eq!(options.transport_codec, Some(CodecPolicy::Budget(0.005)));
    settings.codec_error = 0.001;
    let options = lightfarm_server::bake::pipeline::encoding::encode_options(&settings, None);
    assert_eq!(options.transport_codec, Some(CodecPolicy::Budget(0.001)));
}

#[test]
fn a_truncated_bundle_lights_the_scene_from_the_sections_that_arrived() {
    let (bundle, _) = cornell();
    let bytes = bundle.encode();
    let mrt = indirect(bundle.clone(), Method::Mrt);
    let drt = indirect(bundle.clone(), Method::Drt);
    let (mut saw_mrt_only, mut saw_drt) = (false, false);
    let mut last_present = 0;
    // 150 evenly spaced cuts plus the last bytes (the table of contents and footer).
    let cuts: Vec<usize> = (0..150)
        .map(|k| k * bytes.len() / 150)
        .chain(bytes.len() - 20..=bytes.len())
        .collect();
    for cut in cuts {
        let Ok(partial) = Bundle::decode_prefix(&bytes[..cut]) else {
            // Too short to hold layout, shapes and blocks.
            assert!(
                last_present == 0,
                "decodable prefix became undecodable at {cut}"
            );
            continue;
        };
        assert!(partial.present.len() >= last_present);
        last_present = partial.present.len();
        assert_eq!(partial.complete, cut == bytes.len(), "cut {cut}");
        let has_transport = partial.bundle.transport.is_some();
        let has_drt = partial.bundle.drt.is_some();
        if has_transport {
            // MRT from the prefix is exactly MRT from the whole bundle.
            assert_eq!(
                indirect(partial.bundle.clone(), Method::Mrt),
                mrt,
                "cut {cut}"
            );
        }
        if has_drt {
            assert_eq!(
                indirect(partial.bundle.clone(), Method::Drt),
                drt,
                "cut {cut}"
            );
            saw_drt = true;
        } else if has_transport {
            saw_mrt_only = true;
            let mut rt = Runtime::try_new(partial.bundle).unwrap();
            let direct = direct_for(&rt);
            let mut out = IndirectLight::default();
            assert!(rt
                .apply(Method::Drt, Bounces::One, &direct, &mut out)
                .is_err());
        }
    }
    assert!(saw_mrt_only && saw_drt);
    assert!(Bundle::decode(&bytes[..bytes.len() - 1]).is_err());
}

#[test]
fn the_rayon_path_is_bit_identical_to_one_thread() {
    let (bundle, lights) = cornell();
    let mut rt = Runtime::try_new(bundle.clone()).unwrap();
    let direct = direct_for(&rt);
    for method in [Method::Mrt, Method::Drt] {
        let single = indirect(bundle.clone(), method);
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        rt.set_parallel(true);
        let mut out = IndirectLight::default();
        pool.install(|| rt.apply(method, Bounces::One, &direct, &mut out))
            .unwrap();
        rt.set_parallel(false);
        assert!(
            out.radiance
                .iter()
                .flatten()
                .zip(single.iter().flatten())
                .all(|(a, b)| a.to_bits() == b.to_bits()),
            "{method:?}"
        );
    }
    // And through eval: the u8 bundle's result stays close to the f32 one on the real lights.
    let (u8_bytes, _) = bundle.encode_with(&EncodeOptions {
        codec: CodecPolicy::Fixed(MatrixCodec::U8Columns),
        transport_codec: None,
        zstd_level: 3,
    });
    let a = apply(&bundle.encode(), &lights, Method::Drt);
    let b = apply(&u8_bytes, &lights, Method::Drt);
    let c = compare(&b, &a);
    assert!(c.relative_l2 < 0.02, "{c:?}");
}

/// A bounded mutation fuzz of a real, compressed, 8-bit bundle (CI's fuzz run; `client/fuzz`
/// holds the cargo-fuzz target for long runs).
#[test]
fn mutated_real_bundles_never_panic() {
    let (bundle, _) = cornell();
    let (bytes, _) = bundle.encode_with(&EncodeOptions {
        codec: CodecPolicy::Budget(0.01),
        transport_codec: None,
        zstd_level: 3,
    });
    let mut state = 0x9e3779b97f4a7c15u64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let try_bytes = |b: &[u8]| {
        if let Ok(bundle) = Bundle::decode(b) {
            let mut rt = Runtime::try_new(bundle).expect("decoded bundles make runtimes");
            let direct = DirectLight {
                radiance: vec![[1.0; 3]; rt.n_texels()],
            };
            let mut out = IndirectLight::default();
            for m in [Method::Mrt, Method::Drt, Method::Full] {
                let _ = rt.apply(m, Bounces::One, &direct, &mut out);
            }
        }
        let _ = Bundle::decode_prefix(b);
    };
    for _ in 0..300 {
        let mut m = bytes.clone();
        for _ in 0..1 + next() % 4 {
            let at = (next() % m.len() as u64) as usize;
            m[at] = next() as u8;
        }
        try_bytes(&m);
        let cut = (next() % bytes.len() as u64) as usize;
        try_bytes(&bytes[..cut]);
    }
    // Raw sections with repaired checksums reach validation.
    let raw = bundle.raw_sections();
    for _ in 0..300 {
        let mut s = raw.clone();
        let i = (next() % s.len() as u64) as usize;
        if s[i].1.is_empty() {
            continue;
        }
        let at = (next() % s[i].1.len() as u64) as usize;
        s[i].1[at] = next() as u8;
        let (b, _) = lightfarm_proto::container::write_container(
            lightfarm_proto::bundle::BUNDLE_MAJOR,
            lightfarm_proto::bundle::BUNDLE_MINOR,
            &s,
            0,
        );
        try_bytes(&b);
    }
}

/// The cargo-fuzz seeds (`client/fuzz/corpus/decode`) are current bundles: a format change
/// that forgets to regenerate them (`client/fuzz/make-seeds.sh`) fails here.
#[test]
fn fuzz_seeds_decode() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../client/fuzz/corpus/decode");
    let mut seeds = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "lfb") {
            let bytes = std::fs::read(&path).unwrap();
            let bundle =
                Bundle::decode(&bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            assert!(
                bundle.drt.is_some(),
                "{}: seeds cover the DRT section",
                path.display()
            );
            seeds += 1;
        }
    }
    assert!(seeds >= 4, "{seeds} seeds");
}
