//! The example scenes under `scenes/` parse, validate and have the shape their README promises.

use std::path::PathBuf;

use lightfarm_proto::lights::LightSet;
use lightfarm_proto::scene::{Opening, Scene};

fn scene_dir(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../scenes")
        .join(name)
}

fn load(name: &str) -> (Scene, LightSet) {
    let dir = scene_dir(name);
    let read = |file: &str| {
        let path = dir.join(file);
        std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
    };
    let scene = Scene::from_json(&read("scene.json"))
        .unwrap_or_else(|e| panic!("scenes/{name}/scene.json: {e}"));
    let lights = LightSet::from_json(&read("lights.json"))
        .unwrap_or_else(|e| panic!("scenes/{name}/lights.json: {e}"));
    scene.validate().expect("a parsed scene validates");
    (scene, lights)
}

/// Union-find over `scene.connections()`; the number of components.
fn components(scene: &Scene) -> usize {
    fn find(parent: &mut [usize], mut x: usize) -> usize {
        while parent[x] != x {
            parent[x] = parent[parent[x]];
            x = parent[x];
        }
        x
    }
    let mut parent: Vec<usize> = (0..scene.blocks.len()).collect();
    for c in scene.connections().expect("connections") {
        let (a, b) = (find(&mut parent, c.block_a), find(&mut parent, c.block_b));
        parent[a] = b;
    }
    (0..parent.len())
        .filter(|&i| find(&mut parent, i) == i)
        .count()
}

fn void_openings(scene: &Scene) -> usize {
    scene
        .openings()
        .expect("openings")
        .iter()
        .flatten()
        .filter(|o| matches!(o, Some(Opening::Void)))
        .count()
}

fn strictly_inside(p: [f64; 3], min: [f64; 3], max: [f64; 3]) -> bool {
    (0..3).all(|k| min[k] < p[k] && p[k] < max[k])
}

fn block_containing(scene: &Scene, p: [f64; 3]) -> Option<&str> {
    scene
        .blocks
        .iter()
        .find(|b| strictly_inside(p, b.min, b.max))
        .map(|b| b.id.as_str())
}

fn assert_lights_inside(name: &str, scene: &Scene, lights: &LightSet) {
    for (k, light) in lights.lights.iter().enumerate() {
        assert!(
            block_containing(scene, light.position).is_some(),
            "{name}: lights[{k}] at {:?} is in no block",
            light.position
        );
    }
}

fn assert_clutter_inside(name: &str, scene: &Scene) {
    for c in &scene.clutter {
        let b = c.box_.expect("example clutter is boxes");
        let host = scene
            .blocks
            .iter()
            .find(|blk| (0..3).all(|k| blk.min[k] <= b.min[k] && b.max[k] <= blk.max[k]));
        let host = host.unwrap_or_else(|| panic!("{name}: clutter \"{}\" is in no block", c.id));
        // Stands on the floor and does not touch the walls or the ceiling.
        assert_eq!(
            b.min[1], host.min[1],
            "{name}: clutter \"{}\" is not on the floor",
            c.id
        );
        assert!(
            b.max[1] < host.max[1],
            "{name}: clutter \"{}\" touches the ceiling",
            c.id
        );
        for k in [0, 2] {
            assert!(
                host.min[k] < b.min[k] && b.max[k] < host.max[k],
                "{name}: clutter \"{}\" touches a wall of block \"{}\"",
                c.id,
                host.id
            );
        }
    }
}

#[test]
fn cornell_box() {
    let (scene, lights) = load("cornell");
    assert_eq!(scene.blocks.len(), 1);
    assert!(scene.blocks[0].open.is_empty(), "the Cornell box is closed");
    assert_eq!(scene.connections().unwrap().len(), 0);
    assert_eq!(components(&scene), 1);
    assert_eq!(void_openings(&scene), 0);
    assert_eq!(scene.clutter.len(), 2);
    assert_clutter_inside("cornell", &scene);
    assert_eq!(lights.lights.len(), 1);
    assert!(lights.poses.is_empty());
    assert_lights_inside("cornell", &scene, &lights);
}

#[test]
fn maze() {
    let (scene, lights) = load("maze");
    let n = scene.blocks.len();
    assert_eq!(n, 19);
    let connections = scene.connections().unwrap();
    assert_eq!(components(&scene), 1, "the maze is one connected graph");
    // A connected graph with at least as many edges as vertices has a cycle.
    assert!(
        connections.len() >= n,
        "the maze has a loop ({} connections, {n} blocks)",
        connections.len()
    );
    assert!(
        void_openings(&scene) <= 2,
        "at most two openings onto the void"
    );

    // Some dead ends (blocks with a single connection).
    let mut degree = vec![0usize; n];
    for c in &connections {
        degree[c.block_a] += 1;
        degree[c.block_b] += 1;
    }
    assert!(
        degree.iter().filter(|&&d| d == 1).count() >= 2,
        "the maze has dead ends"
    );

    // Every closed floor is at y = 0, and blocks come in more than one height.
    for b in &scene.blocks {
        if !b.is_open(lightfarm_proto::Face::NegY) {
            assert_eq!(b.min[1], 0.0, "block \"{}\": floor is not at y = 0", b.id);
        }
    }
    let mut heights: Vec<f64> = scene.blocks.iter().map(|b| b.max[1] - b.min[1]).collect();
    heights.sort_by(f64::total_cmp);
    heights.dedup();
    assert!(
        heights.len() >= 2,
        "blocks of different heights: {heights:?}"
    );

    assert_eq!(scene.clutter.len(), 4, "four pillars");
    assert_clutter_inside("maze", &scene);

    assert_eq!(lights.lights.len(), 4);
    assert_lights_inside("maze", &scene, &lights);
    let mut hosts: Vec<&str> = lights
        .lights
        .iter()
        .filter_map(|l| block_containing(&scene, l.position))
        .collect();
    hosts.sort();
    hosts.dedup();
    assert_eq!(
        hosts.len(),
        4,
        "the maze lights are in four different blocks"
    );
    for l in &lights.lights {
        assert!(
            l.intensity.iter().all(|&i| (5.0..=20.0).contains(&i)),
            "intensity {:?}",
            l.intensity
        );
    }
}

#[test]
fn corridor() {
    let (scene, lights) = load("corridor");
    assert_eq!(scene.blocks.len(), 5);
    let connections = scene.connections().unwrap();
    assert_eq!(connections.len(), 4, "a chain of five blocks");
    assert_eq!(components(&scene), 1);
    assert_eq!(void_openings(&scene), 0, "both ends are closed");
    assert!(scene.clutter.is_empty());
    // The chain runs along +x and the block lengths vary.
    for w in scene.blocks.windows(2) {
        assert_eq!(w[0].max[0], w[1].min[0]);
    }
    assert_eq!(lights.lights.len(), 1);
    assert_lights_inside("corridor", &scene, &lights);
    assert_eq!(
        block_containing(&scene, lights.lights[0].position),
        Some(scene.blocks[0].id.as_str())
    );
}

#[test]
fn ball_corridor() {
    let (scene, lights) = load("ball_corridor");
    assert_eq!(scene.blocks.len(), 2);
    assert_eq!(scene.connections().unwrap().len(), 1);
    assert_eq!(void_openings(&scene), 0);
    assert!(scene.clutter.is_empty());
    assert_eq!(scene.dynamic.len(), 1);
    let ball = &scene.dynamic[0];
    assert_eq!(ball.id, "red_ball");
    assert!(ball.albedo[0] > 4.0 * ball.albedo[1], "the ball is red");
    assert!(scene_dir("ball_corridor").join(&ball.mesh).is_file());
    assert_lights_inside("ball_corridor", &scene, &lights);
    // The ball (radius 0.35 m) is posed clear of the floor and the -z wall, close to both.
    assert_eq!(lights.poses.len(), 1);
    let t = lights.poses[0].translation;
    assert_eq!(lights.poses[0].id, "red_ball");
    assert!(t[1] - 0.35 > 0.0 && t[1] - 0.35 < 0.2, "gap to the floor");
    assert!(t[2] - 0.35 > 0.0 && t[2] - 0.35 < 0.2, "gap to the wall");
}

#[test]
fn cornell_mesh() {
    let (scene, lights) = load("cornell_mesh");
    let (cornell, cornell_lights) = load("cornell");
    assert_eq!(scene.blocks, cornell.blocks);
    assert_eq!(lights, cornell_lights);
    assert_eq!(scene.clutter.len(), 2);
    assert_eq!(scene.clutter[0].mesh.as_deref(), Some("short_box.gltf"));
    assert_eq!(scene.clutter[1], cornell.clutter[1]);
    assert!(scene_dir("cornell_mesh").join("short_box.bin").exists());
}
