//! `scripts/gt_check.py`: the Mitsuba check's scene with each closed block face moved into its
//! block, so that no two blocks' faces share a plane (the stock converter's coincident quads
//! let Mitsuba take a neighbouring room's face and albedo).
//!
//! Runs the script's `coincident` report and its `convert` (lfgt.py's converter, which needs
//! no Mitsuba) on a hand-made level of three rooms: A and B side by side (a shared wall), C on
//! top of A (A's ceiling is C's floor), a clutter box in A.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::{json, Value};

/// What the script moves each closed block face by (metres; `OFFSET` in the script).
const OFFSET: f64 = 2e-4;

fn script() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../scripts/gt_check.py")
}

/// `../shared/groundtruth` beside the repository (where CI has it, `.ci/run`).
fn groundtruth() -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/groundtruth");
    assert!(
        dir.join("lfgt.py").is_file(),
        "{} has no lfgt.py: these tests need ../shared beside the repository",
        dir.display()
    );
    dir
}

fn run(args: &[&str]) -> String {
    let out = Command::new("python3")
        .args(args)
        .env("LF_GROUNDTRUTH", groundtruth())
        .output()
        .expect("python3 runs");
    assert!(
        out.status.success(),
        "{args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// A (x 0–2) and B (x 2–4) share the wall x = 2 with different albedos; C (y 3–6) sits on A
/// with A's albedo; every face closed but B's +x.
fn write_level(dir: &Path) -> (PathBuf, PathBuf) {
    std::fs::create_dir_all(dir).unwrap();
    let scene = json!({
        "format": 1,
        "name": "coincident",
        "settings": {"texels_per_face": 4, "rays_per_texel": 64, "tolerance": 0.001},
        "blocks": [
            {"id": "a", "min": [0.0, 0.0, 0.0], "max": [2.0, 3.0, 2.0], "open": [], "albedo": [0.7, 0.7, 0.7]},
            {"id": "b", "min": [2.0, 0.0, 0.0], "max": [4.0, 3.0, 2.0], "open": ["+x"], "albedo": [0.3, 0.4, 0.5]},
            {"id": "c", "min": [0.0, 3.0, 0.0], "max": [2.0, 6.0, 2.0], "open": [], "albedo": [0.7, 0.7, 0.7]}
        ],
        "clutter": [
            {"id": "crate", "box": {"min": [0.5, 0.0, 0.5], "max": [1.0, 0.5, 1.0]}, "albedo": [0.5, 0.5, 0.5]}
        ]
    });
    let lights = json!({"lights": [{"kind": "point", "position": [1.5, 2.0, 1.5], "intensity": [5.0, 5.0, 5.0]}]});
    let (s, l) = (dir.join("scene.json"), dir.join("lights.json"));
    std::fs::write(&s, serde_json::to_string_pretty(&scene).unwrap()).unwrap();
    std::fs::write(&l, lights.to_string()).unwrap();
    (s, l)
}

fn scratch(tag: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lf-gt-check-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// A mesh's vertices as points.
fn vertices(mesh: &Value) -> Vec<[f64; 3]> {
    mesh["vertices"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| [0, 1, 2].map(|k| v[k].as_f64().unwrap()))
        .collect()
}

/// The axis a quad is flat along and its coordinate there, if it is axis-aligned and flat.
fn plane_of(quad: &[[f64; 3]]) -> Option<(usize, f64)> {
    (0..3).find_map(|ax| {
        let c = quad[0][ax];
        quad.iter().all(|p| p[ax] == c).then_some((ax, c))
    })
}

#[test]
fn coincident_lists_back_to_back_faces_and_their_area() {
    let dir = scratch("report");
    let (scene, _) = write_level(&dir);
    let out = run(&[
        script().to_str().unwrap(),
        "coincident",
        scene.to_str().unwrap(),
    ]);
    // The shared wall (3 × 2 m², albedos differ) and A's ceiling on C's floor (2 × 2 m², one
    // albedo); B's open +x face and faces of one block never pair.
    assert_eq!(
        out.trim(),
        "coincident_pairs=2 differing_albedo=1 area_m2=10.00 differing_area_m2=6.00"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn convert_moves_each_closed_block_face_into_its_block_and_nothing_else() {
    let dir = scratch("convert");
    let (scene, lights) = write_level(&dir);
    let (stock, separated) = (dir.join("stock.json"), dir.join("separated.json"));
    let lfgt = groundtruth().join("lfgt.py");
    let args = |tool: &Path, out: &Path| {
        run(&[
            tool.to_str().unwrap(),
            "convert",
            scene.to_str().unwrap(),
            lights.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ])
    };
    args(&lfgt, &stock);
    args(&script(), &separated);
    let read =
        |p: &Path| -> Value { serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap() };
    let (stock, separated) = (read(&stock), read(&separated));
    let (a, b) = (
        stock["meshes"].as_array().unwrap(),
        separated["meshes"].as_array().unwrap(),
    );
    // 6 + 5 + 6 closed block faces, then the crate's 6.
    assert_eq!(a.len(), 23);
    assert_eq!(b.len(), a.len());
    assert_eq!(separated["lights"], stock["lights"]);
    let centres = [[1.0, 1.5, 1.0], [3.0, 1.5, 1.0], [1.0, 4.5, 1.0]];
    let block_of = |k: usize| match k {
        0..6 => 0,
        6..11 => 1,
        _ => 2,
    };
    for (k, (m0, m1)) in a.iter().zip(b).enumerate() {
        assert_eq!(m0["albedo"], m1["albedo"], "mesh {k}");
        assert_eq!(m0["faces"], m1["faces"], "mesh {k}");
        let (v0, v1) = (vertices(m0), vertices(m1));
        if k >= 17 {
            assert_eq!(v0, v1, "clutter mesh {k} unchanged");
            continue;
        }
        let (ax, c0) = plane_of(&v0).expect("a block face is axis-aligned");
        let (ax1, c1) = plane_of(&v1).expect("and stays so");
        assert_eq!(ax, ax1);
        // Moved by OFFSET toward its block's centre, the other coordinates unchanged.
        let centre = centres[block_of(k)][ax];
        assert!(
            ((c1 - c0).abs() - OFFSET).abs() < 1e-12,
            "mesh {k}: {c0} → {c1}"
        );
        assert!(
            (c1 - centre).abs() < (c0 - centre).abs(),
            "mesh {k} moves inward"
        );
        for (p0, p1) in v0.iter().zip(&v1) {
            for i in (0..3).filter(|&i| i != ax) {
                assert_eq!(p0[i], p1[i], "mesh {k}");
            }
        }
    }
    // Faces of different blocks in one plane that overlap with an area: the shared wall and
    // A's ceiling on C's floor before the move, none after it (neighbours' coplanar outer
    // faces, such as A's and B's floors, touch along an edge only).
    let overlapping = |meshes: &[Value]| {
        let faces: Vec<(usize, f64, [f64; 3], [f64; 3])> = meshes[..17]
            .iter()
            .map(|m| {
                let v = vertices(m);
                let (ax, c) = plane_of(&v).unwrap();
                let lo = [0, 1, 2].map(|i| v.iter().map(|p| p[i]).fold(f64::INFINITY, f64::min));
                let hi =
                    [0, 1, 2].map(|i| v.iter().map(|p| p[i]).fold(f64::NEG_INFINITY, f64::max));
                (ax, c, lo, hi)
            })
            .collect();
        let mut n = 0;
        for i in 0..faces.len() {
            for j in i + 1..faces.len() {
                let ((ai, ci, loi, hii), (aj, cj, loj, hij)) = (faces[i], faces[j]);
                let area = (0..3)
                    .filter(|&k| k != ai)
                    .map(|k| (hii[k].min(hij[k]) - loi[k].max(loj[k])).max(0.0))
                    .product::<f64>();
                if ai == aj && ci == cj && area > 0.0 && block_of(i) != block_of(j) {
                    n += 1;
                }
            }
        }
        n
    };
    assert_eq!(overlapping(a), 2);
    assert_eq!(overlapping(b), 0);
    let _ = std::fs::remove_dir_all(&dir);
}

/// A glTF of two triangle primitives (one indexed, one not: its fourth vertex is left over)
/// under a node hierarchy (a parent turned and moved, a child scaled and moved), its buffer
/// in a file beside it (`.gltf`) or in the binary chunk (`.glb`).
fn write_gltf(dir: &Path) -> PathBuf {
    let positions: [[f32; 3]; 4] = [
        [0.0, 0.0, 0.0],
        [0.4, 0.0, 0.0],
        [0.0, 0.3, 0.0],
        [0.0, 0.0, 0.5],
    ];
    let indices: [u16; 6] = [0, 1, 2, 0, 3, 1];
    let mut bin: Vec<u8> = positions
        .iter()
        .flatten()
        .flat_map(|x| x.to_le_bytes())
        .collect();
    bin.extend(indices.iter().flat_map(|i| i.to_le_bytes()));
    bin.resize(bin.len().next_multiple_of(4), 0);
    let doc = |uri: Option<&str>| {
        let mut buffer = json!({"byteLength": bin.len()});
        if let Some(uri) = uri {
            buffer["uri"] = json!(uri);
        }
        json!({
            "asset": {"version": "2.0"},
            "scene": 0,
            "scenes": [{"nodes": [0]}],
            "nodes": [
                {"translation": [0.2, 0.1, 0.3], "rotation": [0.0, 0.38268343, 0.0, 0.92387953], "children": [1]},
                {"mesh": 0, "translation": [0.1, 0.0, 0.0], "scale": [1.0, 2.0, 1.5]}
            ],
            "meshes": [{"primitives": [
                {"attributes": {"POSITION": 0}, "indices": 1},
                {"attributes": {"POSITION": 0}}
            ]}],
            "buffers": [buffer],
            "bufferViews": [
                {"buffer": 0, "byteOffset": 0, "byteLength": 48},
                {"buffer": 0, "byteOffset": 48, "byteLength": 12}
            ],
            "accessors": [
                {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
                 "min": [0.0, 0.0, 0.0], "max": [0.4, 0.3, 0.5]},
                {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"}
            ]
        })
    };
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(dir.join("prop.bin"), &bin).unwrap();
    let gltf = dir.join("prop.gltf");
    std::fs::write(&gltf, doc(Some("prop.bin")).to_string()).unwrap();
    let mut json_chunk = doc(None).to_string().into_bytes();
    json_chunk.resize(json_chunk.len().next_multiple_of(4), b' ');
    let mut glb = Vec::new();
    glb.extend(b"glTF");
    glb.extend(2u32.to_le_bytes());
    glb.extend(((12 + 8 + json_chunk.len() + 8 + bin.len()) as u32).to_le_bytes());
    glb.extend((json_chunk.len() as u32).to_le_bytes());
    glb.extend(b"JSON");
    glb.extend(&json_chunk);
    glb.extend((bin.len() as u32).to_le_bytes());
    glb.extend(b"BIN\0");
    glb.extend(&bin);
    std::fs::write(dir.join("prop.glb"), glb).unwrap();
    gltf
}

/// Triangles in a loader-independent order (by corners rounded to 0.1 mm; the test's are far
/// apart), to compare two loaders' output.
fn triangle_set(triangles: impl Iterator<Item = [[f64; 3]; 3]>) -> Vec<[[f64; 3]; 3]> {
    let key = |t: &[[f64; 3]; 3]| t.map(|p| p.map(|x| (x * 1e4).round() as i64));
    let mut out: Vec<[[f64; 3]; 3]> = triangles.collect();
    out.sort_by_key(key);
    out
}

#[test]
fn convert_reads_gltf_and_glb_clutter_as_the_bake_does() {
    let dir = scratch("gltf");
    let (scene, lights) = write_level(&dir);
    let gltf = write_gltf(&dir);
    let transform = json!({"translation": [0.5, 0.0, 0.6], "rotation": [0.0, 0.0, 0.0, 1.0], "scale": [1.0, 1.0, 1.0]});
    for name in ["prop.gltf", "prop.glb"] {
        let mut level: Value =
            serde_json::from_str(&std::fs::read_to_string(&scene).unwrap()).unwrap();
        level["clutter"] = json!([{"id": "prop", "mesh": name, "transform": transform, "albedo": [0.5, 0.5, 0.5]}]);
        let with_mesh = dir.join(format!("scene-{name}.json"));
        std::fs::write(&with_mesh, level.to_string()).unwrap();
        let out = dir.join(format!("out-{name}.json"));
        run(&[
            script().to_str().unwrap(),
            "convert",
            with_mesh.to_str().unwrap(),
            lights.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ]);
        let converted: Value =
            serde_json::from_str(&std::fs::read_to_string(&out).unwrap()).unwrap();
        let meshes = converted["meshes"].as_array().unwrap();
        // 17 closed block faces, then the prop.
        assert_eq!(meshes.len(), 18, "{name}");
        let prop = &meshes[17];
        assert_eq!(prop["albedo"], json!([0.5, 0.5, 0.5]));
        let v = vertices(prop);
        let ours = triangle_set(prop["faces"].as_array().unwrap().iter().map(|f| {
            let f: Vec<usize> = f
                .as_array()
                .unwrap()
                .iter()
                .map(|i| i.as_u64().unwrap() as usize)
                .collect();
            [v[f[0]], v[f[1]], v[f[2]]]
        }));
        let parsed: lightfarm_proto::scene::Transform =
            serde_json::from_value(transform.clone()).unwrap();
        let bake =
            lightfarm_server::bake::scene::mesh::load_mesh("prop", &dir, name, &parsed).unwrap();
        assert_eq!(
            bake.triangles.len(),
            3,
            "{name}: two indexed triangles and one unindexed"
        );
        // The bake's glTF reader composes node transforms in f32: 1e-8 m apart.
        let theirs = triangle_set(bake.triangles.iter().copied());
        assert_eq!(ours.len(), theirs.len(), "{name}");
        for (a, b) in ours.iter().zip(&theirs) {
            for (p, q) in a.iter().zip(b) {
                for k in 0..3 {
                    assert!((p[k] - q[k]).abs() < 1e-6, "{name}: {a:?} against {b:?}");
                }
            }
        }
    }
    // A primitive with a colour of its own is refused, not given the object's albedo.
    let mut doc: Value = serde_json::from_str(&std::fs::read_to_string(&gltf).unwrap()).unwrap();
    doc["materials"] = json!([{"pbrMetallicRoughness": {"baseColorFactor": [0.9, 0.2, 0.2, 1.0]}}]);
    doc["meshes"][0]["primitives"][0]["material"] = json!(0);
    std::fs::write(dir.join("red.gltf"), doc.to_string()).unwrap();
    let mut level: Value = serde_json::from_str(&std::fs::read_to_string(&scene).unwrap()).unwrap();
    level["clutter"] = json!([{"id": "prop", "mesh": "red.gltf", "albedo": [0.5, 0.5, 0.5]}]);
    let red = dir.join("scene-red.json");
    std::fs::write(&red, level.to_string()).unwrap();
    let out = Command::new("python3")
        .args([
            script().to_str().unwrap(),
            "convert",
            red.to_str().unwrap(),
            lights.to_str().unwrap(),
            "-o",
            dir.join("red.json").to_str().unwrap(),
        ])
        .env("LF_GROUNDTRUTH", groundtruth())
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("colours of its own"));
    let _ = std::fs::remove_dir_all(&dir);
}
