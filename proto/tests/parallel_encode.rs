//! The bundle writer encodes operator matrices on several threads (`Bundle::encode_with` uses
//! every core): every thread count must give the bytes and the report of one thread, which
//! encodes each matrix as it writes it, for every codec policy and every section that holds
//! matrices (shapes, transport under its own policy, DRT entries and gathers, probes); and
//! the same with a memo of earlier encodings.

use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use lightfarm_proto::bundle::{Bundle, EncodeOptions, EncodingMemo, Matrix, MatrixEncoding};
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

/// A memo of every encoding by the matrix's size, value bits and policy.
#[derive(Default)]
struct Memo {
    kept: Mutex<HashMap<(u32, u32, Vec<u32>, String), MatrixEncoding>>,
    hits: AtomicUsize,
}

impl EncodingMemo for Memo {
    fn encoding(
        &self,
        _index: usize,
        m: &Matrix,
        policy: CodecPolicy,
        encode: &dyn Fn() -> MatrixEncoding,
    ) -> MatrixEncoding {
        let key = (
            m.rows,
            m.cols,
            m.data.iter().map(|x| x.to_bits()).collect(),
            format!("{policy:?}"),
        );
        let found = self.kept.lock().unwrap().get(&key).cloned();
        if found.is_some() {
            self.hits.fetch_add(1, Ordering::Relaxed);
        }
        let e = found.unwrap_or_else(encode);
        self.kept.lock().unwrap().insert(key, e.clone());
        e
    }
}

/// With a memo, a second write takes every matrix from it and gives the same bytes and report;
/// a bundle with one matrix changed takes the others from it and encodes that one.
#[test]
fn a_memo_of_earlier_encodings_writes_the_same_bytes() {
    let mut rng = Lcg(23);
    let bundle = drt_bundle(&mut rng, true, true, true);
    for options in policies() {
        let (want, want_report) = bundle.encode_on(&options, 1);
        let memo = Memo::default();
        let (first, _) = bundle.encode_memo(&options, 2, Some(&memo));
        assert!(first == want);
        assert_eq!(memo.hits.load(Ordering::Relaxed), 0);
        let kept = memo.kept.lock().unwrap().len();
        assert!(kept > 10, "{kept} encodings kept");
        for threads in [1, 3] {
            memo.hits.store(0, Ordering::Relaxed);
            let (again, report) = bundle.encode_memo(&options, threads, Some(&memo));
            assert!(again == want, "{threads} threads");
            assert_eq!(report, want_report);
            assert!(memo.hits.load(Ordering::Relaxed) >= kept);
        }
        // One shape matrix changed: the bytes of a fresh write, from the memo otherwise.
        let mut changed = bundle.clone();
        changed.shapes[0].u_b.data[0] += 0.25;
        memo.hits.store(0, Ordering::Relaxed);
        let (with_memo, r1) = changed.encode_memo(&options, 2, Some(&memo));
        let (fresh, r2) = changed.encode_on(&options, 1);
        assert!(with_memo == fresh);
        assert_eq!(r1, r2);
        assert!(memo.hits.load(Ordering::Relaxed) > 0);
    }
}
