//! The shape plan: which canonical shape each block applies, and through which box symmetry.
//!
//! Blocks that are rotations or mirror images of one another share one canonical shape, baked,
//! cached and shipped once; the plan is the first stage of a bake and what the farm's units
//! (`crate::bake::units`) cut the shape work by.
//!
//! Invariant: unique shapes are numbered in order of first use by the scene's blocks, so the
//! plan (and the bundle's shape list) is a pure function of the scene.

use std::collections::HashMap;
use std::sync::Arc;

use rayon::prelude::*;

use lightfarm_proto::box_symmetry::BoxSymmetry;
use lightfarm_proto::scene::Scene;

use crate::bake::mrt::shape::{ShapeLightfields, ShapeOperators, ShapeSpec};
use crate::bake::mrt::shape_symmetry::{
    instance_operators, instance_passes, InstanceLightfield, OpeningPasses,
};
use crate::bake::transport::build::BlockPasses;

/// The `Pass` operators of the (shape, symmetry) instances a level uses (what
/// [`ShapePlan::block_passes`] borrows for blocks that are not in their shape's orientation).
pub type InstancePasses = HashMap<(usize, BoxSymmetry), Vec<OpeningPasses>>;

/// The scene's blocks' shape operators, deduplicated by content key up to box symmetry: blocks
/// that are rotations or mirror images of one another share one canonical shape
/// (`ShapeSpec::canonical`), baked, cached and shipped once.
pub struct ShapePlan {
    /// One per block: its own spec, in its own frame.
    pub specs: Vec<ShapeSpec>,
    /// Unique canonical shape keys, in order of first use.
    pub unique: Vec<String>,
    /// Per unique shape, its canonical spec (what is baked and cached).
    pub unique_specs: Vec<ShapeSpec>,
    /// Per block, its unique shape.
    pub shape_index: Vec<usize>,
    /// Per block, the symmetry taking its frame to its shape's.
    pub symmetry: Vec<BoxSymmetry>,
}

impl ShapePlan {
    /// Per block, the key of the operators it applies: its shape's key, and the symmetry when
    /// it is not the identity (what the transport cache is keyed by).
    pub fn block_keys(&self) -> Vec<String> {
        self.shape_index
            .iter()
            .zip(&self.symmetry)
            .map(|(i, g)| g.instance_key(&self.unique[*i]))
            .collect()
    }

    /// Per block, its openings' lightfields (what the transport's propagation reads), seen
    /// through its symmetry from the unique shapes' (`unique[i]` for shape `i`).
    pub fn block_lightfields<'a>(
        &self,
        unique: &'a [ShapeLightfields],
    ) -> Vec<InstanceLightfield<'a>> {
        (0..self.specs.len())
            .map(|b| {
                InstanceLightfield::new(
                    &unique[self.shape_index[b]],
                    &self.specs[b],
                    self.symmetry[b],
                )
            })
            .collect()
    }

    /// The `Pass` operators of every (shape, symmetry) instance the blocks use (see
    /// [`ShapePlan::block_passes`]).
    pub fn instance_passes(&self, unique: &[Arc<ShapeOperators>]) -> InstancePasses {
        let mut instances = InstancePasses::new();
        for b in 0..self.specs.len() {
            let (shape, g) = (self.shape_index[b], self.symmetry[b]);
            if !g.is_identity() {
                instances
                    .entry((shape, g))
                    .or_insert_with(|| instance_passes(&unique[shape], &self.specs[b], g));
            }
        }
        instances
    }

    /// Per block, its openings and their `Pass` operators as its operators
    /// ([`ShapePlan::block_operators`]) would hold them, the same values in the same order:
    /// the shape's own for an identity block, else its instance's from `instances`. The
    /// propagation reads these, so it runs before the texel-sized instance operators exist.
    pub fn block_passes<'a>(
        &self,
        unique: &'a [Arc<ShapeOperators>],
        instances: &'a InstancePasses,
    ) -> BlockPasses<'a> {
        (0..self.specs.len())
            .map(|b| {
                let (shape, g) = (self.shape_index[b], self.symmetry[b]);
                if g.is_identity() {
                    unique[shape]
                        .openings
                        .iter()
                        .map(|o| (o.face, o.pass_from.as_slice()))
                        .collect()
                } else {
                    instances[&(shape, g)]
                        .iter()
                        .map(|o| (o.face, o.pass_from.as_slice()))
                        .collect()
                }
            })
            .collect()
    }

    /// Per block, the operators it applies, from the unique shapes' (`unique[i]` for shape
    /// `i`): the shape's own for an identity block, else the shape's seen through the block's
    /// symmetry, made once per distinct (shape, symmetry) and shared by the blocks using it.
    pub fn block_operators(&self, unique: &[Arc<ShapeOperators>]) -> Vec<Arc<ShapeOperators>> {
        // Each distinct (shape, symmetry) pair is permuted once, one pair per core; `index`
        // numbers the pairs in the order blocks first need them.
        let mut index: HashMap<(usize, BoxSymmetry), usize> = HashMap::new();
        let mut pairs: Vec<(usize, BoxSymmetry, usize)> = Vec::new();
        for b in 0..self.specs.len() {
            let (shape, g) = (self.shape_index[b], self.symmetry[b]);
            if !g.is_identity() {
                index.entry((shape, g)).or_insert_with(|| {
                    pairs.push((shape, g, b));
                    pairs.len() - 1
                });
            }
        }
        let instances: Vec<Arc<ShapeOperators>> = pairs
            .par_iter()
            .map(|&(shape, g, b)| Arc::new(instance_operators(&unique[shape], &self.specs[b], g)))
            .collect();
        (0..self.specs.len())
            .map(|b| {
                let (shape, g) = (self.shape_index[b], self.symmetry[b]);
                if g.is_identity() {
                    return unique[shape].clone();
                }
                instances[index[&(shape, g)]].clone()
            })
            .collect()
    }
}

/// Which shape each block uses, and the unique shapes.
pub fn shape_plan(scene: &Scene) -> ShapePlan {
    let specs: Vec<ShapeSpec> = scene
        .blocks
        .iter()
        .map(|b| {
            let mut spec =
                ShapeSpec::for_block(&b.aabb(), &b.open, &scene.settings, &scene.light_regions);
            // Pieces of a long block share their shape (`bake::scene::pieces`).
            if let Some(piece) = &b.piece {
                spec.extent = piece.extent;
            }
            spec
        })
        .collect();
    let mut unique: Vec<String> = Vec::new();
    let mut unique_specs = Vec::new();
    let mut shape_index: Vec<usize> = Vec::new();
    let mut symmetry = Vec::new();
    let mut key_to_index: HashMap<String, usize> = HashMap::new();
    for spec in &specs {
        let (canonical, g) = spec.canonical();
        let key = canonical.key();
        let idx = *key_to_index.entry(key.clone()).or_insert_with(|| {
            unique.push(key);
            unique_specs.push(canonical);
            unique.len() - 1
        });
        shape_index.push(idx);
        symmetry.push(g);
    }
    ShapePlan {
        specs,
        unique,
        unique_specs,
        shape_index,
        symmetry,
    }
}
