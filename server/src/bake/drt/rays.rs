//! The two ray passes of DRT (paper 000 §4): what each block texel's rays see of clutter (and
//! the wall behind it), and what each clutter texel's rays see; and their reuse across bakes,
//! so a rebake after moving one clutter object traces only the texels that could see it. With
//! `scene_gather: exact`, a block texel that sees clutter also traces cosine rays on a stream of
//! its own and records what they hit, like a clutter texel (kept in the same unit).
//!
//! Reuse is exact. A texel's cached rays are taken only when
//! (a) its rays would be drawn the same: same stream (the unit's key holds the blocks, texel
//!     count, rays, seed and guiding share; a clutter unit also its object and texel offset)
//!     and the same guiding cones ([`ClutterGuidedSampler::guide_spheres`] over the old and
//!     the new spheres give equal sequences), and
//! (b) no clutter object that changed between the two scenes (removed, moved, reshaped or added;
//!     compared by [`ClutterShape::fingerprint`]) can meet a segment from the texel to a first
//!     hit of its rays ([`RayReach`]), so every ray meets the same surfaces; continued rays
//!     behind clutter see the blocks alone, which the key fixes.
//!
//! Clutter texel indices in cached results are mapped through the objects' new texel offsets.
//! Units are stored on disk by [`DrtRayCache`] ([`crate::bake::cache::drt_rays`]); their keys
//! ([`CODE_VERSION`] and what the streams depend on) are made here.
//! Guiding aims only at clutter in the texel's block or a block one opening away (farther
//! clutter is still reached by the cosine rays); this is what limits (a) to the neighbourhood
//! of the moved object.
//!
//! The clutter lighting-prior bases are reused the same way ([`clutter_basis_unit`]): when no
//! changed object meets a shadow segment from a prior light to a texel.
//!
//! Frames: world, metres. Invariant: results are per texel in global texel order, hit lists
//! ascending by texel with weights summed in ray order, whether traced or reused — so a bake is
//! the same bytes with or without the cache, at any thread count.

use std::path::PathBuf;

use glam::DVec3;
use rayon::prelude::*;

use lightfarm_proto::scene::{Opening, Scene, SceneGather};

use crate::bake::cache::drt_rays::Unit;
use crate::bake::drt::clutter_basis::ClutterBasisOps;
use crate::bake::drt::clutter_sampling::{ClutterGuidedSampler, Sphere};
use crate::bake::drt::error::DrtError;
use crate::bake::drt::reach::{RayReach, ReachRecorder};
use crate::bake::drt::sight::ClutterSight;
use crate::bake::math::low_rank::LowRankError;
use crate::bake::math::sampling::{
    sample_cosine_hemisphere, sobol_2d, stream_key, to_world, Purpose,
};
use crate::bake::mrt::lighting_prior::unshadowed_pattern;
use crate::bake::scene::geometry::{ClutterShape, Geometry, Primitive, SurfaceOwner};
use crate::bake::tracer::{Hit, Tracer};

/// Bumped whenever what a ray pass records for the same inputs, or how its cache stores it,
/// changes (4: the shared entry framing; 5: prior bases through the Gram matrix, which the
/// cache also keeps). In every unit key, and every cache entry's version tag.
pub const CODE_VERSION: &str = "lightfarm-drt-rays-5";

/// The on-disk cache of units and prior bases (it lived here; this path still names it).
pub use crate::bake::cache::drt_rays::DrtRayCache;

/// An axis-aligned box `[min, max]`, world metres.
pub type Bounds = [[f64; 3]; 2];

/// What a block texel's rays saw.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BlockTexelRays {
    /// Block texels behind clutter hits (continued through the blocks alone): (global texel,
    /// summed ray weight), ascending.
    pub occluded: Vec<(u32, f64)>,
    /// Front faces of clutter texels hit: (global texel, summed weight), ascending.
    pub reflected: Vec<(u32, f64)>,
    /// Weight of rays whose first hit is clutter (any side, meshes included).
    pub clutter_hits: f64,
    /// Weight of rays whose first hit is the inside of a clutter box.
    pub back_hits: f64,
    /// With `scene_gather: exact`, for a texel whose view of clutter reaches the tolerance:
    /// lit texels its cosine rays hit (global texel, rays), ascending; empty otherwise.
    pub hits: Vec<(u32, u32)>,
    /// The segments from the texel to every first hit.
    pub reach: RayReach,
}

impl BlockTexelRays {
    /// Whether the texel's view of clutter reaches `tolerance`: the texels that get DRT rows
    /// (or, with `scene_gather: exact`, the gather), the rest being skipped.
    pub fn sees_clutter(&self, tolerance: f64) -> bool {
        self.clutter_hits > 0.0 && self.clutter_hits >= tolerance
    }
}

/// What a clutter texel's rays saw.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ClutterTexelRays {
    /// Lit texels hit (block texels, and front faces of clutter texels): (global texel, rays).
    pub hits: Vec<(u32, u32)>,
    /// Share of rays that hit the inside of a clutter box.
    pub back: f64,
    /// The segments from the texel to every first hit.
    pub reach: RayReach,
}

/// What one ray hit, for the delta operators.
pub enum Seen {
    Nothing,
    /// Block texel (global index), seen from inside its block.
    Block(u32),
    /// Clutter texel (global index), or clutter without texels (mesh) when None.
    Clutter {
        texel: Option<u32>,
        back: bool,
    },
}

/// Classifies a hit against the geometry `g` that `tracer` was built from.
pub fn classify(g: &Geometry, tracer: &Tracer, hit: &Hit) -> Seen {
    match tracer.primitives()[hit.primitive as usize] {
        Primitive::Rect {
            surface: Some(s), ..
        } => {
            let surface = &g.surfaces[s as usize];
            match surface.owner {
                SurfaceOwner::Block { .. } if hit.front => {
                    Seen::Block(g.texel_at(s, hit.point) as u32)
                }
                SurfaceOwner::Block { .. } => Seen::Nothing,
                SurfaceOwner::ClutterBox { .. } => {
                    let t = g.texel_at(s, hit.point);
                    Seen::Clutter {
                        texel: hit.front.then_some(t as u32),
                        back: !hit.front,
                    }
                }
                SurfaceOwner::ClutterMesh { .. } => unreachable!("mesh surfaces have no rectangle"),
            }
        }
        Primitive::Rect { surface: None, .. } => Seen::Nothing,
        // Triangles are mesh clutter (dynamic objects are not in the bake geometry). The lit
        // side is the counter-clockwise one (hit.normal faces the ray's origin); closed
        // pieces were wound outward when the geometry was built.
        Primitive::Triangle {
            v,
            lightmap: Some(m),
            ..
        } => {
            let [v0, v1, v2] = v.map(DVec3::from);
            let front = DVec3::from(hit.normal).dot((v1 - v0).cross(v2 - v0)) > 0.0;
            Seen::Clutter {
                texel: front.then(|| g.mesh_texel_at(m, hit.point) as u32),
                // Only a closed piece has an inside; an open sheet's back is an occluder.
                back: !front && m.closed,
            }
        }
        Primitive::Triangle { lightmap: None, .. } => Seen::Clutter {
            texel: None,
            back: false,
        },
    }
}

/// Bounding spheres of every clutter object, in scene order (from [`Geometry::clutter_shapes`]).
pub fn clutter_spheres(g: &Geometry) -> Vec<Sphere> {
    g.clutter_shapes
        .iter()
        .filter(|s| s.bounds[0][0] <= s.bounds[1][0])
        .map(|s| {
            let center = [0, 1, 2].map(|k| 0.5 * (s.bounds[0][k] + s.bounds[1][k]));
            let radius = (0..3)
                .map(|k| (0.5 * (s.bounds[1][k] - s.bounds[0][k])).powi(2))
                .sum::<f64>()
                .sqrt();
            Sphere { center, radius }
        })
        .collect()
}

/// The boxes of a block and of its neighbours one opening away: where guided rays aim.
struct Neighbourhood {
    boxes: Vec<Bounds>,
}

impl Neighbourhood {
    /// True when the sphere meets the block or one of its neighbours. Clutter farther away is
    /// not aimed at (cosine rays still reach it, so the estimate stays unbiased); this keeps
    /// a texel's rays independent of clutter beyond its neighbourhood.
    fn holds(&self, s: &Sphere) -> bool {
        self.boxes.iter().any(|b| {
            let gap2: f64 = (0..3)
                .map(|k| {
                    let c = s.center[k];
                    let d = (b[0][k] - c).max(c - b[1][k]).max(0.0);
                    d * d
                })
                .sum();
            gap2 <= (s.radius * (1.0 + 1e-9)).powi(2)
        })
    }
}

/// Everything the two passes need; built once per bake.
pub struct RayPass<'a> {
    scene: &'a Scene,
    g: &'a Geometry,
    gb: &'a Geometry,
    tracer: &'a Tracer,
    block_tracer: &'a Tracer,
    sampler: ClutterGuidedSampler,
    neighbourhoods: Vec<Neighbourhood>,
    /// Which block faces could see clutter at all: the others are not traced.
    sight: ClutterSight<'a>,
    /// `g.scale()` (a pass over every primitive), once rather than per unit.
    scale: f64,
}

/// Sums weights per texel in ray order; ascending by texel.
fn merge(hits: &[(u32, f64)]) -> Vec<(u32, f64)> {
    // A stable sort keeps each texel's weights in ray order, so each sum is taken in the order
    // the rays were traced.
    let mut sorted = hits.to_vec();
    sorted.sort_by_key(|&(t, _)| t);
    sum_runs(sorted)
}

/// Pairs sorted by texel, each texel's values summed in the order given; the list is kept for
/// every traced texel until the bake's DRT stage ends, so it carries no growth slack.
fn sum_runs<W: std::ops::AddAssign>(sorted: impl IntoIterator<Item = (u32, W)>) -> Vec<(u32, W)> {
    let mut out: Vec<(u32, W)> = Vec::new();
    for (t, w) in sorted {
        match out.last_mut() {
            Some((last, sum)) if *last == t => *sum += w,
            _ => out.push((t, w)),
        }
    }
    out.shrink_to_fit();
    out
}

impl<'a> RayPass<'a> {
    /// `g` is the full geometry (blocks first, then clutter) and `tracer` its BVH; `gb` the
    /// blocks alone with the same block texel indices.
    pub fn new(
        scene: &'a Scene,
        openings: &[[Option<Opening>; 6]],
        g: &'a Geometry,
        gb: &'a Geometry,
        tracer: &'a Tracer,
        block_tracer: &'a Tracer,
    ) -> RayPass<'a> {
        let neighbourhoods = (0..scene.blocks.len())
            .map(|b| {
                let mut boxes = vec![scene.blocks[b].aabb()];
                for o in openings[b].iter().flatten() {
                    if let Opening::Neighbour { block, .. } = o {
                        boxes.push(scene.blocks[*block].aabb());
                    }
                }
                Neighbourhood {
                    boxes: boxes.iter().map(|a| [a.min, a.max]).collect(),
                }
            })
            .collect();
        RayPass {
            scene,
            g,
            gb,
            tracer,
            block_tracer,
            sampler: ClutterGuidedSampler {
                spheres: clutter_spheres(g),
                alpha: scene.settings.clutter_importance,
            },
            neighbourhoods,
            sight: ClutterSight::new(scene, openings, g),
            scale: g.scale(),
        }
    }

    fn block_of(&self, x: usize) -> usize {
        match self.g.surfaces[self.g.texels[x].surface as usize].owner {
            SurfaceOwner::Block { block, .. } => block,
            SurfaceOwner::ClutterBox { .. } | SurfaceOwner::ClutterMesh { .. } => {
                unreachable!("block texels come first")
            }
        }
    }

    /// The spheres (values, in order) block texel `x` aims at, given a sphere list.
    fn guide(&self, x: usize, spheres: &[Sphere]) -> Vec<[f64; 4]> {
        let texel = &self.g.texels[x];
        let near = &self.neighbourhoods[self.block_of(x)];
        let sampler = ClutterGuidedSampler {
            spheres: spheres.to_vec(),
            alpha: self.sampler.alpha,
        };
        sampler
            .guide_spheres(texel.position, texel.normal, &|s| near.holds(s))
            .into_iter()
            .map(|i| {
                let s = spheres[i];
                [s.center[0], s.center[1], s.center[2], s.radius]
            })
            .collect()
    }

    /// Traces block texel `x` (a global index below the block texel count).
    pub fn trace_block_texel(&self, x: usize) -> BlockTexelRays {
        let (g, gb, tracer) = (self.g, self.gb, self.tracer);
        let settings = &self.scene.settings;
        let sign = |s: u32| g.surfaces[s as usize].normal_sign;
        let sign_b = |s: u32| gb.surfaces[s as usize].normal_sign;
        let rays = settings.rays_per_texel;
        let inv = 1.0 / rays as f64;
        let texel = &g.texels[x];
        let near = &self.neighbourhoods[self.block_of(x)];
        let chosen = self
            .sampler
            .guide_spheres(texel.position, texel.normal, &|s| near.holds(s));
        let cones = self.sampler.cones(texel.position, &chosen);
        let key = stream_key(settings.seed, Purpose::DrtScene, x as u64);
        let mut occluded: Vec<(u32, f64)> = Vec::new();
        let mut reflected: Vec<(u32, f64)> = Vec::new();
        let mut out = BlockTexelRays::default();
        let mut reach = ReachRecorder::default();
        for i in 0..rays {
            let (d, weight) = self.sampler.sample_with(
                &cones,
                texel.normal,
                (i as f64 + 0.5) / rays as f64,
                sobol_2d(key, i),
            );
            if weight == 0.0 {
                continue;
            }
            let w = weight * inv;
            let Some(hit) = tracer.closest(texel.position, d, f64::INFINITY, &sign) else {
                reach.add(d, f64::INFINITY);
                continue;
            };
            reach.add(d, hit.t);
            if let Seen::Clutter { texel: k, back } = classify(g, tracer, &hit) {
                out.clutter_hits += w;
                if back {
                    out.back_hits += w;
                }
                if let Some(k) = k {
                    reflected.push((k, w));
                }
                if let Some(behind) =
                    self.block_tracer
                        .closest(texel.position, d, f64::INFINITY, &sign_b)
                {
                    if let Seen::Block(t) = classify(gb, self.block_tracer, &behind) {
                        occluded.push((t, w));
                    }
                }
            }
        }
        out.occluded = merge(&occluded);
        out.reflected = merge(&reflected);
        if settings.scene_gather == SceneGather::Exact && out.sees_clutter(settings.tolerance) {
            let (hits, _) = self.cosine_hits(x, Purpose::DrtSceneGather, &mut reach);
            out.hits = hits;
        }
        out.reach = reach.finish();
        out
    }

    /// Cosine-weighted rays from texel `x`'s lit side on stream `purpose`: the lit texels they
    /// hit first (block texels, front faces of clutter texels) with their ray counts, ascending,
    /// and the share of rays that hit the inside of a clutter box; every segment goes to `reach`.
    fn cosine_hits(
        &self,
        x: usize,
        purpose: Purpose,
        reach: &mut ReachRecorder,
    ) -> (Vec<(u32, u32)>, f64) {
        let (g, tracer) = (self.g, self.tracer);
        let settings = &self.scene.settings;
        let sign = |s: u32| g.surfaces[s as usize].normal_sign;
        let rays = settings.rays_per_texel;
        let inv = 1.0 / rays as f64;
        let texel = &g.texels[x];
        let key = stream_key(settings.seed, purpose, x as u64);
        let mut seen: Vec<u32> = Vec::with_capacity(rays as usize);
        let mut back = 0.0;
        for i in 0..rays {
            let d = to_world(sample_cosine_hemisphere(sobol_2d(key, i)), texel.normal);
            let Some(hit) = tracer.closest(texel.position, d, f64::INFINITY, &sign) else {
                reach.add(d, f64::INFINITY);
                continue;
            };
            reach.add(d, hit.t);
            match classify(g, tracer, &hit) {
                Seen::Block(t) | Seen::Clutter { texel: Some(t), .. } => seen.push(t),
                Seen::Clutter { back: true, .. } => back += inv,
                _ => {}
            }
        }
        seen.sort_unstable();
        (sum_runs(seen.into_iter().map(|t| (t, 1u32))), back)
    }

    /// Traces clutter texel `x` (cosine-weighted rays from its lit side).
    pub fn trace_clutter_texel(&self, x: usize) -> ClutterTexelRays {
        let mut reach = ReachRecorder::default();
        let (hits, back) = self.cosine_hits(x, Purpose::DrtClutter, &mut reach);
        ClutterTexelRays {
            hits,
            back,
            reach: reach.finish(),
        }
    }
}

/// Both passes' results: the block texels' per block, the clutter texels' in global order.
pub struct RayPassResults {
    /// Per block, one per texel of the block in order (so the rows of each block can consume
    /// its own rays and free them as they go).
    pub block: Vec<Vec<BlockTexelRays>>,
    /// One per clutter texel, in global order (starting at the first clutter texel).
    pub clutter: Vec<ClutterTexelRays>,
    pub traced_texels: usize,
    pub reused_texels: usize,
    /// Block texels that cannot see any clutter (`sight`): not traced.
    pub culled_texels: usize,
}

/// What one unit did with its texels.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UnitCounts {
    /// Texels whose rays were traced.
    pub traced: usize,
    /// Texels whose rays an earlier bake's cache gave.
    pub reused: usize,
    /// Block texels that cannot see any clutter: not traced, and nothing seen.
    pub culled: usize,
}

/// How cached texel indices map into the new scene, and what changed.
struct Changes {
    /// Bounds of every object that is not in both scenes (old and new versions).
    changed: Vec<Bounds>,
    /// Per old object: its old texel range and new texel offset (None: changed).
    old_objects: Vec<(u32, u32, Option<u32>)>,
    margin: f64,
}

impl Changes {
    fn between(
        old: &[(ClutterShape, u32, u32)],
        new: &[(ClutterShape, u32, u32)],
        scale: f64,
    ) -> Changes {
        let mut taken = vec![false; new.len()];
        let mut old_objects = Vec::with_capacity(old.len());
        let mut changed = Vec::new();
        for (shape, start, count) in old {
            let found = new.iter().enumerate().position(|(i, (s, _, c))| {
                !taken[i] && s.fingerprint == shape.fingerprint && c == count
            });
            match found {
                Some(i) => {
                    taken[i] = true;
                    old_objects.push((*start, *count, Some(new[i].1)));
                }
                None => {
                    changed.push(shape.bounds);
                    old_objects.push((*start, *count, None));
                }
            }
        }
        for (i, (shape, _, _)) in new.iter().enumerate() {
            if !taken[i] {
                changed.push(shape.bounds);
            }
        }
        Changes {
            changed,
            old_objects,
            margin: 1e-6 * scale.max(1.0),
        }
    }

    /// True when no ray segment from `origin` recorded in `reach` can meet a changed object.
    fn untouched(&self, origin: [f64; 3], reach: &RayReach) -> bool {
        self.changed
            .iter()
            .all(|b| !reach.meets(origin, b, self.margin))
    }

    /// A cached global texel index in the new scene (block texels are unchanged; clutter
    /// texels move with their object's offset). None: the object changed.
    fn remap(&self, t: u32, first_clutter_texel: u32) -> Option<u32> {
        if t < first_clutter_texel {
            return Some(t);
        }
        self.old_objects
            .iter()
            .find(|(start, count, _)| t >= *start && t < start + count)
            .and_then(|(start, _, new)| new.map(|n| n + (t - start)))
    }

    /// [`Changes::remap`] of every texel of a cached hit list; None if one's object changed.
    fn remap_list<W: Copy>(
        &self,
        list: &[(u32, W)],
        first_clutter_texel: u32,
    ) -> Option<Vec<(u32, W)>> {
        list.iter()
            .map(|&(t, w)| self.remap(t, first_clutter_texel).map(|t| (t, w)))
            .collect()
    }
}

/// The current scene's clutter as units record it: (shape, texel offset, texel count).
fn clutter_list(g: &Geometry) -> Vec<(ClutterShape, u32, u32)> {
    g.clutter_shapes
        .iter()
        .zip(&g.clutter_texels)
        .map(|(s, r)| (*s, r.start as u32, r.len() as u32))
        .collect()
}

/// Traces (in parallel) every texel a unit could not reuse; returns all texels in order and
/// how many were traced.
fn trace_missing<T: Send>(
    mut texels: Vec<Option<T>>,
    trace: impl Fn(usize) -> T + Sync,
    progress: &(dyn Fn(u64) + Sync),
) -> (Vec<T>, usize) {
    let todo: Vec<usize> = (0..texels.len()).filter(|i| texels[*i].is_none()).collect();
    let traced: Vec<T> = todo
        .par_iter()
        .map(|&i| {
            let r = trace(i);
            progress(1);
            r
        })
        .collect();
    for (i, r) in todo.iter().zip(traced) {
        texels[*i] = Some(r);
    }
    let all = texels
        .into_iter()
        .map(|r| r.expect("every texel is reused or traced"))
        .collect();
    (all, todo.len())
}

/// Block `b`'s ray unit: its texels' rays, reusing what `cache` holds from an earlier bake and
/// storing the unit. Texels that cannot see any clutter ([`ClutterSight`]) are neither
/// traced nor looked up: their rays would see no clutter, which is all the delta operators
/// read; their reach is "everywhere", so a later bake never reuses them.
pub fn trace_block_unit(
    pass: &RayPass,
    b: usize,
    cache: Option<&DrtRayCache>,
    progress: &(dyn Fn(u64) + Sync),
) -> std::io::Result<(Vec<BlockTexelRays>, UnitCounts)> {
    let g = pass.g;
    let range = g.block_texels[b].clone();
    let first_clutter = pass.gb.texels.len() as u32;
    let new_clutter = clutter_list(g);
    let key = pass.block_unit_key(b);
    let mut texels: Vec<Option<BlockTexelRays>> = vec![None; range.len()];
    let mut counts = UnitCounts::default();
    // Texels out of clutter's sight: block, then face, then texel centre.
    let sees = pass.sight.block_faces(b);
    let in_sight: Vec<bool> = range
        .clone()
        .into_par_iter()
        .map(|x| {
            let texel = &g.texels[x];
            match g.surfaces[texel.surface as usize].owner {
                SurfaceOwner::Block { face, .. } => {
                    let goals = &sees[face.index()];
                    !goals.is_empty() && pass.sight.texel_sees(b, face, texel.position, goals)
                }
                _ => true,
            }
        })
        .collect();
    for (slot, seen) in texels.iter_mut().zip(in_sight) {
        if !seen {
            *slot = Some(BlockTexelRays {
                reach: RayReach::everywhere(),
                ..BlockTexelRays::default()
            });
            counts.culled += 1;
        }
    }
    if let Some(old) = cache.and_then(|c| c.get_block(&key, range.len())) {
        let changes = Changes::between(&old.clutter, &new_clutter, pass.scale);
        for ((x, slot), cached) in range.clone().zip(texels.iter_mut()).zip(old.texels) {
            if slot.is_some()
                || !changes.untouched(g.texels[x].position, &cached.reach)
                || pass.guide(x, &old.spheres) != pass.guide(x, &pass.sampler.spheres)
            {
                continue;
            }
            let reflected = changes.remap_list(&cached.reflected, first_clutter);
            let hits = changes.remap_list(&cached.hits, first_clutter);
            if let (Some(reflected), Some(hits)) = (reflected, hits) {
                *slot = Some(BlockTexelRays {
                    reflected,
                    hits,
                    ..cached
                });
                counts.reused += 1;
            }
        }
    }
    progress((counts.reused + counts.culled) as u64);
    let (texels, traced) = trace_missing(
        texels,
        |i| pass.trace_block_texel(range.start + i),
        progress,
    );
    counts.traced = traced;
    if let Some(cache) = cache {
        cache.put_block(
            &key,
            &Unit {
                spheres: pass.sampler.spheres.clone(),
                clutter: new_clutter,
                texels: texels.clone(),
            },
        )?;
    }
    Ok((texels, counts))
}

/// Clutter object `c`'s ray unit (like [`trace_block_unit`]); box and mesh clutter alike.
pub fn trace_clutter_unit(
    pass: &RayPass,
    c: usize,
    cache: Option<&DrtRayCache>,
    progress: &(dyn Fn(u64) + Sync),
) -> std::io::Result<(Vec<ClutterTexelRays>, UnitCounts)> {
    let g = pass.g;
    let range = g.clutter_texels[c].clone();
    if range.is_empty() {
        return Ok((Vec::new(), UnitCounts::default()));
    }
    let first_clutter = pass.gb.texels.len() as u32;
    let new_clutter = clutter_list(g);
    let key = pass.clutter_unit_key(c);
    let mut texels: Vec<Option<ClutterTexelRays>> = vec![None; range.len()];
    let mut reused = 0;
    if let Some(old) = cache.and_then(|cache| cache.get_clutter(&key, range.len())) {
        let changes = Changes::between(&old.clutter, &new_clutter, pass.scale);
        for ((x, slot), cached) in range.clone().zip(texels.iter_mut()).zip(old.texels) {
            if !changes.untouched(g.texels[x].position, &cached.reach) {
                continue;
            }
            if let Some(hits) = changes.remap_list(&cached.hits, first_clutter) {
                *slot = Some(ClutterTexelRays { hits, ..cached });
                reused += 1;
            }
        }
    }
    progress(reused as u64);
    let (texels, traced) = trace_missing(
        texels,
        |i| pass.trace_clutter_texel(range.start + i),
        progress,
    );
    if let Some(cache) = cache {
        cache.put_clutter(
            &key,
            &Unit {
                spheres: Vec::new(),
                clutter: new_clutter,
                texels: texels.clone(),
            },
        )?;
    }
    Ok((
        texels,
        UnitCounts {
            traced,
            reused,
            culled: 0,
        },
    ))
}

/// Runs both passes, reusing what `cache` holds and storing the new units. Units run side by
/// side as well as their texels (a unit's lookup, reuse test and store are sequential, and
/// would leave a core idle), and are taken in order.
pub fn trace_all(
    pass: &RayPass,
    cache: Option<&DrtRayCache>,
    progress: &(dyn Fn(u64) + Sync),
) -> std::io::Result<RayPassResults> {
    type Units<T> = std::io::Result<Vec<(Vec<T>, UnitCounts)>>;
    let (blocks, clutter): (Units<BlockTexelRays>, Units<ClutterTexelRays>) = rayon::join(
        || {
            (0..pass.scene.blocks.len())
                .into_par_iter()
                .map(|b| trace_block_unit(pass, b, cache, progress))
                .collect()
        },
        || {
            (0..pass.scene.clutter.len())
                .into_par_iter()
                .map(|c| trace_clutter_unit(pass, c, cache, progress))
                .collect()
        },
    );
    let (blocks, clutter) = (blocks?, clutter?);
    let mut total = UnitCounts::default();
    let counts = blocks.iter().map(|(_, c)| c);
    for c in counts.chain(clutter.iter().map(|(_, c)| c)) {
        total.traced += c.traced;
        total.reused += c.reused;
        total.culled += c.culled;
    }
    Ok(RayPassResults {
        block: blocks.into_iter().map(|(t, _)| t).collect(),
        clutter: clutter.into_iter().flat_map(|(t, _)| t).collect(),
        traced_texels: total.traced,
        reused_texels: total.reused,
        culled_texels: total.culled,
    })
}

impl RayPass<'_> {
    fn block_unit_key(&self, b: usize) -> String {
        unit_key(
            &blocks_fingerprint(self.scene),
            self.scene,
            "block",
            b,
            self.g.block_texels[b].start,
            None,
        )
    }

    fn clutter_unit_key(&self, c: usize) -> String {
        unit_key(
            &blocks_fingerprint(self.scene),
            self.scene,
            "clutter",
            c,
            self.g.clutter_texels[c].start,
            Some(&self.g.clutter_shapes[c]),
        )
    }

    /// The level's geometry (clutter included) the pass traces.
    pub fn geometry(&self) -> &Geometry {
        self.g
    }

    /// Texels in block `b`'s ray unit.
    pub fn block_texel_count(&self, b: usize) -> usize {
        self.g.block_texels[b].len()
    }

    /// Texels in clutter object `c`'s ray unit.
    pub fn clutter_texel_count(&self, c: usize) -> usize {
        self.g.clutter_texels[c].len()
    }

    /// The cache file (relative to the operator cache directory) of block `b`'s ray unit.
    pub fn block_unit_file(&self, b: usize) -> PathBuf {
        crate::bake::cache::drt_rays::ENTRY.relative_path(&self.block_unit_key(b))
    }

    /// The cache file of clutter object `c`'s ray unit (None for an object without texels).
    pub fn clutter_unit_file(&self, c: usize) -> Option<PathBuf> {
        (!self.g.clutter_texels[c].is_empty())
            .then(|| crate::bake::cache::drt_rays::ENTRY.relative_path(&self.clutter_unit_key(c)))
    }
}

/// blake3 of every block's box and open faces: what the blocks-only geometry is built from.
fn blocks_fingerprint(scene: &Scene) -> [u8; 32] {
    let mut h = blake3::Hasher::new();
    for b in &scene.blocks {
        for x in b.min.iter().chain(&b.max) {
            h.update(&x.to_bits().to_le_bytes());
        }
        for f in b.closed_faces() {
            h.update(&[f.index() as u8]);
        }
        h.update(&[0xff]);
    }
    *h.finalize().as_bytes()
}

/// The key of one unit: everything its rays' streams depend on besides the clutter.
fn unit_key(
    blocks: &[u8; 32],
    scene: &Scene,
    kind: &str,
    index: usize,
    texel_start: usize,
    shape: Option<&ClutterShape>,
) -> String {
    let s = &scene.settings;
    let mut h = blake3::Hasher::new();
    h.update(CODE_VERSION.as_bytes());
    h.update(kind.as_bytes());
    h.update(blocks);
    h.update(&s.texels_per_face.to_le_bytes());
    h.update(&s.rays_per_texel.to_le_bytes());
    h.update(&s.seed.to_le_bytes());
    h.update(&s.clutter_importance.to_bits().to_le_bytes());
    // Block units with `scene_gather: exact` also hold cosine hits (and the setting decides
    // which texels trace them with the tolerance).
    if kind == "block" && s.scene_gather == SceneGather::Exact {
        h.update(b"scene-gather-exact");
        h.update(&s.tolerance.to_bits().to_le_bytes());
    }
    h.update(&(index as u64).to_le_bytes());
    h.update(&(texel_start as u64).to_le_bytes());
    if let Some(shape) = shape {
        h.update(&shape.fingerprint);
    }
    h.finalize().to_hex().to_string()
}

/// True when the segment `a → b` meets the box grown by `margin` (slab test).
fn segment_meets(a: [f64; 3], b: [f64; 3], bounds: &Bounds, margin: f64) -> bool {
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for k in 0..3 {
        let (lo, hi) = (bounds[0][k] - margin, bounds[1][k] + margin);
        let d = b[k] - a[k];
        if d.abs() < 1e-300 {
            if a[k] < lo || a[k] > hi {
                return false;
            }
            continue;
        }
        let (s0, s1) = ((lo - a[k]) / d, (hi - a[k]) / d);
        t0 = t0.max(s0.min(s1));
        t1 = t1.min(s0.max(s1));
        if t0 > t1 {
            return false;
        }
    }
    true
}

/// Clutter object `c`'s lighting-prior basis (`clutter_basis` with `settings.clutter_basis:
/// prior`), reused from `cache` when no changed clutter object meets a shadow segment from one
/// of its prior lights to one of its texels that the light faces — then every shadow ray, so
/// the pattern matrix and its SVD, is the same; otherwise `compute`d and stored.
pub fn clutter_basis_unit(
    scene: &Scene,
    g: &Geometry,
    c: usize,
    lights: &[[f64; 3]],
    cache: Option<&DrtRayCache>,
    compute: impl FnOnce() -> Result<ClutterBasisOps, LowRankError>,
) -> Result<ClutterBasisOps, DrtError> {
    let Some(cache) = cache else {
        return Ok(compute()?);
    };
    let s = &scene.settings;
    let range = g.clutter_texels[c].clone();
    let mut h = blake3::Hasher::new();
    h.update(
        unit_key(
            &blocks_fingerprint(scene),
            scene,
            "basis",
            c,
            range.start,
            Some(&g.clutter_shapes[c]),
        )
        .as_bytes(),
    );
    h.update(&s.prior_lights.to_le_bytes());
    h.update(&s.tolerance.to_bits().to_le_bytes());
    for x in lights.iter().flatten() {
        h.update(&x.to_bits().to_le_bytes());
    }
    let key = h.finalize().to_hex().to_string();
    let new_clutter = clutter_list(g);
    if let Some((old_clutter, basis)) = cache.get_basis(&key) {
        let scale = g.scale();
        let changes = Changes::between(&old_clutter, &new_clutter, scale);
        let min_r2 = (1e-3 * scale).powi(2);
        let shadows_same = range.clone().all(|t| {
            let texel = &g.texels[t];
            lights.iter().all(|l| {
                unshadowed_pattern(texel, *l, min_r2) <= 0.0
                    || changes
                        .changed
                        .iter()
                        .all(|b| !segment_meets(texel.position, *l, b, changes.margin))
            })
        });
        if shadows_same && basis.basis.nrows() == range.len() {
            return Ok(basis);
        }
    }
    let basis = compute()?;
    cache.put_basis(&key, &new_clutter, &basis)?;
    Ok(basis)
}
