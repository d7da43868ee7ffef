//! Relighting by the change (`Runtime::apply_delta`, issue 19) on a baked level: the maze (DRT,
//! four lights, pillars) with one light moved. Adding the change's indirect light to the old
//! indirect light equals applying the new lights (within float rounding for one bounce and a
//! fixed count, within the tolerance for all bounces), and the first bounce of the change
//! projects only the blocks the light lights; the adaptive texel average is within 0.5% of
//! tracing every sample. The light's reach (`LightReach`, the portal walk over the bundle's
//! rooms) lights exactly what lighting every texel lights.

use lightfarm_client::{
    direct_from_point_lights_adaptive, direct_from_point_lights_averaged, relative_l2, Bounces,
    DirectLight, IndirectLight, Method, Occluders, Runtime,
};
use lightfarm_proto::bundle::Bundle;
use lightfarm_tests::{bake_scene, check_light_reach, load_scene, scene_dir};

#[test]
fn moving_one_light_relit_by_its_change_equals_relighting_everything() {
    let (scene, lights) = load_scene("maze", 4, 64);
    // The scene's own transport (traced, shipped compact by default).
    let transport = scene.settings.transport;
    let (bytes, _) = bake_scene(&scene, &scene_dir("maze"), transport, false);
    let bundle = Bundle::decode(&bytes).unwrap();
    let layout = bundle.layout.clone();
    let occluders = Occluders::from_layout(&layout);
    let mut runtime = Runtime::new(bundle);
    let n_blocks = runtime.bundle().blocks.len();

    let direct = |lights: &[lightfarm_client::Light]| {
        direct_from_point_lights_adaptive(&layout, &occluders, lights, 4)
    };
    let old = direct(&lights.lights);
    // Tracing every sample gives nearly the same texel averages (measured 0.11% relative L2
    // at T = 4: shadows that cross no corner sample of these 0.5–1 m texels).
    let traced = direct_from_point_lights_averaged(&layout, &occluders, &lights.lights, 4);
    let direct_error = relative_l2(&old.radiance, &traced.radiance);
    assert!(
        direct_error < 5e-3,
        "adaptive direct light: relative L2 {direct_error}"
    );

    let mut moved = lights.lights.clone();
    moved[0].position[0] += 0.3;
    moved[0].position[2] -= 0.2;
    let new = direct(&moved);
    let (before, after) = (direct(&lights.lights[..1]), direct(&moved[..1]));
    let change = DirectLight {
        radiance: after
            .radiance
            .iter()
            .zip(&before.radiance)
            .map(|(a, b)| [a[0] - b[0], a[1] - b[1], a[2] - b[2]])
            .collect(),
    };

    for (bounces, tol) in [
        (Bounces::One, 1e-5),
        (Bounces::Fixed(4), 1e-5),
        (Bounces::Converged { tolerance: 1e-4 }, 1e-3),
    ] {
        for method in [Method::Mrt, Method::Drt] {
            let mut out = IndirectLight::default();
            runtime.apply(method, bounces, &old, &mut out).unwrap();
            let mut want = IndirectLight::default();
            runtime.apply(method, bounces, &new, &mut want).unwrap();
            let d = runtime
                .apply_delta(method, bounces, &change, &mut out)
                .unwrap();
            let err = relative_l2(&out.radiance, &want.radiance);
            assert!(err < tol, "{method:?} {bounces:?}: relative L2 {err}");
            if matches!(bounces, Bounces::Converged { .. }) {
                // The change's light fills the maze: the whole-level solve costs less than
                // bounces by the change (`delta_bounces`), which gives up after its first.
                assert!(
                    runtime.delta_written().is_none(),
                    "{method:?}: answered bounce by bounce"
                );
            }
            if bounces == Bounces::One {
                // The light's own room and what it sees through openings, not the level.
                assert!(
                    d.blocks_projected < n_blocks,
                    "{method:?}: {} of {n_blocks} blocks projected",
                    d.blocks_projected
                );
            }
        }
    }
}

/// Each maze light, at its place and moved about its room: the direct light on the texels its
/// walk reaches, traced against the reached rooms' occluders, is bit-identical to lighting
/// every texel, every texel left out is dark, the walk leaves out most of the maze, and the
/// lights lit one by one where each reaches sum to lighting every texel with them all.
#[test]
fn a_light_reaches_what_lighting_everything_lights() {
    let (scene, lights) = load_scene("maze", 4, 16);
    let (bytes, _) = bake_scene(&scene, &scene_dir("maze"), scene.settings.transport, false);
    let bundle = Bundle::decode(&bytes).unwrap();
    let n = bundle.layout.n_texels();
    let (mut reached, mut lit, mut checked, mut cut) = (0, 0, 0, 0);
    for light in &lights.lights {
        let p = light.position;
        let positions: Vec<[f64; 3]> = [[0.0, 0.0], [0.4, 0.0], [-0.4, 0.3], [0.0, -0.45]]
            .iter()
            .map(|[dx, dz]| [p[0] + dx, p[1], p[2] + dz])
            .collect();
        let (r, l, c) = check_light_reach(&bundle, light, &positions, 4);
        reached += r;
        lit += l;
        cut += c;
        checked += positions.len() * n;
    }
    eprintln!(
        "maze T=4: {reached} of {checked} texel visits reached, {lit} lit, {cut} of {} \
         positions traced against the reached rooms' occluders only",
        4 * lights.lights.len()
    );
    assert!(lit > 0 && reached >= lit);
    assert!(
        cut * 2 > 4 * lights.lights.len(),
        "{cut} positions cut the occluders"
    );
    assert!(reached * 2 < checked, "{reached} of {checked} reached");
}

/// The C ABI's one-light path on the maze: a light's reach before and after each move
/// (`lf_runtime_light_reach`), its direct light computed there only
/// (`lf_runtime_direct_in_spans`), the change and `lf_runtime_apply_delta` give what
/// relighting everything through `lf_runtime_apply` gives, and the light's direct light kept
/// this way is bit-identical to computing it at every texel.
#[test]
fn the_c_abi_moves_one_light_by_its_change() {
    use lightfarm::{
        lf_runtime_apply, lf_runtime_apply_delta, lf_runtime_direct_in_spans, lf_runtime_free,
        lf_runtime_light_reach, lf_runtime_new, lf_runtime_set_bounces, lf_runtime_texel_count,
        LfBounces, LfMethod, LfPointLight, LfStatus, LfTexelSpan,
    };
    const OK: i32 = LfStatus::Ok as i32;
    let (scene, lights) = load_scene("maze", 4, 64);
    let (bytes, _) = bake_scene(&scene, &scene_dir("maze"), scene.settings.transport, false);
    // SAFETY: `bytes` is live for the call; every later call gets this live runtime and
    // buffers of the lengths passed.
    unsafe {
        let rt = lf_runtime_new(bytes.as_ptr(), bytes.len());
        assert!(!rt.is_null());
        assert_eq!(lf_runtime_set_bounces(rt, LfBounces::One as i32, 0.0), OK);
        let texels = lf_runtime_texel_count(rt);
        let n = 3 * texels;
        let everything = [LfTexelSpan {
            start: 0,
            end: texels as u32,
            in_sight: 0,
        }];
        let c_light = |position: [f64; 3], intensity: [f64; 3]| LfPointLight {
            position: position.map(|x| x as f32),
            intensity: intensity.map(|x| x as f32),
        };
        let direct = |lights: &[LfPointLight], spans: &[LfTexelSpan], out: &mut [f32]| {
            let status = lf_runtime_direct_in_spans(
                rt,
                lights.as_ptr(),
                lights.len(),
                spans.as_ptr(),
                spans.len(),
                out.as_mut_ptr(),
                out.len(),
            );
            assert_eq!(status, OK);
        };
        let reach = |p: [f32; 3]| {
            let mut count = 0usize;
            // Too small a buffer: BAD_LENGTH and the count needed.
            let status =
                lf_runtime_light_reach(rt, p.as_ptr(), std::ptr::null_mut(), 0, &mut count);
            assert_eq!(status, LfStatus::BadLength as i32);
            assert!(count > 0);
            let mut spans = vec![LfTexelSpan::default(); count];
            let status =
                lf_runtime_light_reach(rt, p.as_ptr(), spans.as_mut_ptr(), count, &mut count);
            assert_eq!(status, OK);
            spans
        };
        let mdrt = LfMethod::Drt as i32;
        let apply = |d: &[f32], out: &mut [f32]| {
            assert_eq!(
                lf_runtime_apply(rt, mdrt, d.as_ptr(), d.len(), out.as_mut_ptr(), out.len()),
                OK
            );
        };

        let others: Vec<LfPointLight> = lights.lights[1..]
            .iter()
            .map(|l| c_light(l.position, l.intensity))
            .collect();
        let mut rest = vec![0.0f32; n];
        direct(&others, &everything, &mut rest);
        let light = &lights.lights[0];
        let mut p = light.position;
        let mut moving = vec![0.0f32; n];
        direct(
            &[c_light(p, light.intensity)],
            &reach(p.map(|x| x as f32)),
            &mut moving,
        );
        let total =
            |moving: &[f32]| -> Vec<f32> { rest.iter().zip(moving).map(|(a, b)| a + b).collect() };
        let mut indirect = vec![0.0f32; n];
        apply(&total(&moving), &mut indirect);
        let mut reached_less = false;
        for step in 0..4 {
            let before = moving.clone();
            let old_spans = reach(p.map(|x| x as f32));
            p[0] += 0.37;
            p[2] += if step % 2 == 0 { 0.5 } else { -0.3 };
            let new_spans = reach(p.map(|x| x as f32));
            // The light left the old reach and lights the new one.
            for s in &old_spans {
                moving[s.start as usize * 3..s.end as usize * 3].fill(0.0);
            }
            direct(&[c_light(p, light.intensity)], &new_spans, &mut moving);
            let covered: u32 = new_spans.iter().map(|s| s.end - s.start).sum();
            reached_less |= (covered as usize) < texels;
            let mut whole = vec![0.0f32; n];
            direct(&[c_light(p, light.intensity)], &everything, &mut whole);
            assert_eq!(
                moving, whole,
                "step {step}: direct light on the reach differs"
            );
            // Texels outside the spans are never written.
            let mut marked = vec![7.0f32; n];
            direct(&[c_light(p, light.intensity)], &new_spans, &mut marked);
            let inside = |t: usize| {
                new_spans
                    .iter()
                    .any(|s| (s.start as usize..s.end as usize).contains(&t))
            };
            for t in 0..texels {
                let want = if inside(t) {
                    &whole[3 * t..3 * t + 3]
                } else {
                    &[7.0f32; 3][..]
                };
                assert_eq!(&marked[3 * t..3 * t + 3], want, "step {step}: texel {t}");
            }
            let change: Vec<f32> = moving.iter().zip(&before).map(|(a, b)| a - b).collect();
            assert_eq!(
                lf_runtime_apply_delta(rt, mdrt, change.as_ptr(), n, indirect.as_mut_ptr(), n),
                OK
            );
            let mut want = vec![0.0f32; n];
            apply(&total(&moving), &mut want);
            let err = relative_l2(indirect.as_chunks::<3>().0, want.as_chunks::<3>().0);
            assert!(
                err < 1e-5,
                "step {step}: by the change {err:.2e} from everything"
            );
        }
        assert!(reached_less, "the light reached every texel at every step");
        // A span past the layout is refused, and the output is left alone.
        let bad = [LfTexelSpan {
            start: 0,
            end: texels as u32 + 1,
            in_sight: 0,
        }];
        let mut untouched = vec![7.0f32; n];
        let status = lf_runtime_direct_in_spans(
            rt,
            others.as_ptr(),
            others.len(),
            bad.as_ptr(),
            1,
            untouched.as_mut_ptr(),
            n,
        );
        assert_eq!(status, LfStatus::BadIndex as i32);
        assert!(untouched.iter().all(|&v| v == 7.0));
        lf_runtime_free(rt);
    }
}
