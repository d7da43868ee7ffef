//! The zstd level each section is stored at: a shapes section larger than the container's small
//! sections is compressed at level 16 whatever lower level the bundle is written at (a clutter
//! edit leaves it unchanged, so only a cold bake pays for it), and decodes to the same bundle.

use lightfarm_proto::bundle::{section, section_name, Bundle, EncodeOptions, Matrix};
use lightfarm_proto::codec::{CodecPolicy, MatrixCodec};
use lightfarm_proto::container::{compress_section, SMALL_SECTION_BYTES};
use lightfarm_proto::testing::{one_block_bundle, strip_layout};

#[test]
fn a_large_shapes_section_is_stored_at_level_16() {
    // 2,048 texels, rank 80, f32: 1.3 MB of operators with structure zstd can find (values
    // smooth along the texels, rounded to a coarse grid as quantised operators are).
    let (texels, rank) = (2048u32, 80u32);
    let value = |i: u32, k: u32| {
        let x = i as f32 / texels as f32;
        ((x * (k + 1) as f32 * 3.1).sin() * 64.0).round() / 64.0
    };
    let u_b = Matrix::from_fn(texels, rank, value);
    let t_db = Matrix::from_fn(rank, texels, |k, i| value(i, k));
    let bundle = one_block_bundle(strip_layout(texels as usize), "strip", "s", u_b, t_db);
    let raw = bundle
        .raw_sections()
        .into_iter()
        .find(|(kind, _)| *kind == section::SHAPES)
        .expect("a shapes section")
        .1;
    assert!(raw.len() > SMALL_SECTION_BYTES, "{} raw bytes", raw.len());
    let options = EncodeOptions {
        codec: CodecPolicy::Fixed(MatrixCodec::F32),
        transport_codec: None,
        zstd_level: 3,
    };
    let (bytes, report) = bundle.encode_with(&options);
    let stored = report
        .sections
        .iter()
        .find(|(name, _)| *name == section_name(section::SHAPES))
        .expect("the shapes section in the report")
        .1
        .stored_len as usize;
    let at = |level| compress_section(&raw, level).expect("compressible").len();
    eprintln!(
        "shapes: raw {}, level 3 {}, level 16 {}, stored {stored}",
        raw.len(),
        at(3),
        at(16)
    );
    assert_eq!(stored, at(16));
    assert!(at(16) < at(3), "level 16 {} vs level 3 {}", at(16), at(3));
    assert_eq!(Bundle::decode(&bytes).unwrap(), bundle);
}
