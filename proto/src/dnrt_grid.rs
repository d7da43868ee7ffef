//! The on-wire DNRT grid of one dynamic object (paper 003 §5.1): the reflection coefficients
//! `t_j` per RGB channel and the occlusion coefficients `k_j` (one set: they do not depend on
//! the albedo) per SH index at the points of a grid around the object, with the codecs the
//! paper stores them in (8-bit with per-coefficient ranges) and f16 / f32. On the wire an 8-bit
//! grid is written either in the value layout below (codec tag 0, [`DnrtGrid::write`]: the cache
//! and bundle kind 9) or planar and differenced (tag 3, [`DnrtGrid::write_planar`]: bundle kind
//! 18), which zstd shrinks to about half; both read back the same grid.
//!
//! The paper stores `m_j = t_j − k_j`, which ties what the object reflects and what it hides to
//! one set of coefficients `c_j`. They differ: the object reflects all the light it receives
//! (point lights included), but hides only the radiance of the surfaces behind it (a point
//! light it hides is its direct shadow, which is not indirect light). Keeping `k_j` apart costs
//! one value per SH index and point (4 instead of 3 per term: +33%) and lets the client
//! contract `Σ_j c_j t_j − π Σ_j l_j k_j` with the irradiance `c_j` the object reflects and the
//! radiance `l_j` it hides (Appendix B.2's radiance instead of eq. 12's `E/π`; measured in
//! `tests/data/dnrt_accuracy.md`).
//!
//! Frames and units: the grid lives in the object's own frame (the mesh file's coordinates,
//! metres). `centre` and `radius` are the object's bounding sphere. The grid spans the inner
//! cube `centre ± inner_half_extent` on every axis with `resolution` points per axis; point
//! `(i, j, k)` sits at `centre + (offset(i), offset(j), offset(k))` where `offset` depends on
//! the [`DnrtPlacement`] ([`DnrtGrid::offset`]). Beyond the inner cube and up to the outer cube
//! `centre ± outer_half_extent` the client fades the inner boundary's value to zero (§5.2.2).
//! `t_j` and `k_j` are in radiance per unit coefficient: `L = ρ (n_o·n)₊ (Σ_j c_j t_j −
//! π Σ_j l_j k_j)` with `c_j` the SH coefficients of the irradiance `E(n) = Σ_j c_j Y_j(n)` and
//! `l_j` those of the hidden radiance `L(ω) = Σ_j l_j Y_j(ω)`, in the object frame.
//!
//! Value layout: `((point · 4) + slot) · terms + term`, point `= (k · n + j) · n + i`, slots
//! 0–2 `t_j` in R, G, B and slot 3 `k_j`; a term is the SH index j (`terms = n_sh`), or with
//! [`DnrtNormals::Convolution`] (Appendix A) the pair `j · n_sh + t` (`terms = n_sh²`).
//! `ranges` has `2 · terms` entries: the reflection slots' ranges, then the occlusion slot's.
//!
//! Analytic bounds (paper Table 1 in our units): `t_0, k_0 ∈ [0, Y_0/π]` and, for `j ≥ 1`,
//! `|t_j|, |k_j| ≤ max|Y_j| / π`, because `∫_D cos θ dω ≤ π`, the `1/π²` of eq. 8 and 13, and
//! `ρ ≤ 1`; so `m_j = t_j − k_j` lies in `[−Y_0/π, Y_0/π]` and `±2 max|Y_j|/π`, the paper's
//! Table 1 without its `1/π` (its irradiance is pre-divided by π).
//!
//! Invariant: a grid that passed [`DnrtGrid::validate`] (every [`DnrtGrid::read`] runs it) has
//! resolution ≥ 2, `n_sh ∈ {4, 9}`, finite positive extents with outer ≥ inner, finite ordered
//! ranges, exactly `resolution³ · 4 · terms` values and only finite ones.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::wire::{Reader, WireError, Writer};

/// How the coefficients are stored.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum DnrtCodec {
    /// One byte per value, dequantised per SH coefficient as `lo + q/255 · (hi − lo)`.
    #[default]
    U8,
    /// IEEE binary16.
    F16,
    /// f32 (the unquantised baseline).
    F32,
}

/// Where the grid points sit along each axis.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum DnrtPlacement {
    /// Evenly spaced (the paper).
    #[default]
    Regular,
    /// Denser near the object (Appendix B.1): `offset = E · u·|u|` for evenly spaced
    /// `u ∈ [−1, 1]`.
    Quadratic,
}

/// How the receiver's normal enters (paper §4.1.4 or Appendix A).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum DnrtNormals {
    /// The paper's intermediate normal: `m_j` is integrated about `n_o` (towards the centre)
    /// and the client scales by `(n_o·n)₊`. One term per SH index.
    #[default]
    Intermediate,
    /// Appendix A: per SH index j, the SH projection over directions of the transfer function
    /// convolved with the clamped cosine, `G_jt = Â_t ∫_D f_j(ω) Y_t(ω) dω`; the client
    /// evaluates `Σ_t (Σ_j c_j G_jt) Y_t(n)` at the receiver's own normal. `n_sh²` terms.
    Convolution,
}

/// The stored values.
#[derive(Clone, Debug, PartialEq)]
pub enum DnrtData {
    U8(Vec<u8>),
    F16(Vec<u16>),
    F32(Vec<f32>),
}

impl DnrtData {
    pub fn len(&self) -> usize {
        match self {
            DnrtData::U8(v) => v.len(),
            DnrtData::F16(v) => v.len(),
            DnrtData::F32(v) => v.len(),
        }
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// How the values are stored.
    pub fn codec(&self) -> DnrtCodec {
        match self {
            DnrtData::U8(_) => DnrtCodec::U8,
            DnrtData::F16(_) => DnrtCodec::F16,
            DnrtData::F32(_) => DnrtCodec::F32,
        }
    }
}

/// One object's grid (see the module doc).
#[derive(Clone, Debug, PartialEq)]
pub struct DnrtGrid {
    /// The dynamic object's id.
    pub object: String,
    /// Bounding-sphere centre, object frame (metres).
    pub centre: [f32; 3],
    pub radius: f32,
    pub inner_half_extent: f32,
    pub outer_half_extent: f32,
    pub resolution: u32,
    /// 4 (order 1) or 9 (order 2).
    pub n_sh: u32,
    pub placement: DnrtPlacement,
    pub normals: DnrtNormals,
    /// Per term (SH index j, or pair `j · n_sh + t` with [`DnrtNormals::Convolution`]) `[lo, hi]`: the u8 dequantisation range (for f16/f32: the data's
    /// range, informative).
    pub ranges: Vec<[f32; 2]>,
    pub data: DnrtData,
}

/// Why a grid is unusable.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DnrtGridError {
    #[error("DNRT grid of \"{object}\": {message}")]
    Invalid { object: String, message: String },
    #[error("DNRT grid: {0}")]
    Wire(#[from] WireError),
}

/// The largest `|Y_j|` over the sphere, per SH index (Sloan order).
pub const MAX_ABS_BASIS: [f64; 9] = [
    0.282_094_791_773_878_1,
    0.488_602_511_902_919_9,
    0.488_602_511_902_919_9,
    0.488_602_511_902_919_9,
    0.546_274_215_296_039_6,
    0.546_274_215_296_039_6,
    0.630_783_130_505_040_1,
    0.546_274_215_296_039_6,
    0.546_274_215_296_039_6,
];

/// Values stored per grid point and term: `t_j` in R, G, B and `k_j`.
pub const SLOTS: usize = 4;

/// The analytic range of `t_j` and of `k_j` (module doc; paper Table 1 divided by π).
pub fn analytic_range(j: usize) -> [f64; 2] {
    let pi = std::f64::consts::PI;
    if j == 0 {
        [0.0, MAX_ABS_BASIS[0] / pi]
    } else {
        let b = MAX_ABS_BASIS[j] / pi;
        [-b, b]
    }
}

/// The analytic range of a convolved term ([`DnrtNormals::Convolution`]), reflection
/// `Â_t ∫_D ρ Y_j(n_s) Y_t(ω)/π² dω` or occlusion `Â_t ∫_D Y_j(ω) Y_t(ω)/π² dω`:
/// at most `Â_t · max|Y_t| · max|Y_j| · 4π/π²` (at most 4π sr).
pub fn analytic_range_convolved(j: usize, t: usize) -> [f64; 2] {
    let a = crate::sh::irradiance_weights()[t];
    let b = a * MAX_ABS_BASIS[t] * MAX_ABS_BASIS[j] * 4.0 / std::f64::consts::PI;
    [-b, b]
}

/// The analytic range of range index `k` (`0..2 · terms`: reflection, then occlusion) of
/// `terms(n_sh, normals)`.
pub fn analytic_term_range(k: usize, n_sh: usize, normals: DnrtNormals) -> [f64; 2] {
    let k = k % terms(n_sh, normals);
    match normals {
        DnrtNormals::Intermediate => analytic_range(k),
        DnrtNormals::Convolution => analytic_range_convolved(k / n_sh, k % n_sh),
    }
}

/// The index into `ranges` of value `k` (layout of the module doc) for `terms` terms.
#[inline]
pub fn range_index(k: usize, terms: usize) -> usize {
    let term = k % terms;
    if (k / terms) % SLOTS == SLOTS - 1 {
        terms + term
    } else {
        term
    }
}

/// Per SH coefficient (reflection, then occlusion), the range of `values` (layout of the
/// module doc), clamped to the analytic range.
pub fn fitted_ranges(values: &[f64], n_sh: usize) -> Vec<[f32; 2]> {
    fitted_term_ranges(values, n_sh, DnrtNormals::Intermediate)
}

/// [`fitted_ranges`] for any normal mode (one range per term, within its analytic range).
pub fn fitted_term_ranges(values: &[f64], n_sh: usize, normals: DnrtNormals) -> Vec<[f32; 2]> {
    let n_terms = terms(n_sh, normals);
    let mut lo = vec![f64::INFINITY; 2 * n_terms];
    let mut hi = vec![f64::NEG_INFINITY; 2 * n_terms];
    for (k, v) in values.iter().enumerate() {
        let r = range_index(k, n_terms);
        lo[r] = lo[r].min(*v);
        hi[r] = hi[r].max(*v);
    }
    (0..2 * n_terms)
        .map(|r| {
            let [a_lo, a_hi] = analytic_term_range(r, n_sh, normals);
            if lo[r] > hi[r] {
                return [0.0, 0.0];
            }
            [lo[r].max(a_lo) as f32, hi[r].min(a_hi) as f32]
        })
        .collect()
}

/// Quantises `v` to a byte in `range`.
pub fn quantise_u8(v: f64, range: [f32; 2]) -> u8 {
    let (lo, hi) = (range[0] as f64, range[1] as f64);
    if hi <= lo {
        return 0;
    }
    ((v - lo) / (hi - lo) * 255.0).round().clamp(0.0, 255.0) as u8
}

/// The value a byte stands for in `range`.
pub fn dequantise_u8(q: u8, range: [f32; 2]) -> f32 {
    range[0] + (q as f32 / 255.0) * (range[1] - range[0])
}

impl DnrtGrid {
    /// Number of grid points (`resolution³`).
    pub fn n_points(&self) -> usize {
        (self.resolution as usize).pow(3)
    }

    /// Values per channel of a grid point: `n_sh`, or `n_sh²` with convolution.
    pub fn terms(&self) -> usize {
        terms(self.n_sh as usize, self.normals)
    }

    /// Values per grid point (`4 · terms`: [`SLOTS`]).
    pub fn values_per_point(&self) -> usize {
        SLOTS * self.terms()
    }

    /// Offset (metres, object frame) of grid index `i` from the centre along one axis.
    pub fn offset(&self, i: usize) -> f64 {
        placement_offset(
            self.placement,
            self.inner_half_extent as f64,
            self.resolution as usize,
            i,
        )
    }

    /// Continuous grid coordinate (0 ..= resolution − 1) of an offset from the centre along one
    /// axis, clamped to the grid; the inverse of [`DnrtGrid::offset`].
    pub fn grid_coordinate(&self, offset: f32) -> f32 {
        let e = self.inner_half_extent;
        let last = (self.resolution - 1) as f32;
        let u = (offset / e).clamp(-1.0, 1.0);
        let u = match self.placement {
            DnrtPlacement::Regular => u,
            DnrtPlacement::Quadratic => u.signum() * u.abs().sqrt(),
        };
        ((u + 1.0) * 0.5 * last).clamp(0.0, last)
    }

    /// Builds a grid from unquantised values (layout of the module doc) in `codec`. For
    /// [`DnrtCodec::U8`], `ranges` are the dequantisation ranges (e.g. [`fitted_ranges`]).
    #[allow(clippy::too_many_arguments)]
    pub fn encode_values(
        object: &str,
        centre: [f32; 3],
        radius: f32,
        inner_half_extent: f32,
        outer_half_extent: f32,
        resolution: u32,
        n_sh: u32,
        placement: DnrtPlacement,
        normals: DnrtNormals,
        codec: DnrtCodec,
        ranges: Vec<[f32; 2]>,
        values: &[f64],
    ) -> DnrtGrid {
        let n_sh_us = terms(n_sh as usize, normals);
        let data = match codec {
            DnrtCodec::U8 => DnrtData::U8(
                values
                    .iter()
                    .enumerate()
                    .map(|(k, v)| quantise_u8(*v, ranges[range_index(k, n_sh_us)]))
                    .collect(),
            ),
            DnrtCodec::F16 => DnrtData::F16(
                values
                    .iter()
                    .map(|v| half::f16::from_f32(*v as f32).to_bits())
                    .collect(),
            ),
            DnrtCodec::F32 => DnrtData::F32(values.iter().map(|v| *v as f32).collect()),
        };
        DnrtGrid {
            object: object.to_string(),
            centre,
            radius,
            inner_half_extent,
            outer_half_extent,
            resolution,
            n_sh,
            placement,
            normals,
            ranges,
            data,
        }
    }

    /// Every value decoded to f32, in the layout of the module doc.
    pub fn values(&self) -> Vec<f32> {
        let n_sh = self.terms();
        match &self.data {
            DnrtData::U8(v) => v
                .iter()
                .enumerate()
                .map(|(k, q)| dequantise_u8(*q, self.ranges[range_index(k, n_sh)]))
                .collect(),
            DnrtData::F16(v) => v
                .iter()
                .map(|h| half::f16::from_bits(*h).to_f32())
                .collect(),
            DnrtData::F32(v) => v.clone(),
        }
    }

    /// Bytes of the stored values (what the grid costs in memory at its codec).
    pub fn data_bytes(&self) -> usize {
        match &self.data {
            DnrtData::U8(v) => v.len(),
            DnrtData::F16(v) => 2 * v.len(),
            DnrtData::F32(v) => 4 * v.len(),
        }
    }

    fn invalid(&self, message: String) -> DnrtGridError {
        DnrtGridError::Invalid {
            object: self.object.clone(),
            message,
        }
    }

    /// Checks the invariant of the module doc.
    pub fn validate(&self) -> Result<(), DnrtGridError> {
        if !(2..=256).contains(&self.resolution) {
            return Err(self.invalid(format!("resolution {} is not in 2..=256", self.resolution)));
        }
        if self.n_sh != 4 && self.n_sh != 9 {
            return Err(self.invalid(format!("n_sh {} is not 4 or 9", self.n_sh)));
        }
        let positive = |x: f32| x.is_finite() && x > 0.0;
        if !self.centre.iter().all(|x| x.is_finite())
            || !positive(self.radius)
            || !positive(self.inner_half_extent)
            || !positive(self.outer_half_extent)
            || self.outer_half_extent < self.inner_half_extent
        {
            return Err(self.invalid(
                "centre, radius and extents must be finite, positive and outer ≥ inner".into(),
            ));
        }
        if self.ranges.len() != 2 * self.terms()
            || self
                .ranges
                .iter()
                .any(|[lo, hi]| !(lo.is_finite() && hi.is_finite() && lo <= hi))
        {
            return Err(self.invalid("ranges: two finite [lo, hi] per term".into()));
        }
        let expected = self.n_points() as u64 * self.values_per_point() as u64;
        if self.data.len() as u64 != expected {
            return Err(self.invalid(format!("{} values, expected {expected}", self.data.len())));
        }
        let finite = match &self.data {
            DnrtData::U8(_) => true,
            DnrtData::F16(v) => v.iter().all(|h| h & 0x7c00 != 0x7c00),
            DnrtData::F32(v) => v.iter().all(|x| x.is_finite()),
        };
        if !finite {
            return Err(self.invalid("a value is not finite".into()));
        }
        Ok(())
    }

    /// Appends the grid's bytes (codec tags 0–2: values in the layout of the module doc).
    pub fn write(&self, w: &mut Writer) {
        self.write_with(w, false);
    }

    /// Appends the grid's bytes with 8-bit values in their planar, differenced form (codec tag
    /// 3, [`to_planar_differences`]): the same bytes otherwise. Lossless; zstd shrinks it to
    /// about half of tag 0 (a generated level's ball: 530,546 → 250,583 bytes at level 9), the
    /// neighbouring points' values being close. Bundle section kind 18 (format 2.3) holds grids
    /// written so; a reader before it does not know tag 3.
    pub fn write_planar(&self, w: &mut Writer) {
        self.write_with(w, true);
    }

    fn write_with(&self, w: &mut Writer, planar: bool) {
        w.str(&self.object);
        for x in self.centre {
            w.f32(x);
        }
        w.f32(self.radius);
        w.f32(self.inner_half_extent);
        w.f32(self.outer_half_extent);
        w.u32(self.resolution);
        w.u32(self.n_sh);
        w.u8(match self.placement {
            DnrtPlacement::Regular => 0,
            DnrtPlacement::Quadratic => 1,
        });
        w.u8(match self.normals {
            DnrtNormals::Intermediate => 0,
            DnrtNormals::Convolution => 1,
        });
        let flat: Vec<f32> = self.ranges.iter().flatten().copied().collect();
        w.f32s(&flat);
        w.u8(match self.data.codec() {
            DnrtCodec::U8 if planar => 3,
            DnrtCodec::U8 => 0,
            DnrtCodec::F16 => 1,
            DnrtCodec::F32 => 2,
        });
        match &self.data {
            DnrtData::U8(v) if planar => {
                w.u64(v.len() as u64);
                let (n, per_point) = (self.resolution as usize, self.values_per_point());
                w.bytes.extend(to_planar_differences(v, n, per_point));
            }
            DnrtData::U8(v) => {
                w.u64(v.len() as u64);
                w.bytes.extend_from_slice(v);
            }
            DnrtData::F16(v) => {
                w.u64(v.len() as u64);
                for h in v {
                    w.bytes.extend_from_slice(&h.to_le_bytes());
                }
            }
            DnrtData::F32(v) => w.f32s(v),
        }
    }

    /// Reads and validates one grid.
    pub fn read(r: &mut Reader) -> Result<DnrtGrid, DnrtGridError> {
        let object = r.str()?;
        let centre = [r.f32()?, r.f32()?, r.f32()?];
        let radius = r.f32()?;
        let inner_half_extent = r.f32()?;
        let outer_half_extent = r.f32()?;
        let resolution = r.u32()?;
        let n_sh = r.u32()?;
        let invalid = |message: String| DnrtGridError::Invalid {
            object: object.clone(),
            message,
        };
        let placement = match r.u8()? {
            0 => DnrtPlacement::Regular,
            1 => DnrtPlacement::Quadratic,
            p => return Err(invalid(format!("unknown placement {p}"))),
        };
        let normals = match r.u8()? {
            0 => DnrtNormals::Intermediate,
            1 => DnrtNormals::Convolution,
            p => return Err(invalid(format!("unknown normal mode {p}"))),
        };
        let flat = r.f32s()?;
        if flat.len() % 2 != 0 {
            return Err(invalid("odd number of range bounds".into()));
        }
        let ranges = flat.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
        let codec = r.u8()?;
        let data = match codec {
            0 => {
                let n = r.u64()?;
                let bytes = r.take(usize::try_from(n).unwrap_or(usize::MAX))?;
                DnrtData::U8(bytes.to_vec())
            }
            1 => {
                let n = r.u64()?;
                let len = usize::try_from(n)
                    .ok()
                    .and_then(|n| n.checked_mul(2))
                    .unwrap_or(usize::MAX);
                let bytes = r.take(len)?;
                DnrtData::F16(
                    bytes
                        .chunks_exact(2)
                        .map(|c| u16::from_le_bytes([c[0], c[1]]))
                        .collect(),
                )
            }
            2 => DnrtData::F32(r.f32s()?),
            3 => {
                let n = r.u64()?;
                let bytes = r.take(usize::try_from(n).unwrap_or(usize::MAX))?;
                // Undoing the form needs the grid's size, which `validate` checks only after:
                // an SH count it would refuse is refused here (so `terms` cannot overflow), and
                // the points are counted without overflow.
                if n_sh != 4 && n_sh != 9 {
                    return Err(invalid(format!("n_sh {n_sh} is not 4 or 9")));
                }
                let per_point = SLOTS * terms(n_sh as usize, normals);
                let points = (resolution as usize)
                    .checked_mul(resolution as usize)
                    .and_then(|p| p.checked_mul(resolution as usize));
                if points.and_then(|p| p.checked_mul(per_point)) != Some(bytes.len()) {
                    return Err(invalid(
                        "planar values do not fill resolution³ · 4 · terms".into(),
                    ));
                }
                DnrtData::U8(from_planar_differences(
                    bytes,
                    resolution as usize,
                    per_point,
                ))
            }
            c => return Err(invalid(format!("unknown codec {c}"))),
        };
        let grid = DnrtGrid {
            object,
            centre,
            radius,
            inner_half_extent,
            outer_half_extent,
            resolution,
            n_sh,
            placement,
            normals,
            ranges,
            data,
        };
        grid.validate()?;
        Ok(grid)
    }
}

/// 8-bit grid values (`n³` points of `per_point` values, the module doc's layout) in codec tag
/// 3's form: value slot by value slot (all points' value 0, then value 1, …), points in grid
/// order, each point's byte the difference (mod 256) from the point before it along the grid's
/// first axis (`i − 1`), or the value itself at `i = 0`. `values.len()` must be `n³ · per_point`.
pub fn to_planar_differences(values: &[u8], n: usize, per_point: usize) -> Vec<u8> {
    debug_assert_eq!(values.len(), n * n * n * per_point);
    let mut out = Vec::with_capacity(values.len());
    for v in 0..per_point {
        for p in 0..n * n * n {
            let q = values[p * per_point + v];
            out.push(if p % n == 0 {
                q
            } else {
                q.wrapping_sub(values[(p - 1) * per_point + v])
            });
        }
    }
    out
}

/// The inverse of [`to_planar_differences`].
pub fn from_planar_differences(planar: &[u8], n: usize, per_point: usize) -> Vec<u8> {
    debug_assert_eq!(planar.len(), n * n * n * per_point);
    let points = n * n * n;
    let mut out = vec![0u8; planar.len()];
    for v in 0..per_point {
        for p in 0..points {
            let d = planar[v * points + p];
            out[p * per_point + v] = if p % n == 0 {
                d
            } else {
                out[(p - 1) * per_point + v].wrapping_add(d)
            };
        }
    }
    out
}

/// Values per channel of a grid point for `n_sh` coefficients and `normals`.
pub fn terms(n_sh: usize, normals: DnrtNormals) -> usize {
    match normals {
        DnrtNormals::Intermediate => n_sh,
        DnrtNormals::Convolution => n_sh * n_sh,
    }
}

/// Offset of grid index `i` of `n` from the centre for half-extent `e` (see [`DnrtPlacement`]).
pub fn placement_offset(placement: DnrtPlacement, e: f64, n: usize, i: usize) -> f64 {
    let u = -1.0 + 2.0 * i as f64 / (n.max(2) - 1) as f64;
    match placement {
        DnrtPlacement::Regular => e * u,
        DnrtPlacement::Quadratic => e * u * u.abs(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(codec: DnrtCodec, placement: DnrtPlacement) -> (DnrtGrid, Vec<f64>) {
        let n = 3u32;
        let n_sh = 4usize;
        let count = 27 * SLOTS * n_sh;
        let values: Vec<f64> = (0..count)
            .map(|k| {
                let j = k % n_sh;
                let [lo, hi] = analytic_range(j);
                lo + (hi - lo) * ((k * 37 % 101) as f64 / 100.0)
            })
            .collect();
        let ranges = fitted_ranges(&values, n_sh);
        let g = DnrtGrid::encode_values(
            "ball",
            [0.1, 0.2, 0.3],
            0.5,
            1.5,
            3.0,
            n,
            n_sh as u32,
            placement,
            DnrtNormals::Intermediate,
            codec,
            ranges,
            &values,
        );
        (g, values)
    }

    #[test]
    fn every_codec_round_trips_through_bytes_within_its_precision() {
        for codec in [DnrtCodec::U8, DnrtCodec::F16, DnrtCodec::F32] {
            let (g, values) = grid(codec, DnrtPlacement::Regular);
            let mut w = Writer::new();
            g.write(&mut w);
            let back = DnrtGrid::read(&mut Reader::new(&w.bytes)).unwrap();
            assert_eq!(back, g);
            let decoded = back.values();
            for (k, (v, d)) in values.iter().zip(&decoded).enumerate() {
                let [lo, hi] = g.ranges[range_index(k, 4)];
                let tol = match codec {
                    DnrtCodec::U8 => 0.5 * (hi - lo) as f64 / 255.0 + 1e-6,
                    DnrtCodec::F16 => v.abs() * 4.9e-4 + 1e-7,
                    DnrtCodec::F32 => v.abs() * 1e-7,
                };
                assert!((v - *d as f64).abs() <= tol, "{codec:?} {k}: {v} vs {d}");
            }
            // Truncated bytes are an error, never a panic.
            for cut in [0, 5, w.bytes.len() / 2, w.bytes.len() - 1] {
                assert!(DnrtGrid::read(&mut Reader::new(&w.bytes[..cut])).is_err());
            }
        }
    }

    /// The planar, differenced form (codec tag 3) gives back every grid exactly, 8-bit grids
    /// under tag 3 and the others under their own tags; its bytes are the planar differences;
    /// a count that does not fill the grid, or a cut, is an error, never a panic.
    #[test]
    fn the_planar_form_round_trips_exactly() {
        for codec in [DnrtCodec::U8, DnrtCodec::F16, DnrtCodec::F32] {
            let (g, _) = grid(codec, DnrtPlacement::Quadratic);
            let mut w = Writer::new();
            g.write_planar(&mut w);
            let back = DnrtGrid::read(&mut Reader::new(&w.bytes)).unwrap();
            assert_eq!(back, g, "{codec:?}");
            let mut plain = Writer::new();
            g.write(&mut plain);
            assert_eq!(w.bytes.len(), plain.bytes.len());
            if let DnrtData::U8(v) = &g.data {
                let tail = &w.bytes[w.bytes.len() - v.len()..];
                let (n, k) = (g.resolution as usize, g.values_per_point());
                assert_eq!(tail, to_planar_differences(v, n, k).as_slice());
                assert_ne!(tail, v.as_slice());
                // The count says one value fewer: refused.
                let mut short = w.bytes.clone();
                let at = short.len() - v.len() - 8;
                short[at..at + 8].copy_from_slice(&(v.len() as u64 - 1).to_le_bytes());
                short.pop();
                assert!(DnrtGrid::read(&mut Reader::new(&short)).is_err());
            } else {
                assert_eq!(w.bytes, plain.bytes);
            }
            for cut in [0, 5, w.bytes.len() / 2, w.bytes.len() - 1] {
                assert!(DnrtGrid::read(&mut Reader::new(&w.bytes[..cut])).is_err());
            }
        }
    }

    proptest::proptest! {
        /// Any bytes of any grid size go through the planar differences and back unchanged.
        #[test]
        fn planar_differences_invert(
            n in 1usize..5,
            per_point in 1usize..9,
            seed in proptest::prelude::any::<u64>(),
        ) {
            let len = n * n * n * per_point;
            let mut x = seed | 1;
            let values: Vec<u8> = (0..len)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    (x >> 24) as u8
                })
                .collect();
            let planar = to_planar_differences(&values, n, per_point);
            proptest::prop_assert_eq!(from_planar_differences(&planar, n, per_point), values);
        }
    }

    /// Values inside the analytic bounds quantise to bytes whose dequantised values stay inside
    /// the same bounds, within half a quantisation step of the input.
    #[test]
    fn u8_quantisation_stays_within_the_table_1_bounds() {
        for j in 0..9 {
            let range = analytic_range(j);
            let r32 = [range[0] as f32, range[1] as f32];
            let step = (range[1] - range[0]) / 255.0;
            for k in 0..=1000 {
                let v = range[0] + (range[1] - range[0]) * k as f64 / 1000.0;
                let back = dequantise_u8(quantise_u8(v, r32), r32) as f64;
                assert!(back >= range[0] - 1e-7 && back <= range[1] + 1e-7);
                assert!((back - v).abs() <= 0.5 * step + 1e-7, "{j}: {v} -> {back}");
            }
            // Out-of-range values are clamped to the bounds.
            let over = dequantise_u8(quantise_u8(range[1] + 1.0, r32), r32) as f64;
            assert!((over - range[1]).abs() < 1e-7);
        }
        // Table 1 of the paper (the range of m_j = t_j − k_j) is our bound on m_j times π; for
        // j = 4, 5, 7 it takes twice the basis constant (1.0925) where max|Y_j| is half of
        // it, so ours is tighter there.
        let table1 = [
            0.2820, 0.9772, 0.9772, 0.9772, 2.1850, 2.1850, 1.2615, 2.1850, 1.0925,
        ];
        for (j, t) in table1.iter().enumerate() {
            // m_j = t_j − k_j ∈ [t_lo − k_hi, t_hi − k_lo] for j ≥ 1, and m_0 ∈ [−k_0, 0]
            // (ρ ≤ 1 and Y_0 is constant, so t_0 ≤ k_0).
            let [lo, hi] = analytic_range(j);
            let ours = if j == 0 { hi } else { 2.0 * (hi - lo) } * std::f64::consts::PI;
            let paper = if j == 0 { *t } else { 2.0 * t };
            if [4, 5, 7].contains(&j) {
                assert!((2.0 * ours - paper).abs() < 2e-3, "{j}: {ours} vs {paper}");
            } else {
                assert!((ours - paper).abs() < 1e-3, "{j}: {ours} vs {paper}");
            }
        }
    }

    #[test]
    fn grid_coordinates_invert_offsets_for_both_placements() {
        for placement in [DnrtPlacement::Regular, DnrtPlacement::Quadratic] {
            let (mut g, _) = grid(DnrtCodec::F32, placement);
            g.resolution = 7;
            for i in 0..7 {
                let c = g.grid_coordinate(g.offset(i) as f32);
                assert!((c - i as f32).abs() < 1e-4, "{placement:?} {i}: {c}");
            }
            // Outside the inner cube the coordinate clamps to the edge.
            assert_eq!(g.grid_coordinate(100.0), 6.0);
            assert_eq!(g.grid_coordinate(-100.0), 0.0);
        }
    }

    #[test]
    fn inconsistent_grids_are_refused_naming_the_object() {
        let (g, _) = grid(DnrtCodec::U8, DnrtPlacement::Regular);
        let mut bad = g.clone();
        bad.n_sh = 5;
        let e = bad.validate().unwrap_err().to_string();
        assert!(e.contains("\"ball\""), "{e}");
        let mut bad = g.clone();
        bad.outer_half_extent = 1.0;
        assert!(bad.validate().is_err());
        let mut bad = g.clone();
        bad.data = DnrtData::U8(vec![0; 3]);
        assert!(bad.validate().is_err());
        let mut bad = g;
        bad.data = DnrtData::F32(vec![f32::NAN; 27 * 16]);
        assert!(bad.validate().is_err());
    }
}
