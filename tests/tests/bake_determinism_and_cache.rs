//! A bake is bit-identical at 1 and 2 threads; a second bake through the shape cache computes
//! no shape and gives the same bytes; a corrupt cache entry is detected and recomputed.

use lightfarm_proto::scene::Transport;
use lightfarm_server::bake::pipeline::{bake, BakeOptions};
use lightfarm_server::bake::progress::NoProgress;
use lightfarm_server::bake::shape_cache::ShapeCache;
use lightfarm_tests::*;

fn small_corridor() -> lightfarm_proto::scene::Scene {
    load_scene("corridor", 4, 128).0
}

#[test]
fn bake_is_identical_at_one_and_two_threads() {
    let scene = small_corridor();
    let dir = scene_dir("corridor");
    let run = |threads: usize, transport: Transport| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| bake_scene(&scene, &dir, transport, true).0)
    };
    for transport in [Transport::Lightfield, Transport::Traced] {
        assert!(
            run(1, transport) == run(2, transport),
            "{transport:?}: bundles differ between 1 and 2 threads"
        );
    }
}

#[test]
fn second_bake_reuses_every_shape_and_corrupt_entries_are_recomputed() {
    let scene = small_corridor();
    let dir = scene_dir("corridor");
    let cache_dir = std::env::temp_dir().join(format!("lf-cache-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&cache_dir);
    let options = BakeOptions {
        cache: Some(ShapeCache::open(&cache_dir).unwrap()),
        full: false,
        transport: None,
    };
    let (first, r1) = bake(&scene, &dir, &options, &NoProgress).unwrap();
    assert_eq!(r1.shapes_computed, r1.unique_shapes);
    let (second, r2) = bake(&scene, &dir, &options, &NoProgress).unwrap();
    assert_eq!(r2.shapes_computed, 0, "second bake computed shapes");
    assert_eq!(r2.shapes_from_cache, r2.unique_shapes);
    assert!(first.encode() == second.encode());
    // Corrupt one entry: flip a byte in the middle.
    let entry = std::fs::read_dir(&cache_dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .find(|p| p.extension().is_some_and(|e| e == "lfshape"))
        .unwrap();
    let mut bytes = std::fs::read(&entry).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x40;
    std::fs::write(&entry, &bytes).unwrap();
    let (third, r3) = bake(&scene, &dir, &options, &NoProgress).unwrap();
    assert_eq!(r3.corrupt_cache_entries, 1);
    assert_eq!(r3.shapes_computed, 1);
    assert!(
        first.encode() == third.encode(),
        "recomputed entry gives the same bundle"
    );
    let _ = std::fs::remove_dir_all(&cache_dir);
}
