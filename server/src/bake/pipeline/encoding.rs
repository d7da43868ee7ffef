//! How a baked bundle is stored: the scene's codec settings turned into [`EncodeOptions`].
//!
//! Invariant: the choice depends on the settings and the operators alone, so the bytes of a
//! bundle are a pure function of the scene like the operators themselves.

use lightfarm_proto::bundle::EncodeOptions;
use lightfarm_proto::codec::{CodecPolicy, MatrixCodec};
use lightfarm_proto::scene::{BundleCodec, Settings};

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
