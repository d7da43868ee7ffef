//! SH radiance probes: the per-frame probe field [`ProbeField`] that
//! [`Runtime::apply_probes`](crate::Runtime::apply_probes) fills from the bundle's probe volume
//! (U_dyn), and [`irradiance_at`], which shades a point of any normal from it (dynamic objects,
//! clutter shaded MRT-style).
//!
//! Units and convention: positions in metres, world frame (the layout's). A probe holds the
//! order-2 SH coefficients `L_lm = ∫ L(ω) Y_lm(ω) dω` of the radiance arriving at it
//! (`lightfarm_proto::sh`: 9 coefficients per channel, Sloan's order), in the radiance units
//! of the direct light it was computed from; the operators are albedo-free at the probe (there
//! is no surface there), so nothing is multiplied in afterwards. Irradiance is
//! `E(n) = Σ Â_l L_lm Y_lm(n)` (radiance units × sr), clamped at 0 below.
//!
//! Invariants:
//! - A [`ProbeField`] holds `n_probes × 3 × 9` f32: probe-major, then channel (r, g, b), then
//!   coefficient, so coefficient k of channel c of probe p is at `(p·3 + c)·9 + k` and
//!   [`ProbeField::coefficients`] is one contiguous run of 9.
//! - [`irradiance_at`] never panics and never returns NaN, whatever the volume, field, position
//!   or normal: a volume inconsistent with itself (slot count ≠ grid size, bad spacing or
//!   origin), a non-finite position or a zero / non-finite normal gives zeros, and a grid point
//!   counts as a probe only if its slot names a probe the field has.

use lightfarm_proto::bundle::ProbeVolume;
use lightfarm_proto::sh::{irradiance, SH_COEFFS};

/// Channels per probe (r, g, b).
const CHANNELS: usize = 3;
/// f32 values per probe.
const PER_PROBE: usize = CHANNELS * SH_COEFFS;
/// How many rings of grid points beyond the 8 around a position [`irradiance_at`] searches for
/// the nearest probe when none of the 8 has one.
const SEARCH_RINGS: usize = 3;

/// SH radiance coefficients of every probe of a volume (see the module doc for the layout).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ProbeField {
    n_probes: usize,
    /// `(probe·3 + channel)·9 + coefficient`.
    data: Vec<f32>,
}

impl ProbeField {
    /// Number of probes.
    pub fn n_probes(&self) -> usize {
        self.n_probes
    }

    /// The 9 SH coefficients of `channel` (0 = r, 1 = g, 2 = b) at `probe`.
    ///
    /// # Panics
    /// If `probe >= self.n_probes()` or `channel >= 3`.
    pub fn coefficients(&self, probe: usize, channel: usize) -> &[f32; SH_COEFFS] {
        assert!(
            probe < self.n_probes && channel < CHANNELS,
            "probe {probe} channel {channel} out of range ({} probes)",
            self.n_probes
        );
        let at = (probe * CHANNELS + channel) * SH_COEFFS;
        self.data[at..at + SH_COEFFS]
            .try_into()
            .expect("a run of 9")
    }

    /// Every value, in the documented layout (`n_probes · 27` of them), e.g. for a GPU upload.
    pub fn as_slice(&self) -> &[f32] {
        &self.data
    }

    /// Sizes the field for `n_probes` (allocating only if the size is wrong) and zeroes it.
    pub(crate) fn reset(&mut self, n_probes: usize) {
        if self.data.len() != n_probes * PER_PROBE {
            self.data.clear();
            self.data.resize(n_probes * PER_PROBE, 0.0);
        } else {
            self.data.fill(0.0);
        }
        self.n_probes = n_probes;
    }

    /// Adds `v` (one value per channel) to row `probe · 9 + coefficient`; the row must be below
    /// `n_probes · 9`.
    #[inline]
    pub(crate) fn add_row(&mut self, row: u32, v: [f32; 3]) {
        let (p, k) = (row as usize / SH_COEFFS, row as usize % SH_COEFFS);
        let at = p * PER_PROBE + k;
        self.data[at] += v[0];
        self.data[at + SH_COEFFS] += v[1];
        self.data[at + 2 * SH_COEFFS] += v[2];
    }

    /// Sets every value to `v` (tests: stale values must not leak into a result).
    #[cfg(test)]
    pub(crate) fn fill_for_test(&mut self, v: f32) {
        self.data.fill(v);
    }

    /// Coefficients of `probe` as f64, per channel.
    fn probe_f64(&self, probe: usize) -> [[f64; SH_COEFFS]; CHANNELS] {
        let at = probe * PER_PROBE;
        let d = &self.data[at..at + PER_PROBE];
        std::array::from_fn(|c| std::array::from_fn(|k| d[c * SH_COEFFS + k] as f64))
    }
}

/// A volume whose grid is consistent with its slots, in grid units.
struct Grid<'a> {
    dims: [usize; 3],
    slot: &'a [u32],
    n_probes: usize,
}

impl Grid<'_> {
    /// The probe at grid point `(i, j, k)` (in range), if its slot names one the field has.
    fn probe(&self, p: [usize; 3]) -> Option<usize> {
        let s = self.slot[(p[2] * self.dims[1] + p[1]) * self.dims[0] + p[0]] as usize;
        (s < self.n_probes).then_some(s)
    }
}

/// Irradiance (per channel) at `position` (metres) on a surface of normal `normal` (normalised
/// here; a zero or non-finite one gives zeros), from the probe field of `volume`.
///
/// The radiance coefficients are interpolated trilinearly over the 8 grid points around
/// `position` (grid point `(i, j, k)` at `origin + spacing · (i, j, k)`; the position is clamped
/// to the grid first, so outside the grid the boundary values extend outward). Only grid points
/// whose slot is a probe take part, their weights renormalised to sum to 1. If none of the 8
/// has a probe (or those that do all have weight 0, e.g. exactly on an empty grid point), the
/// nearest probe (Euclidean, ties to the first in k, j, i order) within 3 rings of grid points
/// around the 8 is used alone; if there is none, the result is zeros. Then, per channel,
/// `E = Σ Â_l L_lm Y_lm(n)` (`lightfarm_proto::sh::irradiance`), clamped at 0 below.
///
/// `field` should come from [`Runtime::apply_probes`](crate::Runtime::apply_probes) on the
/// bundle that holds `volume`; never panics and never returns NaN (see the module doc).
pub fn irradiance_at(
    volume: &ProbeVolume,
    field: &ProbeField,
    position: [f32; 3],
    normal: [f32; 3],
) -> [f32; 3] {
    let n = normal.map(|x| x as f64);
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if !(len.is_finite() && len > 0.0) {
        return [0.0; 3];
    }
    let n = n.map(|x| x / len);
    let Some(l) = interpolate(volume, field, position) else {
        return [0.0; 3];
    };
    // `!(e > 0)` also maps a NaN (possible only from a hand-made field) to 0.
    l.map(|lc| {
        let e = irradiance(&lc, n);
        if e > 0.0 {
            e as f32
        } else {
            0.0
        }
    })
}

/// The SH coefficients `L_lm` of the incident radiance `L(ω) = Σ L_lm Y_lm(ω)` (ω the
/// direction looked in) per channel at `position`, interpolated as in [`irradiance_at`]: the
/// radiance of the surfaces around a dynamic object, which DNRT's occlusion hides. Zeros where
/// there is no usable probe.
pub fn radiance_sh_at(
    volume: &ProbeVolume,
    field: &ProbeField,
    position: [f32; 3],
) -> [[f32; SH_COEFFS]; CHANNELS] {
    let Some(l) = interpolate(volume, field, position) else {
        return [[0.0; SH_COEFFS]; CHANNELS];
    };
    l.map(|lc| lc.map(|x| x as f32))
}

/// The SH coefficients `c_lm = Â_l L_lm` of the irradiance `E(n) = Σ c_lm Y_lm(n)` per channel
/// at `position` (radiance interpolated as in [`irradiance_at`]), e.g. the input of DNRT for a
/// dynamic object at `position`. Zeros where [`irradiance_at`] gives zeros for lack of a probe.
pub fn irradiance_sh_at(
    volume: &ProbeVolume,
    field: &ProbeField,
    position: [f32; 3],
) -> [[f32; SH_COEFFS]; CHANNELS] {
    let Some(l) = interpolate(volume, field, position) else {
        return [[0.0; SH_COEFFS]; CHANNELS];
    };
    let a = lightfarm_proto::sh::irradiance_weights();
    l.map(|lc| std::array::from_fn(|k| (a[k] * lc[k]) as f32))
}

/// The interpolated radiance coefficients per channel at `position` (see [`irradiance_at`]),
/// or `None` when there is no usable probe (or the volume or position is unusable).
fn interpolate(
    volume: &ProbeVolume,
    field: &ProbeField,
    position: [f32; 3],
) -> Option<[[f64; SH_COEFFS]; CHANNELS]> {
    let spacing = volume.spacing as f64;
    if !(spacing.is_finite() && spacing > 0.0)
        || volume
            .origin
            .iter()
            .chain(&position)
            .any(|x| !x.is_finite())
        || volume.dims.contains(&0)
        || volume.dims.iter().map(|&d| d as u128).product::<u128>() != volume.slot.len() as u128
    {
        return None;
    }
    // Every dimension is now at most slot.len(), so grid indices fit in usize.
    let grid = Grid {
        dims: volume.dims.map(|d| d as usize),
        slot: &volume.slot,
        n_probes: field.n_probes,
    };
    // Clamped grid coordinates g, base corner i0 (at most dims − 2) and fraction t ∈ [0, 1].
    let mut g = [0.0f64; 3];
    let mut i0 = [0usize; 3];
    let mut t = [0.0f64; 3];
    for a in 0..3 {
        let last = (grid.dims[a] - 1) as f64;
        g[a] = ((position[a] as f64 - volume.origin[a] as f64) / spacing).clamp(0.0, last);
        i0[a] = (g[a].floor() as usize).min(grid.dims[a].saturating_sub(2));
        t[a] = (g[a] - i0[a] as f64).clamp(0.0, 1.0);
    }

    let mut sum = [[0.0f64; SH_COEFFS]; CHANNELS];
    let mut total = 0.0f64;
    for corner in 0..8 {
        let mut p = i0;
        let mut w = 1.0;
        for a in 0..3 {
            if corner >> a & 1 == 1 {
                // With a single grid point on this axis the "+1" corner is that point again
                // (its weight t is 0 then).
                p[a] = (i0[a] + 1).min(grid.dims[a] - 1);
                w *= t[a];
            } else {
                w *= 1.0 - t[a];
            }
        }
        let Some(probe) = grid.probe(p) else { continue };
        if w <= 0.0 {
            continue;
        }
        total += w;
        let l = field.probe_f64(probe);
        for (s, lc) in sum.iter_mut().zip(&l) {
            for (sk, lk) in s.iter_mut().zip(lc) {
                *sk += w * lk;
            }
        }
    }
    if total > 0.0 {
        for s in sum.iter_mut().flatten() {
            *s /= total;
        }
        return Some(sum);
    }
    nearest_probe(&grid, g, i0).map(|p| field.probe_f64(p))
}

/// The probe nearest to grid coordinates `g` (inside the cell at base corner `i0`) among the
/// cell's 8 corners and the [`SEARCH_RINGS`] rings of grid points around them, searched ring by
/// ring; ties go to the first in k, j, i order.
fn nearest_probe(grid: &Grid, g: [f64; 3], i0: [usize; 3]) -> Option<usize> {
    let mut best: Option<(f64, usize)> = None;
    for ring in 0..=SEARCH_RINGS {
        // Every point of ring r is at least r cells from g along some axis.
        if best.is_some_and(|(d2, _)| d2 <= (ring * ring) as f64) {
            break;
        }
        let lo = i0.map(|i| i.saturating_sub(ring));
        let hi: [usize; 3] = std::array::from_fn(|a| (i0[a] + 1 + ring).min(grid.dims[a] - 1));
        for k in lo[2]..=hi[2] {
            for j in lo[1]..=hi[1] {
                for i in lo[0]..=hi[0] {
                    let p = [i, j, k];
                    // Chebyshev distance from the cell's corners [i0, i0 + 1]: only this ring.
                    let dist = (0..3)
                        .map(|a| {
                            p[a].saturating_sub(i0[a] + 1)
                                .max(i0[a].saturating_sub(p[a]))
                        })
                        .max()
                        .unwrap_or(0);
                    if dist != ring {
                        continue;
                    }
                    let Some(probe) = grid.probe(p) else { continue };
                    let d2: f64 = (0..3).map(|a| (p[a] as f64 - g[a]).powi(2)).sum();
                    if best.is_none_or(|(b, _)| d2 < b) {
                        best = Some((d2, probe));
                    }
                }
            }
        }
    }
    best.map(|(_, p)| p)
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    fn volume(dims: [u32; 3], slot: Vec<u32>) -> ProbeVolume {
        let n_probes = slot.iter().filter(|&&s| s != u32::MAX).count() as u32;
        ProbeVolume {
            origin: [1.0, -2.0, 0.5],
            spacing: 0.5,
            dims,
            slot,
            n_probes,
            entries: vec![],
        }
    }

    /// A field whose probe p has coefficients `f(p, channel, k)`.
    fn field(n_probes: usize, f: impl Fn(usize, usize, usize) -> f32) -> ProbeField {
        let mut out = ProbeField::default();
        out.reset(n_probes);
        for p in 0..n_probes {
            for c in 0..3 {
                for k in 0..9 {
                    out.data[(p * 3 + c) * 9 + k] = f(p, c, k);
                }
            }
        }
        out
    }

    /// World position of grid coordinates `g` of the test volume.
    fn at(g: [f32; 3]) -> [f32; 3] {
        [1.0 + 0.5 * g[0], -2.0 + 0.5 * g[1], 0.5 + 0.5 * g[2]]
    }

    fn normals() -> Vec<[f32; 3]> {
        let mut v = vec![
            [1.0, 0.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.0, 0.0, 1.0],
            [0.3, 0.4, -0.5],
            [-2.0, 1.0, 3.0],
        ];
        v.push([1e-20, 0.0, 0.0]);
        v
    }

    fn direct_irradiance(field: &ProbeField, probe: usize, n: [f32; 3]) -> [f32; 3] {
        let n = n.map(|x| x as f64);
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        let l = field.probe_f64(probe);
        l.map(|lc| irradiance(&lc, n.map(|x| x / len)).max(0.0) as f32)
    }

    /// The irradiance SH evaluated at a normal equals `irradiance_at` wherever that is
    /// positive (same interpolation, same convolution), at probes and between them.
    #[test]
    fn irradiance_sh_agrees_with_irradiance_at() {
        let vol = volume([2, 2, 2], (0..8).collect());
        let f = field(8, |p, c, k| {
            if k == 0 {
                3.0 + p as f32 + c as f32
            } else {
                0.3 * ((p * 7 + c * 3 + k) % 5) as f32 - 0.6
            }
        });
        for g in [[0.0, 0.0, 0.0], [0.3, 0.7, 0.5], [1.0, 1.0, 0.2]] {
            let x = at(g);
            let c = irradiance_sh_at(&vol, &f, x);
            for n in normals().into_iter().take(5) {
                let nn = n.map(|v| v as f64);
                let len = (nn[0] * nn[0] + nn[1] * nn[1] + nn[2] * nn[2]).sqrt();
                let y = lightfarm_proto::sh::sh_basis(nn.map(|v| v / len));
                let e = irradiance_at(&vol, &f, x, n);
                for ch in 0..3 {
                    let from_sh: f64 = (0..9).map(|k| c[ch][k] as f64 * y[k]).sum();
                    let want = e[ch] as f64;
                    assert!(
                        (from_sh.max(0.0) - want).abs() < 1e-4 * want.max(1.0),
                        "{g:?} {n:?} {ch}: {from_sh} vs {want}"
                    );
                }
            }
        }
        // No probe: zeros.
        let empty = volume([2, 2, 2], vec![u32::MAX; 8]);
        assert_eq!(irradiance_sh_at(&empty, &f, at([0.5; 3])), [[0.0; 9]; 3]);
    }

    #[test]
    fn layout_and_accessors() {
        let mut f = ProbeField::default();
        assert_eq!(f.n_probes(), 0);
        f.reset(2);
        f.add_row(9 + 4, [1.0, 2.0, 3.0]);
        assert_eq!(f.n_probes(), 2);
        assert_eq!(f.as_slice().len(), 54);
        assert_eq!(f.coefficients(1, 0)[4], 1.0);
        assert_eq!(f.coefficients(1, 1)[4], 2.0);
        assert_eq!(f.coefficients(1, 2)[4], 3.0);
        assert_eq!(f.as_slice()[(3 + 2) * 9 + 4], 3.0);
        assert_eq!(f.as_slice().iter().filter(|&&v| v != 0.0).count(), 3);
        f.reset(2);
        assert!(f.as_slice().iter().all(|&v| v == 0.0));
    }

    #[test]
    fn constant_radiance_gives_pi_for_every_normal_and_position() {
        // 2×2×2 with one empty slot; L = 1 everywhere ⇒ L_00 = √(4π), E = π.
        let v = volume([2, 2, 2], vec![0, 1, 2, u32::MAX, 3, 4, 5, 6]);
        let l00 = (4.0 * PI).sqrt() as f32;
        let f = field(7, |_, _, k| if k == 0 { l00 } else { 0.0 });
        for g in [
            [0.0, 0.0, 0.0],
            [1.0, 1.0, 0.0],
            [0.5, 0.5, 0.5],
            [0.9, 0.99, 0.01],
            [-3.0, 0.5, 7.0],
            [1.0, 0.5, 1.0],
        ] {
            for n in normals() {
                let e = irradiance_at(&v, &f, at(g), n);
                for c in 0..3 {
                    assert!((e[c] as f64 - PI).abs() < 1e-5, "g {g:?} n {n:?}: {e:?}");
                }
            }
        }
    }

    #[test]
    fn at_a_probe_is_the_probes_own_irradiance() {
        let v = volume([2, 2, 2], vec![0, 1, 2, u32::MAX, 3, 4, 5, 6]);
        let f = field(7, |p, c, k| {
            if k == 0 {
                3.0 + p as f32
            } else {
                0.1 * (p as f32 - 3.0) * (k as f32 - 4.0) + 0.05 * c as f32
            }
        });
        for (i, &s) in v.slot.iter().enumerate() {
            if s == u32::MAX {
                continue;
            }
            let g = [(i & 1) as f32, (i >> 1 & 1) as f32, (i >> 2) as f32];
            for n in normals() {
                assert_eq!(
                    irradiance_at(&v, &f, at(g), n),
                    direct_irradiance(&f, s as usize, n),
                    "probe {s}"
                );
            }
        }
    }

    #[test]
    fn midway_is_the_average_and_empty_slots_drop_out() {
        let v = volume([2, 2, 2], vec![0, 1, 2, u32::MAX, 3, 4, 5, 6]);
        let f = field(7, |p, c, k| {
            if k == 0 {
                5.0 + p as f32 + c as f32
            } else {
                0.2 * ((p * 7 + k * 3 + c) % 5) as f32 - 0.4
            }
        });
        // Between probes 0 (0,0,0) and 1 (1,0,0): coefficients and irradiance are the mean.
        let mid = interpolate(&v, &f, at([0.5, 0.0, 0.0])).unwrap();
        let (a, b) = (f.probe_f64(0), f.probe_f64(1));
        for c in 0..3 {
            for k in 0..9 {
                assert!((mid[c][k] - 0.5 * (a[c][k] + b[c][k])).abs() < 1e-6);
            }
        }
        for n in normals() {
            let e = irradiance_at(&v, &f, at([0.5, 0.0, 0.0]), n);
            let (ea, eb) = (direct_irradiance(&f, 0, n), direct_irradiance(&f, 1, n));
            for c in 0..3 {
                assert!(ea[c] > 0.0 && eb[c] > 0.0, "no clamping in this field");
                assert!((e[c] - 0.5 * (ea[c] + eb[c])).abs() < 1e-4, "{e:?}");
            }
        }
        // Between probe 2 (0,1,0) and the empty slot (1,1,0): probe 2 alone.
        let n = [0.0, 1.0, 0.0];
        assert_eq!(
            irradiance_at(&v, &f, at([0.5, 1.0, 0.0]), n),
            direct_irradiance(&f, 2, n)
        );
        // Exactly on the empty slot: every probe corner has weight 0, so the nearest probes
        // (1 and 2, one cell away) are used; the first in k, j, i order wins the tie.
        assert_eq!(
            irradiance_at(&v, &f, at([1.0, 1.0, 0.0]), n),
            direct_irradiance(&f, 1, n)
        );
        // At the cell centre: the mean of the 7 probes.
        let centre = interpolate(&v, &f, at([0.5, 0.5, 0.5])).unwrap();
        for c in 0..3 {
            for k in 0..9 {
                let want = (0..7).map(|p| f.probe_f64(p)[c][k]).sum::<f64>() / 7.0;
                assert!((centre[c][k] - want).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn edges_outside_and_degenerate_inputs_are_never_nan() {
        let v = volume([2, 2, 2], vec![0, 1, 2, u32::MAX, 3, 4, 5, 6]);
        let f = field(7, |p, c, k| (p + c + k) as f32 * 0.3 - 1.0);
        let n = [0.2, -0.3, 0.9];
        // On the grid's far edge (x = y = 1, z between) and far corner.
        for g in [[1.0, 0.0, 0.5], [1.0, 1.0, 1.0], [0.0, 1.0, 0.25]] {
            let e = irradiance_at(&v, &f, at(g), n);
            assert!(e.iter().all(|x| x.is_finite() && *x >= 0.0), "{g:?}: {e:?}");
        }
        // Outside: clamped to the grid.
        assert_eq!(
            irradiance_at(&v, &f, at([-4.0, -0.1, -9.0]), n),
            direct_irradiance(&f, 0, n)
        );
        assert_eq!(
            irradiance_at(&v, &f, at([30.0, 1e30, 2.0]), n),
            irradiance_at(&v, &f, at([1.0, 1.0, 1.0]), n)
        );
        // Zero, tiny-but-zero-length and non-finite normals; non-finite positions.
        for bad in [[0.0; 3], [f32::NAN, 0.0, 1.0], [f32::INFINITY, 0.0, 0.0]] {
            assert_eq!(irradiance_at(&v, &f, at([0.5; 3]), bad), [0.0; 3]);
        }
        for bad in [[f32::NAN, 0.0, 0.0], [0.0, f32::NEG_INFINITY, 0.0]] {
            assert_eq!(irradiance_at(&v, &f, bad, n), [0.0; 3]);
        }
        // Fields that do not match the volume, and volumes inconsistent with themselves.
        assert_eq!(
            irradiance_at(&v, &ProbeField::default(), at([0.5; 3]), n),
            [0.0; 3]
        );
        let short = field(3, |_, _, _| 1.0);
        let e = irradiance_at(&v, &short, at([0.5; 3]), n);
        assert!(e.iter().all(|x| x.is_finite()));
        let mut broken = v.clone();
        broken.slot.pop();
        assert_eq!(irradiance_at(&broken, &f, at([0.5; 3]), n), [0.0; 3]);
        for (dims, spacing) in [([0, 2, 2], 0.5), ([u32::MAX; 3], 0.5), ([2, 2, 2], 0.0)] {
            let mut b = v.clone();
            b.dims = dims;
            b.spacing = spacing;
            assert_eq!(irradiance_at(&b, &f, at([0.5; 3]), n), [0.0; 3]);
        }
        // A NaN or huge coefficient in a hand-made field still gives no NaN.
        let nan = field(7, |p, _, k| if p == 0 && k == 1 { f32::NAN } else { 1.0 });
        let e = irradiance_at(&v, &nan, at([0.0; 3]), n);
        assert!(e.iter().all(|x| !x.is_nan()), "{e:?}");
        let huge = field(7, |_, _, k| if k == 0 { f32::MAX } else { -f32::MAX });
        let e = irradiance_at(&v, &huge, at([0.5; 3]), n);
        assert!(e.iter().all(|x| !x.is_nan()), "{e:?}");
    }

    #[test]
    fn flat_and_single_point_grids() {
        // One grid point: every position gets it.
        let v = volume([1, 1, 1], vec![0]);
        let f = field(1, |_, c, k| if k == 0 { 1.0 + c as f32 } else { 0.0 });
        let n = [0.0, 0.0, 1.0];
        for g in [[0.0; 3], [5.0, -5.0, 0.3]] {
            assert_eq!(irradiance_at(&v, &f, at(g), n), direct_irradiance(&f, 0, n));
        }
        // A 3×1×1 line: midway between the last two is their mean.
        let v = volume([3, 1, 1], vec![0, 1, 2]);
        let f = field(3, |p, _, k| if k == 0 { 1.0 + p as f32 } else { 0.0 });
        let mid = interpolate(&v, &f, at([1.5, 0.0, 0.0])).unwrap();
        assert!((mid[0][0] - 2.5).abs() < 1e-12);
    }

    #[test]
    fn ring_search_finds_the_nearest_probe_within_three_rings() {
        // A 7×1×1 line with probes only at x = 5 (probe 0) and x = 6 (probe 1).
        let mut slot = vec![u32::MAX; 7];
        slot[5] = 0;
        slot[6] = 1;
        let v = volume([7, 1, 1], slot);
        let f = field(
            2,
            |p, _, k| if k == 0 { 10.0 * (p + 1) as f32 } else { 0.0 },
        );
        let n = [0.0, 1.0, 0.0];
        // Cell [2, 3]: probe 0 is in ring 2.
        assert_eq!(
            irradiance_at(&v, &f, at([2.2, 0.0, 0.0]), n),
            direct_irradiance(&f, 0, n)
        );
        // Cell [1, 2]: ring 3 reaches x = 5.
        assert_eq!(
            irradiance_at(&v, &f, at([1.0, 0.0, 0.0]), n),
            direct_irradiance(&f, 0, n)
        );
        // Cell [0, 1]: x = 5 is ring 4, too far.
        assert_eq!(irradiance_at(&v, &f, at([0.7, 0.0, 0.0]), n), [0.0; 3]);
        assert!(interpolate(&v, &f, at([0.7, 0.0, 0.0])).is_none());

        // The nearest, not the first ring's: in a 2-D grid, from (1.9, 1.5) in cell (1, 1),
        // (0, 0) is ring 1 at distance √(1.9² + 1.5²) ≈ 2.4, (4, 1) ring 2 at ≈ 2.2.
        let mut slot = vec![u32::MAX; 6 * 4];
        slot[0] = 0; // (0, 0)
        slot[6 + 4] = 1; // (4, 1)
        let v = volume([6, 4, 1], slot);
        let f = field(
            2,
            |p, _, k| if k == 0 { 10.0 * (p + 1) as f32 } else { 0.0 },
        );
        assert_eq!(
            irradiance_at(&v, &f, at([1.9, 1.5, 0.0]), n),
            direct_irradiance(&f, 1, n)
        );
        assert_eq!(
            irradiance_at(&v, &f, at([1.1, 1.0, 0.0]), n),
            direct_irradiance(&f, 0, n)
        );
    }
}
