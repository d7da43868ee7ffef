//! The texel layout and atlas queries called as C calls them, on a four-surface bundle with a
//! mesh atlas: exact values, every error path, and direct light an engine computes from them
//! applying like the client's.

use std::ffi::CStr;
use std::ptr::{null, null_mut};

use lightfarm::*;
use lightfarm_client::{Atlas, Light, Occluders};
use lightfarm_proto::bundle::{Bundle, Layout, Matrix, SurfaceAtlas, SurfaceInfo};
use lightfarm_proto::lights::LightKind;
use lightfarm_proto::testing::one_block_bundle;

mod common;

use common::{last_error, Rt, OK};

/// Four surfaces, 17 texels, every per-texel value distinct: a 2×2 floor and wall of block
/// `room`, a box (`clutter:crate`, six texels: two atlas tiles) and a mesh (`clutter:teapot`,
/// three slanted texels) with its own 2×2 lightmap image. One operator block holds them all.
fn layout_bundle() -> Bundle {
    let surfaces = [
        ("block:room/-y", 4u32),
        ("block:room/+x", 4),
        ("clutter:crate", 6),
        ("clutter:teapot", 3),
    ];
    let mut next = 0;
    let surfaces = surfaces
        .iter()
        .map(|&(name, texel_count)| {
            next += texel_count;
            SurfaceInfo {
                name: name.into(),
                texel_offset: next - texel_count,
                texel_count,
            }
        })
        .collect();
    let n = next as usize;
    let normal = |t: usize| match t {
        0..=3 => [0.0, 1.0, 0.0],
        4..=7 => [-1.0, 0.0, 0.0],
        8..=13 => [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]][t % 3],
        _ => [0.6, 0.8, 0.0],
    };
    let layout = Layout {
        scene_name: "layout".into(),
        surfaces,
        positions: (0..n)
            .map(|t| {
                let t = t as f32;
                [0.125 + 0.25 * t, 0.0625 * (t % 3.0), 2.0 - 0.0625 * t]
            })
            .collect(),
        normals: (0..n).map(normal).collect(),
        albedo: (0..n)
            .map(|t| {
                let t = t as f32;
                [0.03125 * (t + 1.0), 0.5, 0.875 - 0.03125 * t]
            })
            .collect(),
        texel_size: (0..n)
            .map(|t| [0.25 + 0.015625 * t as f32, 0.5 - 0.0078125 * t as f32])
            .collect(),
        rects: vec![],
        triangles: vec![],
    };
    let m = |rows: usize, cols: usize| Matrix {
        rows: rows as u32,
        cols: cols as u32,
        data: (0..rows * cols).map(|k| 0.02 + 0.001 * k as f32).collect(),
    };
    let mut bundle = one_block_bundle(layout, "room", "room", m(n, 2), m(2, n));
    bundle.surface_atlases = vec![SurfaceAtlas {
        surface: 3,
        width: 2,
        height: 2,
        texel_xy: vec![[0, 0], [1, 0], [1, 1]],
    }];
    bundle
}

/// A runtime of [`layout_bundle`], and the bundle as decoded.
fn load_layout() -> (Rt, Bundle) {
    let bytes = layout_bundle().encode();
    // SAFETY: `bytes` is live for the call.
    let rt = unsafe { lf_runtime_new(bytes.as_ptr(), bytes.len()) };
    assert!(!rt.is_null(), "layout bundle loads: {}", last_error());
    (Rt(rt), Bundle::decode(&bytes).unwrap())
}

/// The four per-texel float queries with their floats per texel.
type FloatQuery = unsafe extern "C" fn(*const LfRuntime, *mut f32, usize) -> i32;
const FLOAT_QUERIES: [(&str, FloatQuery, usize); 4] = [
    ("lf_runtime_texel_positions", lf_runtime_texel_positions, 3),
    ("lf_runtime_texel_normals", lf_runtime_texel_normals, 3),
    ("lf_runtime_texel_albedo", lf_runtime_texel_albedo, 3),
    ("lf_runtime_texel_sizes", lf_runtime_texel_sizes, 2),
];

/// A per-texel float query into a fresh buffer of `per_texel × texels` floats.
fn floats(rt: &Rt, query: FloatQuery, per_texel: usize) -> Vec<f32> {
    // SAFETY: live runtime.
    let n = per_texel * unsafe { lf_runtime_texel_count(rt.0) };
    let mut out = vec![f32::NAN; n];
    // SAFETY: live runtime; `n` writable floats.
    assert_eq!(unsafe { query(rt.0, out.as_mut_ptr(), n) }, OK);
    out
}

#[test]
fn texel_layout_is_the_bundles_exactly() {
    let (rt, bundle) = load_layout();
    let layout = &bundle.layout;
    // SAFETY: live runtime.
    assert_eq!(unsafe { lf_runtime_texel_count(rt.0) }, 17);
    let [positions, normals, albedo, sizes] =
        FLOAT_QUERIES.map(|(_, query, per_texel)| floats(&rt, query, per_texel));
    assert_eq!(positions, layout.positions.as_flattened());
    assert_eq!(normals, layout.normals.as_flattened());
    assert_eq!(albedo, layout.albedo.as_flattened());
    assert_eq!(sizes, layout.texel_size.as_flattened());
    // Spot checks against the fixture's formulas: texel 5 (the wall), texel 15 (the mesh).
    assert_eq!(&positions[15..18], &[1.375, 0.125, 1.6875]);
    assert_eq!(&normals[45..48], &[0.6, 0.8, 0.0]);
    assert_eq!(&albedo[15..18], &[0.1875, 0.5, 0.71875]);
    assert_eq!(&sizes[10..12], &[0.328125, 0.4609375]);
}

#[test]
fn atlas_placement_is_the_lightmap_files_atlas() {
    let (rt, bundle) = load_layout();
    let (mut width, mut height) = (0u32, 0u32);
    // SAFETY: live runtime; two writable integers.
    assert_eq!(
        unsafe { lf_runtime_atlas_size(rt.0, &mut width, &mut height) },
        OK
    );
    let mut xy = [u32::MAX; 34];
    // SAFETY: live runtime; 34 writable integers.
    assert_eq!(
        unsafe { lf_runtime_atlas_texels(rt.0, xy.as_mut_ptr(), xy.len()) },
        OK
    );
    let atlas = Atlas::from_layout_with(&bundle.layout, &bundle.surface_atlases);
    assert_eq!((width, height), (atlas.width, atlas.height));
    let want: Vec<u32> = atlas.texel_xy.iter().flat_map(|&(x, y)| [x, y]).collect();
    assert_eq!(xy.as_slice(), want);
    // By hand: 2×2 tiles one pixel apart on a 2×2 grid (floor, wall, the crate's two), the
    // teapot's own 2×2 image on the row below them.
    assert_eq!((width, height), (5, 8));
    let pairs: Vec<(u32, u32)> = xy.chunks(2).map(|p| (p[0], p[1])).collect();
    let by_surface: [&[(u32, u32)]; 4] = [
        &[(0, 0), (1, 0), (0, 1), (1, 1)],                 // floor: tile 0
        &[(3, 0), (4, 0), (3, 1), (4, 1)],                 // wall: tile 1
        &[(0, 3), (1, 3), (0, 4), (1, 4), (3, 3), (4, 3)], // crate: tiles 2, 3
        &[(0, 6), (1, 6), (1, 7)],                         // teapot: its own image
    ];
    assert_eq!(pairs, by_surface.concat());
}

#[test]
fn surfaces_name_their_texel_ranges() {
    let (rt, bundle) = load_layout();
    // SAFETY: live runtime.
    let count = unsafe { lf_runtime_surface_count(rt.0) };
    assert_eq!(count, 4);
    let mut got = Vec::new();
    for index in 0..count {
        let mut name = [0x55u8; 32];
        let (mut offset, mut texels) = (u32::MAX, u32::MAX);
        // SAFETY: live runtime; 32 writable bytes, two writable integers.
        let needed = unsafe {
            lf_runtime_surface(
                rt.0,
                index,
                name.as_mut_ptr().cast(),
                name.len(),
                &mut offset,
                &mut texels,
            )
        };
        let name = CStr::from_bytes_until_nul(&name).unwrap().to_str().unwrap();
        assert_eq!(needed, name.len() as i64 + 1);
        got.push((name.to_owned(), offset, texels));
    }
    assert_eq!(
        got,
        [
            ("block:room/-y".to_owned(), 0, 4),
            ("block:room/+x".to_owned(), 4, 4),
            ("clutter:crate".to_owned(), 8, 6),
            ("clutter:teapot".to_owned(), 14, 3),
        ]
    );
    let want: Vec<_> = bundle
        .layout
        .surfaces
        .iter()
        .map(|s| (s.name.clone(), s.texel_offset, s.texel_count))
        .collect();
    assert_eq!(got, want);
    // SAFETY: NULL runtime: no surfaces.
    assert_eq!(unsafe { lf_runtime_surface_count(null()) }, 0);
}

#[test]
fn surface_names_are_cut_to_the_buffer_and_report_their_size() {
    let (rt, _) = load_layout();
    // Size only: NULL buffer, zero capacity, no texel range wanted.
    // SAFETY: live runtime; nothing is written.
    let needed = unsafe { lf_runtime_surface(rt.0, 3, null_mut(), 0, null_mut(), null_mut()) };
    assert_eq!(needed, "clutter:teapot".len() as i64 + 1);
    // Too small: the first cap - 1 bytes and a NUL; the range is still written.
    let mut name = [0x55u8; 8];
    let mut offset = u32::MAX;
    // SAFETY: live runtime; 8 writable bytes, one writable integer.
    let got = unsafe {
        lf_runtime_surface(
            rt.0,
            3,
            name.as_mut_ptr().cast(),
            8,
            &mut offset,
            null_mut(),
        )
    };
    assert_eq!(got, 15);
    assert_eq!(&name, b"clutter\0");
    assert_eq!(offset, 14);
    // Exactly the size it asked for.
    let mut name = [0x55u8; 15];
    // SAFETY: live runtime; 15 writable bytes.
    let got = unsafe {
        lf_runtime_surface(
            rt.0,
            3,
            name.as_mut_ptr().cast(),
            15,
            null_mut(),
            null_mut(),
        )
    };
    assert_eq!(got, 15);
    assert_eq!(&name, b"clutter:teapot\0");
    // One byte: only the NUL.
    let mut one = [0x55u8; 1];
    // SAFETY: live runtime; 1 writable byte.
    let got =
        unsafe { lf_runtime_surface(rt.0, 0, one.as_mut_ptr().cast(), 1, null_mut(), null_mut()) };
    assert_eq!((got, one), (14, [0]));
}

#[test]
fn surface_errors_name_the_index_and_write_nothing() {
    let (rt, _) = load_layout();
    let mut name = [0x55u8; 32];
    let (mut offset, mut texels) = (7u32, 7u32);
    let mut call = |rt: *const LfRuntime, index: usize, name_ptr: *mut u8, cap: usize| {
        // SAFETY: NULL or live runtime; NULL or `cap` writable bytes; two writable integers.
        unsafe { lf_runtime_surface(rt, index, name_ptr.cast(), cap, &mut offset, &mut texels) }
    };
    let p = name.as_mut_ptr();
    for index in [4, 5, usize::MAX] {
        assert_eq!(call(rt.0, index, p, 32), LfStatus::BadIndex as i64);
        assert_eq!(
            last_error(),
            format!("lf_runtime_surface: surface index {index} is out of range: this bundle has 4 surfaces")
        );
    }
    assert_eq!(call(null(), 0, p, 32), LfStatus::NullPointer as i64);
    assert_eq!(last_error(), "lf_runtime_surface: rt is NULL");
    assert_eq!(call(rt.0, 0, null_mut(), 32), LfStatus::NullPointer as i64);
    assert_eq!(last_error(), "lf_runtime_surface: name is NULL");
    assert_eq!((offset, texels), (7, 7));
    assert_eq!(name, [0x55; 32]);
    assert_eq!(LfStatus::BadIndex as i32, -10);
}

#[test]
fn layout_queries_refuse_null_and_wrong_lengths_and_write_nothing() {
    let (rt, _) = load_layout();
    let mut buf = [7.0f32; 60];
    let p = buf.as_mut_ptr();
    for (function, query, per_texel) in FLOAT_QUERIES {
        let n = per_texel * 17;
        for len in [n - 1, n + 1, 0] {
            // SAFETY: live runtime; `len` <= 60 writable floats.
            assert_eq!(unsafe { query(rt.0, p, len) }, LfStatus::BadLength as i32);
            assert_eq!(
                last_error(),
                format!(
                    "{function}: out holds {len} floats but this bundle needs {n} ({per_texel} per texel)"
                )
            );
        }
        // SAFETY: NULL runtime / NULL output.
        unsafe {
            assert_eq!(query(null(), p, n), LfStatus::NullPointer as i32);
            assert_eq!(last_error(), format!("{function}: rt is NULL"));
            assert_eq!(query(rt.0, null_mut(), n), LfStatus::NullPointer as i32);
            assert_eq!(last_error(), format!("{function}: out is NULL"));
        }
    }
    assert_eq!(buf, [7.0; 60]);

    let mut xy = [7u32; 40];
    let q = xy.as_mut_ptr();
    let (mut width, mut height) = (7u32, 7u32);
    // SAFETY: NULL or live runtime; NULL or `len` <= 40 writable integers.
    unsafe {
        for len in [33, 35, 0] {
            assert_eq!(
                lf_runtime_atlas_texels(rt.0, q, len),
                LfStatus::BadLength as i32
            );
            assert_eq!(
                last_error(),
                format!("lf_runtime_atlas_texels: xy holds {len} integers but this bundle needs 34 (2 per texel)")
            );
        }
        assert_eq!(
            lf_runtime_atlas_texels(null(), q, 34),
            LfStatus::NullPointer as i32
        );
        assert_eq!(
            lf_runtime_atlas_texels(rt.0, null_mut(), 34),
            LfStatus::NullPointer as i32
        );
        assert_eq!(last_error(), "lf_runtime_atlas_texels: xy is NULL");
        assert_eq!(
            lf_runtime_atlas_size(null(), &mut width, &mut height),
            LfStatus::NullPointer as i32
        );
        assert_eq!(last_error(), "lf_runtime_atlas_size: rt is NULL");
        assert_eq!(
            lf_runtime_atlas_size(rt.0, null_mut(), &mut height),
            LfStatus::NullPointer as i32
        );
        assert_eq!(last_error(), "lf_runtime_atlas_size: width is NULL");
        assert_eq!(
            lf_runtime_atlas_size(rt.0, &mut width, null_mut()),
            LfStatus::NullPointer as i32
        );
        assert_eq!(last_error(), "lf_runtime_atlas_size: height is NULL");
    }
    assert_eq!((xy, width, height), ([7; 40], 7, 7));
}

/// What an engine does with the layout: direct light from point lights at each texel centre,
/// `ρ/π · Σ I · max(cosθ, 0) / r²`, in the client's operation order (f64, then f32), without
/// shadows (the engine has its own; the fixture has no occluders).
fn engine_direct(positions: &[f32], normals: &[f32], albedo: &[f32], lights: &[Light]) -> Vec<f32> {
    let mut direct = Vec::with_capacity(albedo.len());
    for ((x, n), rho) in positions
        .chunks(3)
        .zip(normals.chunks(3))
        .zip(albedo.chunks(3))
    {
        let mut irr = [0.0f64; 3];
        for light in lights {
            let to: Vec<f64> = (0..3).map(|k| light.position[k] - x[k] as f64).collect();
            let r2 = to[0] * to[0] + to[1] * to[1] + to[2] * to[2];
            let cos = (n[0] as f64 * to[0] + n[1] as f64 * to[1] + n[2] as f64 * to[2]) / r2.sqrt();
            if cos <= 0.0 {
                continue;
            }
            let g = cos / r2;
            for (e, i) in irr.iter_mut().zip(light.intensity) {
                *e += i * g;
            }
        }
        for c in 0..3 {
            direct.push((rho[c] as f64 * std::f64::consts::FRAC_1_PI * irr[c]) as f32);
        }
    }
    direct
}

#[test]
fn direct_light_from_the_c_layout_applies_like_the_clients() {
    let (rt, bundle) = load_layout();
    let lights = [
        Light {
            kind: LightKind::Point,
            position: [1.5, 2.0, 1.0],
            intensity: [3.0, 2.0, 1.0],
        },
        Light {
            kind: LightKind::Point,
            position: [-1.0, 0.5, 3.0],
            intensity: [0.5, 0.5, 4.0],
        },
    ];
    let [positions, normals, albedo, _] =
        FLOAT_QUERIES.map(|(_, query, per_texel)| floats(&rt, query, per_texel));
    let direct = engine_direct(&positions, &normals, &albedo, &lights);
    let client = lightfarm_client::direct_from_point_lights(
        &bundle.layout,
        &Occluders::from_layout(&bundle.layout),
        &lights,
    );
    assert_eq!(direct, client.radiance.as_flattened());
    assert!(direct.iter().any(|&v| v > 0.0), "some texels are lit");
    assert!(direct.contains(&0.0), "some face away");
    // Applied through C, the two give the same indirect light.
    let mut from_engine = vec![f32::NAN; direct.len()];
    let mut from_client = vec![f32::NAN; direct.len()];
    let rt_apply = |d: &[f32], out: &mut [f32]| {
        // SAFETY: live runtime; the slices are live for the call.
        unsafe { lf_runtime_apply(rt.0, 0, d.as_ptr(), d.len(), out.as_mut_ptr(), out.len()) }
    };
    assert_eq!(rt_apply(&direct, &mut from_engine), OK);
    assert_eq!(
        rt_apply(client.radiance.as_flattened(), &mut from_client),
        OK
    );
    assert_eq!(from_engine, from_client);
    assert!(from_engine.iter().all(|v| v.is_finite() && *v > 0.0));
}
