//! Seeded quasi-random sampling: scrambled Sobol' points in 2D, cosine-weighted hemisphere
//! directions and the concentric square↔disk maps.
//!
//! Invariant: every sample is a pure function of (seed, stream, index), so a bake is
//! bit-identical whatever the thread count or the order texels are processed in. Samplers come
//! in threes (pbrt-v4 habit): `sample_*`, `*_pdf`, `invert_*`, with round-trip tests.

use std::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI};

/// A 64-bit mix (SplitMix64 finaliser).
pub fn mix64(mut x: u64) -> u64 {
    x ^= x >> 30;
    x = x.wrapping_mul(0xbf58476d1ce4e5b9);
    x ^= x >> 27;
    x = x.wrapping_mul(0x94d049bb133111eb);
    x ^ (x >> 31)
}

/// Every stream of quasi-random numbers the engine draws, one value each: the registry behind
/// the bit-identical-bake invariant. Two uses sharing a value would draw correlated samples, so
/// every use names its own variant (the compiler refuses duplicate values). The values are part
/// of every bake's bytes: changing one changes the bundles that stream feeds (the test below
/// pins them).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u64)]
pub enum Purpose {
    /// MRT: a shape's texels gathering from its own faces (`mrt::shape`).
    ShapeGather = 1,
    /// MRT: rays leaving a shape's openings for its lightfield (`mrt::shape`).
    ShapeLightfield = 2,
    /// Traced transport between blocks (`transport::build`).
    TracedTransport = 3,
    /// The dense per-texel operator, `bake --full` (`pipeline::stages`).
    FullOperator = 4,
    /// The reference solver's first bounce (`reference`).
    Reference = 5,
    /// Lighting prior: lights inside a block (`mrt::lighting_prior`).
    PriorInside = 11,
    /// Lighting prior: lights in the slabs beyond a block's openings (`mrt::lighting_prior`).
    PriorSlabs = 12,
    /// Prior lights around a clutter object (`drt::clutter_basis`).
    ClutterPrior = 21,
    /// DRT: scene texels' rays toward clutter (`drt::rays`).
    DrtScene = 31,
    /// DRT: clutter texels' gathering rays (`drt::rays`).
    DrtClutter = 32,
    /// DRT: scene texels gathered exactly (`drt::rays`).
    DrtSceneGather = 33,
    /// The SH probe volume (`sh::probe_volume`).
    Probes = 41,
    /// DNRT grids (`dnrt::grid`).
    Dnrt = 51,
    /// DNRT grids, the convolved pass (`dnrt::grid`).
    DnrtConvolved = 52,
    /// SH responses of normal-mapped texels (`sh::responses`).
    ShResponse = 61,
    /// The reference solver's SH incident radiance (`reference`).
    ReferenceSh = 62,
    /// The reference solver's irradiance at points (`reference`).
    ReferenceIrradiance = 63,
    /// The reference solver's path continuations after the first bounce (`reference`).
    ReferencePath = 64,
    /// `bench`'s ray-throughput measurement ("throughp" in ASCII).
    Throughput = 0x7468_726f_7567_6870,
}

/// Hashes a seed with a purpose and a stream id (e.g. a texel's global index).
pub fn stream_key(seed: u64, purpose: Purpose, stream: u64) -> u64 {
    mixed_key(seed, purpose as u64, stream)
}

/// [`stream_key`] with a bare tag: for tests that need streams of their own, never for a
/// bake (which names a [`Purpose`]).
pub fn mixed_key(seed: u64, tag: u64, stream: u64) -> u64 {
    mix64(mix64(seed ^ tag.wrapping_mul(0x9e3779b97f4a7c15)) ^ stream)
}

/// Radical inverse of `i` in `base` (the Halton sequence's coordinate).
pub fn radical_inverse(mut i: u64, base: u64) -> f64 {
    let inv = 1.0 / base as f64;
    let mut f = inv;
    let mut r = 0.0;
    while i > 0 {
        r += f * (i % base) as f64;
        i /= base;
        f *= inv;
    }
    r
}

/// Quasi-random point `i` in a box: Halton (2, 3, 5) with a Cranley–Patterson rotation seeded
/// by `key`.
pub fn halton_point_in(aabb: &lightfarm_proto::scene::Aabb, i: u64, key: u64) -> [f64; 3] {
    let mut p = [0.0; 3];
    for (k, base) in [2u64, 3, 5].into_iter().enumerate() {
        let shift = (mix64(key ^ k as u64) >> 11) as f64 / (1u64 << 53) as f64;
        let x = (radical_inverse(i + 1, base) + shift).fract();
        p[k] = aabb.min[k] + x * (aabb.max[k] - aabb.min[k]);
    }
    p
}

/// Laine–Karras style nested uniform scramble of a 32-bit reversed integer.
fn owen_scramble(mut v: u32, seed: u32) -> u32 {
    v = v.reverse_bits();
    v ^= v.wrapping_mul(0x3d20adea);
    v = v.wrapping_add(seed);
    v = v.wrapping_mul((seed >> 16) | 1);
    v ^= v.wrapping_mul(0x05526c56);
    v ^= v.wrapping_mul(0x53a22864);
    v.reverse_bits()
}

/// Sobol' dimension 1 (dimension 0 is the van der Corput sequence): the XOR of the direction
/// numbers of `i`'s set bits, which is linear over GF(2) in `i`, so it is the XOR of four
/// byte tables' entries ([`SOBOL_DIM1_BYTES`]) — the same value as the bit-by-bit loop
/// ([`sobol_dim1_by_bits`], which the tables are made from and the tests check against) in four
/// loads instead of up to 32 dependent steps (the index is scrambled over all 32 bits).
fn sobol_dim1(i: u32) -> u32 {
    let t = &SOBOL_DIM1_BYTES;
    t[0][(i & 0xff) as usize]
        ^ t[1][(i >> 8 & 0xff) as usize]
        ^ t[2][(i >> 16 & 0xff) as usize]
        ^ t[3][(i >> 24) as usize]
}

/// Per byte `k` of the index and value `b` of that byte: [`sobol_dim1_by_bits`]`(b << 8k)`.
static SOBOL_DIM1_BYTES: [[u32; 256]; 4] = sobol_dim1_bytes();

const fn sobol_dim1_bytes() -> [[u32; 256]; 4] {
    let mut t = [[0u32; 256]; 4];
    let mut k = 0;
    while k < 4 {
        let mut b = 0;
        while b < 256 {
            t[k][b] = sobol_dim1_by_bits((b as u32) << (8 * k));
            b += 1;
        }
        k += 1;
    }
    t
}

/// Sobol' dimension 1 bit by bit: direction number `v_k` for bit `k` (`v_0 = 2³¹`, `v_{k+1} =
/// v_k ^ (v_k >> 1)`).
const fn sobol_dim1_by_bits(mut i: u32) -> u32 {
    let mut v: u32 = 1 << 31;
    let mut out = 0u32;
    while i != 0 {
        if i & 1 != 0 {
            out ^= v;
        }
        i >>= 1;
        v ^= v >> 1;
    }
    out
}

fn to_unit(x: u32) -> f64 {
    // Keep strictly below 1.
    (x as f64) * (1.0 / 4294967296.0)
}

/// The `index`-th point of an Owen-scrambled 2D Sobol' sequence for stream `key`.
/// Any prefix of length 2^k is a stratified (0, k, 2)-net.
pub fn sobol_2d(key: u64, index: u32) -> [f64; 2] {
    // Shuffle the index order too (nested scramble of the index), keeping net properties.
    let shuffled = owen_scramble(index, (key >> 32) as u32 ^ 0x68bc21eb);
    let x = shuffled.reverse_bits();
    let y = sobol_dim1(shuffled);
    [
        to_unit(owen_scramble(x, key as u32)),
        to_unit(owen_scramble(y, (key as u32).rotate_left(13) ^ 0x02e5be93)),
    ]
}

/// Maps the unit square to the unit disk (Shirley–Chiu concentric map).
pub fn sample_concentric_disk(u: [f64; 2]) -> [f64; 2] {
    let a = 2.0 * u[0] - 1.0;
    let b = 2.0 * u[1] - 1.0;
    if a == 0.0 && b == 0.0 {
        return [0.0, 0.0];
    }
    let (r, theta) = if a.abs() > b.abs() {
        (a, FRAC_PI_4 * (b / a))
    } else {
        (b, FRAC_PI_2 - FRAC_PI_4 * (a / b))
    };
    [r * theta.cos(), r * theta.sin()]
}

/// Inverse of [`sample_concentric_disk`].
pub fn invert_concentric_disk(p: [f64; 2]) -> [f64; 2] {
    let [x, y] = p;
    let r = (x * x + y * y).sqrt();
    if r == 0.0 {
        return [0.5, 0.5];
    }
    let mut phi = y.atan2(x);
    if phi < -FRAC_PI_4 {
        phi += 2.0 * PI;
    }
    let (a, b) = if phi < FRAC_PI_4 {
        (r, phi * r / FRAC_PI_4)
    } else if phi < 3.0 * FRAC_PI_4 {
        (-(phi - FRAC_PI_2) * r / FRAC_PI_4, r)
    } else if phi < 5.0 * FRAC_PI_4 {
        (-r, -(phi - PI) * r / FRAC_PI_4)
    } else {
        ((phi - 3.0 * FRAC_PI_2) * r / FRAC_PI_4, -r)
    };
    [
        ((a + 1.0) * 0.5).clamp(0.0, 1.0),
        ((b + 1.0) * 0.5).clamp(0.0, 1.0),
    ]
}

/// A cosine-weighted direction in the local frame (z is the normal).
pub fn sample_cosine_hemisphere(u: [f64; 2]) -> [f64; 3] {
    let d = sample_concentric_disk(u);
    let z = (1.0 - d[0] * d[0] - d[1] * d[1]).max(0.0).sqrt();
    [d[0], d[1], z]
}

/// Density of [`sample_cosine_hemisphere`] per steradian.
pub fn cosine_hemisphere_pdf(cos_theta: f64) -> f64 {
    cos_theta.max(0.0) / PI
}

/// Inverse of [`sample_cosine_hemisphere`] (for a direction with z ≥ 0).
pub fn invert_cosine_hemisphere(w: [f64; 3]) -> [f64; 2] {
    invert_concentric_disk([w[0], w[1]])
}

/// A uniformly distributed direction on the hemisphere in the local frame (z is the normal).
/// `u[0]` maps to `cos θ` linearly, so a stratified `u` stratifies solid angle.
pub fn sample_uniform_hemisphere(u: [f64; 2]) -> [f64; 3] {
    let z = u[0];
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = 2.0 * PI * u[1];
    [r * phi.cos(), r * phi.sin(), z]
}

/// Density of [`sample_uniform_hemisphere`] per steradian.
pub fn uniform_hemisphere_pdf() -> f64 {
    1.0 / (2.0 * PI)
}

/// Inverse of [`sample_uniform_hemisphere`] (for a unit direction with z ≥ 0).
pub fn invert_uniform_hemisphere(w: [f64; 3]) -> [f64; 2] {
    let phi = w[1].atan2(w[0]);
    let phi = if phi < 0.0 { phi + 2.0 * PI } else { phi };
    [w[2].clamp(0.0, 1.0), (phi / (2.0 * PI)).clamp(0.0, 1.0)]
}

/// An orthonormal frame whose third axis is `n` (a unit vector along a world axis or not).
pub fn frame(n: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    // Duff et al. 2017, branchless ONB.
    let sign = 1f64.copysign(n[2]);
    let a = -1.0 / (sign + n[2]);
    let b = n[0] * n[1] * a;
    (
        [1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]],
        [b, sign + n[1] * n[1] * a, -n[1]],
    )
}

/// Turns a local direction into world space in the frame of `n`.
pub fn to_world(local: [f64; 3], n: [f64; 3]) -> [f64; 3] {
    let (t, b) = frame(n);
    [
        local[0] * t[0] + local[1] * b[0] + local[2] * n[0],
        local[0] * t[1] + local[1] * b[1] + local[2] * n[1],
        local[0] * t[2] + local[1] * b[2] + local[2] * n[2],
    ]
}

#[cfg(test)]
mod tests {
    /// The byte tables give the bit-by-bit value at every index of a dense sweep of each byte,
    /// at the ends, and at a million scattered indices (the scrambled indices span all 32 bits).
    #[test]
    fn sobol_dim1_tables_equal_the_bit_by_bit_sequence() {
        use super::{sobol_dim1, sobol_dim1_by_bits};
        for k in 0..4 {
            for b in 0..256u32 {
                let i = b << (8 * k);
                assert_eq!(sobol_dim1(i), sobol_dim1_by_bits(i), "{i:#x}");
            }
        }
        let mut x = 0x9e37_79b9u32;
        for i in (0..1 << 20).chain([u32::MAX, u32::MAX - 1, 1 << 31]) {
            x = x.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            assert_eq!(sobol_dim1(i), sobol_dim1_by_bits(i), "{i:#x}");
            assert_eq!(sobol_dim1(x), sobol_dim1_by_bits(x), "{x:#x}");
        }
    }

    #[test]
    fn purpose_values_are_pinned_and_unique() {
        use super::Purpose::*;
        // Changing a value changes every bundle its stream feeds: pinned here on purpose.
        let table = [
            (ShapeGather, 1),
            (ShapeLightfield, 2),
            (TracedTransport, 3),
            (FullOperator, 4),
            (Reference, 5),
            (PriorInside, 11),
            (PriorSlabs, 12),
            (ClutterPrior, 21),
            (DrtScene, 31),
            (DrtClutter, 32),
            (DrtSceneGather, 33),
            (Probes, 41),
            (Dnrt, 51),
            (DnrtConvolved, 52),
            (ShResponse, 61),
            (ReferenceSh, 62),
            (ReferenceIrradiance, 63),
            (ReferencePath, 64),
            (Throughput, 0x7468_726f_7567_6870),
        ];
        let mut seen = std::collections::HashSet::new();
        for (purpose, value) in table {
            assert_eq!(purpose as u64, value, "{purpose:?}");
            assert!(seen.insert(value), "{purpose:?} repeats {value}");
            assert_eq!(
                super::stream_key(9, purpose, 5),
                super::mixed_key(9, value, 5)
            );
        }
    }

    use super::*;

    #[test]
    fn concentric_map_round_trips() {
        for i in 0..4096u32 {
            let u = sobol_2d(7, i);
            let back = invert_concentric_disk(sample_concentric_disk(u));
            assert!(
                (back[0] - u[0]).abs() < 1e-9 && (back[1] - u[1]).abs() < 1e-9,
                "{u:?} -> {back:?}"
            );
        }
    }

    #[test]
    fn sobol_prefix_is_stratified() {
        // A (0, 8, 2)-net: every 1/16 × 1/16 cell holds exactly one of the first 256 points.
        let mut cells = [0u32; 256];
        for i in 0..256 {
            let [x, y] = sobol_2d(12345, i);
            cells[(x * 16.0) as usize * 16 + (y * 16.0) as usize] += 1;
        }
        assert!(cells.iter().all(|c| *c == 1), "{cells:?}");
    }

    #[test]
    fn cosine_estimator_converges_to_the_known_integral() {
        // ∫ cos θ · cos θ dω / π over the hemisphere = 2/3; estimate E[cos θ] with cosine samples.
        let mut errors = Vec::new();
        for n in [64u32, 256, 1024, 4096] {
            let mut err = 0.0;
            for key in 0..32u64 {
                let mean: f64 = (0..n)
                    .map(|i| sample_cosine_hemisphere(sobol_2d(key, i))[2])
                    .sum::<f64>()
                    / n as f64;
                err += (mean - 2.0 / 3.0).powi(2);
            }
            errors.push((err / 32.0).sqrt());
        }
        for w in errors.windows(2) {
            assert!(
                w[1] < 0.5 * w[0],
                "error must at least halve as samples quadruple: {errors:?}"
            );
        }
        // The pdf integrates to one: Riemann sum over (θ, φ) of pdf · sin θ.
        let steps = 400;
        let mut total = 0.0;
        for k in 0..steps {
            let theta = (k as f64 + 0.5) / steps as f64 * FRAC_PI_2;
            total += cosine_hemisphere_pdf(theta.cos())
                * theta.sin()
                * (FRAC_PI_2 / steps as f64)
                * 2.0
                * PI;
        }
        assert!((total - 1.0).abs() < 1e-4, "{total}");
    }

    #[test]
    fn uniform_hemisphere_round_trips_and_converges() {
        for i in 1..2048u32 {
            let u = sobol_2d(3, i);
            let w = sample_uniform_hemisphere(u);
            assert!((w[0] * w[0] + w[1] * w[1] + w[2] * w[2] - 1.0).abs() < 1e-12);
            let back = invert_uniform_hemisphere(w);
            assert!((back[0] - u[0]).abs() < 1e-9 && (back[1] - u[1]).abs() < 1e-9);
        }
        // ∫ cos θ dω over the hemisphere = π, estimated as mean(cos θ / pdf).
        let n = 4096;
        let estimate: f64 = (0..n)
            .map(|i| sample_uniform_hemisphere(sobol_2d(9, i))[2] / uniform_hemisphere_pdf())
            .sum::<f64>()
            / n as f64;
        assert!((estimate - PI).abs() < 1e-3, "{estimate}");
    }

    #[test]
    fn frame_is_orthonormal() {
        for n in [
            [0.0, 0.0, 1.0],
            [0.0, 0.0, -1.0],
            [1.0, 0.0, 0.0],
            [0.0, -1.0, 0.0],
            [0.6, 0.0, 0.8],
        ] {
            let (t, b) = frame(n);
            let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
            assert!(dot(t, b).abs() < 1e-12 && dot(t, n).abs() < 1e-12 && dot(b, n).abs() < 1e-12);
            assert!((dot(t, t) - 1.0).abs() < 1e-12 && (dot(b, b) - 1.0).abs() < 1e-12);
        }
    }
}
