//! Numerical stability, geometry: warps from 1:1 to 1:100 (crawlspaces, a shaft), scales from
//! 1 cm to 10 km, lights on a surface / in a corner / outside every light region, and blocks
//! with every face open. Every case is finite, energy-bounded, bit-identical at 1 and 2 threads
//! and within its stated relative L2 bound of the brute-force reference (see
//! `stability_common`). Bounds: `// measured m; bound b` as measured at the time of writing
//! (texels_per_face 6, 256 rays; references at 2048 rays per texel, or 1024 per sub-texel for
//! the texel-averaged references of `reference_3x` and `reference_kx`).

mod stability_common;

use lightfarm_proto::scene::Transport;
use stability_common::*;

const T: u32 = 6;
const RAYS: u32 = 256;
const REF_RAYS: u32 = 2048;

fn block(id: &str, min: [f64; 3], max: [f64; 3], open: &[&str], albedo: f64) -> String {
    format!(
        r#"{{ "id": "{id}", "min": {min:?}, "max": {max:?}, "open": {open:?}, "albedo": [{albedo}, {albedo}, {albedo}] }}"#
    )
}

fn scene_json(name: &str, blocks: &[String], clutter: &str, extra: &str) -> String {
    format!(
        r#"{{ "format": "lightfarm.scene/1", "name": "{name}", "blocks": [ {} ], "clutter": [ {clutter} ] {extra} }}"#,
        blocks.join(", ")
    )
}

/// Boxes from a cube to 1:100 crawlspaces and a 1:100 shaft. With T×T texels on every face, a
/// lamp 5 cm from the floor of a 10 m crawlspace lights a spot far smaller than a texel: the
/// point reference at texel centres and the texel average differ by 70% there, so every warp is
/// compared with the texel average of a reference at 9T (`reference_kx`), which is what a
/// texel-based bake estimates (at 3T the mean of 3 × 3 sub-texels still missed most of such a
/// spot: the 1:100 crawlspace's reference held 0.94 of the light's flux, 1.02 at 9T); the
/// reference's per-texel energy bound applies where texel centres resolve the lamp
/// (`resolved`). The direct light fed in is exact near a lamp
/// (`lightfarm_client::texel_samples`); on the 4 × 4 grid alone the two 1:100 boxes kept 0.68
/// of the flux and were 0.33 from this reference, the shaft 0.16.
#[test]
fn warps_from_one_to_one_to_one_to_a_hundred() {
    // (label, extent, open faces, light, resolved, bound)
    let cases: [(&str, [f64; 3], &[&str], [f64; 3], bool, f64); 5] = [
        // measured 0.0226 (0.0166 against texel centres); bound 0.04
        (
            "cube 1:1",
            [2.0, 2.0, 2.0],
            &[],
            [0.6, 1.4, 0.8],
            true,
            0.04,
        ),
        // Baked as 3 × 3 pieces (`bake/scene/pieces.rs`): measured 0.0722 (0.1258 as one
        // block); bound 0.11
        (
            "crawlspace 1:10",
            [5.0, 0.5, 5.0],
            &[],
            [1.5, 0.25, 2.0],
            true,
            0.11,
        ),
        // The lamp's footprint (5 cm from floor and ceiling) is far below a 1.7 m texel: the
        // texel average is what the bake can hold (2.18 against texel centres).
        // measured 0.0227; bound 0.04
        (
            "crawlspace 1:100, lamp inside",
            [10.0, 0.1, 10.0],
            &[],
            [3.0, 0.05, 4.0],
            false,
            0.04,
        ),
        // A shaft open to the sky, the lamp a metre above its mouth.
        // measured 0.0924; bound 0.13
        (
            "shaft 1:100, lit from above",
            [0.3, 30.0, 0.3],
            &["+y"],
            [0.12, 31.0, 0.17],
            true,
            0.12,
        ),
        // measured 0.0272 (2.25 against texel centres); bound 0.05
        (
            "wall slab 1:100:100",
            [0.2, 20.0, 20.0],
            &[],
            [0.1, 6.0, 12.0],
            false,
            0.05,
        ),
    ];
    for (label, extent, open, position, resolved, bound) in cases {
        let scene = scene(
            &scene_json(label, &[block("b", [0.0; 3], extent, open, 0.7)], "", ""),
            T,
            RAYS,
        );
        let size = extent.iter().cloned().fold(0.0, f64::max);
        let lights = one_light(position, size * size);
        let dir = no_meshes();
        let (centre, average) = reference_kx(&scene, &dir, &lights, REF_RAYS / 2, 9);
        let check = if resolved {
            check_case
        } else {
            check_case_unresolved
        };
        let m = check(
            label,
            &scene,
            &dir,
            Transport::Lightfield,
            &lights,
            &average,
            bound,
        );
        // The point reference at texel centres, for the record.
        eprintln!(
            "{label}: against texel centres {:.4}",
            distance(&m.result, &centre)
        );
    }
}

/// A 1:100 shaft standing on a small junction cube that opens into a 1:100 duct; the lamp is in
/// the junction. Light must climb the shaft and run along the duct through both transports.
#[test]
fn shaft_and_duct_carry_light_through_warped_openings() {
    let s = 0.3;
    let scene = scene(
        &scene_json(
            "shaft and duct",
            &[
                block("junction", [0.0; 3], [s, s, s], &["+y", "+x"], 0.7),
                block("shaft", [0.0, s, 0.0], [s, 100.0 * s, s], &["-y"], 0.7),
                block("duct", [s, 0.0, 0.0], [100.0 * s, s, s], &["-x"], 0.7),
            ],
            "",
            "",
        ),
        T,
        RAYS,
    );
    let lights = one_light([0.1, 0.15, 0.2], 1.0);
    let dir = no_meshes();
    let reference = reference(&scene, &dir, &lights, REF_RAYS);
    // (transport, bound)
    for (transport, bound) in [
        // measured 0.1018; bound 0.15
        (Transport::Lightfield, 0.15),
        // measured 0.1018; bound 0.15
        (Transport::Traced, 0.15),
    ] {
        check_case(
            &format!("shaft and duct {transport:?}"),
            &scene,
            &dir,
            transport,
            &lights,
            &reference,
            bound,
        );
    }
}

/// A room (4 × 3 × 4), an annex through an opening and a crate, scaled by s = 0.0025 … 10⁴: the
/// room from 1 cm to 40 km (lights scaled with intensity ∝ s² so radiance is scale-free). Each scale matches its reference, and the
/// indirect light is the same at every scale.
#[test]
fn scales_from_one_centimetre_to_ten_kilometres() {
    let unit = |s: f64| {
        let v = |p: [f64; 3]| p.map(|x| x * s);
        let scene = scene(
            &scene_json(
                &format!("scale {s}"),
                &[
                    block("room", v([0.0; 3]), v([4.0, 3.0, 4.0]), &["+x"], 0.7),
                    block(
                        "annex",
                        v([4.0, 0.0, 0.0]),
                        v([7.0, 3.0, 4.0]),
                        &["-x"],
                        0.6,
                    ),
                ],
                &format!(
                    r#"{{ "id": "crate", "box": {{ "min": {:?}, "max": {:?} }}, "albedo": [0.5, 0.5, 0.5] }}"#,
                    v([1.5, 0.0, 1.5]),
                    v([2.5, 1.2, 2.5])
                ),
                // The probe grid follows the scene's scale (1 m spacing over 70 km is refused;
                // see stability_inputs.rs).
                &format!(r#", "settings": {{ "probe_spacing": {s} }}"#),
            ),
            T,
            RAYS,
        );
        (scene, one_light(v([0.8, 2.4, 1.0]), 6.0 * s * s))
    };
    let dir = no_meshes();
    let mut results = Vec::new();
    // (scale, bound)
    for (s, bound) in [
        // measured 0.0594; bound 0.09
        (0.0025, 0.09),
        // measured 0.0594; bound 0.09
        (0.01, 0.09),
        // measured 0.0594; bound 0.09
        (1.0, 0.09),
        // measured 0.0594; bound 0.09
        (4.0, 0.09),
        // measured 0.0594; bound 0.09
        (2500.0, 0.09),
        // measured 0.0594; bound 0.09
        (1e4, 0.09),
    ] {
        let (scene, lights) = unit(s);
        let reference = reference(&scene, &dir, &lights, REF_RAYS);
        let m = check_case(
            &format!("scale ×{s}"),
            &scene,
            &dir,
            Transport::Lightfield,
            &lights,
            &reference,
            bound,
        );
        results.push((s, m.result));
    }
    for (s, r) in &results {
        let d = distance(r, &results[2].1);
        eprintln!("scale {s}: distance to the 1 m result {d:.2e}");
        if *s == 4.0 {
            // A power of two scales every float exactly: no absolute length anywhere in the
            // bake or the client, so the light is bit for bit the same.
            assert!(d == 0.0, "scale 4: indirect light differs from 1 m by {d}");
        }
        // At other scales rounding moves a few discrete ray events (a ray grazing the seam
        // between two faces lands on one or the other), which can move a shape's rank cut by one
        // mode: another estimate of the same operator, not a scale error (the room alone, baked
        // before box symmetries, differs by 1.2% between 1 m and 2.5 mm the same way). Measured
        // 1.0e-2 at s = 0.0025; bound 2e-2.
        assert!(
            d <= 2e-2,
            "scale {s}: indirect light differs from 1 m by {d}"
        );
    }
}

fn two_rooms(extra: &str) -> String {
    scene_json(
        "two rooms",
        &[
            block("room", [0.0; 3], [4.0, 3.0, 4.0], &["+x"], 0.7),
            block("annex", [4.0, 0.0, 0.0], [7.0, 3.0, 4.0], &["-x"], 0.6),
        ],
        "",
        extra,
    )
}

/// Lights exactly on a wall, on the floor, on the opening between two blocks, in a corner and a
/// hair from it; and lights outside every light region (in a block no region reaches, in the
/// region's block but outside it).
#[test]
fn lights_on_surfaces_in_corners_and_outside_every_region() {
    let dir = no_meshes();
    let plain = scene(&two_rooms(""), T, RAYS);
    let regions = scene(
        &two_rooms(r#", "light_regions": [ { "min": [0.5, 2.0, 0.5], "max": [1.5, 2.8, 1.5] } ]"#),
        T,
        RAYS,
    );
    // (label, scene, position, bound)
    let cases = [
        // measured 0.0395; bound 0.06
        ("on the floor", &plain, [1.3, 0.0, 2.1], 0.06),
        // measured 0.0485; bound 0.07
        ("on a wall", &plain, [0.0, 1.6, 2.2], 0.07),
        // measured 0.0228; bound 0.04
        ("on the opening", &plain, [4.0, 1.4, 1.9], 0.04),
        // measured 0.0487; bound 0.07
        ("in a corner", &plain, [0.0, 0.0, 0.0], 0.07),
        // No L2 bound: 7/8 of the lamp's power lands within millimetres of the corner, and
        // the brute-force reference has no finite variance there (between 8192 and 32768 rays
        // per texel its own estimate moves by 127%; against ours 0.28 at 2048 rays, 0.999 at
        // 32768). The client's direct light is exact on the texels around the lamp (the solid
        // angle each subtends), so ours carries the corner's reflected power: flux 0.90, as a
        // lamp standing free gives in these rooms (0.81–0.92 here), where the 4 × 4 grid alone
        // gave 0.12 and the reference gives 0.2–0.56. Finite, deterministic and
        // energy-bounded all the same.
        (
            "a millimetre from a corner",
            &plain,
            [0.001, 2.999, 0.001],
            f64::INFINITY,
        ),
        // The lamp is not in the prior's span.
        // measured 0.1047; bound 0.15
        (
            "outside the region, same block",
            &regions,
            [3.2, 0.6, 3.1],
            0.15,
        ),
        // measured 0.0284; bound 0.045
        (
            "outside the region, other block",
            &regions,
            [5.5, 1.5, 2.0],
            0.045,
        ),
    ];
    for (label, scene, position, bound) in cases {
        let lights = one_light(position, 5.0);
        let (_, average) = reference_3x(scene, &dir, &lights, REF_RAYS / 2);
        check_case_unresolved(
            label,
            scene,
            &dir,
            Transport::Lightfield,
            &lights,
            &average,
            bound,
        );
    }
}

/// A lamp outside every block and every light region: behind a closed wall it lights nothing;
/// in front of an opening onto the void it lights the room through it.
#[test]
fn lights_outside_every_block() {
    let dir = no_meshes();
    let regions = r#", "light_regions": [ { "min": [0.5, 2.0, 0.5], "max": [1.5, 2.8, 1.5] } ]"#;
    let closed = scene(&two_rooms(regions), T, RAYS);
    let lights = one_light([-2.0, 1.5, 2.0], 5.0);
    let (bundle, ours) = bake_and_apply_deterministically(
        "behind a closed wall",
        &closed,
        &dir,
        Transport::Lightfield,
        &lights,
    );
    assert!(
        ours.texels
            .iter()
            .all(|t| t.direct == [0.0; 3] && t.indirect == [0.0; 3]),
        "light leaks through a closed wall"
    );
    // The reference leaks a trace through the wall's edges (shadow rays from hit points within
    // the tracer's epsilon of a corner start past the wall): bounded, not zero.
    let reference = reference(&closed, &dir, &lights, REF_RAYS);
    let leak = flux_ratio(&reference, &texel_areas(&bundle), 0.7, &lights);
    eprintln!("behind a closed wall: reference flux ratio {leak:.2e}");
    // measured 2.0e-6; bound 1e-5
    assert!(leak <= 1e-5, "reference leak {leak}");

    let open = scene(
        &scene_json(
            "window",
            &[
                block("room", [0.0; 3], [4.0, 3.0, 4.0], &["+x", "-z"], 0.7),
                block("annex", [4.0, 0.0, 0.0], [7.0, 3.0, 4.0], &["-x"], 0.6),
            ],
            "",
            regions,
        ),
        T,
        RAYS,
    );
    let lights = one_light([1.5, 2.0, -1.5], 5.0);
    let (_, average) = reference_3x(&open, &dir, &lights, REF_RAYS / 2);
    // measured 0.0330; bound 0.05
    check_case(
        "in front of an opening onto the void",
        &open,
        &dir,
        Transport::Lightfield,
        &lights,
        &average,
        0.05,
    );
}

/// A junction block with every face open, an arm on each of its six faces, the lamp in the
/// junction (which has no texels of its own).
#[test]
fn a_block_with_every_face_open_joins_six_arms() {
    let (a, b) = (2.0, 5.0);
    let arms = [
        ("px", [b, a, a], [b + 3.0, b, b], "-x"),
        ("nx", [a - 3.0, a, a], [a, b, b], "+x"),
        ("py", [a, b, a], [b, b + 3.0, b], "-y"),
        ("ny", [a, a - 3.0, a], [b, a, b], "+y"),
        ("pz", [a, a, b], [b, b, b + 3.0], "-z"),
        ("nz", [a, a, a - 3.0], [b, b, a], "+z"),
    ];
    let mut blocks = vec![block(
        "junction",
        [a; 3],
        [b; 3],
        &["-x", "+x", "-y", "+y", "-z", "+z"],
        0.7,
    )];
    for (id, min, max, open) in arms {
        blocks.push(block(id, min, max, &[open], 0.65));
    }
    let scene = scene(&scene_json("junction", &blocks, "", ""), T, RAYS);
    let dir = no_meshes();
    for (label, position) in [
        ("lamp in the open junction", [3.1, 3.6, 3.3]),
        ("lamp in an arm", [6.5, 3.2, 3.9]),
    ] {
        let lights = one_light(position, 5.0);
        let reference = reference(&scene, &dir, &lights, REF_RAYS);
        for (transport, bound) in [
            // measured 0.0232 (lamp in the junction) / 0.0248 (in an arm); bound 0.04
            (Transport::Lightfield, 0.04),
            // measured 0.0191 / 0.0203; bound 0.04
            (Transport::Traced, 0.04),
        ] {
            check_case(
                &format!("{label}, {transport:?}"),
                &scene,
                &dir,
                transport,
                &lights,
                &reference,
                bound,
            );
        }
    }
}

/// A lone block with every face open has nothing to light: it bakes to an empty layout (or is
/// refused with a clear error), never a panic.
#[test]
fn a_lone_block_with_every_face_open() {
    let scene = scene(
        &scene_json(
            "open",
            &[block(
                "cage",
                [0.0; 3],
                [2.0; 3],
                &["-x", "+x", "-y", "+y", "-z", "+z"],
                0.7,
            )],
            "",
            "",
        ),
        T,
        RAYS,
    );
    let lights = one_light([1.0; 3], 1.0);
    let dir = no_meshes();
    let (_, result) = bake_and_apply_deterministically(
        "lone open block",
        &scene,
        &dir,
        Transport::Lightfield,
        &lights,
    );
    assert!(result.texels.is_empty());
}
