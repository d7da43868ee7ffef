//! Shared machinery of the numerical-stability suite (`stability_*.rs`): one call runs a hard
//! case through every check the suite makes.
//!
//! For every case: the bundle is bit-identical when baked at 1 and at 2 threads, and so is the
//! applied result; every direct and indirect value is finite (ours and the reference's); two
//! energy bounds hold; and the relative L2 error of the indirect light against the brute-force
//! reference is within the case's stated bound.
//!
//! Energy bounds:
//! - Per texel, ours: indirect ≤ albedo × the brightest direct radiance the operators are fed
//!   (the texel-averaged direct light; [`fed_energy_ratio`]); the low-rank operators may ring
//!   slightly above it (1.05, as in mrt_accuracy.rs).
//! - Per texel, the reference: `energy_ratio` (tests/lib.rs) ≤ 1, i.e. indirect ≤ albedo × the
//!   brightest direct radiance at a texel centre, where texel centres resolve the lamp's peak
//!   (not for a lamp a millimetre from a wall: [`check_case_unresolved`]).
//! - The flux bound, which holds whatever the light's position: one bounce cannot reflect more
//!   than `ρ_max²` of the power the lights emit (`4π Σ I`), so
//!   `Σ_texels π L_ind A_texel ≤ ρ_max² · 4π Σ I` per channel (over the texels not buried in
//!   clutter, see [`visible`]). A closed box reaches it (the
//!   reference's own unit test checks the equality), hence 1.05 for sampling noise.

#![allow(dead_code)]

use std::collections::HashMap;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use lightfarm_client::Method;
use lightfarm_proto::lights::LightSet;
use lightfarm_proto::result::{compare, ResultFile};
use lightfarm_proto::scene::{Scene, Transport};
use lightfarm_tests::*;

/// Largest [`fed_energy_ratio`] accepted from the operators.
pub const ENERGY_RATIO_BOUND: f64 = 1.05;
/// Largest flux ratio accepted (ours and the reference).
pub const FLUX_BOUND: f64 = 1.05;

/// Parses a scene (it must validate) and sets test-sized settings.
pub fn scene(json: &str, texels_per_face: u32, rays_per_texel: u32) -> Scene {
    let mut scene = Scene::from_json(json).unwrap_or_else(|e| panic!("scene refused: {e}"));
    scene.settings.texels_per_face = texels_per_face;
    scene.settings.rays_per_texel = rays_per_texel;
    scene.validate().unwrap();
    scene
}

/// Parses LIGHTS.json (it must validate).
pub fn lights(json: &str) -> LightSet {
    LightSet::from_json(json).unwrap_or_else(|e| panic!("lights refused: {e}"))
}

/// One point light.
pub fn one_light(position: [f64; 3], intensity: f64) -> LightSet {
    lights(&format!(
        r#"{{ "lights": [ {{ "kind": "point", "position": {position:?}, "intensity": [{i}, {i}, {i}] }} ] }}"#,
        i = intensity
    ))
}

/// Runs `f` on a fresh rayon pool of `n` threads.
pub fn with_threads<T: Send>(n: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build()
        .expect("thread pool")
        .install(f)
}

/// A directory for a case's mesh files (fresh, per process and case).
pub fn temp_dir(case: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("lf-stab-{}-{case}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// The directory for scenes without meshes.
pub fn no_meshes() -> PathBuf {
    scene_dir("cornell")
}

/// What a case measured.
#[derive(Clone, Debug)]
pub struct Measured {
    pub relative_l2: f64,
    pub energy_ratio: f64,
    pub reference_energy_ratio: f64,
    pub flux_ratio: f64,
    pub reference_flux_ratio: f64,
    pub result: ResultFile,
    pub bundle: Vec<u8>,
}

/// Every value finite.
pub fn assert_finite(label: &str, r: &ResultFile) {
    for t in &r.texels {
        assert!(
            t.direct.iter().chain(&t.indirect).all(|x| x.is_finite()),
            "{label}: non-finite value at {} #{}: direct {:?} indirect {:?}",
            t.surface,
            t.index,
            t.direct,
            t.indirect
        );
    }
}

/// Largest albedo component anywhere in the scene.
pub fn max_albedo(scene: &Scene) -> f64 {
    let mut m: f64 = 0.0;
    for b in &scene.blocks {
        m = b
            .albedo
            .iter()
            .chain(b.face_albedo.values().flatten())
            .fold(m, |m, x| m.max(*x));
    }
    for c in &scene.clutter {
        m = c.albedo.iter().fold(m, |m, x| m.max(*x));
    }
    for d in &scene.dynamic {
        m = d.albedo.iter().fold(m, |m, x| m.max(*x));
    }
    m
}

/// Texel areas by `(surface, index)` from a bundle's layout.
pub fn texel_areas(bundle: &[u8]) -> HashMap<(String, u32), f64> {
    let bundle = lightfarm_client::decode(bundle).expect("decode");
    let layout = &bundle.layout;
    let mut out = HashMap::new();
    for (s, first) in layout.surfaces.iter().zip(layout.surface_first_index()) {
        for k in 0..s.texel_count {
            let size = layout.texel_size[(s.texel_offset + k) as usize];
            out.insert((s.name.clone(), first + k), size[0] as f64 * size[1] as f64);
        }
    }
    out
}

/// `Σ π L_ind A / (ρ_max² 4π Σ I)`, the largest over channels (0 without light or albedo).
pub fn flux_ratio(
    r: &ResultFile,
    areas: &HashMap<(String, u32), f64>,
    rho_max: f64,
    lights: &LightSet,
) -> f64 {
    let mut worst: f64 = 0.0;
    for c in 0..3 {
        let power: f64 = lights
            .lights
            .iter()
            .map(|l| 4.0 * PI * l.intensity[c])
            .sum();
        if power <= 0.0 || rho_max <= 0.0 {
            continue;
        }
        let flux: f64 = r
            .texels
            .iter()
            .map(|t| PI * t.indirect[c] * areas[&(t.surface.clone(), t.index)])
            .sum();
        worst = worst.max(flux / (rho_max * rho_max * power));
    }
    worst
}

/// Texels the comparison uses: not buried in a clutter box, and clutter texels inside a block
/// (buried texels are inpainted by design and dark in the reference).
pub fn visible(scene: &Scene, r: &ResultFile) -> ResultFile {
    let inside = |p: [f64; 3], min: [f64; 3], max: [f64; 3], open: bool| {
        let e = 1e-6 * (0..3).map(|k| max[k] - min[k]).fold(0.0, f64::max);
        if open {
            (0..3).all(|k| p[k] > min[k] + e && p[k] < max[k] - e)
        } else {
            (0..3).all(|k| p[k] >= min[k] - e && p[k] <= max[k] + e)
        }
    };
    let mut out = r.clone();
    out.texels.retain(|t| {
        let own = t.surface.strip_prefix("clutter:");
        let in_box = scene.clutter.iter().any(|c| {
            Some(c.id.as_str()) != own
                && c.box_
                    .is_some_and(|b| inside(t.position, b.min, b.max, false))
        });
        let in_block = own.is_none()
            || scene
                .blocks
                .iter()
                .any(|b| inside(t.position, b.min, b.max, true));
        !in_box && in_block
    });
    out
}

/// The method a case applies: DRT when the scene has clutter, MRT otherwise.
pub fn method_of(scene: &Scene) -> Method {
    if scene.clutter.is_empty() {
        Method::Mrt
    } else {
        Method::Drt
    }
}

/// Bakes at 1 and 2 threads (bit-identical), applies at 1 and 2 threads (bit-identical), and
/// returns the bundle and the applied result.
pub fn bake_and_apply_deterministically(
    label: &str,
    scene: &Scene,
    dir: &Path,
    transport: Transport,
    lights: &LightSet,
) -> (Vec<u8>, ResultFile) {
    let method = method_of(scene);
    let bake_at = |n| with_threads(n, || bake_scene(scene, dir, transport, false).0);
    let one = bake_at(1);
    let two = bake_at(2);
    assert!(
        one == two,
        "{label}: bundles differ between 1 and 2 threads ({} vs {} bytes)",
        one.len(),
        two.len()
    );
    let apply_at = |n| with_threads(n, || apply(&one, lights, method));
    let r1 = apply_at(1);
    assert_finite(label, &r1);
    let r2 = apply_at(2);
    assert!(
        r1 == r2,
        "{label}: applied results differ between 1 and 2 threads"
    );
    (one, r1)
}

/// Largest `indirect / (albedo × brightest direct radiance the operators are fed)`: the client
/// feeds the operators the texel-averaged direct light (4×4 samples per texel, as `evaluate`
/// does), and a one-bounce operator whose rows sum to at most 1 cannot return more than the
/// brightest texel it reads. Unlike `energy_ratio` on texel centres, this holds however small
/// the lamp's footprint is next to a texel.
pub fn fed_energy_ratio(bundle: &[u8], ours: &ResultFile, lights: &LightSet) -> f64 {
    use lightfarm_client::{direct_from_point_lights_averaged, Occluders};
    let bundle = lightfarm_client::decode(bundle).expect("decode");
    let occluders = Occluders::from_layout(&bundle.layout);
    let fed = direct_from_point_lights_averaged(&bundle.layout, &occluders, &lights.lights, 4);
    let max_fed = fed
        .radiance
        .iter()
        .flatten()
        .fold(0.0f64, |m, x| m.max(*x as f64));
    let mut worst: f64 = 0.0;
    for t in &ours.texels {
        for c in 0..3 {
            if t.albedo[c] > 0.0 && max_fed > 0.0 {
                worst = worst.max(t.indirect[c] / (t.albedo[c] * max_fed));
            }
        }
    }
    worst
}

/// The whole battery for one case against a precomputed reference. `l2_bound` is the case's
/// stated relative L2 bound. The reference's own per-texel energy ratio is asserted ≤ 1 (use
/// [`check_case_unresolved`] where texel centres cannot see the lamp's peak).
pub fn check_case(
    label: &str,
    scene: &Scene,
    dir: &Path,
    transport: Transport,
    lights: &LightSet,
    reference: &ResultFile,
    l2_bound: f64,
) -> Measured {
    let m = check_case_unresolved(label, scene, dir, transport, lights, reference, l2_bound);
    assert!(
        m.reference_energy_ratio <= 1.0 + 1e-9,
        "{label}: reference energy ratio {}",
        m.reference_energy_ratio
    );
    m
}

/// [`check_case`] without the reference's per-texel energy ratio (the lamp's footprint is
/// smaller than a texel, so texel centres understate the brightest direct light).
pub fn check_case_unresolved(
    label: &str,
    scene: &Scene,
    dir: &Path,
    transport: Transport,
    lights: &LightSet,
    reference: &ResultFile,
    l2_bound: f64,
) -> Measured {
    let (bundle, ours) = bake_and_apply_deterministically(label, scene, dir, transport, lights);
    assert_finite(&format!("{label} (reference)"), reference);
    let areas = texel_areas(&bundle);
    let rho = max_albedo(scene);
    let m = Measured {
        relative_l2: f64::NAN,
        energy_ratio: fed_energy_ratio(&bundle, &ours, lights),
        reference_energy_ratio: energy_ratio(reference),
        // Texels buried in clutter are inpainted from their neighbours by design (hidden, so
        // their values only avoid dark seams): they hold no energy of the scene.
        flux_ratio: flux_ratio(&visible(scene, &ours), &areas, rho, lights),
        reference_flux_ratio: flux_ratio(&visible(scene, reference), &areas, rho, lights),
        result: ours,
        bundle,
    };
    eprintln!(
        "{label}: flux_ratio={:.4} (reference {:.4})",
        m.flux_ratio, m.reference_flux_ratio
    );
    assert!(
        m.energy_ratio <= ENERGY_RATIO_BOUND,
        "{label}: energy ratio {} (indirect over albedo × brightest direct fed)",
        m.energy_ratio
    );
    assert!(
        m.flux_ratio <= FLUX_BOUND && m.reference_flux_ratio <= FLUX_BOUND,
        "{label}: flux bound: ours {} reference {}",
        m.flux_ratio,
        m.reference_flux_ratio
    );
    let ours = visible(scene, &m.result);
    let reference_visible = visible(scene, reference);
    let c = check_against_reference(label, &ours, &reference_visible, l2_bound);
    let m = Measured {
        relative_l2: c.relative_l2,
        ..m
    };
    eprintln!(
        "STAB | {label} | l2 {:.4} | bound {l2_bound} | energy {:.4} (ref {:.4}) | flux {:.4} (ref {:.4}) |",
        m.relative_l2, m.energy_ratio, m.reference_energy_ratio, m.flux_ratio, m.reference_flux_ratio
    );
    m
}

/// The reference of a scene (rays per texel `rays`), checked finite.
pub fn reference(scene: &Scene, dir: &Path, lights: &LightSet, rays: u32) -> ResultFile {
    let r = reference_of(scene, dir, lights, rays);
    assert_finite("reference", &r);
    r
}

/// Relative L2 distance between the indirect light of two results.
pub fn distance(a: &ResultFile, b: &ResultFile) -> f64 {
    compare(a, b).relative_l2
}

/// Asserts that validating `json` fails, that nothing panics, and that the message contains
/// every one of `expected` (the object and the field).
pub fn assert_refused(json: &str, expected: &[&str]) -> String {
    let text = json.to_string();
    let outcome = std::panic::catch_unwind(move || Scene::from_json(&text));
    let err = match outcome {
        Err(_) => panic!("validation panicked on {json}"),
        Ok(Ok(_)) => panic!("accepted: {json}"),
        Ok(Err(e)) => e.to_string(),
    };
    for e in expected {
        assert!(err.contains(e), "error {err:?} does not name {e:?}");
    }
    err
}

/// Asserts that baking `scene` (which may bypass `from_json`) fails without a panic, with a
/// message containing every one of `expected`.
pub fn assert_bake_refused(scene: &Scene, dir: &Path, expected: &[&str]) -> String {
    use lightfarm_server::bake::progress::NoProgress;
    use lightfarm_server::bake::{bake, BakeOptions};
    let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        bake(scene, dir, &BakeOptions::default(), &NoProgress).map(|_| ())
    }));
    let err = match outcome {
        Err(_) => panic!("bake panicked on {}", scene.name),
        Ok(Ok(())) => panic!("bake accepted {}", scene.name),
        Ok(Err(e)) => e.to_string(),
    };
    for e in expected {
        assert!(err.contains(e), "error {err:?} does not name {e:?}");
    }
    err
}

/// The reference at `3 × texels_per_face`, brought back to the scene's own texels two ways:
/// `(centre, average)`. `centre` is the middle sub-texel of each 3×3 group (its centre is the
/// texel's centre: exactly what `reference_of` computes at the scene's own resolution, from a
/// finer-grained evaluation); `average` is the mean over the 3×3 sub-texels, the texel average
/// the operators estimate. The two differ where the light varies within a texel (a lamp close
/// to a wall in a 10 cm crawlspace).
pub fn reference_3x(
    scene: &Scene,
    dir: &Path,
    lights: &LightSet,
    rays: u32,
) -> (ResultFile, ResultFile) {
    reference_kx(scene, dir, lights, rays, 3)
}

/// [`reference_3x`] at `k × texels_per_face` (`k` odd, so one sub-texel sits at each texel's
/// centre): the `k × k` sub-texels' mean resolves light that peaks within a texel more
/// finely (a lamp a metre above a shaft whose texels are 5 m long).
pub fn reference_kx(
    scene: &Scene,
    dir: &Path,
    lights: &LightSet,
    rays: u32,
    k: u32,
) -> (ResultFile, ResultFile) {
    assert!(k % 2 == 1, "an odd number of sub-texels per edge");
    let t = scene.settings.texels_per_face;
    let mut fine_scene = scene.clone();
    fine_scene.settings.texels_per_face = k * t;
    let fine = reference(&fine_scene, dir, lights, rays);
    let f = k * t;
    // (surface, coarse index) → (sum of records, count, centre record)
    let mut groups: Vec<(String, u32)> = Vec::new();
    let mut sums: HashMap<(String, u32), (lightfarm_proto::result::TexelRecord, u32)> =
        HashMap::new();
    let mut centres: HashMap<(String, u32), lightfarm_proto::result::TexelRecord> = HashMap::new();
    for r in &fine.texels {
        let (face, local) = (r.index / (f * f), r.index % (f * f));
        let (i, j) = (local % f, local / f);
        let coarse = face * t * t + (j / k) * t + i / k;
        let key = (r.surface.clone(), coarse);
        if i % k == k / 2 && j % k == k / 2 {
            let mut c = r.clone();
            c.index = coarse;
            centres.insert(key.clone(), c);
        }
        match sums.get_mut(&key) {
            Some((s, n)) => {
                for c in 0..3 {
                    s.position[c] += r.position[c];
                    s.direct[c] += r.direct[c];
                    s.indirect[c] += r.indirect[c];
                }
                *n += 1;
            }
            None => {
                groups.push(key.clone());
                let mut s = r.clone();
                s.index = coarse;
                sums.insert(key, (s, 1));
            }
        }
    }
    let mut centre = ResultFile::default();
    let mut average = ResultFile::default();
    for key in groups {
        let (mut s, n) = sums.remove(&key).unwrap();
        assert_eq!(n, k * k);
        let n = n as f64;
        for c in 0..3 {
            s.position[c] /= n;
            s.direct[c] /= n;
            s.indirect[c] /= n;
        }
        average.texels.push(s);
        centre.texels.push(centres.remove(&key).unwrap());
    }
    (centre, average)
}
