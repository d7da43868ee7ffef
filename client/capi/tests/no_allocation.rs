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
