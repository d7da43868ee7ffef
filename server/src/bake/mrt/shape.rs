//! Scene-independent operators of one shape (MRT): a box with a set of open faces and given
//! extents, baked once and reused by every block that instances it.
//!
//! Per shape, in its local frame (block spans `[0, extent]`), all albedo-free, f64:
//! - `F` (texels × texels): one-bounce gather, `F[x,t]` = fraction of x's cosine rays hitting t.
//! - `In_o` (texels × LF): the same rays leaving through opening `o`, binned into the incoming
//!   lightfield; rows of `F` plus all `In_o` sum to exactly 1 (energy bookkeeping).
//! - `Out_o` (LF × texels): outgoing lightfield at `o` from texel radiance; `Pass_{o'→o}`
//!   (LF × LF, sparse): incoming lightfield at `o'` that flies straight out through `o`.
//! - Prior `P` (texels × n) and `S` (n) from [`crate::bake::mrt::lighting_prior`].
//! - `M = [F; Out] P S = U Σ Vᵀ`, truncated to rank r by the tolerance (ours: the outgoing
//!   lightfield rows make the rank keep what neighbours need through a lightfield transport;
//!   for a traced transport, the default, `Out`'s rows averaged over directions per cell:
//!   `ShapeSpec::lightfield_rows`, `exit_rows`).
//!   `L_imp = P S V_r` (texels × r), `U_b = F L_imp` (texels × r), `T_d→b = V_rᵀ S⁻¹ Pᵀ` (r × texels);
//!   then (ours, [`crate::bake::mrt::flux`]) the coefficients are turned so that the first
//!   alone carries the rebuilt light's flux, which the bundle's 8-bit `T_d→b` then keeps.
//! - Per opening: `In_o ≈ U_r,o W_o` truncated to q (U_r: texels × q, W: q × LF) and
//!   `OutImp_o = Out_o L_imp` (LF × r).
//!
//! Runtime (paper 001): `l_ind = ρ ⊙ (U_b b + Σ_o U_r,o r_o)`, `b = T_d→b l_d`.

use std::time::Instant;

use faer::Mat;
use rayon::prelude::*;

use lightfarm_proto::box_symmetry::BoxSymmetry;
use lightfarm_proto::scene::{Aabb, Settings, Transport};
use lightfarm_proto::wire::{Reader, WireError, Writer};
use lightfarm_proto::Face;

use crate::bake::math::low_rank::{truncated_svd, LowRankError};
use crate::bake::math::matrix::{narrow, widen};
use crate::bake::math::sampling::{
    sample_cosine_hemisphere, sobol_2d, stream_key, to_world, Purpose,
};
use crate::bake::mrt::flux::flux_first;
use crate::bake::mrt::lightfield::LightfieldFrame;
use crate::bake::mrt::lighting_prior::{build_prior, prior_light_positions};
use crate::bake::scene::geometry::{Geometry, Primitive};
use crate::bake::tracer::Tracer;

/// Bump when operator math changes: it is part of every cache key.
pub const SHAPE_CODE_VERSION: &str = "shape-ops/6";

/// What identifies a shape's operators.
#[derive(Clone, Debug, PartialEq)]
pub struct ShapeSpec {
    pub extent: [f64; 3],
    /// Open faces, canonical order.
    pub open: Vec<Face>,
    pub texels_per_face: usize,
    pub rays_per_texel: u32,
    pub tolerance: f64,
    pub lightfield_cells: usize,
    pub lightfield_directions: usize,
    pub prior_lights: usize,
    pub seed: u64,
    /// Light region clipped to the block, local frame (None: the whole block).
    pub light_region: Option<Aabb>,
    /// True when the scene has light regions and none reaches this block.
    pub no_light_inside: bool,
    /// Which rows of what leaves through the openings `M` keeps besides `F` (see
    /// [`exit_rows`]): the outgoing lightfields themselves (`Out` rows) when a lightfield
    /// transport will read them, else, for a traced transport (which reads the implicit lights
    /// `L_imp` at the texels its rays hit), the light leaving each cell of each opening averaged
    /// over its directions. Full `Out` rows for a traced transport cost bytes for nothing: on the
    /// maze at 16 texels per face DRT's all-bounce error was 0.0250 with them against 0.0235
    /// with `F` alone, the bundle 5.55 against 4.28 MB (2026-11-28); with the exit rows the
    /// bundle stays 4.28 MB.
    pub lightfield_rows: bool,
}

impl ShapeSpec {
    /// The spec of a block of a scene.
    pub fn for_block(
        block_aabb: &Aabb,
        open: &[Face],
        settings: &Settings,
        regions: &[Aabb],
    ) -> ShapeSpec {
        let extent = block_aabb.extent();
        let mut open: Vec<Face> = open.to_vec();
        open.sort();
        let (light_region, no_light_inside) = if regions.is_empty() {
            (None, false)
        } else {
            // Union of regions approximated by their bounding box within the block.
            let clipped: Vec<Aabb> = regions
                .iter()
                .filter_map(|r| r.intersection(block_aabb))
                .collect();
            if clipped.is_empty() {
                (None, true)
            } else {
                let mut u = clipped[0];
                for c in &clipped[1..] {
                    for k in 0..3 {
                        u.min[k] = u.min[k].min(c.min[k]);
                        u.max[k] = u.max[k].max(c.max[k]);
                    }
                }
                let local = Aabb {
                    min: [
                        u.min[0] - block_aabb.min[0],
                        u.min[1] - block_aabb.min[1],
                        u.min[2] - block_aabb.min[2],
                    ],
                    max: [
                        u.max[0] - block_aabb.min[0],
                        u.max[1] - block_aabb.min[1],
                        u.max[2] - block_aabb.min[2],
                    ],
                };
                if local.min == [0.0; 3] && local.max == extent {
                    (None, false)
                } else {
                    (Some(local), false)
                }
            }
        };
        ShapeSpec {
            extent,
            open,
            texels_per_face: settings.texels_per_face as usize,
            rays_per_texel: settings.rays_per_texel,
            tolerance: settings.tolerance,
            lightfield_cells: settings.lightfield_cells as usize,
            lightfield_directions: settings.lightfield_directions as usize,
            prior_lights: settings.prior_lights as usize,
            seed: settings.seed,
            light_region,
            no_light_inside,
            lightfield_rows: settings.transport == Transport::Lightfield,
        }
    }

    /// The same shape seen in the frame `g` takes this one's to: extents permuted, open faces
    /// and the light region mapped (`lightfarm_proto::box_symmetry`).
    pub fn transformed(&self, g: BoxSymmetry) -> ShapeSpec {
        let mut open: Vec<Face> = self.open.iter().map(|f| g.map_face(*f)).collect();
        open.sort();
        let light_region = self.light_region.map(|r| {
            let a = g.map_point(r.min, self.extent);
            let b = g.map_point(r.max, self.extent);
            Aabb {
                min: [a[0].min(b[0]), a[1].min(b[1]), a[2].min(b[2])],
                max: [a[0].max(b[0]), a[1].max(b[1]), a[2].max(b[2])],
            }
        });
        ShapeSpec {
            extent: g.map_extent(self.extent),
            open,
            light_region,
            ..self.clone()
        }
    }

    /// The canonical member of this shape's orbit under the 48 box symmetries and the symmetry
    /// taking this shape's frame to it. Blocks that are rotations or mirror images of one
    /// another get the same canonical spec, so their operators are baked, cached and shipped
    /// once (`crate::bake::mrt::shape_symmetry`).
    ///
    /// The choice depends on the shape's form, never on its size: the orbit member with the
    /// smallest `ShapeSpec::form` (how the extents compare, which faces are open, the light
    /// region relative to the extents), the first symmetry in code order on ties. A level
    /// scaled by any factor picks the same orientation, so its operators scale with it.
    pub fn canonical(&self) -> (ShapeSpec, BoxSymmetry) {
        let mut best: Option<(Form, ShapeSpec, BoxSymmetry)> = None;
        for g in BoxSymmetry::all() {
            let spec = self.transformed(g);
            let form = spec.form();
            if best.as_ref().is_none_or(|(f, _, _)| form.precedes(f)) {
                best = Some((form, spec, g));
            }
        }
        let (_, spec, g) = best.expect("48 symmetries");
        (spec, g)
    }

    /// What orders the members of an orbit, free of the shape's scale.
    fn form(&self) -> Form {
        let e = self.extent;
        let order = [
            compare_lengths(e[0], e[1]),
            compare_lengths(e[0], e[2]),
            compare_lengths(e[1], e[2]),
        ];
        let open = self.open.iter().fold(0u8, |m, f| m | 1 << f.index());
        let region = self.light_region.map(|r| {
            let mut v = [0.0; 6];
            for k in 0..3 {
                v[k] = r.min[k] / e[k];
                v[3 + k] = r.max[k] / e[k];
            }
            v
        });
        Form {
            order,
            open,
            region,
        }
    }

    /// Content key: a hash of everything the operators depend on, and the code version.
    pub fn key(&self) -> String {
        let mut h = blake3::Hasher::new();
        let text = format!(
            "{SHAPE_CODE_VERSION}|extent={:?}|open={:?}|t={}|rays={}|tol={:?}|lf={}x{}|prior={}|seed={}|region={:?}|dark={}|lfrows={}",
            self.extent.map(f64::to_bits),
            self.open.iter().map(|f| f.name()).collect::<Vec<_>>(),
            self.texels_per_face,
            self.rays_per_texel,
            self.tolerance.to_bits(),
            self.lightfield_cells,
            self.lightfield_directions,
            self.prior_lights,
            self.seed,
            self.light_region.map(|r| (r.min.map(f64::to_bits), r.max.map(f64::to_bits))),
            self.no_light_inside,
            self.lightfield_rows,
        );
        h.update(text.as_bytes());
        h.finalize().to_hex()[..32].to_string()
    }

    /// Texels of the shape: `T²` per closed face.
    pub fn n_texels(&self) -> usize {
        (6 - self.open.len()) * self.texels_per_face * self.texels_per_face
    }

    pub fn closed(&self) -> Vec<Face> {
        Face::ALL
            .into_iter()
            .filter(|f| !self.open.contains(f))
            .collect()
    }

    /// The lone shape's geometry (local frame, albedo-free).
    pub fn geometry(&self) -> Geometry {
        let mut g = Geometry::default();
        let aabb = Aabb {
            min: [0.0; 3],
            max: self.extent,
        };
        g.add_block(
            0,
            "shape",
            &aabb,
            &self.closed(),
            |_| [1.0; 3],
            self.texels_per_face,
        );
        g
    }

    /// The lightfield frame on opening `face` for light travelling out of (`outgoing`) or into
    /// the shape.
    pub fn frame(&self, face: Face, outgoing: bool) -> LightfieldFrame {
        let aabb = Aabb {
            min: [0.0; 3],
            max: self.extent,
        };
        let (min, max, coord) = aabb.face_rect(face);
        let out_sign = if face.is_max_side() { 1.0 } else { -1.0 };
        LightfieldFrame {
            axis: face.axis(),
            sign: if outgoing { out_sign } else { -out_sign },
            coord,
            min,
            max,
            cells: self.lightfield_cells,
            dirs: self.lightfield_directions,
        }
    }
}

/// Orders two lengths, equal within a relative 1e-9: extents computed as `max − min` at
/// another scale round differently (`7s − 4s` vs `3s`), and the canonical orientation must not
/// change with them.
fn compare_lengths(a: f64, b: f64) -> std::cmp::Ordering {
    if (a - b).abs() <= 1e-9 * a.abs().max(b.abs()) {
        std::cmp::Ordering::Equal
    } else {
        a.total_cmp(&b)
    }
}

/// A shape's form for choosing the canonical orientation ([`ShapeSpec::canonical`]).
struct Form {
    order: [std::cmp::Ordering; 3],
    open: u8,
    region: Option<[f64; 6]>,
}

impl Form {
    fn precedes(&self, other: &Form) -> bool {
        let region = |f: &Form| f.region.map_or([f64::NEG_INFINITY; 6], |r| r);
        let (a, b) = (region(self), region(other));
        let regions = a
            .iter()
            .zip(&b)
            .map(|(x, y)| compare_lengths(*x, *y))
            .find(|o| o.is_ne())
            .unwrap_or(std::cmp::Ordering::Equal);
        (self.order, self.open)
            .cmp(&(other.order, other.open))
            .then(regions)
            .is_lt()
    }
}

/// A sparse matrix as (row, col, value) triplets.
pub type Triplets = Vec<(u32, u32, f64)>;

/// Operators of one opening.
#[derive(Clone, Debug)]
pub struct OpeningOperators {
    pub face: Face,
    /// texels × q.
    pub u_r: Mat<f64>,
    /// Incoming lightfield at `from` → outgoing lightfield here (LF × LF); empty on a symmetry
    /// instance (the propagation reads `shape_symmetry::instance_passes`).
    pub pass_from: Vec<(Face, Triplets)>,
    /// `OutImp` and `W`, which only the lightfield propagation reads: present on a shape as
    /// baked or cached, never on a symmetry instance (made on use from the canonical shape's:
    /// `shape_symmetry::InstanceLightfield`). A bake takes them out
    /// ([`ShapeOperators::take_lightfields`]) and drops them once the transport is built: they
    /// are two thirds of a shape's bytes.
    pub lightfield: Option<OpeningLightfield>,
}

/// The lightfield side of one opening, held in f32 (computed in f64, and widened again for
/// the propagation's products): two thirds of a shape's bytes, and at 1,000 blocks the
/// largest thing a bake holds while it propagates; f32's rounding (6e-8 relative) is far below
/// the shape's truncation (`tolerance` of the energy). The shape cache stores them in f64
/// (the f32 values exactly), so a cached shape reads back the same bits.
#[derive(Clone, Debug)]
pub struct OpeningLightfield {
    /// LF × r: outgoing lightfield from the shape's implicit lights.
    pub out_imp: Mat<f32>,
    /// q × LF: incoming lightfield → the q coefficients `U_r` expands.
    pub w: Mat<f32>,
}

/// A shape's openings' lightfields, by face (what [`ShapeOperators::take_lightfields`] takes).
pub type ShapeLightfields = Vec<(Face, OpeningLightfield)>;

/// Figures about a bake of one shape.
#[derive(Clone, Debug, Default)]
pub struct ShapeStats {
    pub prior_rank: usize,
    pub rank: usize,
    pub dropped_energy: f64,
    pub seconds: f64,
}

/// All scene-independent operators of a shape.
#[derive(Clone, Debug)]
pub struct ShapeOperators {
    pub key: String,
    /// texels × r.
    pub u_b: Mat<f64>,
    /// r × texels; empty (0 × 0) on a symmetry instance, whose `T_d→b` no stage reads
    /// (`shape_symmetry::instance_operators`).
    pub t_db: Mat<f64>,
    /// texels × r.
    pub l_imp: Mat<f64>,
    pub openings: Vec<OpeningOperators>,
    pub stats: ShapeStats,
}

impl ShapeOperators {
    pub fn n_texels(&self) -> usize {
        self.u_b.nrows()
    }
    pub fn rank(&self) -> usize {
        self.u_b.ncols()
    }
    pub fn opening(&self, face: Face) -> Option<&OpeningOperators> {
        self.openings.iter().find(|o| o.face == face)
    }
    /// Takes the openings' lightfields out (those that have one), leaving `None`.
    pub fn take_lightfields(&mut self) -> ShapeLightfields {
        self.openings
            .iter_mut()
            .filter_map(|o| o.lightfield.take().map(|l| (o.face, l)))
            .collect()
    }
}

/// Why a shape could not be baked.
#[derive(Debug, thiserror::Error)]
pub enum ShapeError {
    #[error("shape {key}: {source}")]
    LowRank { key: String, source: LowRankError },
}

/// The box face a ray from inside leaves through, and where.
pub fn box_exit(o: [f64; 3], d: [f64; 3], extent: [f64; 3]) -> (Face, [f64; 3]) {
    let mut best = (f64::INFINITY, Face::PosX);
    for face in Face::ALL {
        let a = face.axis();
        let leaving = if face.is_max_side() {
            d[a] > 0.0
        } else {
            d[a] < 0.0
        };
        if !leaving {
            continue;
        }
        let plane = if face.is_max_side() { extent[a] } else { 0.0 };
        let s = (plane - o[a]) / d[a];
        if s < best.0 {
            best = (s, face);
        }
    }
    let s = best.0.max(0.0);
    (best.1, [o[0] + s * d[0], o[1] + s * d[1], o[2] + s * d[2]])
}

fn lit_sign(g: &Geometry) -> impl Fn(u32) -> f64 + '_ {
    move |s| g.surfaces[s as usize].normal_sign
}

/// The texel a hit lands on (front side of a lightmapped rectangle), if any.
pub fn hit_texel(g: &Geometry, tracer: &Tracer, hit: &crate::bake::tracer::Hit) -> Option<usize> {
    if !hit.front {
        return None;
    }
    match tracer.primitives()[hit.primitive as usize] {
        Primitive::Rect {
            surface: Some(s), ..
        } => Some(g.texel_at(s, hit.point)),
        _ => None,
    }
}

/// Bakes a shape. `progress` is called with the number of finished work items (texels).
pub fn bake_shape(
    spec: &ShapeSpec,
    progress: &(dyn Fn(u64) + Sync),
) -> Result<ShapeOperators, ShapeError> {
    let start = Instant::now();
    let key = spec.key();
    let low_rank = |source| ShapeError::LowRank {
        key: key.clone(),
        source,
    };
    let g = spec.geometry();
    let tracer = Tracer::new(
        g.primitives.clone(),
        spec.extent.iter().cloned().fold(0.0, f64::max),
    );
    let n = g.texels.len();
    let rays = spec.rays_per_texel;
    let sign = lit_sign(&g);
    let in_frames: Vec<LightfieldFrame> = spec.open.iter().map(|f| spec.frame(*f, false)).collect();
    let out_frames: Vec<LightfieldFrame> = spec.open.iter().map(|f| spec.frame(*f, true)).collect();
    let lf_len = in_frames.first().map_or(0, |f| f.len());

    // F and In_o from the same cosine rays.
    type Row = (Vec<(u32, f64)>, Vec<(u8, u32)>);
    let rows: Vec<Row> = (0..n)
        .into_par_iter()
        .map(|x| {
            let texel = &g.texels[x];
            let key = stream_key(spec.seed, Purpose::ShapeGather, x as u64);
            let mut hits: Vec<(u32, f64)> = Vec::new();
            let mut exits: Vec<(u8, u32)> = Vec::new();
            for i in 0..rays {
                let d = to_world(sample_cosine_hemisphere(sobol_2d(key, i)), texel.normal);
                match tracer.closest(texel.position, d, f64::INFINITY, &sign) {
                    Some(hit) => {
                        if let Some(t) = hit_texel(&g, &tracer, &hit) {
                            hits.push((t as u32, 1.0));
                        }
                    }
                    None => {
                        let (face, p) = box_exit(texel.position, d, spec.extent);
                        if let Some(k) = spec.open.iter().position(|f| *f == face) {
                            let incoming = [-d[0], -d[1], -d[2]];
                            exits.push((k as u8, in_frames[k].index(p, incoming) as u32));
                        }
                    }
                }
            }
            progress(1);
            (hits, exits)
        })
        .collect();
    let inv = 1.0 / rays as f64;
    let mut f = Mat::<f64>::zeros(n, n);
    let mut in_ops: Vec<Mat<f64>> = spec.open.iter().map(|_| Mat::zeros(n, lf_len)).collect();
    for (x, (hits, exits)) in rows.iter().enumerate() {
        for (t, w) in hits {
            f[(x, *t as usize)] += w * inv;
        }
        for (k, idx) in exits {
            in_ops[*k as usize][(x, *idx as usize)] += inv;
        }
    }

    // Out_o and Pass: rays from each lightfield cell/bin back into the shape.
    let samples = (rays / 16).clamp(16, 256);
    let mut out_ops: Vec<Mat<f64>> = Vec::new();
    let mut passes: Vec<Vec<(Face, Triplets)>> = Vec::new();
    for (k, frame) in out_frames.iter().enumerate() {
        let entries: Vec<(Vec<(u32, f64)>, Vec<(u8, u32)>)> = (0..lf_len)
            .into_par_iter()
            .map(|idx| {
                let key = stream_key(
                    spec.seed,
                    Purpose::ShapeLightfield,
                    (k * lf_len + idx) as u64,
                );
                let mut hits = Vec::new();
                let mut through = Vec::new();
                for i in 0..samples {
                    let (p, w) = frame.sample(idx, sobol_2d(key, i), sobol_2d(key ^ 0x5bd1e995, i));
                    let back = [-w[0], -w[1], -w[2]];
                    match tracer.closest(p, back, f64::INFINITY, &sign) {
                        Some(hit) => {
                            if let Some(t) = hit_texel(&g, &tracer, &hit) {
                                hits.push((t as u32, 1.0));
                            }
                        }
                        None => {
                            let (face, q) = box_exit(p, back, spec.extent);
                            if let Some(j) = spec.open.iter().position(|f| *f == face) {
                                if j != k {
                                    through.push((j as u8, in_frames[j].index(q, w) as u32));
                                }
                            }
                        }
                    }
                }
                (hits, through)
            })
            .collect();
        let inv_s = 1.0 / samples as f64;
        let mut out = Mat::<f64>::zeros(lf_len, n);
        let mut pass: Vec<(Face, std::collections::BTreeMap<(u32, u32), f64>)> =
            spec.open.iter().map(|f| (*f, Default::default())).collect();
        for (idx, (hits, through)) in entries.iter().enumerate() {
            for (t, w) in hits {
                out[(idx, *t as usize)] += w * inv_s;
            }
            for (j, col) in through {
                *pass[*j as usize].1.entry((idx as u32, *col)).or_insert(0.0) += inv_s;
            }
        }
        out_ops.push(out);
        passes.push(
            pass.into_iter()
                .filter(|(_, m)| !m.is_empty())
                .map(|(face, m)| (face, m.into_iter().map(|((r, c), v)| (r, c, v)).collect()))
                .collect(),
        );
    }

    // Prior and the reduced operators.
    let lights = prior_light_positions(
        spec.extent,
        &spec.open,
        if spec.no_light_inside {
            Some(Aabb {
                min: [-2.0; 3],
                max: [-1.0; 3],
            })
        } else {
            spec.light_region
        },
        spec.prior_lights,
        spec.seed,
    );
    let prior =
        build_prior(&g, spec.extent, &spec.open, lights, spec.tolerance).map_err(low_rank)?;
    let p_s = Mat::from_fn(n, prior.basis.ncols(), |i, j| {
        prior.basis[(i, j)] * prior.singular_values[j]
    });
    let f_ps = &f * &p_s;
    // What leaves through the openings, so that the rank keeps the light only neighbours see
    // (`ShapeSpec::lightfield_rows`, `exit_rows`).
    let exits: Vec<Mat<f64>>;
    let out_rows: &[Mat<f64>] = if spec.lightfield_rows {
        &out_ops
    } else {
        exits = out_ops
            .iter()
            .map(|out| exit_rows(out, spec.lightfield_cells, spec.lightfield_directions))
            .collect();
        &exits
    };
    let extra: usize = out_rows.iter().map(|m| m.nrows()).sum();
    let mut m_ext = Mat::<f64>::zeros(n + extra, p_s.ncols());
    m_ext.subrows_mut(0, n).copy_from(&f_ps);
    let mut row = n;
    for out in out_rows {
        let o_ps = out * &p_s;
        m_ext.subrows_mut(row, out.nrows()).copy_from(&o_ps);
        row += out.nrows();
    }
    let svd = truncated_svd(m_ext.as_ref(), spec.tolerance).map_err(low_rank)?;
    let r = svd.s.len();
    let mut l_imp = &p_s * &svd.v; // texels × r
                                   // T_d→b = V_rᵀ S⁻¹ Pᵀ
    let v_s_inv = Mat::from_fn(r, prior.basis.ncols(), |i, j| {
        svd.v[(j, i)] / prior.singular_values[j]
    });
    let mut t_db = &v_s_inv * prior.basis.transpose();
    let area: Vec<f64> = (0..g.texels.len()).map(|x| g.texel_area(x)).collect();
    flux_first(&mut t_db, &mut l_imp, &area);
    let u_b = &f * &l_imp;

    let mut openings = Vec::new();
    for (k, face) in spec.open.iter().enumerate() {
        let reduced = truncated_svd(in_ops[k].as_ref(), spec.tolerance).map_err(low_rank)?;
        let q = reduced.s.len();
        let u_r = Mat::from_fn(n, q, |i, j| reduced.u[(i, j)] * reduced.s[j]);
        let w = reduced.v.transpose().to_owned();
        let out_imp = &out_ops[k] * &l_imp;
        openings.push(OpeningOperators {
            face: *face,
            u_r,
            pass_from: passes[k].clone(),
            lightfield: Some(OpeningLightfield {
                out_imp: narrow(&out_imp),
                w: narrow(&w),
            }),
        });
    }
    Ok(ShapeOperators {
        key,
        u_b,
        t_db,
        l_imp,
        openings,
        stats: ShapeStats {
            prior_rank: prior.basis.ncols(),
            rank: r,
            dropped_energy: svd.dropped_energy,
            seconds: start.elapsed().as_secs_f64(),
        },
    })
}

/// The weight of [`exit_rows`] against `F`'s rows in `M`: the rank they add follows their
/// share of `M`'s energy (`EXIT_WEIGHT²`). Against Mitsuba at all bounces, bundle bytes beside
/// (the levels of `tests/data/multibounce_accuracy.md`: two storeys 60 blocks, two storeys 80,
/// one storey 80), side by side on 2026-12-02: weight 1: 0.0564 / 0.0564 / 0.0486, 6.06 / 5.41 /
/// 3.42 MB; 0.25: 0.0572 / 0.0566 / 0.0480, 5.76 / 5.10 / 3.26 MB; **0.1**: 0.0594 / 0.0556 /
/// 0.0489, 5.54 / 4.89 / 3.14 MB; without exit rows: 0.1126 / 0.0912 / 0.0503, 5.45 / 4.79 /
/// 3.09 MB. A block whose `F` is zero keeps what leaves it at any weight.
const EXIT_WEIGHT: f64 = 0.1;

/// The light leaving an opening per cell of its lightfield, averaged over the cell's direction
/// bins (`cells² × texels` from `Out_o`'s `cells² · dirs² × texels`; the bins are equal in
/// projected solid angle, so the mean is the cell's cosine-weighted exitance over π), times
/// [`EXIT_WEIGHT`].
///
/// `M`'s rows for a traced transport. With `F` alone the rank keeps only the direct light a
/// block's own texels gather, and a block open on most sides loses what it sends out: a block
/// open on five faces has `F = 0` (its one closed face cannot see itself), rank 0, and carried
/// none of its light to its neighbours (a generated two-storey level's lamp in such a block
/// left the floor below it at 0.42 of the reference's light, one bounce). These rows keep
/// what leaves for less rank than `Out`'s (that level without its clutter, at weight 1: median
/// rank 47 → 61, against 109 with `Out` rows, for the same error within 0.01).
fn exit_rows(out: &Mat<f64>, cells: usize, dirs: usize) -> Mat<f64> {
    let bins = dirs * dirs;
    debug_assert_eq!(out.nrows(), cells * cells * bins);
    Mat::from_fn(cells * cells, out.ncols(), |cell, t| {
        (0..bins).map(|b| out[(cell * bins + b, t)]).sum::<f64>() / bins as f64 * EXIT_WEIGHT
    })
}

fn write_mat(w: &mut Writer, m: &Mat<f64>) {
    w.u32(m.nrows() as u32);
    w.u32(m.ncols() as u32);
    let mut flat = Vec::with_capacity(m.nrows() * m.ncols());
    for i in 0..m.nrows() {
        for j in 0..m.ncols() {
            flat.push(m[(i, j)]);
        }
    }
    w.f64s(&flat);
}

fn read_mat(r: &mut Reader) -> Result<Mat<f64>, WireError> {
    let rows = r.u32()? as usize;
    let cols = r.u32()? as usize;
    let flat = r.f64s()?;
    if flat.len() != rows * cols || flat.iter().any(|x| !x.is_finite()) {
        return Err(WireError::Invalid("matrix size or value".into()));
    }
    Ok(Mat::from_fn(rows, cols, |i, j| flat[i * cols + j]))
}

impl ShapeOperators {
    /// Serialises the operators for the operator cache, without the openings' lightfields
    /// (those are [`ShapeOperators::encode_lightfields`]'s: only a transport that is computed
    /// reads them, and they are two thirds of the bytes).
    pub fn encode(&self) -> Vec<u8> {
        let mut w = Writer::new();
        w.str(SHAPE_CODE_VERSION);
        w.str(&self.key);
        write_mat(&mut w, &self.u_b);
        write_mat(&mut w, &self.t_db);
        write_mat(&mut w, &self.l_imp);
        w.u32(self.openings.len() as u32);
        for o in &self.openings {
            w.u8(o.face.index() as u8);
            write_mat(&mut w, &o.u_r);
            w.u32(o.pass_from.len() as u32);
            for (face, triplets) in &o.pass_from {
                w.u8(face.index() as u8);
                w.u64(triplets.len() as u64);
                for (r, c, v) in triplets {
                    w.u32(*r);
                    w.u32(*c);
                    w.f64(*v);
                }
            }
        }
        w.u64(self.stats.prior_rank as u64);
        w.u64(self.stats.rank as u64);
        w.f64(self.stats.dropped_energy);
        w.f64(self.stats.seconds);
        w.bytes
    }

    /// Serialises the openings' lightfields (`OutImp`, `W`) for the operator cache.
    ///
    /// Panics on a shape without its lightfields (an instance, or one a bake has taken them
    /// from): only shapes as baked are cached.
    pub fn encode_lightfields(&self) -> Vec<u8> {
        let mut w = Writer::new();
        w.str(SHAPE_CODE_VERSION);
        w.str(&self.key);
        w.u32(self.openings.len() as u32);
        for o in &self.openings {
            let lightfield = o
                .lightfield
                .as_ref()
                .expect("only shapes as baked, with their lightfields, are cached");
            w.u8(o.face.index() as u8);
            write_mat(&mut w, &widen(&lightfield.out_imp));
            write_mat(&mut w, &widen(&lightfield.w));
        }
        w.bytes
    }

    /// Reads what [`ShapeOperators::encode`] wrote: the operators, every opening's
    /// lightfield `None`.
    pub fn decode(bytes: &[u8]) -> Result<ShapeOperators, WireError> {
        let mut r = Reader::new(bytes);
        if r.str()? != SHAPE_CODE_VERSION {
            return Err(WireError::Invalid("other code version".into()));
        }
        let key = r.str()?;
        let u_b = read_mat(&mut r)?;
        let t_db = read_mat(&mut r)?;
        let l_imp = read_mat(&mut r)?;
        let n_open = r.u32()?;
        if n_open > 6 {
            return Err(WireError::Invalid("too many openings".into()));
        }
        let mut openings = Vec::new();
        for _ in 0..n_open {
            let face = face_of(r.u8()?)?;
            let u_r = read_mat(&mut r)?;
            let n_pass = r.u32()?;
            if n_pass > 6 {
                return Err(WireError::Invalid("too many passes".into()));
            }
            let mut pass_from = Vec::new();
            for _ in 0..n_pass {
                let from = face_of(r.u8()?)?;
                let count = r.u64()?;
                if count > (r.remaining() / 16) as u64 {
                    return Err(WireError::Invalid("pass length".into()));
                }
                let mut t = Vec::with_capacity(count as usize);
                for _ in 0..count {
                    t.push((r.u32()?, r.u32()?, r.f64()?));
                }
                pass_from.push((from, t));
            }
            openings.push(OpeningOperators {
                face,
                u_r,
                pass_from,
                lightfield: None,
            });
        }
        let stats = ShapeStats {
            prior_rank: r.u64()? as usize,
            rank: r.u64()? as usize,
            dropped_energy: r.f64()?,
            seconds: r.f64()?,
        };
        if r.remaining() != 0 {
            return Err(WireError::Invalid("trailing bytes".into()));
        }
        Ok(ShapeOperators {
            key,
            u_b,
            t_db,
            l_imp,
            openings,
            stats,
        })
    }

    /// Reads what [`ShapeOperators::encode_lightfields`] wrote, for the shape `self` (its key
    /// and openings, in order): the lightfields, to give back with
    /// [`ShapeOperators::with_lightfields`].
    pub fn decode_lightfields(&self, bytes: &[u8]) -> Result<ShapeLightfields, WireError> {
        let mut r = Reader::new(bytes);
        if r.str()? != SHAPE_CODE_VERSION {
            return Err(WireError::Invalid("other code version".into()));
        }
        if r.str()? != self.key {
            return Err(WireError::Invalid("another shape's lightfields".into()));
        }
        if r.u32()? as usize != self.openings.len() {
            return Err(WireError::Invalid("opening count".into()));
        }
        let mut lightfields = Vec::with_capacity(self.openings.len());
        for o in &self.openings {
            if face_of(r.u8()?)? != o.face {
                return Err(WireError::Invalid("opening face".into()));
            }
            let out_imp = read_mat(&mut r)?;
            let w = read_mat(&mut r)?;
            if out_imp.ncols() != self.rank() || w.nrows() != o.u_r.ncols() {
                return Err(WireError::Invalid("lightfield size".into()));
            }
            // An entry written before the lightfields were held in f32 reads back as a fresh
            // bake holds them.
            lightfields.push((
                o.face,
                OpeningLightfield {
                    out_imp: narrow(&out_imp),
                    w: narrow(&w),
                },
            ));
        }
        if r.remaining() != 0 {
            return Err(WireError::Invalid("trailing bytes".into()));
        }
        Ok(lightfields)
    }

    /// The shape with `lightfields` (as [`ShapeOperators::take_lightfields`] or
    /// [`ShapeOperators::decode_lightfields`] give them) put back on its openings.
    pub fn with_lightfields(mut self, lightfields: ShapeLightfields) -> ShapeOperators {
        for (face, lightfield) in lightfields {
            if let Some(o) = self.openings.iter_mut().find(|o| o.face == face) {
                o.lightfield = Some(lightfield);
            }
        }
        self
    }
}

fn face_of(i: u8) -> Result<Face, WireError> {
    Face::ALL
        .get(i as usize)
        .copied()
        .ok_or_else(|| WireError::Invalid("face".into()))
}
