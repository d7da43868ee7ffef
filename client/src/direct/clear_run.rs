//! A run of texels the lights see whole ([`Shadows::Clear`]: a box query found nothing in the
//! way, or a span in sight): each texel's value is its lights' unshadowed means, with none of
//! the adaptive average's per-texel steps (samples, corners, shadow queries). On the maze's
//! one-light update these runs are 70% of the texels whose light is worked out.
//!
//! The loop here gives what [`super::adaptive_texel`] and [`super::add_adaptive`] give those
//! texels, bit for bit: per light in order, nothing when it faces away or is dark, else
//! `I ·` [`axis_aligned_mean`] (the unshadowed mean those functions take when every corner is
//! seen), then `ρ/π ·` the sum. It takes axis-aligned runs with `2 ≤ m ≤`
//! [`ADAPTIVE_MAX_SAMPLES_PER_EDGE`] samples per edge; a texel without a size goes the usual
//! way. The whole loop is compiled for AVX2 where the CPU has it (chosen once per run), so the
//! means inline; no fused products, so every copy gives the same bits.
//!
//! Units: as [`super`]: `irr` in W/m² per channel, values in W/m²/sr.

use std::ops::Range;

use lightfarm_proto::bundle::Layout;
use lightfarm_proto::face::tangent_axes;
use lightfarm_proto::lights::Light;

use super::{add_term, is_dark, outgoing, texel_direct, Lighting, Shadows};
use crate::texel_samples::{
    axis_aligned_mean, dominant_axis, is_axis_aligned, TexelAt, TexelSamples,
    ADAPTIVE_MAX_SAMPLES_PER_EDGE,
};

/// The axes (normal, two tangents) of `run` when the loop here takes it: `lighting` sees it
/// whole, its normal (one per run) is axis-aligned and `m` is in the adaptive range.
pub(super) fn axes(
    lighting: &Lighting,
    layout: &Layout,
    run: &Range<usize>,
    m: usize,
) -> Option<(usize, usize, usize)> {
    if !matches!(lighting.shadows, Shadows::Clear)
        || !(2..=ADAPTIVE_MAX_SAMPLES_PER_EDGE as usize).contains(&m)
        || run.is_empty()
    {
        return None;
    }
    let n = layout.normals[run.start];
    if !is_axis_aligned(n) {
        return None;
    }
    let a = dominant_axis(n);
    let (u, v) = tangent_axes(a);
    Some((a, u, v))
}

/// The values [`super::adaptive_in_with`] writes on `run` (after [`axes`] gave `axes`).
pub(super) fn values(
    lighting: &Lighting,
    layout: &Layout,
    (run, m, axes): (Range<usize>, usize, (usize, usize, usize)),
    samples: &mut TexelSamples,
    out: &mut [[f32; 3]],
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked above); the function has no other contract.
        return unsafe { values_avx2(lighting, layout, (run, m, axes), samples, out) };
    }
    values_portable(lighting, layout, (run, m, axes), samples, out)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn values_avx2(
    lighting: &Lighting,
    layout: &Layout,
    run: (Range<usize>, usize, (usize, usize, usize)),
    samples: &mut TexelSamples,
    out: &mut [[f32; 3]],
) {
    values_portable(lighting, layout, run, samples, out)
}

#[inline(always)]
fn values_portable(
    lighting: &Lighting,
    layout: &Layout,
    (run, m, axes): (Range<usize>, usize, (usize, usize, usize)),
    samples: &mut TexelSamples,
    out: &mut [[f32; 3]],
) {
    for t in run {
        let at = TexelAt::of(layout, t);
        if at.size == [0.0, 0.0] {
            out[t] = texel_direct(lighting, at, m, Some(samples));
            continue;
        }
        let mut irr = [0.0f64; 3];
        for light in lighting.lights {
            if faces_away_along(&at, light, axes) || is_dark(light) {
                continue;
            }
            add_term(
                &mut irr,
                light,
                axis_aligned_mean(&at, light, lighting.r2_min, axes),
            );
        }
        out[t] = outgoing(at.rho, irr).map(|v| v as f32);
    }
}

/// The terms [`super::add_light_term_in`] adds on `run` (adaptive, one light, after [`axes`]
/// gave `axes`) into `irr`.
pub(super) fn terms(
    lighting: &Lighting,
    layout: &Layout,
    (run, axes): (Range<usize>, (usize, usize, usize)),
    irr: &mut [[f64; 3]],
) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2 (checked above); the function has no other contract.
        return unsafe { terms_avx2(lighting, layout, (run, axes), irr) };
    }
    terms_portable(lighting, layout, (run, axes), irr)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn terms_avx2(
    lighting: &Lighting,
    layout: &Layout,
    run: (Range<usize>, (usize, usize, usize)),
    irr: &mut [[f64; 3]],
) {
    terms_portable(lighting, layout, run, irr)
}

#[inline(always)]
fn terms_portable(
    lighting: &Lighting,
    layout: &Layout,
    (run, axes): (Range<usize>, (usize, usize, usize)),
    irr: &mut [[f64; 3]],
) {
    let light = &lighting.lights[0];
    for t in run {
        let at = TexelAt::of(layout, t);
        if faces_away_along(&at, light, axes) {
            continue;
        }
        if at.size == [0.0, 0.0] {
            lighting.add_point(0, at.x, at.n, &mut irr[t]);
        } else if !is_dark(light) {
            let w = axis_aligned_mean(&at, light, lighting.r2_min, axes);
            add_term(&mut irr[t], light, w);
        }
    }
}

/// [`crate::texel_samples::faces_away`] of a texel whose normal lies along `a` (its tangent
/// components zero, as on every texel of an axis-aligned run): the light is behind or in its
/// plane, or the product is NaN. The same product and test, so the same answer.
#[inline(always)]
#[allow(clippy::neg_cmp_op_on_partial_ord)] // `!(… > 0)`: a NaN product faces away too.
fn faces_away_along(t: &TexelAt, light: &Light, (a, _, _): (usize, usize, usize)) -> bool {
    !(t.n[a] as f64 * (light.position[a] - t.x[a] as f64) > 0.0)
}
