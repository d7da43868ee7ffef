//! Fuzz target: any byte string given to `Bundle::decode` / `decode_prefix` gives `Ok` or
//! `Err`, never a panic, an unbounded allocation or a hang; a bundle that decodes makes a
//! runtime that applies every method without panicking.
//!
//! Run (stable toolchain, from `client/fuzz`):
//! `RUSTC_BOOTSTRAP=1 cargo fuzz run decode corpus/decode -- -max_total_time=300 -rss_limit_mb=2048`

#![no_main]

use libfuzzer_sys::fuzz_target;
use lightfarm_client::{Bounces, DirectLight, IndirectLight, Method, Runtime};
use lightfarm_proto::bundle::Bundle;

fuzz_target!(|bytes: &[u8]| {
    let _ = Bundle::decode_prefix(bytes);
    if let Ok(bundle) = Bundle::decode(bytes) {
        let mut runtime = Runtime::try_new(bundle).expect("a decoded bundle makes a runtime");
        let direct = DirectLight {
            radiance: vec![[1.0, 0.5, 0.25]; runtime.n_texels()],
        };
        let mut out = IndirectLight::default();
        for method in [Method::Mrt, Method::Drt, Method::Full] {
            let _ = runtime.apply(method, Bounces::One, &direct, &mut out);
        }
    }
});
