//! One light's direct light where it reaches (`ReachDirect::light`, what a game calls per
//! frame for a moving light and what `lf_runtime_light_direct` runs) allocates nothing once it
//! has seen a reach as large: the walk, the light buffer, the box queries and the lighting keep
//! their scratch. Its own test binary, because it replaces the global allocator with one that
//! counts the current thread's allocations.

use lightfarm_client::direct::direct_scale;
use lightfarm_client::{Occluders, ReachDirect};
use lightfarm_proto::bundle::Bundle;
use lightfarm_proto::testing::{allocs, CountingAlloc};
use lightfarm_tests::{bake_scene, load_scene, scene_dir};

#[global_allocator]
static GLOBAL: CountingAlloc = CountingAlloc;

#[test]
fn a_lights_direct_light_allocates_nothing_after_its_first_call() {
    let (scene, lights) = load_scene("maze", 4, 16);
    let (bytes, _) = bake_scene(&scene, &scene_dir("maze"), scene.settings.transport, false);
    let bundle = Bundle::decode(&bytes).unwrap();
    let layout = &bundle.layout;
    let occluders = Occluders::from_layout(layout);
    let scale = direct_scale(layout, &occluders);
    let mut reach = ReachDirect::new(&bundle, &occluders).expect("the maze has rooms");
    let mut spans = Vec::new();
    let mut out = vec![[0.0f32; 3]; layout.n_texels()];
    for light in &lights.lights {
        reach.light(layout, &occluders, light, 4, scale, &mut spans, &mut out);
    }
    let first: Vec<[f32; 3]> = out.clone();

    let _counter_works = std::hint::black_box(Box::new(0u8));
    let before = allocs();
    for light in &lights.lights {
        reach.light(layout, &occluders, light, 4, scale, &mut spans, &mut out);
    }
    assert_eq!(allocs(), before, "ReachDirect::light allocated");
    assert_eq!(out, first);
    assert!(out.iter().any(|v| v[0] > 0.0), "some texel lit");
}
