//! Seeded random light sets for `lightfarm bench`: the generator of `scripts/mrt_figures.py`
//! in Rust. Each set holds 1–4 white-ish point lights inside random blocks, 0.25 m from the
//! walls and 0.25 m clear of clutter boxes, 2–20 W/sr with each channel scaled by U(0.8, 1),
//! and, for a scene with dynamic objects, one pose per object inside a random block.
//!
//! Invariant: a light set is a pure function of (scene, seed, set index); nothing reads the
//! clock or the thread count.

use lightfarm_proto::lights::{Light, LightKind, LightSet, Pose};
use lightfarm_proto::scene::{Aabb, Scene};

/// Distance kept between a light and the walls of its block, and between a light and clutter.
const WALL_MARGIN: f64 = 0.25;
/// Distance kept between a posed dynamic object's origin and the walls of its block (the
/// objects of the example scenes are at most 0.35 m in radius).
const POSE_MARGIN: f64 = 0.5;

/// SplitMix64: a small, well-mixed, seedable generator (Steele, Lea & Flood 2014).
#[derive(Clone, Debug)]
pub struct SplitMix64 {
    state: u64,
}

impl SplitMix64 {
    pub fn new(seed: u64) -> SplitMix64 {
        SplitMix64 { state: seed }
    }

    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1) with 53 random bits.
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    /// Uniform integer in `0..n` (n > 0).
    pub fn below(&mut self, n: usize) -> usize {
        ((self.unit() * n as f64) as usize).min(n - 1)
    }
}

fn clear_of_boxes(p: [f64; 3], boxes: &[Aabb], margin: f64) -> bool {
    boxes
        .iter()
        .all(|b| (0..3).any(|k| p[k] < b.min[k] - margin || p[k] > b.max[k] + margin))
}

fn point_in_block(rng: &mut SplitMix64, scene: &Scene, margin: f64) -> [f64; 3] {
    let block = &scene.blocks[rng.below(scene.blocks.len())];
    [0, 1, 2].map(|k| {
        let lo = block.min[k] + margin;
        let hi = block.max[k] - margin;
        if hi > lo {
            rng.uniform(lo, hi)
        } else {
            0.5 * (block.min[k] + block.max[k])
        }
    })
}

/// Light set number `index` of a bench run with `seed`.
pub fn random_light_set(scene: &Scene, seed: u64, index: u64) -> LightSet {
    let mut rng = SplitMix64::new(seed ^ index.wrapping_mul(0xA076_1D64_78BD_642F));
    let boxes: Vec<Aabb> = scene.clutter.iter().filter_map(|c| c.box_).collect();
    let poses: Vec<Pose> = scene
        .dynamic
        .iter()
        .map(|object| Pose {
            id: object.id.clone(),
            translation: point_in_block(&mut rng, scene, POSE_MARGIN),
            rotation: {
                // A random rotation about y (the objects stand on the floor in the examples).
                let half = rng.uniform(0.0, std::f64::consts::PI);
                [0.0, half.sin(), 0.0, half.cos()]
            },
        })
        .collect();
    let n_lights = 1 + rng.below(4);
    let mut lights = Vec::with_capacity(n_lights);
    for _ in 0..n_lights {
        let mut position = point_in_block(&mut rng, scene, WALL_MARGIN);
        for _ in 0..1000 {
            let clear_of_poses = poses.iter().all(|p| {
                (0..3)
                    .map(|k| (p.translation[k] - position[k]).powi(2))
                    .sum::<f64>()
                    > POSE_MARGIN * POSE_MARGIN
            });
            if clear_of_boxes(position, &boxes, WALL_MARGIN) && clear_of_poses {
                break;
            }
            position = point_in_block(&mut rng, scene, WALL_MARGIN);
        }
        let base = rng.uniform(2.0, 20.0);
        let intensity = [0; 3].map(|_| base * rng.uniform(0.8, 1.0));
        lights.push(Light {
            kind: LightKind::Point,
            position,
            intensity,
        });
    }
    LightSet { lights, poses }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn maze() -> Scene {
        let text = include_str!("../../../../scenes/maze/scene.json");
        Scene::from_json(text).unwrap()
    }

    #[test]
    fn light_sets_are_seeded_and_inside_blocks_clear_of_clutter() {
        let scene = maze();
        let boxes: Vec<Aabb> = scene.clutter.iter().filter_map(|c| c.box_).collect();
        for index in 0..50 {
            let a = random_light_set(&scene, 7, index);
            assert_eq!(a, random_light_set(&scene, 7, index));
            assert!((1..=4).contains(&a.lights.len()));
            for light in &a.lights {
                assert!(scene.blocks.iter().any(|b| (0..3)
                    .all(|k| light.position[k] >= b.min[k] + WALL_MARGIN
                        && light.position[k] <= b.max[k] - WALL_MARGIN)));
                assert!(clear_of_boxes(light.position, &boxes, WALL_MARGIN));
                assert!(light.intensity.iter().all(|&i| (1.6..20.0).contains(&i)));
            }
        }
        assert_ne!(
            random_light_set(&scene, 7, 0),
            random_light_set(&scene, 8, 0)
        );
    }
}
