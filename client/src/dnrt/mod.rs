//! DNRT apply (paper 003 §5.2): the light a dynamic object adds to (reflection) and takes from
//! (occlusion) the receivers around it, per frame, from its baked transfer grid.
//!
//! For a receiver at `x` with unit normal `n` and albedo `ρ`:
//! `L += ρ (n_o·n)₊ · s(x) · (Σ_j c_j T_j(x) − π Σ_j l_j K_j(x))` per channel (eq. 16 with
//! reflection and occlusion apart), where `n_o` points from `x` to the object's bounding-sphere
//! centre, `c_j` are the SH coefficients of the irradiance the object reflects (world frame:
//! everything that lights it, point lights included, e.g. the engine's light probe),
//! `l_j` those of the radiance it hides (the surfaces around it, without point lights: e.g.
//! [`crate::radiance_sh_at`] on the probe field; the paper's anti-radiance `E/π` is
//! `l_j = c_j/π`), both rotated into the object's frame ([`lightfarm_proto::sh_rotation`]), and
//! `T_j`, `K_j` the grid interpolated trilinearly at `x` in the object frame. Inside the inner cube `s = 1`;
//! between the inner and the outer cube (half-sizes `E` and `E_o`, box norm `‖x − c‖∞ = r`) the
//! inner cube's value on the same ray from the centre (at `x · E/r`) is faded with the inverse
//! square of the distance, shifted to reach zero at the outer cube:
//! `s = ((E/r)² − (E/E_o)²) / (1 − (E/E_o)²)`; beyond the outer cube nothing is added.
//! With a convolution grid (Appendix A) `(n_o·n)₊ (…)` is replaced by
//! `Σ_t (Σ_j c_j T_jt − π Σ_j l_j K_jt) Y_t(n)` at the receiver's own normal (object frame).
//!
//! Frames and units: poses map the object frame to the world (`x_world = R x_obj + t`, R from
//! the pose quaternion `[x, y, z, w]`); metres; output in the radiance units of `c_j`/π and
//! `l_j`.
//!
//! Invariants: [`DnrtInstance::shade`] never panics and returns finite values for finite
//! inputs, including receivers inside the object, at its centre or exactly on a grid edge; a
//! non-finite position or a zero normal adds nothing. The grid is decoded to f32 once
//! ([`DnrtVolume::new`]); [`DnrtInstance::new`] (once per object and frame) contracts it with
//! `c_j` and `l_j` into 3 values per grid point (3 · n_sh with convolution; one or two
//! multiply-adds per stored value); applying to receivers allocates nothing. [`DnrtNear`]
//! contracts only the points the lightmap texels near the object read, the same values.
//!
//! # Layout
//! - this file: the decoded grid ([`DnrtVolume`]), a posed object under this frame's light
//!   ([`DnrtInstance`]: contraction, lookup, shading of G-buffers and lightmap texels).
//! - `near`: [`DnrtNear`], the lightmap texels near an object shaded from the grid points they
//!   read alone.

mod near;

pub use near::DnrtNear;

use std::ops::Range;

use lightfarm_proto::bundle::Layout;
use lightfarm_proto::dnrt_grid::{DnrtGrid, DnrtGridError, DnrtNormals, SLOTS};
use lightfarm_proto::sh::SH_COEFFS;
use lightfarm_proto::sh_rotation::{mul_vec, quaternion_matrix, transpose, ShRotation};

use crate::surface_bounds::SurfaceBounds;

/// Why DNRT could not be applied.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DnrtError {
    #[error(transparent)]
    Grid(#[from] DnrtGridError),
    #[error("DNRT of \"{object}\": {what} has {got} entries, expected {expected}")]
    Length {
        object: String,
        what: &'static str,
        expected: usize,
        got: usize,
    },
}

/// One object's grid, decoded for the CPU.
#[derive(Clone, Debug, PartialEq)]
pub struct DnrtVolume {
    grid: DnrtGrid,
    /// Decoded values, layout of `lightfarm_proto::dnrt_grid`.
    values: Vec<f32>,
}

impl DnrtVolume {
    /// Validates and decodes `grid`.
    pub fn new(grid: &DnrtGrid) -> Result<DnrtVolume, DnrtError> {
        grid.validate()?;
        let mut grid = grid.clone();
        let values = grid.values();
        // The decoded copy is what is sampled; drop the encoded one.
        grid.data = lightfarm_proto::dnrt_grid::DnrtData::U8(Vec::new());
        Ok(DnrtVolume { grid, values })
    }

    /// The object's id.
    pub fn object(&self) -> &str {
        &self.grid.object
    }

    /// The grid's centre (its bounding sphere's, object frame) in the world at a pose
    /// (`translation`, quaternion `rotation` `[x, y, z, w]`): what
    /// [`DnrtInstance::centre_world`] gives, without contracting the grid.
    pub fn centre_world(&self, translation: [f64; 3], rotation: [f64; 4]) -> [f32; 3] {
        let r = quaternion_matrix(rotation);
        let rc = mul_vec(&r, self.grid.centre.map(|x| x as f64));
        std::array::from_fn(|k| (rc[k] + translation[k]) as f32)
    }
}

/// One posed object with this frame's lighting, ready to shade receivers.
#[derive(Clone, Debug)]
pub struct DnrtInstance<'a> {
    volume: &'a DnrtVolume,
    /// World → object rotation (Rᵀ).
    to_object: [[f32; 3]; 3],
    centre_world: [f32; 3],
    /// Irradiance SH per channel in the object frame.
    c: [[f32; SH_COEFFS]; 3],
    /// The hidden radiance's SH per channel in the object frame, times π.
    l: [[f32; SH_COEFFS]; 3],
    /// Per grid point and channel, `Σ_j c_j t_j − π Σ_j l_j k_j` (1 value), or with
    /// convolution the same per t (n_sh values): contracted once per frame, point-major
    /// (by [`DnrtNear`] only at the points its receivers read).
    contracted: Vec<f32>,
    /// Values per channel in `contracted`.
    out_terms: usize,
    convolution: bool,
}

/// Where one receiver reads a DNRT grid ([`DnrtInstance::lookup`]).
struct Lookup {
    /// Object-frame point (grid coordinates' frame) the grid is interpolated at.
    local: [f32; 3],
    /// `(n_o·n)₊` (1 with convolution) times the fade.
    k: f32,
    /// Length of the receiver's normal.
    n_len: f32,
}

impl<'a> DnrtInstance<'a> {
    /// `volume` posed at `translation` / `rotation` (quaternion `[x, y, z, w]`) under the
    /// world-frame irradiance coefficients `irradiance` the object reflects (per channel,
    /// `E(n) = Σ c_j Y_j(n)`) and radiance coefficients `hidden` of what it hides
    /// (`L(ω) = Σ l_j Y_j(ω)`, ω the direction looked in); coefficients beyond the grid's SH
    /// count are ignored.
    pub fn new(
        volume: &'a DnrtVolume,
        translation: [f64; 3],
        rotation: [f64; 4],
        irradiance: [[f32; SH_COEFFS]; 3],
        hidden: [[f32; SH_COEFFS]; 3],
    ) -> DnrtInstance<'a> {
        let mut instance =
            DnrtInstance::uncontracted(volume, translation, rotation, irradiance, hidden);
        for p in 0..instance.n_points() {
            instance.contract_point(p);
        }
        instance
    }

    /// [`DnrtInstance::new`] with every contracted value 0 (none computed yet).
    fn uncontracted(
        volume: &'a DnrtVolume,
        translation: [f64; 3],
        rotation: [f64; 4],
        irradiance: [[f32; SH_COEFFS]; 3],
        hidden: [[f32; SH_COEFFS]; 3],
    ) -> DnrtInstance<'a> {
        let r = quaternion_matrix(rotation);
        let rt = transpose(&r);
        // Object-frame coefficients of g(ω_obj) = E(R ω_obj) = E((Rᵀ)ᵀ ω_obj).
        let sh_rotation = ShRotation::new(&rt);
        let rotate = |f: [[f32; SH_COEFFS]; 3], scale: f64| {
            f.map(|cc| {
                let mut v = cc.map(|x| x as f64 * scale);
                sh_rotation.apply(&mut v);
                v.map(|x| x as f32)
            })
        };
        let c = rotate(irradiance, 1.0);
        let l = rotate(hidden, std::f64::consts::PI);
        let convolution = volume.grid.normals == DnrtNormals::Convolution;
        let out_terms = if convolution {
            volume.grid.n_sh as usize
        } else {
            1
        };
        let points = volume.values.len() / (SLOTS * volume.grid.terms());
        DnrtInstance {
            volume,
            to_object: rt.map(|row| row.map(|x| x as f32)),
            centre_world: volume.centre_world(translation, rotation),
            c,
            l,
            contracted: vec![0.0; points * 3 * out_terms],
            out_terms,
            convolution,
        }
    }

    /// Grid points.
    fn n_points(&self) -> usize {
        self.contracted.len() / (3 * self.out_terms)
    }

    /// Contracts grid point `p` with this frame's `c` and `l` into its `3 · out_terms` values.
    fn contract_point(&mut self, p: usize) {
        let (n_sh, out_terms) = (self.volume.grid.n_sh as usize, self.out_terms);
        let terms = self.volume.grid.terms();
        let point = &self.volume.values[p * SLOTS * terms..(p + 1) * SLOTS * terms];
        let out = &mut self.contracted[p * 3 * out_terms..(p + 1) * 3 * out_terms];
        let k = &point[3 * terms..];
        for (ch, t_ch) in point[..3 * terms].chunks_exact(terms).enumerate() {
            let (cc, ll) = (&self.c[ch][..n_sh], &self.l[ch][..n_sh]);
            for t in 0..out_terms {
                // Term (j, t) sits at j · out_terms + t (out_terms = 1: the SH index j).
                out[ch * out_terms + t] = (0..n_sh)
                    .map(|j| cc[j] * t_ch[j * out_terms + t] - ll[j] * k[j * out_terms + t])
                    .sum();
            }
        }
    }

    /// The grid cell holding object-frame `x` (clamped inside the inner cube): its lowest
    /// corner's indices and `x`'s position in it (0 to 1 per axis).
    #[inline]
    fn cell(&self, x: [f32; 3]) -> ([usize; 3], [f32; 3]) {
        let g = &self.volume.grid;
        let n = g.resolution as usize;
        let mut i0 = [0usize; 3];
        let mut t = [0f32; 3];
        for a in 0..3 {
            let gc = g.grid_coordinate(x[a] - g.centre[a]);
            // A NaN coordinate becomes 0 through `as`; the base corner is at most n − 2.
            let base = (gc.floor() as usize).min(n - 2);
            i0[a] = base;
            t[a] = (gc - base as f32).clamp(0.0, 1.0);
        }
        (i0, t)
    }

    /// Per channel, the contracted values (`Σ_j c_j M_j`: 1, or `Σ_j c_j G_jt` for each t
    /// with convolution) at object-frame `x` inside the inner cube (clamped), trilinear over
    /// the 8 surrounding grid points.
    #[inline]
    fn transfer(&self, x: [f32; 3]) -> [[f32; SH_COEFFS]; 3] {
        let n = self.volume.grid.resolution as usize;
        let (i0, t) = self.cell(x);
        let k = self.out_terms;
        let per_point = 3 * k;
        let base = ((i0[2] * n + i0[1]) * n + i0[0]) * per_point;
        let mut out = [[0f32; SH_COEFFS]; 3];
        if k == 1 {
            // Intermediate normal: one value per channel, nested lerps.
            let (sx, sy, sz) = (3, 3 * n, 3 * n * n);
            let v = &self.contracted[base..base + sz + sy + sx + 3];
            for (ch, o) in out.iter_mut().enumerate() {
                let at = |off: usize| v[off + ch];
                let x00 = at(0) + t[0] * (at(sx) - at(0));
                let x10 = at(sy) + t[0] * (at(sy + sx) - at(sy));
                let x01 = at(sz) + t[0] * (at(sz + sx) - at(sz));
                let x11 = at(sz + sy) + t[0] * (at(sz + sy + sx) - at(sz + sy));
                let y0 = x00 + t[1] * (x10 - x00);
                let y1 = x01 + t[1] * (x11 - x01);
                o[0] = y0 + t[2] * (y1 - y0);
            }
            return out;
        }
        for corner in 0..8usize {
            let (cx, cy, cz) = (corner & 1, corner >> 1 & 1, corner >> 2 & 1);
            let w = (if cx == 1 { t[0] } else { 1.0 - t[0] })
                * (if cy == 1 { t[1] } else { 1.0 - t[1] })
                * (if cz == 1 { t[2] } else { 1.0 - t[2] });
            let at = base + ((cz * n + cy) * n + cx) * per_point;
            let v = &self.contracted[at..at + per_point];
            for (ch, o) in out.iter_mut().enumerate() {
                for (oi, vi) in o[..k].iter_mut().zip(&v[ch * k..(ch + 1) * k]) {
                    *oi += w * vi;
                }
            }
        }
        out
    }

    /// This frame's irradiance SH per channel, rotated into the object frame.
    pub fn irradiance_object_frame(&self) -> &[[f32; SH_COEFFS]; 3] {
        &self.c
    }

    /// The object's bounding-sphere centre in the world (where to sample its irradiance).
    pub fn centre_world(&self) -> [f32; 3] {
        self.centre_world
    }

    /// Where a receiver at `position` with `normal` reads the grid, and the factor its value
    /// takes (`(n_o·n)₊` times the fade); `None` where it adds nothing (see [`DnrtInstance::shade`]).
    #[inline]
    fn lookup(&self, position: [f32; 3], normal: [f32; 3]) -> Option<Lookup> {
        let g = &self.volume.grid;
        let d: [f32; 3] = std::array::from_fn(|k| position[k] - self.centre_world[k]);
        // Object frame, relative to the centre.
        let x: [f32; 3] = std::array::from_fn(|i| {
            self.to_object[i][0] * d[0] + self.to_object[i][1] * d[1] + self.to_object[i][2] * d[2]
        });
        let r = x[0].abs().max(x[1].abs()).max(x[2].abs());
        if r.is_nan() || r > g.outer_half_extent {
            return None;
        }
        let dist = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let n_len = (normal[0] * normal[0] + normal[1] * normal[1] + normal[2] * normal[2]).sqrt();
        if !(dist > 0.0 && n_len > 0.0 && n_len.is_finite()) {
            return None;
        }
        // Intermediate normal: (n_o·n)₊; with convolution the cosine lobe is in the grid.
        let lambert = if self.convolution {
            1.0
        } else {
            -(d[0] * normal[0] + d[1] * normal[1] + d[2] * normal[2]) / (dist * n_len)
        };
        if lambert.is_nan() || lambert <= 0.0 {
            return None;
        }
        let inner = g.inner_half_extent;
        let (sample, fade) = if r <= inner {
            (x, 1.0)
        } else {
            let q = inner / r;
            let q_outer = inner / g.outer_half_extent;
            let denom = 1.0 - q_outer * q_outer;
            let fade = if denom > 0.0 {
                ((q * q - q_outer * q_outer) / denom).max(0.0)
            } else {
                0.0
            };
            (x.map(|v| v * q), fade)
        };
        if fade == 0.0 {
            return None;
        }
        let local: [f32; 3] = std::array::from_fn(|k| sample[k] + g.centre[k]);
        Some(Lookup {
            local,
            k: lambert * fade,
            n_len,
        })
    }

    /// The radiance the object adds at one receiver (negative where it occludes more than it
    /// reflects).
    #[inline]
    pub fn shade(&self, position: [f32; 3], normal: [f32; 3], albedo: [f32; 3]) -> [f32; 3] {
        let Some(Lookup { local, k, n_len }) = self.lookup(position, normal) else {
            return [0.0; 3];
        };
        let m = self.transfer(local);
        if self.convolution {
            // Σ_t v_t Y_t(n) at the receiver's normal, in the object frame.
            let nw = normal.map(|v| (v / n_len) as f64);
            let no: [f64; 3] =
                std::array::from_fn(|i| (0..3).map(|j| self.to_object[i][j] as f64 * nw[j]).sum());
            let y = lightfarm_proto::sh::sh_basis(no);
            return [0, 1, 2].map(|ch| {
                let v: f32 = (0..self.out_terms).map(|t| m[ch][t] * y[t] as f32).sum();
                albedo[ch] * k * v
            });
        }
        [0, 1, 2].map(|ch| albedo[ch] * k * m[ch][0])
    }

    fn check(&self, what: &'static str, expected: usize, got: usize) -> Result<(), DnrtError> {
        if expected == got {
            Ok(())
        } else {
            Err(DnrtError::Length {
                object: self.volume.object().to_string(),
                what,
                expected,
                got,
            })
        }
    }

    /// Every G-buffer slice has the positions' length.
    fn check_gbuffer(
        &self,
        n: usize,
        normals: &[[f32; 3]],
        albedo: &[[f32; 3]],
        out: &[[f32; 3]],
    ) -> Result<(), DnrtError> {
        self.check("normals", n, normals.len())?;
        self.check("albedo", n, albedo.len())?;
        self.check("out", n, out.len())
    }

    /// Adds the object's effect to every pixel of a G-buffer (`positions`, `normals`, `albedo`
    /// and `out` of equal length; world frame).
    pub fn apply_gbuffer(
        &self,
        positions: &[[f32; 3]],
        normals: &[[f32; 3]],
        albedo: &[[f32; 3]],
        out: &mut [[f32; 3]],
    ) -> Result<(), DnrtError> {
        self.check_gbuffer(positions.len(), normals, albedo, out)?;
        for (((p, nn), a), o) in positions.iter().zip(normals).zip(albedo).zip(out) {
            let v = self.shade(*p, *nn, *a);
            for ch in 0..3 {
                o[ch] += v[ch];
            }
        }
        Ok(())
    }

    /// As [`DnrtInstance::apply_gbuffer`], in parallel over rows of pixels (feature `rayon`);
    /// the result is identical to the sequential one (pixels are independent).
    #[cfg(feature = "rayon")]
    pub fn apply_gbuffer_par(
        &self,
        positions: &[[f32; 3]],
        normals: &[[f32; 3]],
        albedo: &[[f32; 3]],
        out: &mut [[f32; 3]],
    ) -> Result<(), DnrtError> {
        use rayon::prelude::*;
        self.check_gbuffer(positions.len(), normals, albedo, out)?;
        const CHUNK: usize = 4096;
        out.par_chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(k, chunk)| {
                let s = k * CHUNK;
                let e = s + chunk.len();
                let _ = self.apply_gbuffer(&positions[s..e], &normals[s..e], &albedo[s..e], chunk);
            });
        Ok(())
    }

    /// Adds the object's effect to every lightmap texel of `layout` (`out` in layout order).
    pub fn apply_texels(&self, layout: &Layout, out: &mut [[f32; 3]]) -> Result<(), DnrtError> {
        self.apply_gbuffer(&layout.positions, &layout.normals, &layout.albedo, out)
    }

    /// How far from [`DnrtInstance::centre_world`] a receiver can be and still be shaded: the
    /// outer cube's half diagonal, with room for f32 rounding (a texel farther away gets zero).
    pub fn reach_radius(&self) -> f32 {
        self.volume.grid.outer_half_extent * 3f32.sqrt() * (1.0 + 1e-4)
    }

    /// [`DnrtInstance::apply_texels`] on the surfaces that may hold a texel within the object's
    /// reach ([`SurfaceBounds::near`] of [`DnrtInstance::reach_radius`]; `bounds` made from
    /// `layout`, `ranges` scratch): the same values (every other texel would add a zero), at a
    /// cost that follows the object's neighbourhood rather than the level.
    pub fn apply_texels_near(
        &self,
        layout: &Layout,
        bounds: &SurfaceBounds,
        ranges: &mut Vec<Range<usize>>,
        out: &mut [[f32; 3]],
    ) -> Result<(), DnrtError> {
        self.near_ranges(layout, bounds, ranges, out)?;
        self.apply_ranges(layout, ranges, out)
    }

    /// The texel ranges of the surfaces within reach into `ranges`, after checking that the
    /// layout's slices and `out` have one entry per texel.
    fn near_ranges(
        &self,
        layout: &Layout,
        bounds: &SurfaceBounds,
        ranges: &mut Vec<Range<usize>>,
        out: &[[f32; 3]],
    ) -> Result<(), DnrtError> {
        self.check_gbuffer(layout.positions.len(), &layout.normals, &layout.albedo, out)?;
        bounds.near(self.centre_world, self.reach_radius(), ranges);
        Ok(())
    }

    /// Adds the object's effect to the texels of `ranges` (clipped to the layout).
    fn apply_ranges(
        &self,
        layout: &Layout,
        ranges: &[Range<usize>],
        out: &mut [[f32; 3]],
    ) -> Result<(), DnrtError> {
        for r in ranges {
            let r = r.start.min(out.len())..r.end.min(out.len());
            self.apply_gbuffer(
                &layout.positions[r.clone()],
                &layout.normals[r.clone()],
                &layout.albedo[r.clone()],
                &mut out[r],
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use lightfarm_proto::dnrt_grid::{DnrtCodec, DnrtPlacement};

    /// A grid whose `t_j` and `k_j` are affine functions of the object-frame position, so
    /// trilinear interpolation reproduces them exactly.
    fn affine(slot: usize, s: usize, x: [f64; 3]) -> f64 {
        (0.01 * (1 + s + slot) as f64) * (1.0 + 0.2 * x[0] - 0.1 * x[1]) + 0.05 * x[2]
    }

    fn affine_grid(n: u32, n_sh: u32, placement: DnrtPlacement) -> DnrtGrid {
        let mut g = DnrtGrid::encode_values(
            "probe",
            [0.1, 0.2, -0.3],
            0.5,
            1.5,
            3.0,
            n,
            n_sh,
            placement,
            DnrtNormals::Intermediate,
            DnrtCodec::F32,
            vec![[0.0, 0.0]; 2 * n_sh as usize],
            &[],
        );
        let nn = n as usize;
        let mut values = Vec::new();
        for k in 0..nn {
            for j in 0..nn {
                for i in 0..nn {
                    let x = [g.offset(i), g.offset(j), g.offset(k)];
                    for ch in 0..4 {
                        for s in 0..n_sh as usize {
                            values.push(affine(ch, s, x));
                        }
                    }
                }
            }
        }
        g.data =
            lightfarm_proto::dnrt_grid::DnrtData::F32(values.iter().map(|v| *v as f32).collect());
        g
    }

    #[test]
    fn interpolation_is_exact_for_affine_data_and_output_is_finite_everywhere() {
        let grid = affine_grid(5, 9, DnrtPlacement::Regular);
        let volume = DnrtVolume::new(&grid).unwrap();
        let c = [[1.0; 9], [0.5; 9], [0.25; 9]];
        let l = [[0.1; 9], [0.2; 9], [0.3; 9]];
        let inst = DnrtInstance::new(&volume, [2.0, 0.0, 1.0], [0.0, 0.0, 0.0, 1.0], c, l);
        let centre = inst.centre_world();
        // Exact inside the inner cube: Σ c_j t_j − π Σ l_j k_j (identity rotation).
        let x = [0.37f32, -0.81, 1.2];
        let m = inst.transfer(std::array::from_fn(|k| x[k] + grid.centre[k]));
        let xd = x.map(|v| v as f64);
        for ch in 0..3 {
            let want: f64 = (0..9)
                .map(|s| {
                    inst.c[ch][s] as f64 * affine(ch, s, xd)
                        - std::f64::consts::PI * l[ch][s] as f64 * affine(3, s, xd)
                })
                .sum();
            assert!(
                (m[ch][0] as f64 - want).abs() < 1e-5,
                "{ch}: {} vs {want}",
                m[ch][0]
            );
        }
        // Finite at the centre, inside the object, on the grid's edges and corners, on the
        // outer boundary and beyond, for any normal (including zero and NaN).
        let e = grid.inner_half_extent;
        let o = grid.outer_half_extent;
        let offsets = [
            [0.0, 0.0, 0.0],
            [0.1, 0.0, 0.0],
            [e, 0.0, 0.0],
            [e, e, e],
            [-e, e, -e],
            [o, 0.0, 0.0],
            [o, o, o],
            [2.0 * o, 0.0, 0.0],
            [e * 1.0001, 0.0, 0.0],
        ];
        let normals = [
            [1.0, 0.0, 0.0],
            [-1.0, 0.0, 0.0],
            [0.0, 0.0, 0.0],
            [f32::NAN, 0.0, 1.0],
        ];
        for d in offsets {
            for n in normals {
                let p = std::array::from_fn(|k| centre[k] + d[k]);
                let v = inst.shade(p, n, [0.7; 3]);
                assert!(v.iter().all(|x| x.is_finite()), "{d:?} {n:?}: {v:?}");
            }
        }
        assert_eq!(
            inst.shade([f32::NAN, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0; 3]),
            [0.0; 3]
        );
        // Beyond the outer cube nothing, at its boundary zero, continuous across the inner one.
        let facing = [-1.0, 0.0, 0.0];
        let at = |r: f32| inst.shade([centre[0] + r, centre[1], centre[2]], facing, [1.0; 3]);
        assert_eq!(at(2.0 * o), [0.0; 3]);
        assert!(at(o)[0].abs() < 1e-7);
        let (a, b) = (at(e * 0.9999), at(e * 1.0001));
        assert!(
            (a[0] - b[0]).abs() < 1e-3 * a[0].abs().max(1e-6),
            "{a:?} {b:?}"
        );
        // Inverse-square shape: s(2E) = (1/4 − 1/4·(E/E_o)²…) with E_o = 2E gives 0 at 2E,
        // and at 1.5E: ((1/1.5)² − 1/4) / (3/4).
        let s15 = at(1.5 * e)[0] / at(e)[0];
        let want = ((1.0 / 1.5f32).powi(2) - 0.25) / 0.75;
        // The value on the inner boundary along the same ray is the same point here.
        assert!((s15 - want).abs() < 1e-4, "{s15} vs {want}");
    }

    #[test]
    fn gbuffer_and_texel_paths_agree_and_lengths_are_checked() {
        let grid = affine_grid(4, 4, DnrtPlacement::Quadratic);
        let volume = DnrtVolume::new(&grid).unwrap();
        let inst = DnrtInstance::new(
            &volume,
            [0.0; 3],
            [0.0, 0.38, 0.0, 0.92],
            [[0.3; 9]; 3],
            [[0.05; 9]; 3],
        );
        let positions: Vec<[f32; 3]> = (0..50)
            .map(|i| [0.05 * i as f32 - 1.0, 0.3, 0.02 * i as f32])
            .collect();
        // Receivers above the centre, facing down towards it.
        let normals = vec![[0.0, -1.0, 0.0]; 50];
        let albedo = vec![[0.5, 0.6, 0.7]; 50];
        let mut out = vec![[1.0; 3]; 50];
        inst.apply_gbuffer(&positions, &normals, &albedo, &mut out)
            .unwrap();
        for (k, o) in out.iter().enumerate() {
            let v = inst.shade(positions[k], normals[k], albedo[k]);
            for ch in 0..3 {
                assert_eq!(o[ch], 1.0 + v[ch]);
            }
        }
        assert!(
            out.iter().any(|o| o[0] != 1.0),
            "some receivers must be affected"
        );
        let layout = Layout {
            positions: positions.clone(),
            normals: normals.clone(),
            albedo: albedo.clone(),
            ..Layout::default()
        };
        let mut texels = vec![[1.0; 3]; 50];
        inst.apply_texels(&layout, &mut texels).unwrap();
        assert_eq!(texels, out);
        let err = inst
            .apply_gbuffer(&positions, &normals[..3], &albedo, &mut out)
            .unwrap_err();
        assert!(err.to_string().contains("\"probe\""), "{err}");
    }

    /// The texels near the object get what the whole layout's pass gives them, bit for bit,
    /// and the rest nothing: on a layout of many surfaces spread over 80 m, posed at several
    /// places and turns (including astride two surfaces and off every texel); so does
    /// [`DnrtNear`], which contracts only the grid points those texels read, with an
    /// intermediate-normal grid and with a convolution grid.
    #[test]
    fn texels_near_the_object_are_the_whole_passes() {
        let grid = affine_grid(4, 4, DnrtPlacement::Quadratic);
        texels_near_are_the_whole_pass(&DnrtVolume::new(&grid).unwrap(), 64);
        // 9³ points of a convolution grid (4 SH in, 4 out), every value its own.
        let n = 9usize;
        let values: Vec<f64> = (0..n * n * n * 4 * 16)
            .map(|k| 0.01 * ((k * 7919) % 101) as f64 - 0.3)
            .collect();
        let grid = DnrtGrid::encode_values(
            "conv",
            [0.1, 0.0, -0.1],
            0.5,
            0.8,
            1.6,
            n as u32,
            4,
            DnrtPlacement::Regular,
            DnrtNormals::Convolution,
            DnrtCodec::F32,
            vec![[0.0, 0.25]; 32],
            &values,
        );
        texels_near_are_the_whole_pass(&DnrtVolume::new(&grid).unwrap(), n * n * n);
    }

    /// [`texels_near_the_object_are_the_whole_passes`] on one grid of `points` points.
    fn texels_near_are_the_whole_pass(volume: &DnrtVolume, points: usize) {
        use lightfarm_proto::bundle::SurfaceInfo;
        let volume = volume.clone();
        // 40 surfaces of 25 texels, each a 5 × 5 patch of 0.2 m texels, strung along x (a
        // surface every 2 m), the receivers facing every which way.
        let (mut positions, mut normals, mut surfaces) = (Vec::new(), Vec::new(), Vec::new());
        for s in 0..40u32 {
            surfaces.push(SurfaceInfo {
                name: format!("block:b{s}/-y"),
                texel_offset: 25 * s,
                texel_count: 25,
            });
            for i in 0..25 {
                let (u, v) = ((i % 5) as f32 * 0.2, (i / 5) as f32 * 0.2);
                positions.push([2.0 * s as f32 + u, 0.1 * (s % 3) as f32 + v, v - 0.4]);
                let a = 0.3 * (s + i) as f32;
                normals.push([a.cos(), -0.8, a.sin()]);
            }
        }
        let n = positions.len();
        let layout = Layout {
            surfaces,
            albedo: vec![[0.5, 0.6, 0.7]; n],
            positions,
            normals,
            ..Layout::default()
        };
        let bounds = SurfaceBounds::new(&layout);
        let mut ranges = Vec::new();
        let mut shaded_somewhere = 0;
        for (translation, rotation) in [
            ([3.5, 0.6, 0.0], [0.0, 0.0, 0.0, 1.0]),
            ([41.0, 1.2, -0.2], [0.0, 0.38, 0.0, 0.92]),
            ([15.0, -0.5, 0.3], [0.3, 0.1, -0.2, 0.9]),
            ([200.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]),
        ] {
            let inst = DnrtInstance::new(
                &volume,
                translation,
                rotation,
                [[0.3; 9]; 3],
                [[0.05; 9]; 3],
            );
            let mut whole = vec![[1.0f32; 3]; n];
            inst.apply_texels(&layout, &mut whole).unwrap();
            let mut near = vec![[1.0f32; 3]; n];
            inst.apply_texels_near(&layout, &bounds, &mut ranges, &mut near)
                .unwrap();
            let bits = |v: &[[f32; 3]]| -> Vec<u32> {
                v.iter().flatten().map(|x| (x + 0.0).to_bits()).collect()
            };
            assert_eq!(bits(&near), bits(&whole), "pose at {translation:?}");
            let visited: usize = ranges.iter().map(|r| r.len()).sum();
            assert!(visited < n / 4, "{visited} of {n} texels visited");
            let (c, l) = ([[0.3; 9]; 3], [[0.05; 9]; 3]);
            let mut lazy = DnrtNear::new(&volume, translation, rotation, c, l);
            let mut only = vec![[1.0f32; 3]; n];
            lazy.apply_texels_near(&layout, &bounds, &mut ranges, &mut only)
                .unwrap();
            assert_eq!(bits(&only), bits(&whole), "DnrtNear at {translation:?}");
            assert!(lazy.contracted_points() < points, "{points} points");
            shaded_somewhere += whole.iter().filter(|o| o[0] != 1.0).count();
        }
        assert!(shaded_somewhere > 10, "the poses shade some texels");
    }

    /// With a convolution grid the receiver's own normal selects the value, in the object
    /// frame: a grid whose only term is `G_{0,3}` (band 0 in, `Y_11 ∝ x` out), posed rotated
    /// 90° about z (object x → world y), gives `ρ c_0 G Y_11` to a receiver facing world +y,
    /// and nothing to one facing world +x; no `(n_o·n)₊` factor applies.
    #[test]
    fn convolution_grids_use_the_receiver_normal_in_the_object_frame() {
        let n = 3usize;
        // Reflection slots only (the occlusion slot, every 4th run of 16, stays zero).
        let mut values = vec![0.0f64; n * n * n * 4 * 16];
        for (k, v) in values.iter_mut().enumerate() {
            if k % 16 == 3 && (k / 16) % 4 != 3 {
                *v = 0.25;
            }
        }
        let grid = DnrtGrid::encode_values(
            "conv",
            [0.0; 3],
            0.5,
            1.5,
            3.0,
            n as u32,
            4,
            DnrtPlacement::Regular,
            DnrtNormals::Convolution,
            DnrtCodec::F32,
            vec![[0.0, 0.25]; 32],
            &values,
        );
        let volume = DnrtVolume::new(&grid).unwrap();
        let h = std::f64::consts::FRAC_1_SQRT_2;
        let mut c = [[0.0f32; 9]; 3];
        c[0][0] = 2.0;
        c[1][0] = 1.0;
        let inst = DnrtInstance::new(&volume, [1.0, 0.0, 0.0], [0.0, 0.0, h, h], c, [[0.0; 9]; 3]);
        // A receiver 0.4 m from the centre along world +y, facing +y (away from the object).
        let p = [1.0, 0.4, 0.0];
        let up = inst.shade(p, [0.0, 1.0, 0.0], [0.5; 3]);
        let y11 = 0.488_602_5f32;
        assert!((up[0] - 0.5 * 2.0 * 0.25 * y11).abs() < 1e-5, "{up:?}");
        assert!((up[1] - 0.5 * 1.0 * 0.25 * y11).abs() < 1e-5, "{up:?}");
        assert_eq!(up[2], 0.0);
        let side = inst.shade(p, [1.0, 0.0, 0.0], [0.5; 3]);
        assert!(side.iter().all(|v| v.abs() < 1e-6), "{side:?}");
    }
}
