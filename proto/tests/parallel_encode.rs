//! The bundle writer encodes operator matrices on several threads (`Bundle::encode_with` uses
//! every core): every thread count must give the bytes and the report of one thread, which
//! encodes each matrix as it writes it, for every codec policy and every section that holds
//! matrices (shapes, transport under its own policy, DRT entries and gathers, probes).

use lightfarm_proto::bundle::{Bundle, EncodeOptions};
use lightfarm_proto::codec::{CodecPolicy, MatrixCodec};
use lightfarm_proto::testing::{drt_bundle, probe_bundle, Lcg};

fn policies() -> Vec<EncodeOptions> {
    vec![
        EncodeOptions::default(),
        EncodeOptions {
            codec: CodecPolicy::Budget(0.02),
            transport_codec: Some(CodecPolicy::Budget(0.002)),
            zstd_level: 3,
        },
        EncodeOptions {
            codec: CodecPolicy::Fixed(MatrixCodec::F16),
            transport_codec: None,
            zstd_level: 0,
        },
        EncodeOptions {
            codec: CodecPolicy::Fixed(MatrixCodec::U8Rows),
            transport_codec: Some(CodecPolicy::Budget(0.05)),
            zstd_level: 1,
        },
    ]
}

#[test]
fn every_thread_count_writes_the_bytes_and_report_of_one() {
    let mut rng = Lcg(17);
    let bundles: Vec<Bundle> = vec![
        drt_bundle(&mut rng, true, true, true),
        drt_bundle(&mut rng, false, false, false),
        probe_bundle(&mut rng, true),
    ];
    let mut matrices = 0;
    for (b, bundle) in bundles.iter().enumerate() {
        for (p, options) in policies().iter().enumerate() {
            let (one, one_report) = bundle.encode_on(options, 1);
            matrices += one_report.codecs.values().map(|u| u.matrices).sum::<u64>();
            for threads in [2, 3, 8] {
                let (many, many_report) = bundle.encode_on(options, threads);
                assert!(
                    many == one,
                    "bundle {b}, policy {p}, {threads} threads: bytes"
                );
                assert_eq!(many_report, one_report, "bundle {b}, policy {p}");
            }
            assert!(Bundle::decode(&one).is_ok(), "bundle {b}, policy {p}");
            assert!(bundle.encode_with(options).0 == one);
        }
    }
    assert!(matrices > 100, "{matrices} matrices written");
}
