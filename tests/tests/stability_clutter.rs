//! Numerical stability, clutter (DRT): boxes touching a wall, intersecting a wall, intersecting
//! each other, spanning an opening, larger than their block and enclosing it; meshes with
//! degenerate and zero-area triangles and non-manifold meshes; meshes that cannot be baked are
//! refused with an error naming the object. Every case is finite, energy-bounded, bit-identical
//! at 1 and 2 threads and within its stated relative L2 bound of the brute-force reference on
//! the texels not buried in clutter (see `stability_common`). Bounds: `// measured m; bound b`
//! as measured at the time of writing (texels_per_face 6, 256 rays; reference 2048 rays).

mod stability_common;

use std::path::Path;

use lightfarm_proto::scene::Transport;
use stability_common::*;

const T: u32 = 6;
const RAYS: u32 = 256;
const REF_RAYS: u32 = 2048;

/// A room (open on +x) and an annex through the opening, with `clutter` (JSON objects).
fn rooms_with(clutter: &[String]) -> String {
    format!(
        r#"{{ "format": "lightfarm.scene/1", "name": "rooms with clutter",
             "blocks": [
               {{ "id": "room", "min": [0,0,0], "max": [4,3,4], "open": ["+x"], "albedo": [0.7,0.7,0.7],
                  "face_albedo": {{ "-x": [0.7, 0.2, 0.2] }} }},
               {{ "id": "annex", "min": [4,0,0], "max": [7,3,4], "open": ["-x"], "albedo": [0.6,0.6,0.6] }} ],
             "clutter": [ {} ] }}"#,
        clutter.join(", ")
    )
}

fn box_clutter(id: &str, min: [f64; 3], max: [f64; 3]) -> String {
    format!(
        r#"{{ "id": "{id}", "box": {{ "min": {min:?}, "max": {max:?} }}, "albedo": [0.2, 0.6, 0.3] }}"#
    )
}

fn mesh_clutter(id: &str, path: &str) -> String {
    format!(r#"{{ "id": "{id}", "mesh": "{path}", "albedo": [0.5, 0.5, 0.5] }}"#)
}

fn lamp() -> lightfarm_proto::lights::LightSet {
    one_light([0.8, 2.4, 1.0], 6.0)
}

fn run(
    label: &str,
    clutter: &[String],
    dir: &Path,
    lights: &lightfarm_proto::lights::LightSet,
    bound: f64,
) {
    let scene = scene(&rooms_with(clutter), T, RAYS);
    let reference = reference(&scene, dir, lights, REF_RAYS);
    for transport in [Transport::Lightfield, Transport::Traced] {
        check_case(
            &format!("{label}, {transport:?}"),
            &scene,
            dir,
            transport,
            lights,
            &reference,
            bound,
        );
    }
}

#[test]
fn clutter_touching_and_intersecting_walls() {
    let dir = no_meshes();
    // (label, clutter, bound)
    let cases = [
        // measured 0.0643 (Lightfield) / 0.0612 (Traced); bound 0.1
        (
            "touching the wall and the floor",
            vec![box_clutter("crate", [0.0, 0.0, 1.5], [1.0, 1.2, 2.5])],
            0.1,
        ),
        // measured 0.0664 / 0.0631; bound 0.1
        (
            "intersecting a wall",
            vec![box_clutter("crate", [-0.5, 0.0, 1.5], [0.8, 1.2, 2.5])],
            0.1,
        ),
        // measured 0.0657 / 0.0625; bound 0.1
        (
            "intersecting other clutter",
            vec![
                box_clutter("crate", [1.5, 0.0, 1.5], [2.5, 1.2, 2.5]),
                box_clutter("crate2", [2.0, 0.6, 2.0], [3.0, 1.8, 3.0]),
            ],
            0.1,
        ),
        // measured 0.0656 / 0.0627; bound 0.1
        (
            "spanning an opening",
            vec![box_clutter("beam", [3.5, 0.0, 1.5], [4.5, 1.0, 2.5])],
            0.1,
        ),
    ];
    for (label, clutter, bound) in cases {
        run(label, &clutter, &dir, &lamp(), bound);
    }
}

/// A slab wider than its block in x and z (through every wall and across the opening): the
/// lamp above it, the space below it dark.
#[test]
fn clutter_larger_than_its_block() {
    let dir = no_meshes();
    // measured 0.0818 / 0.0784; bound 0.12
    run(
        "slab through every wall",
        &[box_clutter("slab", [-1.0, 1.0, -1.0], [5.0, 1.3, 5.0])],
        &dir,
        &lamp(),
        0.12,
    );
}

/// A box enclosing the whole room (and reaching into the annex), the lamp in the annex: the room
/// is buried and stays dark and finite, the annex is lit.
#[test]
fn clutter_enclosing_its_block() {
    let dir = no_meshes();
    let scene = scene(
        &rooms_with(&[box_clutter("hangar", [-1.0, -1.0, -1.0], [5.0, 4.0, 5.0])]),
        T,
        RAYS,
    );
    let lights = one_light([6.0, 1.5, 2.0], 6.0);
    let reference = reference(&scene, &dir, &lights, REF_RAYS);
    // measured 0.0315; bound 0.05
    let m = check_case(
        "enclosing its block",
        &scene,
        &dir,
        Transport::Lightfield,
        &lights,
        &reference,
        0.05,
    );
    let lit_room = m
        .result
        .texels
        .iter()
        .filter(|t| t.surface.starts_with("block:room/"))
        .flat_map(|t| t.indirect)
        .fold(0.0, |a: f64, x| a.max(x.abs()));
    let lit_annex = m
        .result
        .texels
        .iter()
        .filter(|t| t.surface.starts_with("block:annex/"))
        .flat_map(|t| t.indirect)
        .fold(0.0, f64::max);
    eprintln!("buried room: {lit_room:.3e}, annex {lit_annex:.3e}");
    assert!(lit_annex > 0.0);
    // Before the fix in drt.rs (inpainting cancels every source's transport) the room held
    // 0.27 of the annex's brightest indirect light, through its opening.
    // With lightfield transport: measured 1.0e-7 (f32 round-off of MRT minus MRT). With the
    // default compact transport the cancellation is built from the uncompacted transport, so
    // the residual is the compaction's own error: measured 6.0e-3 of the annex; bound 1e-2.
    assert!(lit_room <= 1e-2 * lit_annex, "buried room lit: {lit_room}");
}

const PYRAMID: &str = "v 1.5 0.3 1.5\nv 2.5 0.3 1.5\nv 2.5 0.3 2.5\nv 1.5 0.3 2.5\nv 2.0 1.5 2.0\n\
f 1 2 5\nf 2 3 5\nf 3 4 5\nf 4 1 5\nf 1 3 2\nf 1 4 3\n";

/// A closed pyramid plus zero-area triangles (a repeated vertex, collinear vertices, all three
/// vertices equal) and slivers of area ~1e-9 m² and a 1 µm-wide needle.
#[test]
fn degenerate_and_zero_area_triangles() {
    let dir = temp_dir("degenerate");
    let degenerate = "v 3.0 1.0 3.0\nv 3.5 1.0 3.0\nv 3.0 1.0 3.0\nv 3.25 1.0 3.0\n\
v 3.0 1.0 3.5\nv 3.0 1.000000001 3.5\nv 3.0 1.0 3.5000001\nv 2.0 2.0 0.5\nv 2.0 2.0 0.500001\n";
    // Pyramid vertices are 1–5, the rest 6–14.
    let faces = "f 6 7 8\nf 6 7 9\nf 6 6 6\nf 6 10 11\nf 10 11 12\nf 6 13 14\nf 13 14 7\n";
    std::fs::write(dir.join("m.obj"), format!("{PYRAMID}{degenerate}{faces}")).unwrap();
    // measured 0.0664 / 0.0632 (the mesh now has texels, matched too); bound 0.11
    run(
        "degenerate and zero-area triangles",
        &[mesh_clutter("junk", "m.obj")],
        &dir,
        &lamp(),
        0.11,
    );
}

/// Non-manifold meshes: three triangles on one edge (a fin), two triangles meeting at a vertex
/// (a bowtie), a duplicated and a flipped face, a T-junction, and an open sheet poking through
/// the room's wall.
#[test]
fn non_manifold_meshes() {
    let dir = temp_dir("nonmanifold");
    let fin = "v 2.5 0.5 2.0\nv 2.5 1.5 2.0\nv 3.0 1.0 2.0\nv 2.0 1.0 2.0\nv 2.5 1.0 2.6\n\
f 1 2 3\nf 1 2 4\nf 2 1 5\nf 1 2 3\nf 3 2 1\n";
    let bowtie = "v 1.0 2.0 3.0\nv 1.5 2.0 3.0\nv 1.0 2.0 3.5\nv 0.5 2.0 2.5\nv 1.0 2.0 2.5\n\
f 6 7 8\nf 6 9 10\n";
    // T-junction: one big triangle's edge carries the vertex of two smaller ones.
    let tee = "v 3.0 0.2 0.5\nv 3.6 0.2 0.5\nv 3.3 0.2 1.0\nv 3.3 0.2 0.5\nv 3.3 0.2 0.0\n\
f 11 12 13\nf 11 14 15\nf 14 12 15\n";
    // An open quad through the -z wall.
    let sheet =
        "v 0.6 0.2 -0.5\nv 0.6 1.4 -0.5\nv 0.6 1.4 0.8\nv 0.6 0.2 0.8\nf 16 17 18\nf 16 18 19\n";
    std::fs::write(dir.join("n.obj"), format!("{fin}{bowtie}{tee}{sheet}")).unwrap();
    // measured 0.0678 / 0.0642 (the meshes now have texels, matched too); bound 0.11
    run(
        "non-manifold meshes",
        &[mesh_clutter("tangle", "n.obj")],
        &dir,
        &lamp(),
        0.11,
    );
}

/// Meshes that cannot be baked are refused with an error naming the object: no triangle with
/// positive area, a missing file, a NaN vertex, an index out of range.
#[test]
fn unbakeable_meshes_are_refused_without_a_panic() {
    let dir = temp_dir("refused");
    std::fs::write(
        dir.join("flat.obj"),
        "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\nf 1 1 2\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("nan.obj"),
        "v 1 1 1\nv 2 1 1\nv 1 nan 1\nf 1 2 3\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("index.obj"),
        "v 1 1 1\nv 2 1 1\nv 1 2 1\nf 1 2 9\n",
    )
    .unwrap();
    std::fs::write(dir.join("empty.obj"), "# nothing\n").unwrap();
    let cases: [(&str, &[&str]); 5] = [
        (
            "flat.obj",
            &["clutter \"thing\"", "no triangles with positive area"],
        ),
        ("missing.obj", &["clutter \"thing\"", "missing.obj"]),
        ("nan.obj", &["clutter \"thing\""]),
        ("index.obj", &["clutter \"thing\""]),
        ("empty.obj", &["clutter \"thing\""]),
    ];
    for (file, expected) in cases {
        let scene = scene(&rooms_with(&[mesh_clutter("thing", file)]), T, RAYS);
        let err = assert_bake_refused(&scene, &dir, expected);
        eprintln!("{file}: {err}");
    }
}
