//! A texel's samples for its direct light, and what a point light gives each before shadows:
//! where the `m × m` samples of a texel lie ([`sample_points`], [`sample_point`]), the
//! unshadowed term `cos θ / max(r², r2_min)` at each ([`unshadowed`], [`unshadowed_samples`],
//! and per row and column on an axis-aligned texel, [`unshadowed_grid`]), the facing test that
//! skips a texel's samples, and the scratch the adaptive average keeps across texels
//! ([`TexelSamples`]). [`crate::direct`] adds the shadow rays and the averaging.
//!
//! Units: world metres; terms in 1/m² (times a light's intensity, W/sr, they are irradiance).
//! Invariants: every path here gives a sample the same f32 coordinates and the same f64
//! operations in the same order, so the terms are bit-identical whichever computes them (on
//! any CPU: the AVX2 variants use IEEE division and square root, never fused products).

use lightfarm_proto::bundle::Layout;
use lightfarm_proto::face::tangent_axes;
use lightfarm_proto::glam::DVec3;
use lightfarm_proto::lights::Light;

/// The most samples per edge [`crate::direct::direct_from_point_lights_adaptive`] handles adaptively (its
/// samples live on the stack); more fall back to [`crate::direct::direct_from_point_lights_averaged`].
pub const ADAPTIVE_MAX_SAMPLES_PER_EDGE: u32 = 8;

/// What the direct light of one layout texel reads: centre, normal, albedo and extent.
#[derive(Clone, Copy)]
pub(crate) struct TexelAt {
    pub(crate) x: [f32; 3],
    pub(crate) n: [f32; 3],
    pub(crate) rho: [f32; 3],
    pub(crate) size: [f32; 2],
}

impl TexelAt {
    #[inline(always)]
    pub(crate) fn of(layout: &Layout, t: usize) -> TexelAt {
        TexelAt {
            x: layout.positions[t],
            n: layout.normals[t],
            rho: layout.albedo[t],
            size: layout.texel_size.get(t).copied().unwrap_or([0.0, 0.0]),
        }
    }
}

/// Scratch for one texel's adaptive average (kept across texels, so nothing is cleared per
/// texel): the unshadowed terms of the light at hand and the sample points, the four corners
/// always and the rest only once some light's corners disagree (or the texel is slanted).
pub(crate) struct TexelSamples {
    pub(crate) g: [f64; MAX_ADAPTIVE_SAMPLES],
    pub(crate) points: [[f32; 3]; MAX_ADAPTIVE_SAMPLES],
    /// `points` holds every sample of the current texel.
    pub(crate) all_points: bool,
    /// `points` holds the current texel's four corners ([`TexelSamples::corners`]).
    corner_points: bool,
    /// Samples per edge `offsets` are for (0: none yet), and the samples' offsets along an
    /// edge ([`sample_offset`], made once per `m` rather than per texel).
    m: usize,
    offsets: [f32; ADAPTIVE_MAX_SAMPLES_PER_EDGE as usize],
}

/// Samples of the adaptive average at most.
const MAX_ADAPTIVE_SAMPLES: usize =
    (ADAPTIVE_MAX_SAMPLES_PER_EDGE * ADAPTIVE_MAX_SAMPLES_PER_EDGE) as usize;

impl TexelSamples {
    pub(crate) fn new() -> TexelSamples {
        TexelSamples {
            g: [0.0; MAX_ADAPTIVE_SAMPLES],
            points: [[0.0; 3]; MAX_ADAPTIVE_SAMPLES],
            all_points: false,
            corner_points: false,
            m: 0,
            offsets: [0.0; ADAPTIVE_MAX_SAMPLES_PER_EDGE as usize],
        }
    }

    /// Starts texel `t` (`m × m` samples): every point when it is slanted (its unshadowed
    /// terms are then taken per point); an axis-aligned texel's corner points wait for
    /// [`TexelSamples::corners`].
    pub(crate) fn start(&mut self, t: &TexelAt, m: usize) {
        self.all_points = false;
        self.corner_points = false;
        if self.m != m {
            self.m = m;
            for (i, o) in self.offsets.iter_mut().enumerate().take(m) {
                *o = sample_offset(i, m);
            }
        }
        if !is_axis_aligned(t.n) {
            self.fill_points(t, m);
        }
    }

    /// Makes the started texel's four corner points (the first shadow rays), if not made.
    pub(crate) fn corners(&mut self, t: &TexelAt, m: usize) {
        if self.all_points || self.corner_points {
            return;
        }
        for k in corner_indices(m) {
            let (ou, ov) = (self.offsets[k % m], self.offsets[k / m]);
            self.points[k] = sample_point(t.x, t.n, t.size, ou, ov);
        }
        self.corner_points = true;
    }

    pub(crate) fn fill_points(&mut self, t: &TexelAt, m: usize) {
        if !self.all_points {
            sample_points(t.x, t.n, t.size, m, &mut self.points[..m * m]);
            self.all_points = true;
        }
    }

    /// `light`'s unshadowed terms at the texel's samples into `g[..m²]`.
    pub(crate) fn unshadowed(&mut self, t: &TexelAt, m: usize, light: &Light, r2_min: f64) {
        let g = &mut self.g[..m * m];
        if is_axis_aligned(t.n) {
            assert_eq!(self.m, m, "started on this texel");
            unshadowed_grid(t, (m, &self.offsets), light, r2_min, g);
        } else {
            unshadowed_samples(&self.points[..m * m], t.n, light, r2_min, g);
        }
    }
}

/// The indices of the four corner samples of an `m × m` grid (row by row).
pub(crate) fn corner_indices(m: usize) -> [usize; 4] {
    [0, m - 1, m * (m - 1), m * m - 1]
}

pub(crate) fn is_axis_aligned(n: [f32; 3]) -> bool {
    let a = dominant_axis(n);
    let (u, v) = tangent_axes(a);
    n[u] == 0.0 && n[v] == 0.0
}

/// True when `n` is axis-aligned and `light` lies behind or in the plane through `x` normal to
/// it: then every sample point of the texel (which [`sample_points`] keeps in that plane) gets
/// a zero [`unshadowed`] term, `n · (p − x)` being the same product `n_a (p_a − x_a)` at each.
#[allow(clippy::neg_cmp_op_on_partial_ord)] // `!(… > 0)`: a NaN product faces away too.
pub(crate) fn faces_away(x: &[f32; 3], n: &[f32; 3], light: &Light) -> bool {
    let a = dominant_axis(*n);
    let (u, v) = tangent_axes(a);
    n[u] == 0.0 && n[v] == 0.0 && !(n[a] as f64 * (light.position[a] - x[a] as f64) > 0.0)
}

/// Lights closer to a texel's centre than this many of its half-diagonals get the texel's
/// exact unshadowed mean ([`near_light_mean`]). Farther, the 2 × 2 Gauss–Legendre mean
/// ([`far_light_mean`]) is close: within 0.025% of the exact one on a rectangle, the worst over
/// 4,000 random directions down to 1° above the texel's plane and texels of aspect 1:4 to 2:1
/// (0.08% at 6 half-diagonals, 0.35% at 4), where the 4 × 4 grid of samples the texel's
/// shadows are traced at is off by 0.18% (0.32%, 0.73%). Nearer, a grid misses the peak: a
/// light 5 cm from a wall whose texels are 1.5 × 0.75 m gave the four texels around its foot
/// 36% of their light on the 4 × 4 grid.
pub(crate) const NEAR_HALF_DIAGONALS: f64 = 8.0;

/// The texel's unshadowed mean of `cos θ / max(r², r2_min)` from `light`: exact near the light
/// ([`near_light_mean`]), by the 2 × 2 Gauss–Legendre rule farther ([`far_light_mean`]).
pub(crate) fn unshadowed_mean(t: &TexelAt, light: &Light, r2_min: f64) -> f64 {
    near_light_mean(t, light).unwrap_or_else(|| far_light_mean(t, light, r2_min))
}

/// Offset of the 2-point Gauss–Legendre nodes on an edge of unit length: ±1/(2√3).
const GAUSS_2_OFFSET: f64 = 0.288_675_134_594_812_9;

/// The mean of `cos θ / max(r², r2_min)` from `light` over texel `t`'s parallelogram (what
/// [`sample_point`] spans, in f64) by the 2 × 2 Gauss–Legendre rule: exact for terms cubic in
/// each edge's coordinate, so four terms come closer to the exact mean than the 16 of a 4 × 4
/// grid of midpoints wherever the light is a few texels away (see [`NEAR_HALF_DIAGONALS`]).
/// The nodes are summed row by row.
pub(crate) fn far_light_mean(t: &TexelAt, light: &Light, r2_min: f64) -> f64 {
    let a = dominant_axis(t.n);
    let (u, v) = tangent_axes(a);
    let x = DVec3::from(t.x.map(f64::from));
    let n = t.n.map(f64::from);
    let slanted = n[u] != 0.0 || n[v] != 0.0;
    if !slanted {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked above); the function has no other
            // contract.
            return unsafe { axis_aligned_far_mean_avx2(t, light, r2_min, (a, u, v)) };
        }
        return axis_aligned_far_mean(t, light, r2_min, (a, u, v));
    }
    let mut sum = 0.0;
    for ov in [-GAUSS_2_OFFSET, GAUSS_2_OFFSET] {
        for ou in [-GAUSS_2_OFFSET, GAUSS_2_OFFSET] {
            let (du, dv) = (ou * t.size[0] as f64, ov * t.size[1] as f64);
            let mut p = x;
            p[u] += du;
            p[v] += dv;
            p[a] -= (n[u] * du + n[v] * dv) / n[a];
            sum += unshadowed_at(p, t.n, light, r2_min);
        }
    }
    0.25 * sum
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn axis_aligned_far_mean_avx2(
    t: &TexelAt,
    light: &Light,
    r2_min: f64,
    axes: (usize, usize, usize),
) -> f64 {
    axis_aligned_far_mean(t, light, r2_min, axes)
}

/// [`far_light_mean`] on an axis-aligned texel: every node lies at the centre's height along
/// the normal, so `cos θ / r² = n_a (l_a − x_a) / (r · max(r², r2_min))` with only the tangent
/// offsets varying; the four nodes' terms as lanes (IEEE square root and division, no fused
/// products: the same bits on any CPU), summed in node order.
#[inline(always)]
#[allow(clippy::neg_cmp_op_on_partial_ord)] // `!(… > 0)`: a NaN height gives nothing too.
fn axis_aligned_far_mean(
    t: &TexelAt,
    light: &Light,
    r2_min: f64,
    (a, u, v): (usize, usize, usize),
) -> f64 {
    let l = light.position;
    let height = t.n[a] as f64 * (l[a] - t.x[a] as f64);
    // `!(… > 0)`: a light behind or in the plane (or NaN) gives nothing.
    if !(height > 0.0) {
        return 0.0;
    }
    let (hu, hv) = (
        GAUSS_2_OFFSET * t.size[0] as f64,
        GAUSS_2_OFFSET * t.size[1] as f64,
    );
    let (cu, cv) = (l[u] - t.x[u] as f64, l[v] - t.x[v] as f64);
    let to_u = [cu + hu, cu - hu, cu + hu, cu - hu];
    let to_v = [cv + hv, cv + hv, cv - hv, cv - hv];
    let h2 = height * height;
    let mut g = [0.0f64; 4];
    for k in 0..4 {
        let r2 = to_u[k] * to_u[k] + to_v[k] * to_v[k] + h2;
        let value = height / (r2.sqrt() * r2.max(r2_min));
        g[k] = if r2 > 0.0 { value } else { 0.0 };
    }
    0.25 * (((g[0] + g[1]) + g[2]) + g[3])
}

/// The exact mean of `cos θ / r²` from `light` over a texel (the solid angle the texel
/// subtends from the light, over its area): on an axis-aligned texel's rectangle in closed
/// form, on a slanted texel's parallelogram (what [`sample_point`] spans) by two triangles'
/// solid angles. `None` when the texel has no area, when the light lies behind or in its plane,
/// or when it is farther than [`NEAR_HALF_DIAGONALS`] half-diagonals from the centre (there
/// [`far_light_mean`] stands).
pub(crate) fn near_light_mean(t: &TexelAt, light: &Light) -> Option<f64> {
    let a = dominant_axis(t.n);
    let (u, v) = tangent_axes(a);
    if t.n[u] != 0.0 || t.n[v] != 0.0 {
        return slanted_near_light_mean(t, light, (a, u, v));
    }
    axis_aligned_near_mean(t, light, (a, u, v))
}

/// [`unshadowed_mean`] of an axis-aligned texel whose normal lies along axis `a` (tangent axes
/// `u`, `v`: [`dominant_axis`], [`tangent_axes`]), for a caller that has them already: the
/// same operations, so the same bits. The far rule runs in the caller's instruction set.
#[inline(always)]
pub(crate) fn axis_aligned_mean(
    t: &TexelAt,
    light: &Light,
    r2_min: f64,
    axes: (usize, usize, usize),
) -> f64 {
    match axis_aligned_near_mean(t, light, axes) {
        Some(mean) => mean,
        None => axis_aligned_far_mean(t, light, r2_min, axes),
    }
}

/// [`near_light_mean`] on an axis-aligned texel (normal along `a`).
#[inline(always)]
fn axis_aligned_near_mean(
    t: &TexelAt,
    light: &Light,
    (a, u, v): (usize, usize, usize),
) -> Option<f64> {
    let (su, sv) = ((t.size[0] as f64).abs(), (t.size[1] as f64).abs());
    let to = [0, 1, 2].map(|k| light.position[k] - t.x[k] as f64);
    // Height of the light above the texel's plane, on the lit side.
    let d = if t.n[a] > 0.0 { to[a] } else { -to[a] };
    let half_diagonal2 = 0.25 * (su * su + sv * sv);
    let r2 = to[0] * to[0] + to[1] * to[1] + to[2] * to[2];
    let near2 = NEAR_HALF_DIAGONALS * NEAR_HALF_DIAGONALS * half_diagonal2;
    // `!(… < …)` so that a NaN is not near either.
    if !(d > 0.0) || su * sv == 0.0 || !(r2 < near2) {
        return None;
    }
    // The rectangle relative to the light's foot on the plane.
    let (u0, u1) = (-0.5 * su - to[u], 0.5 * su - to[u]);
    let (v0, v1) = (-0.5 * sv - to[v], 0.5 * sv - to[v]);
    // Solid angle of [0, x] × [0, y] (signed) at height d: atan(xy / (d √(d² + x² + y²))).
    let corner = |x: f64, y: f64| (x * y / (d * (d * d + x * x + y * y).sqrt())).atan();
    let solid_angle = corner(u1, v1) - corner(u0, v1) - corner(u1, v0) + corner(u0, v0);
    Some((solid_angle / (su * sv)).max(0.0))
}

/// [`near_light_mean`] on a slanted texel: the parallelogram `x ± E_u/2 ± E_v/2` whose edges
/// step `size[0]` along tangent `u` and `size[1]` along `v`, lifted along the dominant axis `a`
/// onto the texel's plane (as [`sample_point`] places samples), its solid angle from the light
/// as two triangles' (Van Oosterom and Strackee).
fn slanted_near_light_mean(
    t: &TexelAt,
    light: &Light,
    (a, u, v): (usize, usize, usize),
) -> Option<f64> {
    let n = DVec3::from(t.n.map(f64::from));
    let mut eu = DVec3::ZERO;
    eu[u] = t.size[0] as f64;
    eu[a] = -t.size[0] as f64 * n[u] / n[a];
    let mut ev = DVec3::ZERO;
    ev[v] = t.size[1] as f64;
    ev[a] = -t.size[1] as f64 * n[v] / n[a];
    let area = eu.cross(ev).length();
    let to = DVec3::from(light.position) - DVec3::from(t.x.map(f64::from));
    let half_diagonal = 0.5 * (eu + ev).length().max((eu - ev).length());
    let near = NEAR_HALF_DIAGONALS * half_diagonal;
    // `!(… > …)` so that a NaN is not near either.
    if !(to.dot(n) > 0.0) || !(area > 0.0) || !(to.length_squared() < near * near) {
        return None;
    }
    // Corners relative to the light, in order around the parallelogram.
    let corner = |su: f64, sv: f64| 0.5 * su * eu + 0.5 * sv * ev - to;
    let c = [
        corner(-1.0, -1.0),
        corner(1.0, -1.0),
        corner(1.0, 1.0),
        corner(-1.0, 1.0),
    ];
    let triangle = |p: DVec3, q: DVec3, r: DVec3| {
        let (lp, lq, lr) = (p.length(), q.length(), r.length());
        let num = p.dot(q.cross(r));
        let den = lp * lq * lr + p.dot(q) * lr + p.dot(r) * lq + q.dot(r) * lp;
        2.0 * num.atan2(den)
    };
    let solid_angle = (triangle(c[0], c[1], c[2]) + triangle(c[0], c[2], c[3])).abs();
    Some(solid_angle / area)
}

/// [`unshadowed`] at every point of `points` into `g`: the same operations in the same order
/// (so the same bits), written without branches so the loop vectorizes (four lanes where the
/// CPU has AVX2, chosen at run time; IEEE division and square root round alike in every
/// width).
#[inline]
pub(crate) fn unshadowed_samples(
    points: &[[f32; 3]],
    n: [f32; 3],
    light: &Light,
    r2_min: f64,
    g: &mut [f64],
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked above); the function has no other contract.
        return unsafe { unshadowed_samples_avx2(points, n, light, r2_min, g) };
    }
    unshadowed_samples_portable(points, n, light, r2_min, g)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn unshadowed_samples_avx2(
    points: &[[f32; 3]],
    n: [f32; 3],
    light: &Light,
    r2_min: f64,
    g: &mut [f64],
) {
    unshadowed_samples_portable(points, n, light, r2_min, g)
}

#[inline(always)]
fn unshadowed_samples_portable(
    points: &[[f32; 3]],
    n: [f32; 3],
    light: &Light,
    r2_min: f64,
    g: &mut [f64],
) {
    let l = light.position;
    let nn = n.map(f64::from);
    for (gi, q) in g.iter_mut().zip(points) {
        let to = [l[0] - q[0] as f64, l[1] - q[1] as f64, l[2] - q[2] as f64];
        let r2 = to[0] * to[0] + to[1] * to[1] + to[2] * to[2];
        let cos = (nn[0] * to[0] + nn[1] * to[1] + nn[2] * to[2]) / r2.sqrt();
        let value = cos / r2.max(r2_min);
        *gi = if r2 > 0.0 && cos > 0.0 { value } else { 0.0 };
    }
}

/// `cos θ / max(r², r2_min)` of `light` at point `x` with normal `n`, 0 when the light is
/// behind (or at) the point; no shadow ray. Every direct-light path here shares it.
pub(crate) fn unshadowed(x: [f32; 3], n: [f32; 3], light: &Light, r2_min: f64) -> f64 {
    unshadowed_at(DVec3::from(x.map(f64::from)), n, light, r2_min)
}

/// [`unshadowed`] at a point given in f64 (the same operations: an f32 point widens exactly).
#[inline]
fn unshadowed_at(x: DVec3, n: [f32; 3], light: &Light, r2_min: f64) -> f64 {
    let to = [0, 1, 2].map(|k| light.position[k] - x[k]);
    let r2 = to[0] * to[0] + to[1] * to[1] + to[2] * to[2];
    if r2.is_nan() || r2 <= 0.0 {
        return 0.0;
    }
    let cos = (n[0] as f64 * to[0] + n[1] as f64 * to[1] + n[2] as f64 * to[2]) / r2.sqrt();
    if cos.is_nan() || cos <= 0.0 {
        return 0.0;
    }
    cos / r2.max(r2_min)
}

/// The sample of a texel at offsets `(ou, ov)` along its edges ([`sample_offset`] of its
/// column and row): the point [`sample_points`] puts there, bit for bit (the same
/// expressions).
#[inline]
pub(crate) fn sample_point(x: [f32; 3], n: [f32; 3], size: [f32; 2], ou: f32, ov: f32) -> [f32; 3] {
    let axis = dominant_axis(n);
    let (u, v) = tangent_axes(axis);
    let du = ou * size[0];
    let dv = ov * size[1];
    let slanted = n[u] != 0.0 || n[v] != 0.0;
    let lifted = if slanted {
        x[axis] - (n[u] * du + n[v] * dv) / n[axis]
    } else {
        x[axis]
    };
    match axis {
        0 => [lifted, x[1] + du, x[2] + dv],
        1 => [x[0] + du, lifted, x[2] + dv],
        _ => [x[0] + du, x[1] + dv, lifted],
    }
}

/// A box holding every one of the `m × m` sample points of texel `t` ([`sample_point`] at
/// offsets ±(0.5 − 0.5/m) at most; the centre when `m` is 1): the centre ± the samples' reach
/// along the tangent axes and, on a slanted texel, ± the lift those offsets give along the
/// dominant axis, padded well above f32 rounding. On an axis-aligned texel every sample has
/// the centre's coordinate along the normal, exactly, and so has the box. The whole space
/// when anything is not finite.
pub(crate) fn sample_bounds(t: &TexelAt, m: usize) -> ([f64; 3], [f64; 3]) {
    let axis = dominant_axis(t.n);
    let (u, v) = tangent_axes(axis);
    let x = t.x.map(f64::from);
    let reach = 0.5 - 0.5 / m.max(1) as f64;
    let (hu, hv) = (
        reach * (t.size[0] as f64).abs(),
        reach * (t.size[1] as f64).abs(),
    );
    let n = t.n.map(f64::from);
    let slanted = n[u] != 0.0 || n[v] != 0.0;
    let lift = if slanted {
        (n[u].abs() * hu + n[v].abs() * hv) / n[axis].abs()
    } else {
        0.0
    };
    let mag = x.iter().fold(hu + hv + lift, |m, c| m.max(c.abs()));
    let pad = 1e-6 * mag + f64::MIN_POSITIVE;
    let mut half = [0.0; 3];
    half[u] = hu * (1.0 + 1e-6) + pad;
    half[v] = hv * (1.0 + 1e-6) + pad;
    half[axis] = if slanted {
        lift * (1.0 + 1e-6) + pad
    } else {
        0.0
    };
    let lo = [0, 1, 2].map(|k| x[k] - half[k]);
    let hi = [0, 1, 2].map(|k| x[k] + half[k]);
    if lo.iter().chain(&hi).all(|c| c.is_finite()) {
        (lo, hi)
    } else {
        ([f64::NEG_INFINITY; 3], [f64::INFINITY; 3])
    }
}

/// The offset of sample `i` of `m` along a texel's edge, in texel units (−0.5 … 0.5).
#[inline]
pub(crate) fn sample_offset(i: usize, m: usize) -> f32 {
    (i as f32 + 0.5) / m as f32 - 0.5
}

/// Samples per edge and their offsets ([`sample_offset`] of `0..m`).
type GridSamples<'a> = (usize, &'a [f32; ADAPTIVE_MAX_SAMPLES_PER_EDGE as usize]);

/// [`unshadowed_samples`] at the `m × m` [`sample_points`] of an axis-aligned texel (`m ≤
/// ADAPTIVE_MAX_SAMPLES_PER_EDGE`), bit for bit, without making the points: each sample's
/// vector to the light has one component per column, one per row and one shared by all (the
/// same f32 sample coordinates, the same f64 operations in the same order), so the squares
/// and products are made per column and row and the per-sample work is the sums, the square
/// root and the two divisions (four lanes at a time where the CPU has AVX2).
fn unshadowed_grid(
    t: &TexelAt,
    (m, offsets): GridSamples,
    light: &Light,
    r2_min: f64,
    g: &mut [f64],
) {
    debug_assert!(is_axis_aligned(t.n) && m <= ADAPTIVE_MAX_SAMPLES_PER_EDGE as usize);
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked above); the function has no other contract.
        return unsafe { unshadowed_grid_avx2(t, (m, offsets), light, r2_min, g) };
    }
    unshadowed_grid_portable(t, (m, offsets), light, r2_min, g)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn unshadowed_grid_avx2(
    t: &TexelAt,
    (m, offsets): GridSamples,
    light: &Light,
    r2_min: f64,
    g: &mut [f64],
) {
    unshadowed_grid_portable(t, (m, offsets), light, r2_min, g)
}

#[inline(always)]
fn unshadowed_grid_portable(
    t: &TexelAt,
    (m, offsets): GridSamples,
    light: &Light,
    r2_min: f64,
    g: &mut [f64],
) {
    match dominant_axis(t.n) {
        0 => unshadowed_grid_on::<0>(t, (m, offsets), light, r2_min, g),
        1 => unshadowed_grid_on::<1>(t, (m, offsets), light, r2_min, g),
        _ => unshadowed_grid_on::<2>(t, (m, offsets), light, r2_min, g),
    }
}

/// [`unshadowed_grid`] on a texel whose normal lies along axis `A`.
#[inline(always)]
fn unshadowed_grid_on<const A: usize>(
    t: &TexelAt,
    (m, offsets): GridSamples,
    light: &Light,
    r2_min: f64,
    g: &mut [f64],
) {
    const M: usize = ADAPTIVE_MAX_SAMPLES_PER_EDGE as usize;
    let (u, v) = tangent_axes(A);
    let (x, size, l) = (t.x, t.size, light.position);
    let nn = t.n.map(f64::from);
    // Per column (u) and row (v): the component toward the light, its square and its product
    // with the normal's component, as `unshadowed_samples` forms them from the f32 point.
    let (mut tu, mut tv) = ([0.0f64; M], [0.0f64; M]);
    for i in 0..m {
        tu[i] = l[u] - (x[u] + offsets[i] * size[0]) as f64;
        tv[i] = l[v] - (x[v] + offsets[i] * size[1]) as f64;
    }
    let ta = l[A] - x[A] as f64;
    // Whole rows of four or eight lanes (fixed trip counts vectorize); lanes past `m` are
    // made from zeros and dropped.
    if m <= 4 {
        for j in 0..m {
            let row: [f64; 4] =
                grid_row::<A, 4>(tu[..4].try_into().expect("4"), tv[j], ta, nn, r2_min);
            g[j * m..(j + 1) * m].copy_from_slice(&row[..m]);
        }
    } else {
        for j in 0..m {
            let row: [f64; 8] = grid_row::<A, 8>(tu, tv[j], ta, nn, r2_min);
            g[j * m..(j + 1) * m].copy_from_slice(&row[..m]);
        }
    }
}

/// One row of [`unshadowed_grid_on`]: the terms at columns `tu` (components toward the light
/// along the first tangent axis), row component `tv`, normal component `ta`.
#[inline(always)]
fn grid_row<const A: usize, const L: usize>(
    tu: [f64; L],
    tv: f64,
    ta: f64,
    nn: [f64; 3],
    r2_min: f64,
) -> [f64; L] {
    let mut out = [0.0f64; L];
    for i in 0..L {
        let to = match A {
            0 => [ta, tu[i], tv],
            1 => [tu[i], ta, tv],
            _ => [tu[i], tv, ta],
        };
        let r2 = to[0] * to[0] + to[1] * to[1] + to[2] * to[2];
        let cos = (nn[0] * to[0] + nn[1] * to[1] + nn[2] * to[2]) / r2.sqrt();
        let value = cos / r2.max(r2_min);
        out[i] = if r2 > 0.0 && cos > 0.0 { value } else { 0.0 };
    }
    out
}

/// The `m × m` sample points of a texel (centre `x`, normal `n`, extent `size` along its
/// dominant plane's axes), row by row, lifted onto the texel's plane: the samples
/// [`crate::direct::direct_from_point_lights_averaged`] averages.
pub(crate) fn sample_points(
    x: [f32; 3],
    n: [f32; 3],
    size: [f32; 2],
    m: usize,
    out: &mut [[f32; 3]],
) {
    let axis = dominant_axis(n);
    let (u, v) = tangent_axes(axis);
    // The offset of sample `i` along an edge, in texel units: the same expression per sample
    // whether evaluated once per column (up to 16 samples per edge) or per sample.
    let offset = |i: usize| (i as f32 + 0.5) / m as f32 - 0.5;
    let mut du_of = [0.0f32; 16];
    for (i, du) in du_of.iter_mut().enumerate().take(m) {
        *du = offset(i) * size[0];
    }
    let slanted = n[u] != 0.0 || n[v] != 0.0;
    for j in 0..m {
        let dv = offset(j) * size[1];
        for i in 0..m {
            let du = if m <= du_of.len() {
                du_of[i]
            } else {
                offset(i) * size[0]
            };
            // A slanted (mesh) texel: the sample lifted onto the texel's plane along the
            // dominant axis.
            let lifted = if slanted {
                x[axis] - (n[u] * du + n[v] * dv) / n[axis]
            } else {
                x[axis]
            };
            // Built whole rather than by indexed stores (which stall the store of the array).
            out[j * m + i] = match axis {
                0 => [lifted, x[1] + du, x[2] + dv],
                1 => [x[0] + du, lifted, x[2] + dv],
                _ => [x[0] + du, x[1] + dv, lifted],
            };
        }
    }
}

pub(crate) fn dominant_axis(n: [f32; 3]) -> usize {
    let a = n.map(f32::abs);
    if a[0] >= a[1] && a[0] >= a[2] {
        0
    } else if a[1] >= a[2] {
        1
    } else {
        2
    }
}

#[cfg(test)]
mod tests {
    use super::{
        far_light_mean, near_light_mean, sample_offset, unshadowed, TexelAt, NEAR_HALF_DIAGONALS,
    };
    use lightfarm_proto::face::tangent_axes;
    use lightfarm_proto::lights::{Light, LightKind};

    fn light(position: [f64; 3]) -> Light {
        Light {
            kind: LightKind::Point,
            position,
            intensity: [1.0; 3],
        }
    }

    /// The closed form against a fine midpoint sum on texels facing each axis both ways, lights
    /// over the texel, beside it, low over its plane and over a corner, and on slanted texels;
    /// `None` behind, in the plane and far.
    #[test]
    fn the_near_light_mean_is_the_texels_exact_mean() {
        let at = |x: [f32; 3], n: [f32; 3], size: [f32; 2]| TexelAt {
            x,
            n,
            rho: [0.5; 3],
            size,
        };
        // Two slanted normals.
        let n = [0.0f32, 0.6, 0.8];
        let m = [0.48f32, -0.6, 0.64];
        let cases = [
            (at([1.0, 2.0, 0.0], n, [0.5, 0.25]), [1.1, 2.1, 0.1]),
            (at([1.0, 2.0, 0.0], n, [0.5, 0.25]), [1.4, 2.06, 0.08]),
            (at([1.0, 2.0, 0.0], m, [0.3, 0.4]), [1.05, 1.97, 0.03]),
            (
                at([1.0, 2.0, 0.0], [0.0, 0.0, 1.0], [0.5, 0.25]),
                [1.1, 2.05, 0.05],
            ),
            (
                at([1.0, 2.0, 0.0], [0.0, 0.0, 1.0], [0.5, 0.25]),
                [1.25, 2.125, 0.02],
            ),
            (
                at([1.0, 2.0, 0.0], [0.0, 0.0, 1.0], [0.5, 0.25]),
                [1.9, 2.0, 0.03],
            ),
            (
                at([0.0, 1.0, 3.0], [-1.0, 0.0, 0.0], [0.3, 0.6]),
                [-0.4, 1.2, 2.9],
            ),
            (
                at([5.0, 3.0, 1.0], [0.0, -1.0, 0.0], [1.5, 0.75]),
                [5.2, 2.95, 1.1],
            ),
            (
                at([5.0, 3.0, 1.0], [0.0, 1.0, 0.0], [1.5, 0.75]),
                [5.0, 3.5, 1.0],
            ),
        ];
        for (i, (t, p)) in cases.iter().enumerate() {
            let l = light(*p);
            let exact = near_light_mean(t, &l).expect("near");
            let brute = brute_mean(t, &l);
            assert!(
                (exact / brute - 1.0).abs() < 2e-3,
                "case {i}: {exact} against {brute}"
            );
        }
        let t = at([1.0, 2.0, 0.0], [0.0, 0.0, 1.0], [0.5, 0.25]);
        let half_diagonal = 0.5 * (0.5f64.powi(2) + 0.25f64.powi(2)).sqrt();
        let far = NEAR_HALF_DIAGONALS * half_diagonal * 1.01;
        for p in [[1.0, 2.0, -0.1], [1.3, 2.0, 0.0], [1.0, 2.0, far]] {
            assert_eq!(near_light_mean(&t, &light(p)), None, "{p:?}");
        }
        let behind = [
            1.0 - 0.1 * n[0] as f64,
            2.0 - 0.1 * n[1] as f64,
            -0.1 * n[2] as f64,
        ];
        let slanted = at([1.0, 2.0, 0.0], n, [0.5, 0.25]);
        assert_eq!(near_light_mean(&slanted, &light(behind)), None);
    }

    /// Beyond [`NEAR_HALF_DIAGONALS`] half-diagonals, the 2 × 2 Gauss–Legendre mean against
    /// the rectangle's closed form (its solid angle over its area): 2,000 seeded texels of
    /// aspect 1:4 to 2:1 facing each axis both ways, lights at 8 to 9 half-diagonals from 1° to
    /// 90° above the plane. Its worst error is well under the 4 × 4 midpoint grid's (what the
    /// texel's value took before: 1.7e-3 here), and a slanted texel's mean is the fine sum's.
    #[test]
    fn the_far_light_mean_is_closer_to_the_exact_mean_than_the_sample_grid() {
        let mut rng = lightfarm_proto::testing::Lcg(7);
        let mut uniform = || rng.unit() as f64;
        let (mut worst_gauss, mut worst_grid) = (0.0f64, 0.0f64);
        for i in 0..2000 {
            let axis = i % 3;
            let sign = if i % 2 == 0 { 1.0f32 } else { -1.0 };
            let (u, v) = tangent_axes(axis);
            let mut n = [0.0f32; 3];
            n[axis] = sign;
            let size = [1.0f32, (0.25 + 1.75 * uniform()) as f32];
            let x = [0.5f32, -1.25, 2.0];
            let t = TexelAt {
                x,
                n,
                rho: [0.5; 3],
                size,
            };
            let half_diagonal = 0.5 * (size[0] as f64).hypot(size[1] as f64);
            let r = NEAR_HALF_DIAGONALS * half_diagonal * (1.0 + 0.125 * uniform());
            let elevation = (1.0 + 89.0 * uniform()).to_radians();
            let azimuth = std::f64::consts::TAU * uniform();
            let (lu, lv, d) = (
                r * elevation.cos() * azimuth.cos(),
                r * elevation.cos() * azimuth.sin(),
                r * elevation.sin(),
            );
            let mut p = x.map(f64::from);
            p[u] += lu;
            p[v] += lv;
            p[axis] += sign as f64 * d;
            let l = light(p);
            assert_eq!(near_light_mean(&t, &l), None, "case {i} is far");
            // The rectangle relative to the light's foot, in closed form.
            let (su, sv) = (size[0] as f64, size[1] as f64);
            let corner = |a: f64, b: f64| (a * b / (d * (d * d + a * a + b * b).sqrt())).atan();
            let (u0, u1, v0, v1) = (-0.5 * su - lu, 0.5 * su - lu, -0.5 * sv - lv, 0.5 * sv - lv);
            let exact =
                (corner(u1, v1) - corner(u0, v1) - corner(u1, v0) + corner(u0, v0)) / (su * sv);
            let gauss = far_light_mean(&t, &l, 0.0);
            let mut grid = 0.0;
            for j in 0..4 {
                for k in 0..4 {
                    let q =
                        super::sample_point(x, n, size, sample_offset(k, 4), sample_offset(j, 4));
                    grid += unshadowed(q, n, &l, 0.0) / 16.0;
                }
            }
            worst_gauss = worst_gauss.max((gauss / exact - 1.0).abs());
            worst_grid = worst_grid.max((grid / exact - 1.0).abs());
        }
        assert!(worst_gauss < 3e-4, "Gauss–Legendre: {worst_gauss}");
        assert!(
            worst_grid > 1e-3 && worst_gauss < worst_grid / 5.0,
            "grid: {worst_grid}"
        );
        // Slanted texels (a parallelogram) against the fine sum.
        let slanted = [
            ([0.0f32, 0.6, 0.8], [0.5f32, 0.25], [1.0, 4.0, 3.0]),
            ([0.48, -0.6, 0.64], [0.3, 0.4], [4.0, -2.0, 3.5]),
        ];
        for (n, size, p) in slanted {
            let t = TexelAt {
                x: [1.0, 2.0, 0.0],
                n,
                rho: [0.5; 3],
                size,
            };
            let l = light(p);
            assert_eq!(near_light_mean(&t, &l), None);
            let (gauss, brute) = (far_light_mean(&t, &l, 0.0), brute_mean(&t, &l));
            assert!(
                (gauss / brute - 1.0).abs() < 3e-4,
                "{gauss} against {brute}"
            );
        }
    }

    /// The mean of `cos θ / r²` over the texel by a 2,000 × 2,000 midpoint sum over the
    /// points [`super::sample_point`] places (a rectangle, or a slanted texel's parallelogram,
    /// whose points cover equal areas).
    fn brute_mean(t: &TexelAt, l: &Light) -> f64 {
        let k = 2000;
        let mut sum = 0.0;
        for i in 0..k {
            for j in 0..k {
                let (ou, ov) = (
                    (i as f32 + 0.5) / k as f32 - 0.5,
                    (j as f32 + 0.5) / k as f32 - 0.5,
                );
                let p = super::sample_point(t.x, t.n, t.size, ou, ov);
                let to = [0, 1, 2].map(|c| l.position[c] - p[c] as f64);
                let r2: f64 = to.iter().map(|x| x * x).sum();
                let cos = (0..3).map(|c| t.n[c] as f64 * to[c]).sum::<f64>() / r2.sqrt();
                sum += cos.max(0.0) / r2;
            }
        }
        sum / (k * k) as f64
    }
}
