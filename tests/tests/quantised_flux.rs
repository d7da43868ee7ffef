//! A closed level of many blocks keeps its flux through the 8-bit bundle
//! (`lightfarm_server::bake::mrt::flux`).
//!
//! A 30 × 12 × 4 m shaft made of 7 × 2 × 2 blocks open to each other (4.3 × 6 × 2 m each), of
//! albedo ρ, lit by one point light of intensity I, at a tight tolerance (1e-4, 1,024 rays,
//! T = 8). Every reflected photon lands on a wall again, so the indirect light carries exactly
//! `ρ²·4πI` at one bounce and `ρ²·4πI/(1−ρ)` over all bounces. The bundle stores each shape's
//! `T_d→b` in 8 bits a row at a time; before its coefficients were turned so that one row
//! alone carries the flux, that rounding gave this level +5.5% at one bounce (all bounces
//! multiply it by about `1/(1−ρ)`); turned, +0.5% at one bounce and +2.6% at all. The rest
//! was the transport's 8-bit `Z'` and source bases (+0.19% and +0.74% with the transport
//! stored losslessly); turned as well (`lightfarm_server::bake::transport::flux`), +0.09% and
//! +0.75%, which the bounds below hold (the all-bounce one fails without that turn).

use std::f64::consts::PI;

use lightfarm_client::{Bounces, Method};
use lightfarm_proto::lights::LightSet;
use lightfarm_proto::scene::{Scene, Transport};
use lightfarm_server::evaluate::evaluate;
use lightfarm_tests::{bake_scene, check_flux_against, grey_blocks, indirect_flux};

const RHO: f64 = 0.8;
const INTENSITY: f64 = 1.0;

/// The shaft: `n` blocks along each axis of a 30 × 12 × 4 m box, open where they touch.
fn shaft(n: [usize; 3]) -> Scene {
    let size = [30.0, 12.0, 4.0];
    let mut blocks = Vec::new();
    for i in 0..n[0] {
        for j in 0..n[1] {
            for k in 0..n[2] {
                let at = [i, j, k];
                let min = std::array::from_fn(|a| size[a] * at[a] as f64 / n[a] as f64);
                let max = std::array::from_fn(|a| size[a] * (at[a] + 1) as f64 / n[a] as f64);
                let mut open = Vec::new();
                for (a, axis) in ["x", "y", "z"].iter().enumerate() {
                    if at[a] > 0 {
                        open.push(format!("\"-{axis}\""));
                    }
                    if at[a] + 1 < n[a] {
                        open.push(format!("\"+{axis}\""));
                    }
                }
                blocks.push((format!("s{i}_{j}_{k}"), min, max, open.join(", ")));
            }
        }
    }
    let blocks: Vec<(&str, [f64; 3], [f64; 3], &str)> = blocks
        .iter()
        .map(|(id, min, max, open)| (id.as_str(), *min, *max, open.as_str()))
        .collect();
    grey_blocks("shaft", &blocks, RHO, (8, 1024, 0.0001))
}

#[test]
fn a_closed_shaft_of_28_blocks_keeps_the_geometric_series_at_a_tight_tolerance() {
    let scene = shaft([7, 2, 2]);
    let lights = LightSet::from_json(&format!(
        r#"{{"lights": [{{"kind": "point", "position": [25.0, 10.0, 2.3],
             "intensity": [{INTENSITY}, {INTENSITY}, {INTENSITY}]}}], "poses": []}}"#
    ))
    .expect("lights");
    let (bytes, report) = bake_scene(&scene, &std::env::temp_dir(), Transport::Traced, false);
    assert_eq!(report.blocks, 28);
    let phi = 4.0 * PI * INTENSITY;
    for (mode, want, within) in [
        (Bounces::One, RHO * RHO * phi, 0.005),
        (Bounces::default(), RHO * RHO * phi / (1.0 - RHO), 0.015),
    ] {
        let bundle = lightfarm_client::decode(&bytes).expect("decode");
        let r = evaluate(bundle.clone(), &lights, Method::Mrt, mode).expect("evaluate");
        let flux = indirect_flux(&bundle, &r);
        check_flux_against(&format!("{mode:?}"), flux, want, within);
    }
}
