//! Direct light from point lights at every layout texel: the input the runtime turns into
//! indirect light.
//!
//! Owns the project's direct-light convention (see `shared/papers/README.md`): at a Lambertian
//! texel of albedo ρ, unit normal n and centre x, a point light of radiant intensity I (W/sr) at
//! p gives outgoing radiance `L_d = ρ/π · I · max(cosθ, 0) / r² · V`, with `r = |p − x|`,
//! `cosθ = n · (p − x) / r` and `V` the shadow-ray visibility from [`Occluders::occluded`].
//!
//! Shadow rays go to a [`LightBuffer`] per light when the level has at most
//! [`WHOLE_LEVEL_MAX_OCCLUDERS`] occluders and at most `LIGHT_BUFFERS_MAX` occluders × lights
//! (a few microseconds to build, then a handful of primitive tests per ray), else to the
//! occluders' hierarchy: both give the same answers, so the values do not depend on which was
//! used. With one light over a buffer (a light's reach, one light's term), texels go by runs of
//! a few on one face (module `box_shadows`): a run the light sees whole traces no ray, one an
//! occluder hides whole neither, and the rest test only the occluders that may cross their
//! segments, all with the buffer's answers.
//!
//! A texel's value is the mean of `L_d` over its area: the unshadowed mean of `cosθ / r²`
//! times the share of it an `m × m` grid of samples sees. Within a few texels of the light
//! that mean is exact (the solid angle the texel subtends, over its area,
//! [`crate::texel_samples::near_light_mean`]): a light peaks there more sharply than a grid
//! resolves (a light 5 cm from a wall of 1.5 × 0.75 m texels lost 31% of its indirect light on
//! the 4 × 4 grid alone, 0.69 of Mitsuba's, all bounces). Farther it is the 2 × 2
//! Gauss–Legendre rule ([`crate::texel_samples::far_light_mean`]), closer to the exact mean
//! than the grid's 16 midpoints; a texel whose samples all see the light takes it without
//! making the grid's terms.
//!
//! Invariants:
//! - [`DirectLight::radiance`] has one entry per layout texel, in layout order.
//! - Every value is finite and non-negative for finite, non-negative lights: `r²` is clamped
//!   below at `(1e-4 · scene scale)²` (scene scale: the diagonal of the box around texel centres
//!   and occluders), and a light exactly at a texel centre (no direction) contributes nothing.

use std::ops::Range;

use lightfarm_proto::bundle::Layout;
use lightfarm_proto::lights::{Light, LightKind};

use crate::box_shadows::{run_bounds, runs, BoxShadow, BoxShadows};
use crate::light_buffer::{LightBuffer, WHOLE_LEVEL_MAX_OCCLUDERS};
use crate::occluders::Occluders;
pub use crate::texel_samples::ADAPTIVE_MAX_SAMPLES_PER_EDGE;
use crate::texel_samples::{
    corner_indices, faces_away, is_axis_aligned, sample_points, unshadowed, unshadowed_mean,
    TexelAt, TexelSamples,
};

/// `r²` is clamped below at `(R_MIN_REL · scene scale)²`.
pub(crate) const R_MIN_REL: f64 = 1e-4;

/// Direct outgoing radiance, one RGB value per layout texel.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DirectLight {
    pub radiance: Vec<[f32; 3]>,
}

/// The scene scale every direct-light call clamps `r²` by: the diagonal of the box around the
/// texel centres and the occluders (1 if that is empty or degenerate).
pub fn direct_scale(layout: &Layout, occluders: &Occluders) -> f64 {
    let mut bounds = occluders.bounds();
    for p in &layout.positions {
        bounds = Some(match bounds {
            None => (*p, *p),
            Some((mut lo, mut hi)) => {
                for k in 0..3 {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
                (lo, hi)
            }
        });
    }
    let diag = bounds.map_or(0.0, |(lo, hi)| {
        (0..3)
            .map(|k| (hi[k] as f64 - lo[k] as f64).powi(2))
            .sum::<f64>()
            .sqrt()
    });
    if diag.is_finite() && diag > 0.0 {
        diag
    } else {
        1.0
    }
}

/// What the shadow rays of a [`Lighting`] are tested against; every kind answers what
/// [`Occluders::occluded`] answers for its occluders.
#[derive(Clone, Copy)]
pub(crate) enum Shadows<'a> {
    /// Nothing is in the way (texels the caller knows every light sees).
    Clear,
    /// The occluders' hierarchy.
    Occluders(&'a Occluders),
    /// One [`LightBuffer`] per light, in the lighting's light order, over these occluders.
    Buffers(&'a Occluders, &'a [LightBuffer]),
    /// Only these primitives of the occluders can cross the segments at hand (a run of texels
    /// after [`BoxShadow::Listed`]).
    Listed(&'a Occluders, &'a [u32]),
}

/// The lights' positions in f32: one light's inline (so lighting one light allocates
/// nothing), several lights' in a vector, or another [`Lighting`]'s borrowed.
enum Positions<'a> {
    One([f32; 3]),
    Many(Vec<[f32; 3]>),
    Borrowed(&'a [[f32; 3]]),
}

impl std::ops::Deref for Positions<'_> {
    type Target = [[f32; 3]];

    fn deref(&self) -> &[[f32; 3]] {
        match self {
            Positions::One(p) => std::slice::from_ref(p),
            Positions::Many(v) => v,
            Positions::Borrowed(s) => s,
        }
    }
}

/// The lights and what every texel's direct light shares: their positions in f32 (the
/// occluders' precision), the shadow queries and the `r²` clamp.
struct Lighting<'a> {
    lights: &'a [Light],
    positions: Positions<'a>,
    shadows: Shadows<'a>,
    r2_min: f64,
}

impl<'a> Lighting<'a> {
    fn new(lights: &'a [Light], shadows: Shadows<'a>, scale: f64) -> Lighting<'a> {
        let f32_position = |l: &Light| l.position.map(|x| x as f32);
        let positions = match lights {
            [one] => Positions::One(f32_position(one)),
            _ => Positions::Many(lights.iter().map(f32_position).collect()),
        };
        if let Shadows::Buffers(_, buffers) = shadows {
            assert!(
                buffers.len() == positions.len()
                    && buffers
                        .iter()
                        .zip(positions.iter())
                        .all(|(b, p)| b.light().map(f32::to_bits) == p.map(f32::to_bits)),
                "one light buffer per light, built at the light"
            );
        }
        Lighting {
            lights,
            positions,
            shadows,
            r2_min: (R_MIN_REL * scale).powi(2),
        }
    }

    /// The same lights with other shadow queries (for the segments those queries are
    /// about: a run of texels, or texels known to be in sight).
    fn with_shadows<'b>(&'b self, shadows: Shadows<'b>) -> Lighting<'b> {
        Lighting {
            lights: self.lights,
            positions: Positions::Borrowed(&self.positions),
            shadows,
            r2_min: self.r2_min,
        }
    }

    /// Is the segment from `x` to light `li` occluded?
    #[inline]
    fn occluded(&self, li: usize, x: [f32; 3]) -> bool {
        match self.shadows {
            Shadows::Clear => false,
            Shadows::Occluders(occluders) => occluders.occluded(x, self.positions[li]),
            Shadows::Buffers(occluders, buffers) => buffers[li].occluded(occluders, x),
            Shadows::Listed(occluders, prims) => occluders
                .shadow_segment(x, self.positions[li])
                .is_some_and(|seg| {
                    prims
                        .iter()
                        .any(|&p| occluders.prim_crosses(p as usize, &seg))
                }),
        }
    }

    /// Direct outgoing radiance at one point with normal `n` and albedo `rho`.
    fn radiance_at(&self, x: [f32; 3], n: [f32; 3], rho: [f32; 3]) -> [f64; 3] {
        let mut irr = [0.0f64; 3];
        for li in 0..self.lights.len() {
            self.add_point(li, x, n, &mut irr);
        }
        outgoing(rho, irr)
    }

    /// Adds light `li`'s `I · cosθ / r² · V` at point `x` with normal `n` into `irr`.
    fn add_point(&self, li: usize, x: [f32; 3], n: [f32; 3], irr: &mut [f64; 3]) {
        let light = &self.lights[li];
        match light.kind {
            LightKind::Point => {}
        }
        if light.intensity.iter().all(|&i| i == 0.0) {
            return;
        }
        // Unshadowed first: a light behind the texel costs no shadow ray.
        let g = unshadowed(x, n, light, self.r2_min);
        if g == 0.0 || self.occluded(li, x) {
            return;
        }
        for (e, i) in irr.iter_mut().zip(light.intensity) {
            *e += i * g;
        }
    }
}

/// Outgoing radiance `ρ/π · irr` of a texel of albedo `rho` (f64, before the f32 store).
fn outgoing(rho: [f32; 3], irr: [f64; 3]) -> [f64; 3] {
    let k = std::f64::consts::FRAC_1_PI;
    [
        rho[0] as f64 * k * irr[0],
        rho[1] as f64 * k * irr[1],
        rho[2] as f64 * k * irr[2],
    ]
}

/// One texel's direct light with `m × m` samples: the centre alone when `m == 1` or the texel
/// has no size, else the adaptive average ([`adaptive_texel`], when `adaptive` and `m` is at
/// most [`ADAPTIVE_MAX_SAMPLES_PER_EDGE`]) or the average of every sample ([`averaged_texel`]).
fn texel_direct(
    lighting: &Lighting,
    t: TexelAt,
    m: usize,
    adaptive: Option<&mut TexelSamples>,
) -> [f32; 3] {
    if m == 1 || t.size == [0.0, 0.0] {
        lighting.radiance_at(t.x, t.n, t.rho).map(|v| v as f32)
    } else if let Some(samples) = adaptive.filter(|_| m <= ADAPTIVE_MAX_SAMPLES_PER_EDGE as usize) {
        adaptive_texel(lighting, t, m, samples)
    } else {
        averaged_texel(lighting, t, m)
    }
}

/// The most occluders × lights the whole-level functions build [`LightBuffer`]s for (one per
/// light, each listing every occluder about once per direction cell it covers); beyond it, or
/// beyond [`WHOLE_LEVEL_MAX_OCCLUDERS`] occluders, they trace the occluders' hierarchy (whose
/// cost does not grow with the level for a light's nearby texels). Either answers the same.
const LIGHT_BUFFERS_MAX: usize = 1 << 16;

/// A [`LightBuffer`] per light over all of `occluders`, or `None` when there is nothing to
/// hit or the level is too large for it (see [`LIGHT_BUFFERS_MAX`]).
fn light_buffers(occluders: &Occluders, lights: &[Light]) -> Option<Vec<LightBuffer>> {
    let n = occluders.len();
    if n == 0 || n > WHOLE_LEVEL_MAX_OCCLUDERS || n * lights.len() > LIGHT_BUFFERS_MAX {
        return None;
    }
    Some(
        lights
            .iter()
            .map(|l| {
                let mut buffer = LightBuffer::new();
                buffer.build(occluders, l.position.map(|x| x as f32), None);
                buffer
            })
            .collect(),
    )
}

/// The buffers' shadow queries when there are buffers, else the occluders' hierarchy.
fn shadows_of<'a>(occluders: &'a Occluders, buffers: &'a Option<Vec<LightBuffer>>) -> Shadows<'a> {
    match buffers {
        Some(b) => Shadows::Buffers(occluders, b),
        None => Shadows::Occluders(occluders),
    }
}

/// Direct radiance `ρ/π · Σ I cosθ / r² · V` at each texel centre.
pub fn direct_from_point_lights(
    layout: &Layout,
    occluders: &Occluders,
    lights: &[Light],
) -> DirectLight {
    direct_from_point_lights_averaged(layout, occluders, lights, 1)
}

/// Direct radiance averaged over each texel's area (1 sample per edge: the centre only):
/// per light the texel's unshadowed mean (exact within a few texels of the light, by the
/// 2 × 2 Gauss–Legendre rule farther) times the share of it a `samples_per_edge²` grid of
/// samples sees. The texel average is what the
/// one-bounce operators expect as input: a ray landing anywhere in a texel reads that texel's
/// value, so averaging removes the error of point-sampling sharp highlights (a light close to a
/// wall).
pub fn direct_from_point_lights_averaged(
    layout: &Layout,
    occluders: &Occluders,
    lights: &[Light],
    samples_per_edge: u32,
) -> DirectLight {
    let buffers = light_buffers(occluders, lights);
    averaged_with(
        layout,
        shadows_of(occluders, &buffers),
        direct_scale(layout, occluders),
        lights,
        samples_per_edge,
    )
}

/// [`direct_from_point_lights_averaged`] with its shadow rays tested against `shadows`.
fn averaged_with(
    layout: &Layout,
    shadows: Shadows,
    scale: f64,
    lights: &[Light],
    samples_per_edge: u32,
) -> DirectLight {
    let lighting = Lighting::new(lights, shadows, scale);
    let m = samples_per_edge.max(1) as usize;
    let radiance = (0..layout.n_texels())
        .map(|t| texel_direct(&lighting, TexelAt::of(layout, t), m, None))
        .collect();
    DirectLight { radiance }
}

/// One texel of [`direct_from_point_lights_averaged`] (`m ≥ 2`, a texel with a size): per
/// light the mean over its `m × m` samples ([`texel_mean`]), summed.
fn averaged_texel(lighting: &Lighting, t: TexelAt, m: usize) -> [f32; 3] {
    // On the stack up to 8 × 8 samples (no allocation per texel).
    let mut stack = [[0.0f32; 3]; 64];
    let mut heap = Vec::new();
    let points: &mut [[f32; 3]] = if m * m <= stack.len() {
        &mut stack[..m * m]
    } else {
        heap.resize(m * m, [0.0; 3]);
        &mut heap
    };
    sample_points(t.x, t.n, t.size, m, points);
    let mut irr = [0.0f64; 3];
    for (li, light) in lighting.lights.iter().enumerate() {
        if light.intensity.iter().all(|&i| i == 0.0) {
            continue;
        }
        // Every sample's term, and the seen ones' (a shadow ray where the term is not 0).
        let (mut seen, mut all) = (0.0f64, 0.0f64);
        for &p in points.iter() {
            let g = unshadowed(p, t.n, light, lighting.r2_min);
            if g > 0.0 {
                all += g;
                if !lighting.occluded(li, p) {
                    seen += g;
                }
            }
        }
        let w = texel_mean(&t, light, lighting.r2_min, seen, all);
        for (e, i) in irr.iter_mut().zip(light.intensity) {
            *e += i * w;
        }
    }
    outgoing(t.rho, irr).map(|v| v as f32)
}

/// [`direct_from_point_lights_averaged`] with shadow rays only where visibility can change
/// across the texel: per texel and light, the four corner samples of the grid are traced
/// first; when they agree (all lit or all shadowed) the texel is taken as uniformly visible and
/// its unshadowed mean is taken without more rays, otherwise every sample is traced. A light
/// behind every sample (facing away) traces nothing.
///
/// Four rays instead of `samples_per_edge²` wherever a texel is wholly lit or wholly
/// shadowed; what it can miss is a shadow (or a gap in one) narrower than a texel that touches
/// no corner sample. Equal to the full average wherever the corners see what the inner samples
/// see.
pub fn direct_from_point_lights_adaptive(
    layout: &Layout,
    occluders: &Occluders,
    lights: &[Light],
    samples_per_edge: u32,
) -> DirectLight {
    let mut radiance = vec![[0.0f32; 3]; layout.n_texels()];
    direct_from_point_lights_adaptive_in(
        layout,
        occluders,
        lights,
        samples_per_edge,
        direct_scale(layout, occluders),
        &[TexelSpan {
            texels: 0..layout.n_texels(),
            in_sight: false,
        }],
        &mut radiance,
    );
    DirectLight { radiance }
}

/// A run of layout texels for [`direct_from_point_lights_adaptive_in`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TexelSpan {
    pub texels: std::ops::Range<usize>,
    /// The caller knows that every light sees every point of these texels unoccluded (e.g. the
    /// light's own room holds nothing but its walls, [`crate::light_reach`]): no shadow rays
    /// are traced there. Only ever set where a shadow ray could not hit anything.
    pub in_sight: bool,
}

/// [`direct_from_point_lights_adaptive`] on the texels of `spans` only (e.g. where a light
/// reaches, [`crate::light_reach::LightReach::texels`]): writes `out[t]` for every `t` in the
/// spans, bit-identical to the whole-layout call there (spans `in_sight` skip shadow rays that
/// would have hit nothing), and leaves every other texel of `out` untouched. `out` has one entry per layout texel; spans beyond it are cut off. `scale` is
/// [`direct_scale`] of the layout and occluders (a pass over every texel, so the caller keeps
/// it rather than paying it per call).
pub fn direct_from_point_lights_adaptive_in(
    layout: &Layout,
    occluders: &Occluders,
    lights: &[Light],
    samples_per_edge: u32,
    scale: f64,
    spans: &[TexelSpan],
    out: &mut [[f32; 3]],
) {
    let buffers = light_buffers(occluders, lights);
    adaptive_in_with(
        layout,
        shadows_of(occluders, &buffers),
        lights,
        samples_per_edge,
        scale,
        spans,
        &mut BoxShadows::new(),
        out,
    );
}

/// [`direct_from_point_lights_adaptive_in`] with its shadow rays tested against `shadows`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn adaptive_in_with(
    layout: &Layout,
    shadows: Shadows,
    lights: &[Light],
    samples_per_edge: u32,
    scale: f64,
    spans: &[TexelSpan],
    boxes: &mut BoxShadows,
    out: &mut [[f32; 3]],
) {
    let m = samples_per_edge.max(1) as usize;
    let lighting = Lighting::new(lights, shadows, scale);
    let n = out.len().min(layout.n_texels());
    let mut samples = TexelSamples::new();
    for_each_shadowed(
        &lighting,
        layout,
        spans,
        (n, m),
        boxes,
        |lighting, texels| {
            let Some(lighting) = lighting else {
                out[texels].fill([0.0; 3]);
                return;
            };
            for t in texels {
                out[t] = texel_direct(lighting, TexelAt::of(layout, t), m, Some(&mut samples));
            }
        },
    );
}

/// Calls `each(Some(queries), texels)` for the texels `< n` of `spans` (`m × m` samples each),
/// a run at a time, with shadow queries that give the texels' samples what `lighting`'s give
/// them, bit for bit: none in spans in sight, and with one light over a [`LightBuffer`], per
/// run of texels what a box query found ([`crate::box_shadows`]: nothing in the way, one
/// occluder in the way of every sample, or the few occluders that may be), so that most runs
/// trace no ray or test a handful of occluders. With one light, a run whose texels all face
/// away from it, or whose samples it all hides, gets `each(None, texels)`: every value there
/// is zero (no light term), and nothing is queried.
fn for_each_shadowed(
    lighting: &Lighting,
    layout: &Layout,
    spans: &[TexelSpan],
    (n, m): (usize, usize),
    query: &mut BoxShadows,
    mut each: impl FnMut(Option<&Lighting>, Range<usize>),
) {
    let clear = lighting.with_shadows(Shadows::Clear);
    let boxed = match lighting.shadows {
        Shadows::Buffers(occluders, [buffer]) => Some((occluders, buffer)),
        _ => None,
    };
    let one_light = match lighting.lights {
        [one] => Some(one),
        _ => None,
    };
    let facing_away = |run: &Range<usize>| {
        one_light.is_some_and(|light| {
            run.clone()
                .all(|t| faces_away(layout.positions[t], layout.normals[t], light))
        })
    };
    for span in spans {
        let texels = span.texels.start.min(n)..span.texels.end.min(n);
        if span.in_sight {
            for run in runs(layout, texels) {
                each((!facing_away(&run)).then_some(&clear), run);
            }
            continue;
        }
        let Some((occluders, buffer)) = boxed else {
            each(Some(lighting), texels);
            continue;
        };
        for run in runs(layout, texels) {
            if facing_away(&run) {
                each(None, run);
                continue;
            }
            let (lo, hi) = run_bounds(layout, run.clone(), m);
            match query.query(buffer, occluders, lo, hi) {
                BoxShadow::Clear => each(Some(&clear), run),
                BoxShadow::Dark => each(None, run),
                BoxShadow::Listed => {
                    let listed = lighting.with_shadows(Shadows::Listed(occluders, query.listed()));
                    each(Some(&listed), run);
                }
                BoxShadow::Unknown => each(Some(lighting), run),
            }
        }
    }
}

/// One texel of [`direct_from_point_lights_adaptive`] (`2 ≤ m ≤ ADAPTIVE_MAX_SAMPLES_PER_EDGE`,
/// a texel with a size).
fn adaptive_texel(
    lighting: &Lighting,
    t: TexelAt,
    m: usize,
    samples: &mut TexelSamples,
) -> [f32; 3] {
    let mut sampled = false;
    let mut irr = [0.0f64; 3];
    for li in 0..lighting.lights.len() {
        // A light behind the texel adds zero terms (`faces_away`): skip its samples.
        if faces_away(t.x, t.n, &lighting.lights[li]) {
            continue;
        }
        if !std::mem::replace(&mut sampled, true) {
            samples.start(&t, m);
        }
        add_adaptive(lighting, li, &t, m, samples, &mut irr);
    }
    outgoing(t.rho, irr).map(|v| v as f32)
}

/// Adds light `li`'s term of a texel's adaptive average into `irr`: `I` times the mean over
/// the texel's `m × m` samples of `cosθ / r² · V` ([`texel_mean`]), with
/// `V` traced at the four corner samples and at every sample only where the corners disagree
/// (no ray where the shadows are `Clear`). `samples` has been started on the texel
/// ([`TexelSamples::start`]).
fn add_adaptive(
    lighting: &Lighting,
    li: usize,
    t: &TexelAt,
    m: usize,
    samples: &mut TexelSamples,
    irr: &mut [f64; 3],
) {
    let light = &lighting.lights[li];
    // No intensity: the term is zero (adding it leaves `irr`).
    if light.intensity.iter().all(|&i| i == 0.0) {
        return;
    }
    let corners = corner_indices(m);
    // An axis-aligned texel the light does not face away from (the callers' `faces_away`)
    // has a positive term at every sample; a slanted one's terms are made first.
    let axis_aligned = is_axis_aligned(t.n);
    if !axis_aligned {
        samples.unshadowed(t, m, light, lighting.r2_min);
        if samples.g[..m * m].iter().all(|&v| v == 0.0) {
            return;
        }
    }
    let corner_seen = if matches!(lighting.shadows, Shadows::Clear) {
        // What the corners' rays would say, without making the corner points.
        [true; 4]
    } else {
        samples.corners(t, m);
        corners.map(|k| !lighting.occluded(li, samples.points[k]))
    };
    let w = if axis_aligned && corner_seen == [true; 4] {
        // Every sample seen, every term positive: the share seen is 1, the grid's terms are
        // not needed (what `texel_mean` gives, bit for bit: `mean · (all / all)`).
        unshadowed_mean(t, light, lighting.r2_min)
    } else {
        if axis_aligned {
            samples.unshadowed(t, m, light, lighting.r2_min);
        }
        if corner_seen.iter().any(|&v| v != corner_seen[0]) {
            samples.fill_points(t, m);
        }
        let points = &samples.points[..m * m];
        let g = &samples.g[..m * m];
        let sum = visible_sum(g, m, corner_seen, |k| !lighting.occluded(li, points[k]));
        texel_mean(t, light, lighting.r2_min, sum, g.iter().sum())
    };
    for (e, i) in irr.iter_mut().zip(light.intensity) {
        *e += i * w;
    }
}

/// The sum of the unshadowed terms `g` (`m × m` samples) over the samples seen: all of them
/// when the four corners agree they are seen (`corner_seen`), none when they agree they are
/// not, else each corner as seen and every other sample with a positive term as `visible(k)`
/// says (a shadow ray).
fn visible_sum(
    g: &[f64],
    m: usize,
    corner_seen: [bool; 4],
    mut visible: impl FnMut(usize) -> bool,
) -> f64 {
    let corners = corner_indices(m);
    if corner_seen.iter().all(|&v| v == corner_seen[0]) {
        return if corner_seen[0] { g.iter().sum() } else { 0.0 };
    }
    (0..m * m)
        .filter(|&k| g[k] > 0.0)
        .map(|k| match corners.iter().position(|&c| c == k) {
            Some(i) if corner_seen[i] => g[k],
            Some(_) => 0.0,
            None if visible(k) => g[k],
            None => 0.0,
        })
        .sum()
}

/// A light's texel mean of `cos θ / r² · V` from its samples: the unshadowed mean
/// ([`unshadowed_mean`]: exact near the light, 2 × 2 Gauss–Legendre farther) times the share
/// of the samples' terms that is seen (`seen / all`, `all` the sum of every sample's term; 0
/// when no sample has one).
fn texel_mean(t: &TexelAt, light: &Light, r2_min: f64, seen: f64, all: f64) -> f64 {
    if all > 0.0 {
        unshadowed_mean(t, light, r2_min) * (seen / all)
    } else {
        0.0
    }
}

/// Adds one light's term of [`direct_from_point_lights_adaptive_in`]'s texel value, before
/// albedo (`I ·` the texel-averaged `cosθ / r² · V`), into `irr[t]` for every texel `t` of
/// `spans`: summed over the lights in order and finished by [`finish_irradiance`], the terms
/// give that function's values bit for bit (a texel a light cannot reach gets a zero term,
/// which leaves the sum as it is). `m = samples_per_edge` must be at most
/// [`ADAPTIVE_MAX_SAMPLES_PER_EDGE`] (more averages samples over every light at once).
/// With `every_sample` every sample is traced (no corner shortcut): the term of
/// [`direct_from_point_lights_averaged`]'s texel value, to float rounding (that function sums
/// the lights per sample, this per texel).
#[allow(clippy::too_many_arguments)]
pub(crate) fn add_light_term_in(
    layout: &Layout,
    shadows: Shadows,
    light: &Light,
    samples_per_edge: u32,
    scale: f64,
    spans: &[TexelSpan],
    every_sample: bool,
    boxes: &mut BoxShadows,
    irr: &mut [[f64; 3]],
) {
    let m = samples_per_edge.max(1) as usize;
    debug_assert!(m <= ADAPTIVE_MAX_SAMPLES_PER_EDGE as usize);
    let lights = std::slice::from_ref(light);
    let lighting = Lighting::new(lights, shadows, scale);
    let n = irr.len().min(layout.n_texels());
    let mut samples = TexelSamples::new();
    for_each_shadowed(
        &lighting,
        layout,
        spans,
        (n, m),
        boxes,
        |lighting, texels| {
            // A run without light adds zero terms.
            let Some(lighting) = lighting else { return };
            for t in texels {
                let at = TexelAt::of(layout, t);
                // Every sample's term is zero when the light faces away (`faces_away`): what the
                // samples would add.
                if faces_away(at.x, at.n, light) {
                    continue;
                }
                if m == 1 || at.size == [0.0, 0.0] {
                    lighting.add_point(0, at.x, at.n, &mut irr[t]);
                } else if every_sample {
                    add_every_sample(lighting, 0, &at, m, &mut samples, &mut irr[t]);
                } else {
                    samples.start(&at, m);
                    add_adaptive(lighting, 0, &at, m, &mut samples, &mut irr[t]);
                }
            }
        },
    );
}

/// Adds light `li`'s term of a texel's full average into `irr`: `I` times the mean over the
/// texel's `m × m` samples of `cosθ / r² · V` ([`texel_mean`]), a shadow
/// ray at every sample the light faces.
fn add_every_sample(
    lighting: &Lighting,
    li: usize,
    t: &TexelAt,
    m: usize,
    samples: &mut TexelSamples,
    irr: &mut [f64; 3],
) {
    let light = &lighting.lights[li];
    if light.intensity.iter().all(|&i| i == 0.0) {
        return;
    }
    samples.start(t, m);
    samples.fill_points(t, m);
    samples.unshadowed(t, m, light, lighting.r2_min);
    let sum: f64 = samples.g[..m * m]
        .iter()
        .zip(&samples.points[..m * m])
        .filter(|(&gk, &p)| gk > 0.0 && !lighting.occluded(li, p))
        .map(|(&gk, _)| gk)
        .sum();
    let g = &samples.g[..m * m];
    let w = texel_mean(t, light, lighting.r2_min, sum, g.iter().sum());
    for (e, i) in irr.iter_mut().zip(light.intensity) {
        *e += i * w;
    }
}

/// The direct light of texels whose lights' terms ([`add_light_term_in`]) sum to `irr`:
/// `ρ/π · irr` per texel.
pub(crate) fn finish_irradiance(layout: &Layout, irr: &[[f64; 3]]) -> DirectLight {
    DirectLight {
        radiance: irr
            .iter()
            .zip(&layout.albedo)
            .map(|(e, &rho)| outgoing(rho, *e).map(|v| v as f32))
            .collect(),
    }
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)]
pub(crate) mod tests {
    use super::*;
    use crate::texel_samples::{
        dominant_axis, near_light_mean, sample_offset, sample_point, unshadowed_samples,
    };
    use lightfarm_proto::bundle::Rect;

    /// Adds `n` random axis-aligned occluder rects to `layout`: corner and plane in
    /// `[-extent, extent]`, sides up to `side`.
    fn push_random_rects(
        rng: &mut crate::occluders::tests::Lcg,
        layout: &mut Layout,
        n: usize,
        extent: f32,
        side: f32,
    ) {
        for _ in 0..n {
            let (a, b) = (rng.range(-extent, extent), rng.range(-extent, extent));
            layout.rects.push(Rect {
                axis: (rng.next_u32() % 3) as u8,
                coord: rng.range(-extent, extent),
                min: [a, b],
                max: [a + rng.range(0.0, side), b + rng.range(0.0, side)],
            });
        }
    }

    /// A point light (the client's tests share it).
    pub(crate) fn light(position: [f64; 3], intensity: [f64; 3]) -> Light {
        Light {
            kind: LightKind::Point,
            position,
            intensity,
        }
    }

    /// Texels on the floor z = 0 (normal +z) of a 4 m box (the client's tests share it).
    pub(crate) fn floor(points: &[[f32; 3]]) -> Layout {
        Layout {
            scene_name: "test".into(),
            surfaces: vec![],
            positions: points.to_vec(),
            normals: vec![[0.0, 0.0, 1.0]; points.len()],
            albedo: vec![[0.5, 0.25, 0.8]; points.len()],
            texel_size: vec![[0.0, 0.0]; points.len()],
            rects: vec![Rect {
                axis: 2,
                coord: 0.0,
                min: [0.0, 0.0],
                max: [4.0, 4.0],
            }],
            triangles: vec![],
        }
    }

    fn close(a: f32, b: f64) -> bool {
        (a as f64 - b).abs() <= 1e-5 * b.abs().max(1e-12)
    }

    /// A floor of `k × k` texels of `side` metres from the origin, at z = 0, as the bake lays
    /// them out (centres, normal +z, sizes).
    fn tiled_floor(k: usize, side: f32) -> Layout {
        let centres: Vec<[f32; 3]> = (0..k * k)
            .map(|i| {
                let (a, b) = ((i % k) as f32, (i / k) as f32);
                [(a + 0.5) * side, (b + 0.5) * side, 0.0]
            })
            .collect();
        let mut layout = floor(&centres);
        layout.texel_size = vec![[side, side]; k * k];
        layout.rects[0].max = [k as f32 * side; 2];
        layout
    }

    /// Solid angle of the rectangle `[x0, x1] × [y0, y1]` of the plane z = 0 from `(0, 0, d)`.
    fn rect_solid_angle(x0: f64, x1: f64, y0: f64, y1: f64, d: f64) -> f64 {
        let f = |x: f64, y: f64| (x * y / (d * (d * d + x * x + y * y).sqrt())).atan();
        f(x1, y1) - f(x0, y1) - f(x1, y0) + f(x0, y0)
    }

    /// A light 5 cm above a floor of 0.5 m texels, over a texel corner: every texel's value
    /// times its area sums to the light the whole floor receives (`I` times the solid angle
    /// the floor subtends, in closed form), to 1e-6, on the adaptive, full and per-light
    /// paths; the 4 × 4 grid alone gives the four texels around the light's foot 77% of
    /// theirs. Far from the light nothing changes: a texel 11 m away keeps the grid mean.
    #[test]
    fn a_light_near_a_surface_gives_it_all_its_light() {
        let (k, side) = (8usize, 0.5f32);
        let layout = tiled_floor(k, side);
        let occ = Occluders::from_layout(&layout);
        let d = 0.05;
        let foot = [2.0, 1.5];
        let lights = [light([foot[0], foot[1], d], [3.0, 3.0, 3.0])];
        let extent = k as f64 * side as f64;
        let floor_flux =
            3.0 * rect_solid_angle(-foot[0], extent - foot[0], -foot[1], extent - foot[1], d);
        let area = (side * side) as f64;
        // ρ/π · E, back to irradiance with the red albedo 0.5.
        let received = |r: &DirectLight| {
            r.radiance
                .iter()
                .map(|v| v[0] as f64 / 0.5 * std::f64::consts::PI * area)
                .sum::<f64>()
        };
        let adaptive = direct_from_point_lights_adaptive(&layout, &occ, &lights, 4);
        let averaged = direct_from_point_lights_averaged(&layout, &occ, &lights, 4);
        let mut irr = vec![[0.0; 3]; layout.n_texels()];
        let all = [TexelSpan {
            texels: 0..layout.n_texels(),
            in_sight: false,
        }];
        let scale = direct_scale(&layout, &occ);
        add_light_term_in(
            &layout,
            Shadows::Occluders(&occ),
            &lights[0],
            4,
            scale,
            &all,
            true,
            &mut BoxShadows::new(),
            &mut irr,
        );
        let per_light = finish_irradiance(&layout, &irr);
        for (name, r) in [
            ("adaptive", &adaptive),
            ("averaged", &averaged),
            ("per light", &per_light),
        ] {
            let got = received(r);
            assert!(
                (got / floor_flux - 1.0).abs() < 1e-6,
                "{name}: {got} received against {floor_flux}"
            );
        }
        // The grid alone, for scale: the four texels at the foot.
        let grid: f64 = [(3, 2), (4, 2), (3, 3), (4, 3)]
            .iter()
            .map(|&(a, b): &(usize, usize)| {
                let m = 4;
                (0..m * m)
                    .map(|s| {
                        let x = (a as f64 + (s % m) as f64 / 4.0 + 0.125) * 0.5 - foot[0];
                        let y = (b as f64 + (s / m) as f64 / 4.0 + 0.125) * 0.5 - foot[1];
                        d / (d * d + x * x + y * y).powf(1.5) / 16.0 * area
                    })
                    .sum::<f64>()
            })
            .sum();
        let exact = rect_solid_angle(-0.5, 0.5, -0.5, 0.5, d);
        assert!(grid < 0.8 * exact, "the grid gave {grid} of {exact}");
        // A far texel: the near-light mean does not apply, the grid's value stands.
        let far = tiled_floor(40, 0.25);
        let t = far.n_texels() - 1;
        let at = TexelAt::of(&far, t);
        assert_eq!(near_light_mean(&at, &lights[0]), None);
    }

    #[test]
    fn unoccluded_texel_matches_closed_form() {
        let layout = floor(&[[1.0, 1.0, 0.0]]);
        let occ = Occluders::from_layout(&layout);
        let i = [10.0, 20.0, 5.0];
        let p = [2.0, 3.0, 2.5];
        let d = light(p, i);
        let out = direct_from_point_lights(&layout, &occ, std::slice::from_ref(&d));
        let to = [1.0f64, 2.0, 2.5];
        let r2 = to.iter().map(|v| v * v).sum::<f64>();
        let cos = 2.5 / r2.sqrt();
        for c in 0..3 {
            let want = layout.albedo[0][c] as f64 / std::f64::consts::PI * i[c] * cos / r2;
            assert!(
                close(out.radiance[0][c], want),
                "channel {c}: {} vs {want}",
                out.radiance[0][c]
            );
        }
        // Two lights add.
        let twice = direct_from_point_lights(&layout, &occ, &[d.clone(), d]);
        for c in 0..3 {
            assert!(close(twice.radiance[0][c], 2.0 * out.radiance[0][c] as f64));
        }
    }

    #[test]
    fn texel_behind_an_occluder_gets_zero() {
        let mut layout = floor(&[[1.0, 1.0, 0.0], [3.0, 3.0, 0.0]]);
        layout.rects.push(Rect {
            axis: 2,
            coord: 1.0,
            min: [0.5, 0.5],
            max: [1.5, 1.5],
        });
        let occ = Occluders::from_layout(&layout);
        let out = direct_from_point_lights(&layout, &occ, &[light([1.0, 1.0, 3.0], [1.0; 3])]);
        assert_eq!(out.radiance[0], [0.0; 3]);
        assert!(
            out.radiance[1].iter().all(|&v| v > 0.0),
            "the other texel is lit"
        );
    }

    /// A 16 × 16 grid of 0.25 m texels on the floor, under a 1 m square blocker at z = 1 and
    /// a 2 cm bar at z = 0.5 along y, whose shadows from the test's lights fall between corner
    /// samples onto inner ones (one texel column each).
    fn shadowed_floor() -> Layout {
        let mut points = Vec::new();
        for j in 0..16 {
            for i in 0..16 {
                points.push([0.125 + 0.25 * i as f32, 0.125 + 0.25 * j as f32, 0.0]);
            }
        }
        let mut layout = floor(&points);
        layout.texel_size = vec![[0.25, 0.25]; points.len()];
        layout.rects.push(Rect {
            axis: 2,
            coord: 1.0,
            min: [1.0, 1.0],
            max: [2.0, 2.0],
        });
        layout.rects.push(Rect {
            axis: 2,
            coord: 0.5,
            min: [2.6853, 0.0],
            max: [2.7053, 4.0],
        });
        layout
    }

    /// Light buffers answer what the hierarchy answers: on random occluders (rects and
    /// triangles) over random texels, axis-aligned and slanted, facing any way, the averaged
    /// and the adaptive direct light are bit-identical either way.
    #[test]
    fn light_buffers_light_texels_bit_for_bit_as_the_hierarchy() {
        use crate::occluders::tests::Lcg;
        let mut rng = Lcg(0xb0ff_e12);
        let mut lit = 0;
        for case in 0..12 {
            let mut layout = Layout::default();
            for k in 0..300 {
                let mut n = [0.0f32; 3];
                if k % 3 == 0 {
                    n = rng.point(-1.0, 1.0);
                } else {
                    n[(rng.next_u32() % 3) as usize] = if k % 2 == 0 { 1.0 } else { -1.0 };
                }
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                if len < 0.1 {
                    n = [0.0, 1.0, 0.0];
                }
                layout.positions.push(rng.point(-4.0, 4.0));
                layout.normals.push(n.map(|x| x / len.max(0.1)));
                layout.albedo.push([0.5, 0.6, 0.7]);
                layout
                    .texel_size
                    .push([rng.range(0.05, 0.5), rng.range(0.05, 0.5)]);
            }
            push_random_rects(&mut rng, &mut layout, 10 + 5 * case, 5.0, 3.0);
            for _ in 0..(3 * case) {
                let c = rng.point(-4.0, 4.0);
                let mut p = || {
                    let o = rng.point(-1.0, 1.0);
                    [c[0] + o[0], c[1] + o[1], c[2] + o[2]]
                };
                layout.triangles.push([p(), p(), p()]);
            }
            let occ = Occluders::from_layout(&layout);
            let lights: Vec<Light> = (0..3)
                .map(|_| {
                    let p = rng.point(-4.5, 4.5).map(f64::from);
                    light(p, [1.0, 2.0, 3.0])
                })
                .collect();
            let scale = direct_scale(&layout, &occ);
            for m in [1, 4] {
                let by_buffers = direct_from_point_lights_averaged(&layout, &occ, &lights, m);
                let by_tree = averaged_with(&layout, Shadows::Occluders(&occ), scale, &lights, m);
                assert_eq!(by_buffers, by_tree, "case {case}, averaged, m = {m}");
                lit += by_tree.radiance.iter().filter(|v| v[0] > 0.0).count();
            }
            let all = [TexelSpan {
                texels: 0..layout.n_texels(),
                in_sight: false,
            }];
            let by_buffers = direct_from_point_lights_adaptive(&layout, &occ, &lights, 4);
            let mut by_tree = vec![[0.0f32; 3]; layout.n_texels()];
            adaptive_in_with(
                &layout,
                Shadows::Occluders(&occ),
                &lights,
                4,
                scale,
                &all,
                &mut BoxShadows::new(),
                &mut by_tree,
            );
            assert_eq!(by_buffers.radiance, by_tree, "case {case}, adaptive");
        }
        assert!(lit > 1000, "{lit} texels lit");
    }

    /// The adaptive average as first written (every sample point made, the unshadowed terms
    /// per point, corners traced, every sample where they disagree) for one light; which
    /// samples count is `visible_sum`, shared.
    fn adaptive_by_points(lighting: &Lighting, li: usize, t: &TexelAt, m: usize) -> [f64; 3] {
        let mut points = vec![[0.0f32; 3]; m * m];
        sample_points(t.x, t.n, t.size, m, &mut points);
        let light = &lighting.lights[li];
        let mut g = vec![0.0f64; m * m];
        unshadowed_samples(&points, t.n, light, lighting.r2_min, &mut g);
        if g.iter().all(|&v| v == 0.0) {
            return [0.0; 3];
        }
        let seen = corner_indices(m).map(|k| !lighting.occluded(li, points[k]));
        let sum = visible_sum(&g, m, seen, |k| !lighting.occluded(li, points[k]));
        let w = texel_mean(t, light, lighting.r2_min, sum, g.iter().sum());
        light.intensity.map(|i| i * w)
    }

    /// The per-row-and-column unshadowed terms, the corner points made alone and the points
    /// made only when corners disagree give the first-written adaptive average bit for bit:
    /// axis-aligned and slanted texels, lights near, far, in the texel's plane and behind,
    /// `m` from 2 to 8, against random occluders.
    #[test]
    fn grid_terms_and_lazy_points_give_the_per_point_average_bit_for_bit() {
        use crate::occluders::tests::Lcg;
        let mut rng = Lcg(0x9a1d_7e57);
        let mut layout = Layout::default();
        push_random_rects(&mut rng, &mut layout, 40, 3.0, 2.0);
        let occ = Occluders::from_layout(&layout);
        let (mut partial, mut checked) = (0, 0);
        for case in 0..3000 {
            let mut n = [0.0f32; 3];
            let axis = (rng.next_u32() % 3) as usize;
            n[axis] = if case % 2 == 0 { 1.0 } else { -1.0 };
            if case % 5 == 0 {
                n = rng.point(-1.0, 1.0);
                let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt().max(0.1);
                n = n.map(|x| x / len);
            }
            let t = TexelAt {
                x: rng.point(-3.0, 3.0),
                n,
                rho: [0.5, 0.5, 0.5],
                size: [rng.range(0.01, 0.6), rng.range(0.01, 0.6)],
            };
            let mut p = rng.point(-4.0, 4.0).map(f64::from);
            if case % 7 == 0 {
                // In the texel's plane.
                let a = dominant_axis(n);
                p[a] = t.x[a] as f64;
            }
            if case % 11 == 0 {
                // Far away.
                p = p.map(|x| x * 1e4);
            }
            let lights = [light(p, [1.0, 2.0, 0.5])];
            let m = 2 + case % 7;
            let lighting = Lighting::new(&lights, Shadows::Occluders(&occ), 6.0);
            let mut samples = TexelSamples::new();
            // Leftovers of another texel must not leak into this one.
            samples.all_points = case % 3 == 0;
            samples.start(&t, m);
            let mut irr = [0.0f64; 3];
            add_adaptive(&lighting, 0, &t, m, &mut samples, &mut irr);
            let want = adaptive_by_points(&lighting, 0, &t, m);
            assert_eq!(irr.map(f64::to_bits), want.map(f64::to_bits), "case {case}");
            // The every-sample average through the same scratch.
            let mut every = [0.0f64; 3];
            add_every_sample(&lighting, 0, &t, m, &mut samples, &mut every);
            let mut points = vec![[0.0f32; 3]; m * m];
            sample_points(t.x, t.n, t.size, m, &mut points);
            let mut g = vec![0.0f64; m * m];
            unshadowed_samples(&points, t.n, &lights[0], lighting.r2_min, &mut g);
            assert_eq!(samples.g[..m * m], g[..], "case {case}: unshadowed terms");
            assert_eq!(samples.points[..m * m], points[..], "case {case}: points");
            for (k, q) in points.iter().enumerate() {
                let o = |i| sample_offset(i, m);
                assert_eq!(*q, sample_point(t.x, t.n, t.size, o(k % m), o(k / m)));
            }
            checked += usize::from(irr != [0.0; 3]);
            partial += usize::from(irr != [0.0; 3] && every != irr);
        }
        assert!(
            checked > 800 && partial > 10,
            "{checked} lit, {partial} partly shadowed"
        );
    }

    #[test]
    fn adaptive_average_equals_the_full_average_where_corners_see_what_samples_see() {
        let layout = shadowed_floor();
        let occ = Occluders::from_layout(&layout);
        let lights = [
            light([1.6, 1.4, 3.0], [10.0, 8.0, 6.0]),
            light([3.0, 3.5, 2.0], [2.0; 3]),
        ];
        let full = direct_from_point_lights_averaged(&layout, &occ, &lights, 4);
        let adaptive = direct_from_point_lights_adaptive(&layout, &occ, &lights, 4);
        // Without occluders between texels and lights every texel agrees to rounding.
        let open = Occluders::new(&layout.rects[..1], &[]);
        let (a, b) = (
            direct_from_point_lights_averaged(&layout, &open, &lights, 4),
            direct_from_point_lights_adaptive(&layout, &open, &lights, 4),
        );
        for (x, y) in a.radiance.iter().zip(&b.radiance) {
            for c in 0..3 {
                assert!(close(y[c], x[c] as f64), "{x:?} vs {y:?}");
            }
        }
        // With the blockers: penumbra texels (corners disagree) are traced sample by sample,
        // so only the texels whose inner samples alone the bar's thin shadows cross differ.
        let mut differ = 0;
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for (x, y) in full.radiance.iter().zip(&adaptive.radiance) {
            let d: f64 = (0..3).map(|c| (x[c] as f64 - y[c] as f64).powi(2)).sum();
            if d.sqrt() > 1e-5 * (x[0] as f64).abs().max(1e-6) {
                differ += 1;
                // A missed thin shadow only brightens, by at most the shadowed inner samples
                // (at most a half of a 4 × 4 grid's samples lie between its corners' columns).
                for c in 0..3 {
                    assert!(y[c] >= x[c] && y[c] - x[c] <= 0.5 * y[c], "{x:?} vs {y:?}");
                }
            }
            num += d;
            den += (0..3).map(|c| (x[c] as f64).powi(2)).sum::<f64>();
        }
        let rel = (num / den).sqrt();
        assert!(differ > 0 && differ <= 32, "{differ} texels differ");
        // The designed worst case (two shadows missed along whole columns): a few percent.
        assert!(rel < 0.1, "relative L2 {rel}");
        // Under the first light alone, the blocker's umbra is dark in both, texel for texel.
        let one = &lights[..1];
        let (x, y) = (
            direct_from_point_lights_averaged(&layout, &occ, one, 4),
            direct_from_point_lights_adaptive(&layout, &occ, one, 4),
        );
        let dark = x.radiance.iter().filter(|v| v[0] == 0.0).count();
        assert!(dark >= 9, "{dark} dark texels");
        for (x, y) in x.radiance.iter().zip(&y.radiance) {
            assert_eq!(x[0] == 0.0, y[0] == 0.0, "{x:?} vs {y:?}");
        }
    }

    #[test]
    fn light_behind_the_surface_gives_zero() {
        let layout = floor(&[[1.0, 1.0, 0.0]]);
        let occ = Occluders::new(&[], &[]);
        let out = direct_from_point_lights(&layout, &occ, &[light([1.0, 1.0, -2.0], [5.0; 3])]);
        assert_eq!(out.radiance[0], [0.0; 3]);
        // Grazing (in the plane) gives zero too.
        let out = direct_from_point_lights(&layout, &occ, &[light([3.0, 1.0, 0.0], [5.0; 3])]);
        assert_eq!(out.radiance[0], [0.0; 3]);
    }

    #[test]
    fn light_on_or_at_a_texel_stays_finite() {
        let layout = floor(&[[1.0, 1.0, 0.0], [2.0, 2.0, 0.0]]);
        let occ = Occluders::from_layout(&layout);
        // Exactly at texel 0, just above texel 1's plane next to it.
        let lights = [
            light([1.0, 1.0, 0.0], [1.0; 3]),
            light([2.0, 2.0, 1e-7], [1.0; 3]),
        ];
        let out = direct_from_point_lights(&layout, &occ, &lights);
        for v in out.radiance.iter().flatten() {
            assert!(v.is_finite() && *v >= 0.0, "{v}");
        }
        assert!(out.radiance[1][0] > 0.0);
    }

    #[test]
    fn one_value_per_texel_and_nothing_without_lights() {
        let layout = floor(&[[1.0, 1.0, 0.0], [2.0, 1.0, 0.0], [3.0, 1.0, 0.0]]);
        let out = direct_from_point_lights(&layout, &Occluders::from_layout(&layout), &[]);
        assert_eq!(out.radiance, vec![[0.0; 3]; 3]);
    }
}
