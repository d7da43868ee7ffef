//! `lf_runtime_apply` allocates nothing per frame: the runtime keeps its direct and indirect
//! scratch inside `LfRuntime`; nor do the layout queries (the atlas is computed at load). Its own test binary, because it replaces the global allocator
//! with one that counts the current thread's allocations.

use lightfarm::*;
use lightfarm_proto::bundle::Matrix;
use lightfarm_proto::testing::{allocs, one_block_bundle, strip_layout, CountingAlloc};

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

/// A block of `n` texels whose rank-2 operator has distinct entries everywhere.
fn bundle(n: usize) -> Vec<u8> {
    let m = |rows: usize, cols: usize| Matrix {
        rows: rows as u32,
        cols: cols as u32,
        data: (0..rows * cols).map(|k| 1.0 / (1 + k) as f32).collect(),
    };
    one_block_bundle(strip_layout(n), "strip", "strip", m(n, 2), m(2, n)).encode()
}

#[test]
fn apply_allocates_nothing_and_repeats_bit_for_bit() {
    let bytes = bundle(40);
    // SAFETY: `bytes` is live for the call.
    let rt = unsafe { lf_runtime_new(bytes.as_ptr(), bytes.len()) };
    assert!(!rt.is_null());
    let direct: Vec<f32> = (0..120).map(|k| (k % 7) as f32 * 0.25).collect();
    let (mut first, mut second) = (vec![0.0f32; 120], vec![0.0f32; 120]);

    let before = allocs();
    let _counter_works = std::hint::black_box(Box::new(0u8));
    assert_eq!(allocs(), before + 1, "the allocation counter works");

    let before = allocs();
    // SAFETY: live runtime; buffers of 120 floats.
    let statuses = unsafe {
        [
            lf_runtime_apply(rt, 0, direct.as_ptr(), 120, first.as_mut_ptr(), 120),
            lf_runtime_apply(rt, 0, direct.as_ptr(), 120, second.as_mut_ptr(), 120),
        ]
    };
    assert_eq!(allocs(), before, "lf_runtime_apply allocated");
    assert_eq!(statuses, [0, 0]);
    assert_eq!(first, second);
    assert!(first.iter().all(|v| v.is_finite() && *v > 0.0));

    // Relighting by a change allocates only on its first call (the reach's flags).
    let change: Vec<f32> = (0..120).map(|k| if k < 12 { 0.5 } else { 0.0 }).collect();
    // SAFETY: live runtime; buffers of 120 floats, not overlapping.
    let first_delta =
        unsafe { lf_runtime_apply_delta(rt, 0, change.as_ptr(), 120, first.as_mut_ptr(), 120) };
    let before = allocs();
    // SAFETY: as above.
    let again =
        unsafe { lf_runtime_apply_delta(rt, 0, change.as_ptr(), 120, second.as_mut_ptr(), 120) };
    assert_eq!(allocs(), before, "lf_runtime_apply_delta allocated");
    assert_eq!([first_delta, again], [0, 0]);
    assert_eq!(first, second);
    // SAFETY: from lf_runtime_new, freed once.
    unsafe { lf_runtime_free(rt) };
}

#[test]
fn layout_queries_allocate_nothing() {
    let bytes = bundle(40);
    // SAFETY: `bytes` is live for the call.
    let rt = unsafe { lf_runtime_new(bytes.as_ptr(), bytes.len()) };
    assert!(!rt.is_null());
    let mut floats = vec![0.0f32; 120];
    let mut xy = vec![0u32; 80];
    let mut name = [0u8; 32];
    let (mut width, mut height, mut offset, mut count) = (0u32, 0u32, 0u32, 0u32);
    let before = allocs();
    // SAFETY: live runtime; every buffer holds the length passed with it.
    let (statuses, needed, surfaces) = unsafe {
        let f = floats.as_mut_ptr();
        (
            [
                lf_runtime_texel_positions(rt, f, 120),
                lf_runtime_texel_normals(rt, f, 120),
                lf_runtime_texel_albedo(rt, f, 120),
                lf_runtime_texel_sizes(rt, f, 80),
                lf_runtime_atlas_size(rt, &mut width, &mut height),
                lf_runtime_atlas_texels(rt, xy.as_mut_ptr(), 80),
            ],
            lf_runtime_surface(rt, 0, name.as_mut_ptr().cast(), 32, &mut offset, &mut count),
            lf_runtime_surface_count(rt),
        )
    };
    assert_eq!(allocs(), before, "a layout query allocated");
    assert_eq!(statuses, [0; 6]);
    assert_eq!((needed, surfaces, offset, count), (15, 1, 0, 40));
    assert_eq!(&name[..15], b"block:strip/-y\0");
    assert_eq!(&xy[..4], &[0, 0, 1, 0]);
    // SAFETY: from lf_runtime_new, freed once.
    unsafe { lf_runtime_free(rt) };
}

/// The probe calls allocate nothing once the field is filled and a change of the same spans has
/// been added once (the runtime keeps the field and the scratch of both ways), and repeat bit
/// for bit.
#[test]
fn probe_calls_allocate_nothing_after_the_first() {
    let mut rng = lightfarm_proto::testing::Lcg(43);
    let bytes = lightfarm_proto::testing::probe_bundle(&mut rng, true).encode();
    // SAFETY: `bytes` is live for the call.
    let rt = unsafe { lf_runtime_new(bytes.as_ptr(), bytes.len()) };
    assert!(!rt.is_null());
    // SAFETY: live runtime.
    let (n, probes) = unsafe { (lf_runtime_texel_count(rt), lf_runtime_probe_count(rt)) };
    let light: Vec<f32> = (0..3 * n).map(|k| (k % 5) as f32 * 0.5).collect();
    let change: Vec<f32> = (0..3 * n).map(|k| (k % 3) as f32 * 0.125).collect();
    let spans = [LfTexelSpan {
        start: 1,
        end: n as u32 - 1,
        in_sight: 0,
    }];
    let (mut first, mut second) = (
        vec![0.0f32; probes * LF_PROBE_FLOATS],
        vec![0.0f32; probes * LF_PROBE_FLOATS],
    );
    let (p, nrm, mut e) = ([0.5f32, 0.75, -0.75], [0.0f32, 1.0, 0.0], [0.0f32; 3]);
    // SAFETY (every block below): live runtime; every buffer holds the length passed with it.
    let frame = |out: &mut [f32], e: &mut [f32; 3]| unsafe {
        [
            lf_runtime_apply_probes(rt, light.as_ptr(), light.len()),
            lf_runtime_apply_probes_delta_in_spans(
                rt,
                change.as_ptr(),
                change.len(),
                spans.as_ptr(),
                1,
            ),
            lf_runtime_probe_field(rt, out.as_mut_ptr(), out.len()),
            lf_runtime_probe_irradiance(rt, p.as_ptr(), nrm.as_ptr(), e.as_mut_ptr()),
        ]
    };
    assert_eq!(frame(&mut first, &mut e), [0; 4], "the first frame works");
    let before = allocs();
    let statuses = frame(&mut second, &mut e);
    assert_eq!(allocs(), before, "a probe call allocated");
    assert_eq!(statuses, [0; 4]);
    assert_eq!(first, second, "the same frame gives the same bits");
    assert!(first.iter().any(|&v| v != 0.0) && e.iter().any(|&v| v > 0.0));
    // SAFETY: from lf_runtime_new, freed once.
    unsafe { lf_runtime_free(rt) };
}
