//! Long rooms, baked as pieces (`lightfarm_server::bake::scene::pieces`), end to end.
//!
//! `texels_per_face` cuts every face into T × T texels, so a 30 m room's texels are metres long
//! and a lamp near its wall lit a spot far smaller than one of them (one bounce 56% off Mitsuba
//! at T = 8 as one block). The bake now cuts such rooms into pieces of the room's own scale.
//! Checked here:
//! - closed rooms of albedo ρ lit by a point light of intensity I carry exactly the geometric
//!   series `ρ²·4πI/(1−ρ)` of indirect flux over all bounces (`ρ²·4πI` at one bounce), however
//!   many cuts the light crosses: a long box, and a hall under a shaft with a closet, where a
//!   cut forced across an opening made the shaft's pieces six times as tall as deep until they
//!   were cut again (they lost 10% of the light at all bounces against Mitsuba before, most
//!   of it to the 8-bit `T_d→b`'s rounding, which `tests/quantised_flux.rs` covers);
//! - the long box texel by texel against the reference solver at one bounce;
//! - the result keeps the scene's names: texels named `block:<id>/<face>` of the scene's blocks,
//!   `(surface, index)` unique.
//!
//! Bundles are stored as a bake stores them (8-bit codecs), as a game receives them.

use std::collections::HashSet;
use std::f64::consts::PI;

use lightfarm_client::{Bounces, Method};
use lightfarm_proto::lights::LightSet;
use lightfarm_proto::result::ResultFile;
use lightfarm_proto::scene::{Scene, Transport};
use lightfarm_server::bake::scene::geometry::Geometry;
use lightfarm_server::evaluate::evaluate;
use lightfarm_tests::{
    bake_scene, check_against_reference, check_flux_against, grey_blocks, indirect_flux,
    reference_of,
};

const RHO: f64 = 0.8;
const INTENSITY: f64 = 1.0;

/// A scene of closed-off blocks `(id, min, max, open faces)` of albedo [`RHO`] at T = 8.
fn scene(blocks: &[(&str, [f64; 3], [f64; 3], &str)]) -> Scene {
    grey_blocks("long", blocks, RHO, (8, 512, 0.001))
}

/// The 30 × 1.2 × 4 m box.
fn long_box() -> Scene {
    scene(&[("hall", [0.0, 0.0, 0.0], [30.0, 1.2, 4.0], "")])
}

fn light(at: [f64; 3]) -> LightSet {
    LightSet::from_json(&format!(
        r#"{{"lights": [{{"kind": "point", "position": {at:?},
             "intensity": [{INTENSITY}, {INTENSITY}, {INTENSITY}]}}], "poses": []}}"#
    ))
    .expect("lights")
}

/// Bakes `scene`, relights it by `lights` at one bounce and at all, and checks the flux
/// against the geometric series within 3%; returns the bundle and its one-bounce result.
fn check_flux(label: &str, scene: &Scene, lights: &LightSet) -> (Vec<u8>, ResultFile) {
    let (bytes, report) = bake_scene(scene, &std::env::temp_dir(), Transport::Traced, false);
    eprintln!("{label}: {} blocks baked", report.blocks);
    let phi = 4.0 * PI * INTENSITY;
    let mut one = None;
    for (want, mode) in [
        (RHO * RHO * phi, Bounces::One),
        (RHO * RHO * phi / (1.0 - RHO), Bounces::default()),
    ] {
        let bundle = lightfarm_client::decode(&bytes).expect("decode");
        let r = evaluate(bundle.clone(), lights, Method::Mrt, mode).expect("evaluate");
        let flux = indirect_flux(&bundle, &r);
        check_flux_against(&format!("{label} {mode:?}"), flux, want, 0.03);
        if mode == Bounces::One {
            one = Some(r);
        }
    }
    (bytes, one.unwrap())
}

#[test]
fn a_long_closed_box_carries_the_geometric_series_through_its_pieces() {
    let scene = long_box();
    let (bytes, _) = check_flux("long box", &scene, &light([2.0, 0.6, 0.5]));
    let bundle = lightfarm_client::decode(&bytes).expect("decode");
    // Cut along x only, in ⌈30 / (4 · 1.2)⌉ = 7.
    assert_eq!(bundle.blocks.len(), 7);
}

#[test]
fn a_hall_under_a_shaft_carries_the_geometric_series_through_its_pieces() {
    // The hall (30 × 1.2 × 4 m) opens into a 12 m shaft above and a 0.6 m closet at its end.
    // The closet needs 2 along z, which the cut carries across both openings; then the
    // shaft's pieces (30/7 × 12 × 2 m) are cut along y too.
    // The shaft comes first, so that its y cut is found only on a second pass.
    let scene = scene(&[
        ("shaft", [0.0, 1.2, 0.0], [30.0, 13.2, 4.0], r#""-y""#),
        ("hall", [0.0, 0.0, 0.0], [30.0, 1.2, 4.0], r#""+x", "+y""#),
        ("closet", [30.0, 0.0, 0.0], [30.6, 1.2, 4.0], r#""-x""#),
    ]);
    for at in [[2.0, 0.6, 0.5], [25.0, 10.0, 2.3]] {
        let (bytes, one) = check_flux(&format!("hall, light at {at:?}"), &scene, &light(at));
        let bundle = lightfarm_client::decode(&bytes).expect("decode");
        assert_eq!(bundle.blocks.len(), 7 * 2 + 2 + 7 * 2 * 2);
        // Cut along two axes, a face's pieces are numbered row by row: the result's
        // (surface, index) is the reference solver's texel (same name, index and position).
        let g = Geometry::from_scene(&scene, &std::env::temp_dir()).expect("geometry");
        assert_eq!(g.texels.len(), one.texels.len());
        for (t, r) in g.texels.iter().zip(&one.texels) {
            let name = &g.surfaces[t.surface as usize].name;
            assert_eq!((name, t.index), (&r.surface, r.index));
            for k in 0..3 {
                assert!(
                    (t.position[k] - r.position[k]).abs() < 1e-5,
                    "{name} {}",
                    t.index
                );
            }
        }
    }
}

#[test]
fn a_long_box_matches_the_reference_and_keeps_its_names() {
    let scene = long_box();
    let lights = light([2.0, 0.6, 0.5]);
    let dir = std::env::temp_dir();
    let (bytes, ours) = check_flux("long box", &scene, &lights);
    // The reference solver traces the same texels (its geometry is the bake's).
    let reference = reference_of(&scene, &dir, &lights, 4096);
    let c = check_against_reference("long box, one bounce", &ours, &reference, 0.08);
    assert_eq!(c.unmatched, 0);
    // Names: the scene's block, each (surface, index) once, indices 0.. per surface name.
    let bundle = lightfarm_client::decode(&bytes).expect("decode");
    assert_eq!(ours.texels.len(), bundle.layout.n_texels());
    let mut seen = HashSet::new();
    for t in &ours.texels {
        assert!(t.surface.starts_with("block:hall/"), "{}", t.surface);
        assert!(
            seen.insert((t.surface.clone(), t.index)),
            "{} {}",
            t.surface,
            t.index
        );
    }
    for face in ["-x", "+x", "-y", "+y", "-z", "+z"] {
        let name = format!("block:hall/{face}");
        let mut indices: Vec<u32> = ours
            .texels
            .iter()
            .filter(|t| t.surface == name)
            .map(|t| t.index)
            .collect();
        indices.sort_unstable();
        let pieces = if face.ends_with('x') { 1 } else { 7 };
        assert_eq!(indices, (0..pieces * 64).collect::<Vec<u32>>(), "{name}");
    }
}
