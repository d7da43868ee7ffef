//! Blocks that are rotations or mirror images of one another share one shape (bundle format 2):
//! the bake stores it once, each block names its symmetry, and the client lights every block
//! as if it had its own operators. Also the versioning around it: a 1.x bundle (kind-3 blocks)
//! still decodes, and a newer major version is a clear error.

use lightfarm_client::{Bounces, DirectLight, IndirectLight, Method, Runtime};
use lightfarm_proto::bundle::{section, Bundle, BUNDLE_MAJOR};
use lightfarm_proto::container::write_container;
use lightfarm_proto::scene::{Scene, Transport};
use lightfarm_proto::wire::Writer;
use lightfarm_server::bake::progress::NoProgress;
use lightfarm_server::bake::{bake, BakeOptions};

/// Two rooms, mirror images of each other across the opening they share at x = 2 (the second
/// one is also coloured, which shape operators never depend on).
fn mirrored_rooms() -> Scene {
    serde_json::from_str(
        r#"{
          "format": "lightfarm.scene/1", "name": "mirrored",
          "settings": {"texels_per_face": 6, "rays_per_texel": 256},
          "blocks": [
            {"id": "west", "min": [0, 0, 0], "max": [2, 2.5, 3], "open": ["+x"], "albedo": [0.7, 0.7, 0.7]},
            {"id": "east", "min": [2, 0, 0], "max": [4, 2.5, 3], "open": ["-x"], "albedo": [0.7, 0.7, 0.7]}
          ]
        }"#,
    )
    .unwrap()
}

fn baked(scene: &Scene) -> Bundle {
    baked_with(scene, None)
}

fn baked_with(scene: &Scene, transport: Option<Transport>) -> Bundle {
    let options = BakeOptions {
        cache: None,
        full: false,
        transport,
    };
    bake(scene, std::path::Path::new("."), &options, &NoProgress)
        .unwrap()
        .0
}

/// With the lightfield transport every operator is the shared shape's, permuted: the rooms
/// light as exact mirror images. The traced transport (the default) traces each room's texels
/// with rays of their own, so the light one room sends the other is an independent estimate
/// of its mirror's: equal within the rays' noise, not to rounding.
#[test]
fn mirror_image_blocks_share_one_shape_and_light_as_mirror_images() {
    let lightfield = mirror_mismatch(Some(Transport::Lightfield));
    // Independent Monte Carlo estimates of the two rooms differ by about 1e-2 at 256 rays; one
    // shared, permuted estimate differs by float rounding only.
    assert!(lightfield < 1e-4, "mirror mismatch {lightfield:e}");
    let traced = mirror_mismatch(None);
    assert!(
        traced > 1e-4 && traced < 3e-2,
        "traced mirror mismatch {traced:e}"
    );
}

/// Relative L2 between the west room's light and the east room's mirrored, one bounce, for a
/// direct light symmetric about the plane they share.
fn mirror_mismatch(transport: Option<Transport>) -> f64 {
    let bundle = baked_with(&mirrored_rooms(), transport);
    assert_eq!(bundle.shapes.len(), 1, "the two rooms are one shape");
    assert!(
        bundle.blocks.iter().any(|b| b.symmetry.is_some()),
        "at least one room instances the shape through a symmetry"
    );
    // Direct light symmetric about the plane x = 2: a hot spot in each room, mirrored.
    let layout = bundle.layout.clone();
    let direct = DirectLight {
        radiance: layout
            .positions
            .iter()
            .map(|p| {
                let d = (p[0] - 2.0).abs();
                let hot =
                    (-((d - 1.2).powi(2) + (p[1] - 0.4).powi(2) + (p[2] - 2.0).powi(2))).exp();
                [0.1 + hot, 0.05 + 0.5 * hot, 0.02 * p[2]]
            })
            .collect(),
    };
    let mut rt = Runtime::try_new(bundle.clone()).unwrap();
    let mut out = IndirectLight::default();
    rt.apply(Method::Mrt, Bounces::One, &direct, &mut out)
        .unwrap();
    // Every west texel has an east texel at its mirror image, with the same light.
    let (mut diff, mut norm, mut pairs) = (0.0f64, 0.0f64, 0);
    for (t, p) in layout.positions.iter().enumerate() {
        if p[0] > 2.0 || (p[0] - 2.0).abs() < 1e-6 {
            continue;
        }
        let mirror = [4.0 - p[0], p[1], p[2]];
        let m = layout
            .positions
            .iter()
            .zip(&layout.normals)
            .position(|(q, n)| {
                (0..3).all(|k| (q[k] - mirror[k]).abs() < 1e-5)
                    && (n[0] + layout.normals[t][0]).abs() < 1e-6
                    && (n[1] - layout.normals[t][1]).abs() < 1e-6
            })
            .expect("mirror texel");
        for c in 0..3 {
            let (a, b) = (out.radiance[t][c] as f64, out.radiance[m][c] as f64);
            diff += (a - b).powi(2);
            norm += a.powi(2);
        }
        pairs += 1;
    }
    assert_eq!(pairs, layout.n_texels() / 2);
    (diff / norm).sqrt()
}

#[test]
fn symmetric_blocks_round_trip_through_the_bundle() {
    let bundle = baked(&mirrored_rooms());
    let bytes = bundle.encode();
    let decoded = Bundle::decode(&bytes).unwrap();
    assert_eq!(
        decoded
            .blocks
            .iter()
            .map(|b| (b.shape, b.symmetry))
            .collect::<Vec<_>>(),
        bundle
            .blocks
            .iter()
            .map(|b| (b.shape, b.symmetry))
            .collect::<Vec<_>>()
    );
    assert_eq!(u16::from_le_bytes([bytes[8], bytes[9]]), BUNDLE_MAJOR);
}

/// A bundle written by a 1.x baker (blocks in section kind 3, no symmetries) still decodes and
/// lights the scene; a bundle of a newer major version is refused with a message that says to
/// update the client.
#[test]
fn older_major_decodes_and_newer_major_is_a_clear_error() {
    let scene: Scene = serde_json::from_str(
        r#"{"format": "lightfarm.scene/1", "name": "room",
            "settings": {"texels_per_face": 4, "rays_per_texel": 64},
            "blocks": [{"id": "room", "min": [0, 0, 0], "max": [2, 2, 2], "albedo": [0.5, 0.5, 0.5]}]}"#,
    )
    .unwrap();
    let bundle = baked(&scene);
    assert!(bundle.blocks.iter().all(|b| b.symmetry.is_none()));
    let mut sections = bundle.raw_sections();
    for (kind, payload) in sections.iter_mut() {
        if *kind == section::BLOCKS_SYMMETRIC {
            let mut w = Writer::new();
            w.u32(bundle.blocks.len() as u32);
            for b in &bundle.blocks {
                w.str(&b.id);
                w.u32(b.shape);
                w.u32(b.texel_offset);
            }
            *kind = section::BLOCKS;
            *payload = w.bytes;
        }
    }
    let (old, _) = write_container(1, 3, &sections, 3);
    let decoded = Bundle::decode(&old).expect("a 1.3 bundle decodes");
    assert_eq!(decoded.blocks, bundle.blocks);
    assert_eq!(decoded.shapes, bundle.shapes);

    let (newer, _) = write_container(BUNDLE_MAJOR + 1, 0, &bundle.raw_sections(), 3);
    let err = Bundle::decode(&newer).unwrap_err().to_string();
    assert!(err.contains("update the client"), "{err}");
}
