//! How a baked bundle is stored: the scene's codec settings turned into [`EncodeOptions`], and
//! one write of the bundle through the level's encoding memo ([`encode_through`],
//! [`encode_and_keep`]) — what `lightfarm bake`, the service and the farm assembler all do.
//!
//! Invariant: the choice depends on the settings and the operators alone, so the bytes of a
//! bundle are a pure function of the scene like the operators themselves; the memo changes
//! the time a write takes, never its bytes.

use lightfarm_proto::bundle::{Bundle, EncodeOptions, EncodeReport, EncodingMemo};
use lightfarm_proto::codec::{CodecPolicy, MatrixCodec};
use lightfarm_proto::scene::{BundleCodec, Settings};

use crate::bake::cache::encodings::EncodingCache;

/// zstd level for bundle sections: level 9 compresses our quantised operators within a few
/// percent of level 19 at a fraction of the time.
pub const BUNDLE_ZSTD_LEVEL: i32 = 9;

/// The encode options for `codec` (the scene's `bundle_codec` unless overridden).
pub fn encode_options(settings: &Settings, codec: Option<BundleCodec>) -> EncodeOptions {
    let fixed = |codec| (CodecPolicy::Fixed(codec), None);
    let (policy, transport_policy) = match codec.unwrap_or(settings.bundle_codec) {
        BundleCodec::Auto => (
            CodecPolicy::Budget(settings.codec_error),
            Some(CodecPolicy::Budget(
                settings.codec_error.min(settings.transport_codec_error),
            )),
        ),
        BundleCodec::F32 => fixed(MatrixCodec::F32),
        BundleCodec::F16 => fixed(MatrixCodec::F16),
        BundleCodec::U8 => fixed(MatrixCodec::U8Columns),
    };
    EncodeOptions {
        codec: policy,
        transport_codec: transport_policy,
        zstd_level: BUNDLE_ZSTD_LEVEL,
    }
}

/// One write of `bundle` on every core, through the level's encoding `memo` when given (a write
/// of its own: [`EncodingCache::begin_write`]).
pub fn encode_through(
    bundle: &Bundle,
    options: &EncodeOptions,
    memo: Option<&EncodingCache>,
) -> (Vec<u8>, EncodeReport) {
    if let Some(memo) = memo {
        memo.begin_write();
    }
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    bundle.encode_memo(options, threads, memo.map(|m| m as &dyn EncodingMemo))
}

/// [`encode_through`], then the write's encodings kept in `memo` for the level's next write (a
/// failure to keep them is logged: only a later bake's time depends on it).
pub fn encode_and_keep(
    bundle: &Bundle,
    options: &EncodeOptions,
    memo: Option<&EncodingCache>,
) -> (Vec<u8>, EncodeReport) {
    let written = encode_through(bundle, options, memo);
    if let Some(memo) = memo {
        if let Err(e) = memo.save() {
            tracing::warn!(error = %e, "could not keep the bundle's encodings in the cache");
        }
    }
    written
}
