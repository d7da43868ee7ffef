//! A bake is bit-identical at 1 and 2 threads; a second bake through the shape cache computes
//! no shape and gives the same bytes; a corrupt cache entry is detected and recomputed.

use lightfarm_proto::scene::Transport;
use lightfarm_server::bake::cache::shape::ShapeCache;
use lightfarm_server::bake::progress::NoProgress;
use lightfarm_server::bake::{bake, BakeOptions};
use lightfarm_tests::*;

fn small_corridor() -> lightfarm_proto::scene::Scene {
    load_scene("corridor", 4, 128).0
}

/// Bake options over an empty operator cache of the test's own (`name` and this process),
/// with the transport `transport`; and that cache's directory.
fn cached(name: &str, transport: Option<Transport>) -> (std::path::PathBuf, BakeOptions) {
    let cache_dir = std::env::temp_dir().join(format!("{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&cache_dir);
    let options = BakeOptions {
        cache: Some(ShapeCache::open(&cache_dir).unwrap()),
        full: false,
        transport,
    };
    (cache_dir, options)
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
    let (cache_dir, options) = cached("lf-cache-test", None);
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

/// The transport stage never holds a level's f64 transport: it goes to the cache as the
/// compaction is made, or, without a cache, to a scratch directory, from which DRT's inpainting
/// reads the blocks it needs one at a time. The maze (clutter, buried texels, symmetric
/// blocks) comes out the same bytes without a cache, through a cold cache and through a warm
/// one, and its inpainting did run.
#[test]
fn a_bake_without_a_cache_gives_the_bytes_of_a_bake_through_one() {
    let (scene, _) = load_scene("maze", 8, 32);
    let dir = scene_dir("maze");
    let plain = BakeOptions {
        cache: None,
        full: false,
        transport: None,
    };
    let (without, report) = bake(&scene, &dir, &plain, &NoProgress).unwrap();
    let drt = report.drt.expect("the maze has clutter");
    assert!(
        drt.buried_scene_texels > 0,
        "nothing was inpainted: {drt:?}"
    );
    let (cache_dir, options) = cached("lf-scratch-test", None);
    let (cold, r1) = bake(&scene, &dir, &options, &NoProgress).unwrap();
    assert!(!r1.transport_from_cache);
    let (warm, r2) = bake(&scene, &dir, &options, &NoProgress).unwrap();
    assert!(r2.transport_from_cache);
    let bytes = without.encode();
    assert!(bytes == cold.encode(), "a cold cache changed the bundle");
    assert!(bytes == warm.encode(), "a warm cache changed the bundle");
    let _ = std::fs::remove_dir_all(&cache_dir);
}

/// A shape's lightfields are an entry of their own, read only when a lightfield transport is
/// computed: a rebake whose transport is cached bakes no shape without them; a transport
/// computed later reads them, or bakes again the shapes whose lightfield entry is gone or
/// corrupt. Every bake is the same bytes. A traced transport reads none.
#[test]
fn lightfields_are_read_only_for_a_transport_that_is_computed() {
    let scene = small_corridor();
    let dir = scene_dir("corridor");
    let (cache_dir, options) = cached("lf-lightfields", Some(Transport::Lightfield));
    let with_ext = |ext: &str| -> Vec<std::path::PathBuf> {
        std::fs::read_dir(&cache_dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.extension().is_some_and(|e| e == ext))
            .collect()
    };
    let (first, r1) = bake(&scene, &dir, &options, &NoProgress).unwrap();
    let shapes = r1.unique_shapes;
    assert_eq!(r1.shapes_computed, shapes);
    assert_eq!(with_ext("lflight").len(), shapes);
    let fresh = first.encode();

    // Transport cached: the lightfields are not needed.
    for p in with_ext("lflight") {
        std::fs::remove_file(p).unwrap();
    }
    let (second, r2) = bake(&scene, &dir, &options, &NoProgress).unwrap();
    assert!(r2.transport_from_cache);
    assert_eq!((r2.shapes_from_cache, r2.shapes_computed), (shapes, 0));
    assert!(second.encode() == fresh);

    // Transport computed, no lightfield entry: every shape baked again (and stored whole).
    let transport_dir = cache_dir.join("transport");
    std::fs::remove_dir_all(&transport_dir).unwrap();
    let (third, r3) = bake(&scene, &dir, &options, &NoProgress).unwrap();
    assert!(!r3.transport_from_cache);
    assert_eq!(r3.shapes_computed, shapes);
    assert_eq!(with_ext("lflight").len(), shapes);
    assert!(third.encode() == fresh);

    // Transport computed, the lightfields read; one corrupt entry is baked again.
    std::fs::remove_dir_all(&transport_dir).unwrap();
    let entry = with_ext("lflight").into_iter().next().unwrap();
    let mut bytes = std::fs::read(&entry).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x40;
    std::fs::write(&entry, &bytes).unwrap();
    let (fourth, r4) = bake(&scene, &dir, &options, &NoProgress).unwrap();
    assert_eq!((r4.corrupt_cache_entries, r4.shapes_computed), (1, 1));
    assert!(fourth.encode() == fresh);

    // A traced transport's shapes are its own (their rank keeps what leaves each opening's cells,
    // not the lightfields: `ShapeSpec::lightfield_rows`); computed again with no lightfield
    // entry at all, it bakes no shape again.
    let traced = BakeOptions {
        transport: Some(Transport::Traced),
        ..options.clone()
    };
    let (_, r5) = bake(&scene, &dir, &traced, &NoProgress).unwrap();
    assert_eq!((r5.shapes_from_cache, r5.shapes_computed), (0, shapes));
    for p in with_ext("lflight") {
        std::fs::remove_file(p).unwrap();
    }
    std::fs::remove_dir_all(&transport_dir).unwrap();
    let (_, r6) = bake(&scene, &dir, &traced, &NoProgress).unwrap();
    assert!(!r6.transport_from_cache);
    assert_eq!((r6.shapes_from_cache, r6.shapes_computed), (shapes, 0));
    assert!(with_ext("lflight").is_empty());
    let _ = std::fs::remove_dir_all(&cache_dir);
}

/// Incremental rebake: after one pillar moves, the DRT ray passes trace only the texels that
/// could see it (old or new place) and reuse the rest from the cache, the compaction reuses the
/// factorisations of what did not change, and the bundle is byte-identical to a bake without
/// any cache. Corrupt ray-cache and factor entries are dropped and computed again, with the
/// same bytes.
#[test]
fn moving_one_pillar_retraces_its_neighbourhood_only_and_matches_a_fresh_bake() {
    let (scene, _) = load_scene("maze", 4, 64);
    let dir = scene_dir("maze");
    let (cache_dir, options) = cached("lf-drt-cache-test", Some(Transport::Lightfield));
    let (_, first) = bake(&scene, &dir, &options, &NoProgress).unwrap();
    let d1 = first.drt.unwrap();
    assert_eq!(d1.reused_texels, 0);
    let total = d1.traced_texels;
    // Texels out of clutter's sight are not traced at all; the maze has some.
    let block_texels = d1.traced_texels + d1.culled_texels;
    assert!(d1.culled_texels > 0);
    let factors = || std::fs::read_dir(cache_dir.join("factors")).map_or(0, |d| d.count());
    assert!(factors() > 0, "no factorisation was cached");

    let mut moved = scene.clone();
    let pillar = moved
        .clutter
        .iter_mut()
        .find(|c| c.id == "pillar_n_b")
        .unwrap();
    let b = pillar.box_.as_mut().unwrap();
    b.min[0] += 0.5;
    b.max[0] += 0.5;
    let (incremental, second) = bake(&moved, &dir, &options, &NoProgress).unwrap();
    let d2 = second.drt.unwrap();
    eprintln!(
        "one pillar moved: {} of {block_texels} block texels traced again, {} reused, {} out of sight (first bake: {total} traced)",
        d2.traced_texels, d2.reused_texels, d2.culled_texels
    );
    assert_eq!(
        d2.traced_texels + d2.reused_texels + d2.culled_texels,
        block_texels
    );
    assert_eq!(second.shapes_computed, 0);
    // The transport came from the cache (read for the blocks holding a buried texel only).
    assert!(second.transport_from_cache);
    // What could see the pillar's old or new place is traced again: under a third of the level.
    assert!(
        d2.reused_texels > 0 && d2.traced_texels * 3 < block_texels,
        "{} of {block_texels} texels traced again",
        d2.traced_texels
    );
    let (fresh, _) = bake_scene(&moved, &dir, Transport::Lightfield, false);
    assert!(
        stored(&moved, &incremental) == fresh,
        "the incremental bake differs from a fresh one"
    );

    // Corrupt every ray-cache and factor entry: all are dropped, computed again, same bytes.
    for sub in ["drt", "factors"] {
        for entry in std::fs::read_dir(cache_dir.join(sub)).unwrap() {
            let path = entry.unwrap().path();
            let mut bytes = std::fs::read(&path).unwrap();
            let mid = bytes.len() / 2;
            bytes[mid] ^= 0x40;
            std::fs::write(&path, &bytes).unwrap();
        }
    }
    let (again, third) = bake(&moved, &dir, &options, &NoProgress).unwrap();
    assert_eq!(third.drt.unwrap().reused_texels, 0);
    assert!(stored(&moved, &again) == fresh);

    // The pillar stands on a floor texel's centre: that texel is buried, so inpainting reads
    // the cached transport into hall_n. Corrupt every target block's transport entry (the
    // main entry reads fine): the loss is found mid-bake, by inpainting; the main entry is
    // dropped and the bake runs once more, computing the transport: same bytes, and the
    // transport is stored again, then read block by block.
    let mut on_texel = moved.clone();
    let pillar = on_texel
        .clutter
        .iter_mut()
        .find(|c| c.id == "pillar_n_b")
        .unwrap();
    let b = pillar.box_.as_mut().unwrap();
    (b.min[0], b.max[0], b.min[2], b.max[2]) = (9.5, 10.0, 16.25, 16.75);
    let (fresh, _) = bake_scene(&on_texel, &dir, Transport::Lightfield, false);
    let mut corrupted = 0;
    for entry in std::fs::read_dir(cache_dir.join("transport")).unwrap() {
        let path = entry.unwrap().path();
        if !path.file_name().unwrap().to_string_lossy().contains(".t") {
            continue;
        }
        let mut bytes = std::fs::read(&path).unwrap();
        let mid = bytes.len() / 2;
        bytes[mid] ^= 0x40;
        std::fs::write(&path, &bytes).unwrap();
        corrupted += 1;
    }
    assert!(corrupted > 1);
    let (again, fourth) = bake(&on_texel, &dir, &options, &NoProgress).unwrap();
    assert!(fourth.drt.unwrap().buried_scene_texels > 0);
    assert!(
        !fourth.transport_from_cache,
        "the unreadable transport was used"
    );
    assert!(stored(&on_texel, &again) == fresh);
    let (again, fifth) = bake(&on_texel, &dir, &options, &NoProgress).unwrap();
    assert!(
        fifth.transport_from_cache,
        "the transport was not stored again"
    );
    assert!(stored(&on_texel, &again) == fresh);
    let _ = std::fs::remove_dir_all(&cache_dir);
}

/// Incremental rebakes with mesh clutter: moving the box clutter reuses the mesh's own ray
/// unit where nothing its texels saw changed, moving the mesh (its transform) retraces what
/// could see it; both rebakes give the bytes of a fresh bake.
#[test]
fn moving_clutter_next_to_a_mesh_matches_a_fresh_bake() {
    let (scene, _) = load_scene("cornell_mesh", 4, 64);
    let dir = scene_dir("cornell_mesh");
    let (cache_dir, options) = cached("lf-mesh-cache-test", Some(Transport::Lightfield));
    let (_, first) = bake(&scene, &dir, &options, &NoProgress).unwrap();
    let total = first.drt.unwrap().traced_texels;
    let mut moved = scene.clone();
    let tall = moved
        .clutter
        .iter_mut()
        .find(|c| c.id == "tall_box")
        .unwrap();
    let b = tall.box_.as_mut().unwrap();
    b.min[2] -= 0.3;
    b.max[2] -= 0.3;
    let (incremental, second) = bake(&moved, &dir, &options, &NoProgress).unwrap();
    let d2 = second.drt.unwrap();
    eprintln!(
        "tall box moved: {} of {total} texels traced again, {} reused",
        d2.traced_texels, d2.reused_texels
    );
    assert!(d2.reused_texels > 0);
    let (fresh, _) = bake_scene(&moved, &dir, Transport::Lightfield, false);
    assert!(
        stored(&moved, &incremental) == fresh,
        "tall box moved: differs from a fresh bake"
    );
    let mesh = moved
        .clutter
        .iter_mut()
        .find(|c| c.id == "short_box")
        .unwrap();
    let mut t = mesh.transform.unwrap_or_default();
    t.translation[0] -= 0.2;
    mesh.transform = Some(t);
    let (incremental, third) = bake(&moved, &dir, &options, &NoProgress).unwrap();
    let d3 = third.drt.unwrap();
    eprintln!(
        "mesh moved: {} texels traced again, {} reused",
        d3.traced_texels, d3.reused_texels
    );
    let (fresh, _) = bake_scene(&moved, &dir, Transport::Lightfield, false);
    assert!(
        stored(&moved, &incremental) == fresh,
        "mesh moved: differs from a fresh bake"
    );
    let _ = std::fs::remove_dir_all(&cache_dir);
}

/// The farm's units: running every unit of the plan (in any order within a phase, each into the
/// shared cache directory), then the ordinary bake over that cache, computes nothing more and
/// gives the bundle of a bake in one piece. A unit run twice leaves identical files.
#[test]
fn units_then_assembly_give_the_bundle_of_one_piece() {
    use lightfarm_server::bake::units::{plan, run_unit, unit_inputs, BakeUnit, UnitScene};
    for name in ["maze", "ball_corridor", "cornell_mesh"] {
        let (mut scene, _) = load_scene(name, 4, 32);
        scene.settings.dnrt.resolution = 6;
        scene.settings.dnrt.rays = 64;
        let dir = scene_dir(name);
        let cache_dir =
            std::env::temp_dir().join(format!("lf-units-test-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&cache_dir);
        let cache = ShapeCache::open(&cache_dir).unwrap();
        let us = UnitScene::new(scene.clone(), &dir).unwrap();
        let phases = plan(&us).unwrap();
        let mut written = Vec::new();
        for phase in &phases {
            // Reverse order: units of a phase do not depend on each other.
            for unit in phase.iter().rev() {
                assert_eq!(BakeUnit::parse(&unit.name()).as_ref(), Some(unit));
                let inputs = unit_inputs(&us, unit).unwrap();
                let files = run_unit(&us, &cache, unit, &NoProgress).unwrap();
                assert!(!files.is_empty(), "{name}: {} wrote nothing", unit.name());
                for f in &files {
                    assert!(
                        cache_dir.join(f).is_file(),
                        "{name}: {} missing",
                        f.display()
                    );
                    if !matches!(unit, BakeUnit::Transport) {
                        assert!(
                            inputs.contains(f),
                            "{name}: {} not among inputs",
                            f.display()
                        );
                    }
                }
                written.extend(files);
            }
        }
        // A unit run again writes the same bytes.
        let again = &phases[0][phases[0].len() - 1];
        let before: Vec<Vec<u8>> = written
            .iter()
            .map(|f| std::fs::read(cache_dir.join(f)).unwrap())
            .collect();
        // On a fresh UnitScene too: nothing it keeps changes a unit's bytes.
        run_unit(
            &UnitScene::new(scene.clone(), &dir).unwrap(),
            &cache,
            again,
            &NoProgress,
        )
        .unwrap();
        for (f, bytes) in written.iter().zip(&before) {
            assert!(&std::fs::read(cache_dir.join(f)).unwrap() == bytes);
        }
        let options = BakeOptions {
            cache: Some(cache),
            full: false,
            transport: None,
        };
        let (assembled, report) = bake(&scene, &dir, &options, &NoProgress).unwrap();
        assert_eq!(report.shapes_computed, 0, "{name}");
        assert!(report.transport_from_cache, "{name}");
        if let Some(d) = &report.drt {
            assert_eq!(d.traced_texels, 0, "{name}: assembly traced DRT rays");
        }
        let fresh = bake(
            &scene,
            &dir,
            &BakeOptions {
                cache: None,
                full: false,
                transport: None,
            },
            &NoProgress,
        )
        .unwrap()
        .0;
        assert!(
            assembled.encode() == fresh.encode(),
            "{name}: assembled bundle differs from a bake in one piece"
        );
        let _ = std::fs::remove_dir_all(&cache_dir);
    }
}

/// `lightfarm bake --cache`: a rebake of inputs this build baked before hands back the bundle
/// it wrote without baking (the shape entries deleted in between stay gone: nothing was read
/// or computed); a changed mesh file bakes again, as does a corrupt memo entry, dropped — and
/// every time the bytes are the same.
#[test]
fn a_rebake_of_unchanged_inputs_reuses_the_bundle_and_any_change_bakes() {
    use lightfarm_server::cli::bake::{run, BakeArgs};
    let root = std::env::temp_dir().join(format!("lf-memo-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(&root).unwrap();
    let src = scene_dir("cornell_mesh");
    for f in ["short_box.gltf", "short_box.bin"] {
        std::fs::copy(src.join(f), root.join(f)).unwrap();
    }
    let (scene, _) = load_scene("cornell_mesh", 4, 64);
    std::fs::write(
        root.join("scene.json"),
        serde_json::to_string(&scene).unwrap(),
    )
    .unwrap();
    let cache = root.join("cache");
    let bake_to = |out: &str| {
        run(BakeArgs {
            scene: root.join("scene.json"),
            out: root.join(out),
            cache: Some(cache.clone()),
            full: false,
            transport: None,
            codec: None,
            quiet: true,
        })
        .unwrap();
        std::fs::read(root.join(out)).unwrap()
    };
    let files = |dir: &std::path::Path, ext: &str| -> Vec<std::path::PathBuf> {
        std::fs::read_dir(dir)
            .map(|d| {
                d.map(|e| e.unwrap().path())
                    .filter(|p| p.extension().is_some_and(|e| e == ext))
                    .collect()
            })
            .unwrap_or_default()
    };
    let forget_shapes = || {
        for p in files(&cache, "lfshape") {
            std::fs::remove_file(p).unwrap();
        }
    };
    let first = bake_to("a.lfb");
    assert!(!files(&cache, "lfshape").is_empty());
    assert_eq!(files(&cache.join("bundles"), "lfbundle").len(), 1);

    forget_shapes();
    assert!(bake_to("b.lfb") == first, "the memoised bundle differs");
    assert!(files(&cache, "lfshape").is_empty(), "the rebake baked");

    // The glTF file changed (a space after its JSON: the same geometry): a bake, same bytes.
    let gltf = root.join("short_box.gltf");
    let mut text = std::fs::read(&gltf).unwrap();
    text.push(b' ');
    std::fs::write(&gltf, &text).unwrap();
    assert!(bake_to("c.lfb") == first);
    assert!(
        !files(&cache, "lfshape").is_empty(),
        "a changed mesh file did not bake"
    );
    assert_eq!(files(&cache.join("bundles"), "lfbundle").len(), 2);

    // Corrupt memo entries are dropped and baked again.
    for p in files(&cache.join("bundles"), "lfbundle") {
        let mut bytes = std::fs::read(&p).unwrap();
        let mid = bytes.len() / 2;
        bytes[mid] ^= 0x40;
        std::fs::write(&p, &bytes).unwrap();
    }
    forget_shapes();
    assert!(bake_to("d.lfb") == first);
    assert!(
        !files(&cache, "lfshape").is_empty(),
        "a corrupt memo entry was used"
    );
    forget_shapes();
    assert!(bake_to("e.lfb") == first);
    assert!(
        files(&cache, "lfshape").is_empty(),
        "the rewritten entry was not used"
    );
    let _ = std::fs::remove_dir_all(&root);
}
