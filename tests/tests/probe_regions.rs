//! Probes follow where dynamic objects go: a dynamic object that lists the regions it stays in
//! gets a probe volume over those regions only (grown by one probe spacing), whose probes are
//! the whole level's probes at the same lattice points, bit for bit; a scene without regions
//! keeps the whole level's volume. Its entries are stored low-rank where that is smaller
//! (`compact_deltas`, format 2.3), within the scene's tolerance of the dense ones.

use lightfarm_client::{direct_from_point_lights, irradiance_at, Occluders, ProbeField, Runtime};
use lightfarm_proto::bundle::{section, Bundle, ProbeVolume};
use lightfarm_proto::container::read_sections;
use lightfarm_proto::scene::{Aabb, ProbeVolumeMode};
use lightfarm_proto::testing::join_sections;
use lightfarm_server::bake::progress::NoProgress;
use lightfarm_server::bake::{bake, BakeOptions};
use lightfarm_tests::*;

/// Every probe's world position (f64 from the volume's f32 origin and spacing), by probe.
fn probe_positions(v: &ProbeVolume) -> Vec<[f64; 3]> {
    let mut out = vec![[f64::NAN; 3]; v.n_probes as usize];
    let d = v.dims.map(|x| x as usize);
    for k in 0..d[2] {
        for j in 0..d[1] {
            for i in 0..d[0] {
                let s = v.slot[(k * d[1] + j) * d[0] + i];
                if s != u32::MAX {
                    let at = [i, j, k];
                    out[s as usize] =
                        [0, 1, 2].map(|a| v.origin[a] as f64 + at[a] as f64 * v.spacing as f64);
                }
            }
        }
    }
    out
}

fn field(bundle: Bundle, lights: &lightfarm_proto::lights::LightSet) -> ProbeField {
    let occluders = Occluders::from_layout(&bundle.layout);
    let direct = direct_from_point_lights(&bundle.layout, &occluders, &lights.lights);
    let mut runtime = Runtime::try_new(bundle).unwrap();
    let mut field = ProbeField::default();
    runtime.apply_probes(&direct, &mut field).unwrap();
    field
}

#[test]
fn probes_are_baked_only_where_dynamic_objects_go() {
    let (mut scene, lights) = load_scene("ball_corridor", 4, 64);
    let dir = scene_dir("ball_corridor");
    let options = BakeOptions {
        cache: None,
        full: false,
        transport: None,
    };
    let (whole, _) = bake(&scene, &dir, &options, &NoProgress).unwrap();
    // The ball rolls about the west hall, below 1.2 m (its pose is at x = 2.2).
    let region = Aabb {
        min: [0.2, 0.0, 0.2],
        max: [2.6, 1.2, 1.8],
    };
    scene.dynamic[0].regions = vec![region];
    scene.validate().unwrap();
    let grown = scene.probe_regions().unwrap();
    let (part, report) = bake(&scene, &dir, &options, &NoProgress).unwrap();
    let (w, p) = (whole.probes.clone().unwrap(), part.probes.clone().unwrap());
    eprintln!(
        "ball_corridor: {} probes over the level, {} over the ball's region",
        w.n_probes, p.n_probes
    );
    assert_eq!(report.probes, p.n_probes as usize);
    assert!(p.n_probes > 0 && p.n_probes * 3 < w.n_probes);
    assert_eq!(p.spacing, w.spacing);

    // Every probe of the region's volume is a probe of the whole level's at the same point;
    // every one of the level's probes inside the grown region is there.
    let (wp, pp) = (
        probe_positions(&w),
        probe_positions(&part.probes.clone().unwrap()),
    );
    let near = |a: [f64; 3], b: [f64; 3]| (0..3).all(|k| (a[k] - b[k]).abs() < 1e-5);
    let matching: Vec<usize> = pp
        .iter()
        .map(|&x| {
            assert!(
                grown
                    .iter()
                    .any(|r| (0..3).all(|k| x[k] >= r.min[k] - 1e-5 && x[k] <= r.max[k] + 1e-5)),
                "probe at {x:?} outside the grown region"
            );
            wp.iter()
                .position(|&y| near(x, y))
                .unwrap_or_else(|| panic!("probe at {x:?} is not a probe of the whole level"))
        })
        .collect();
    let inside = wp
        .iter()
        .filter(|y| {
            grown
                .iter()
                .any(|r| (0..3).all(|k| y[k] >= r.min[k] + 1e-5 && y[k] <= r.max[k] - 1e-5))
        })
        .count();
    assert!(matching.len() >= inside, "{} of {inside}", matching.len());

    // Their operators are the same: the same light gives the same field there, bit for bit.
    let (fw, fp) = (field(whole, &lights), field(part, &lights));
    for (q, &m) in matching.iter().enumerate() {
        for c in 0..3 {
            assert_eq!(
                fp.coefficients(q, c).map(f32::to_bits),
                fw.coefficients(m, c).map(f32::to_bits),
                "probe {q} (whole {m}) channel {c}"
            );
        }
    }
    // The ball's pose lies in the region: it is lit from its probes as in the whole volume (to
    // the rounding of the interpolation weights, the two grids' origins being apart).
    let pose = lights.poses[0].translation.map(|x| x as f32);
    let up = [0.0, 1.0, 0.0];
    let (a, b) = (
        irradiance_at(&w, &fw, pose, up),
        irradiance_at(&p, &fp, pose, up),
    );
    eprintln!("irradiance at the ball: whole {a:?}, region {b:?}");
    assert!(a[0] > 0.0);
    for c in 0..3 {
        assert!(
            (a[c] - b[c]).abs() <= 1e-5 * a[c],
            "channel {c}: {a:?} against {b:?}"
        );
    }
}

/// The MRT baseline shades clutter from the probes (`eval --method mrt`), so with
/// `probe_volume: always` a volume narrowed to the dynamic objects' regions keeps the probes
/// around every clutter object too: a crate in the hall the ball never enters is lit from its
/// probes as in the whole level's volume. By default (`auto`) only the dynamic objects read the
/// volume, and the crate adds no probe: every probe lies in the ball's grown region.
#[test]
fn probes_around_clutter_stay_when_the_volume_follows_dynamic_objects() {
    let (mut scene, lights) = load_scene("ball_corridor", 4, 64);
    let dir = scene_dir("ball_corridor");
    let mut with_crate = serde_json::to_value(&scene).unwrap();
    with_crate["clutter"] = serde_json::json!([{
        "id": "crate", "box": { "min": [4.4, 0.0, 0.6], "max": [5.2, 0.8, 1.4] },
        "albedo": [0.6, 0.5, 0.3]
    }]);
    scene = serde_json::from_value(with_crate).unwrap();
    scene.validate().unwrap();
    let options = BakeOptions {
        cache: None,
        full: false,
        transport: None,
    };
    scene.settings.probe_volume = ProbeVolumeMode::Always;
    let (whole, _) = bake(&scene, &dir, &options, &NoProgress).unwrap();
    scene.dynamic[0].regions = vec![Aabb {
        min: [0.2, 0.0, 0.2],
        max: [2.6, 1.2, 1.8],
    }];
    let (part, _) = bake(&scene, &dir, &options, &NoProgress).unwrap();

    // By default the crate adds nothing: every probe lies in the ball's grown region, and there
    // are fewer of them than with the crate's.
    let mut auto = scene.clone();
    auto.settings.probe_volume = ProbeVolumeMode::Auto;
    let grown = auto.probe_regions().unwrap();
    let (regions_only, _) = bake(&auto, &dir, &options, &NoProgress).unwrap();
    let r = regions_only.probes.clone().unwrap();
    for x in probe_positions(&r) {
        assert!(
            grown
                .iter()
                .any(|g| (0..3).all(|k| x[k] >= g.min[k] - 1e-5 && x[k] <= g.max[k] + 1e-5)),
            "auto: probe at {x:?} outside the ball's grown region"
        );
    }
    let (w, p) = (whole.probes.clone().unwrap(), part.probes.clone().unwrap());
    eprintln!(
        "ball_corridor with a crate: {} probes over the level, {} over the ball's region and \
         around the crate",
        w.n_probes, p.n_probes
    );
    assert!(
        p.n_probes * 2 < w.n_probes,
        "{} of {}",
        p.n_probes,
        w.n_probes
    );
    // The crate's probes: some lie in the east hall, where the ball never goes.
    let east = probe_positions(&p).iter().filter(|x| x[0] > 3.5).count();
    assert!(east > 0, "no probe around the crate");
    let in_grown = probe_positions(&p)
        .iter()
        .filter(|x| {
            grown
                .iter()
                .any(|g| (0..3).all(|k| x[k] >= g.min[k] - 1e-5 && x[k] <= g.max[k] + 1e-5))
        })
        .count();
    assert_eq!(
        r.n_probes as usize, in_grown,
        "auto: the probes in the ball's region, and those alone"
    );
    assert!(r.n_probes < p.n_probes);

    let layout = whole.layout.clone();
    let crate_surfaces: Vec<_> = layout
        .surfaces
        .iter()
        .filter(|s| !s.name.starts_with("block:"))
        .cloned()
        .collect();
    assert!(!crate_surfaces.is_empty());
    let (fw, fp) = (field(whole, &lights), field(part, &lights));
    let mut lit = 0;
    for s in &crate_surfaces {
        for k in 0..s.texel_count as usize {
            let t = s.texel_offset as usize + k;
            let (pos, n) = (layout.positions[t], layout.normals[t]);
            let (a, b) = (
                irradiance_at(&w, &fw, pos, n),
                irradiance_at(&p, &fp, pos, n),
            );
            let scale = a.iter().fold(0f32, |m, x| m.max(x.abs()));
            lit += usize::from(scale > 0.0);
            for c in 0..3 {
                assert!(
                    (a[c] - b[c]).abs() <= 1e-5 * scale + 1e-12,
                    "{} texel {k} channel {c}: whole {a:?}, narrowed {b:?}",
                    s.name
                );
            }
        }
    }
    assert!(lit > 0, "the crate is dark");
}

/// With `compact_deltas` (the default) the probe entries are stored low-rank where that is
/// smaller, as DRT's deltas are: fewer values, and the probe field of the same light within
/// the tolerance's bound of the dense entries' (both in f32, so the codec adds nothing). They
/// travel in format 2.3's kinds 17 (and the ball's grid in 18), which a 2.2 reader skips: it
/// reads the rest and lights the level the same.
#[test]
fn probe_entries_are_low_rank_where_that_is_smaller() {
    let (mut scene, lights) = load_scene("ball_corridor", 8, 256);
    let dir = scene_dir("ball_corridor");
    scene.settings.bundle_codec = lightfarm_proto::scene::BundleCodec::F32;
    scene.dynamic[0].regions = vec![Aabb {
        min: [0.2, 0.0, 0.2],
        max: [2.6, 1.2, 1.8],
    }];
    let options = BakeOptions {
        cache: None,
        full: false,
        transport: None,
    };
    let (low_rank, report) = bake(&scene, &dir, &options, &NoProgress).unwrap();
    let mut dense_scene = scene.clone();
    dense_scene.settings.compact_deltas = false;
    let (dense, dense_report) = bake(&dense_scene, &dir, &options, &NoProgress).unwrap();
    assert!(dense_report.probe_compaction.is_none());
    let stats = report.probe_compaction.clone().expect("compacted");
    let values = |b: &Bundle| -> usize {
        b.probes
            .as_ref()
            .unwrap()
            .entries
            .iter()
            .map(|e| e.matrix.data.len() + e.mix.as_ref().map_or(0, |m| m.data.len()))
            .sum()
    };
    let (lv, dv) = (values(&low_rank), values(&dense));
    eprintln!(
        "ball_corridor probes: {} entries factored, {} dense; values {dv} -> {lv}; ranks {:?}",
        stats.factored, stats.dense, stats.ranks
    );
    assert!(stats.factored > 0);
    assert_eq!((stats.values_before, stats.values_after), (dv, lv));
    assert!(lv < dv);
    // Written as format 2.3's kinds (low-rank probes, and the ball's 8-bit DNRT grid in its
    // planar form), read back to the same bundle; the dense bake's probes stay kind 7.
    let kinds = |b: &Bundle| -> Vec<u32> {
        let bytes = b.encode();
        let back = Bundle::decode(&bytes).unwrap();
        assert_eq!(&back, b);
        read_sections(&bytes, 2..=2, |_| true, false)
            .unwrap()
            .sections
            .iter()
            .map(|(kind, _)| *kind)
            .collect()
    };
    let (kl, kd) = (kinds(&low_rank), kinds(&dense));
    assert!(kl.contains(&section::PROBES_LOW_RANK) && !kl.contains(&section::PROBES));
    assert!(kl.contains(&section::DNRT_PLANAR) && !kl.contains(&section::DNRT));
    assert!(kd.contains(&section::PROBES) && !kd.contains(&section::PROBES_LOW_RANK));
    // What a 2.2 reader makes of it: it skips the two kinds it does not know and reads the
    // level without a probe volume or grids, lighting it as the whole bundle does.
    let older: Vec<(u32, Vec<u8>)> = low_rank
        .raw_sections()
        .into_iter()
        .filter(|(kind, _)| ![section::PROBES_LOW_RANK, section::DNRT_PLANAR].contains(kind))
        .collect();
    let seen = Bundle::decode(&join_sections(&older)).unwrap();
    assert!(seen.probes.is_none() && seen.dnrt.is_none());
    assert_eq!(
        (&seen.layout, &seen.shapes, &seen.drt),
        (&low_rank.layout, &low_rank.shapes, &low_rank.drt)
    );
    let lit = |b: &Bundle| {
        let occluders = Occluders::from_layout(&b.layout);
        let direct = direct_from_point_lights(&b.layout, &occluders, &lights.lights);
        let mut out = lightfarm_client::IndirectLight::default();
        Runtime::try_new(b.clone())
            .unwrap()
            .apply(
                lightfarm_client::Method::Mrt,
                lightfarm_client::Bounces::One,
                &direct,
                &mut out,
            )
            .unwrap();
        out
    };
    assert_eq!(lit(&seen), lit(&low_rank));
    let (fl, fd) = (field(low_rank, &lights), field(dense, &lights));
    let (mut diff, mut norm) = (0.0f64, 0.0f64);
    for (a, b) in fl.as_slice().iter().zip(fd.as_slice()) {
        diff += (*a as f64 - *b as f64).powi(2);
        norm += (*b as f64).powi(2);
    }
    let rel = (diff / norm).sqrt();
    eprintln!("probe field, low-rank against dense entries: relative L2 {rel:.2e}");
    // Each entry drops at most √tolerance of itself (Frobenius); the field sums the entries.
    assert!(
        norm > 0.0 && rel <= scene.settings.tolerance.sqrt(),
        "{rel}"
    );
}
