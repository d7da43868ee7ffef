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
/// walk reaches is bit-identical to lighting every texel, every texel left out is dark, and the
/// walk leaves out most of the maze.
#[test]
fn a_light_reaches_what_lighting_everything_lights() {
    let (scene, lights) = load_scene("maze", 4, 16);
    let (bytes, _) = bake_scene(&scene, &scene_dir("maze"), scene.settings.transport, false);
    let bundle = Bundle::decode(&bytes).unwrap();
    let n = bundle.layout.n_texels();
    let (mut reached, mut lit, mut checked) = (0, 0, 0);
    for light in &lights.lights {
        let p = light.position;
        let positions: Vec<[f64; 3]> = [[0.0, 0.0], [0.4, 0.0], [-0.4, 0.3], [0.0, -0.45]]
            .iter()
            .map(|[dx, dz]| [p[0] + dx, p[1], p[2] + dz])
            .collect();
        let (r, l) = check_light_reach(&bundle, light, &positions, 4);
        reached += r;
        lit += l;
        checked += positions.len() * n;
    }
    eprintln!("maze T=4: {reached} of {checked} texel visits reached, {lit} lit");
    assert!(lit > 0 && reached >= lit);
    assert!(reached * 2 < checked, "{reached} of {checked} reached");
}
