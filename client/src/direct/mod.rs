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
//! a few on one face (module `box_shadows`): a run the light sees whole traces no ray (its
//! values come from one loop, module `clear_run`), one an occluder hides whole neither, and in
//! the rest each texel's own box is classified the same way against the occluders that may
//! cross the run's segments, so that only texels a shadow's edge crosses trace rays, against
//! those occluders alone; all with the buffer's answers.
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
//!
//! # Layout
//! - this file: the convention, the lights' shadow queries (`Lighting`, `Shadows`), the
//!   whole-level functions, the adaptive average and its runs of texels, one light's terms,
//!   and the same rule at points that are not texels (`point_irradiance`).
//! - `clear_run`: a run of texels the lights see whole, without the adaptive average's
//!   per-texel steps.
//! - `tests`: closed forms, shadows, light buffers and the adaptive average against tracing
//!   every sample; the fixtures other modules' tests share.

use std::ops::Range;

use lightfarm_proto::bundle::Layout;
use lightfarm_proto::lights::{Light, LightKind};

use crate::box_shadows::{run_bounds, run_box, runs, texel_extent, BoxShadow, BoxShadows};
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
    /// One [`LightBuffer`] per light over the level's occluders (some of them), and the posed
    /// objects' triangles ([`Occluders::with_triangles`]) through their own hierarchy: the
    /// lights' shadows where objects move ([`crate::shadow_change`]), whose buffers need no
    /// rebuild as the objects move.
    BuffersAndPosed(&'a Occluders, &'a [LightBuffer]),
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
        if let Shadows::Buffers(_, buffers) | Shadows::BuffersAndPosed(_, buffers) = shadows {
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
            Shadows::BuffersAndPosed(occluders, buffers) => {
                buffers[li].occluded(occluders, x)
                    || occluders.posed_occluded(x, self.positions[li])
            }
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
        if is_dark(light) {
            return;
        }
        // Unshadowed first: a light behind the texel costs no shadow ray.
        let g = unshadowed(x, n, light, self.r2_min);
        if g == 0.0 || self.occluded(li, x) {
            return;
        }
        add_term(irr, light, g);
    }
}

/// A light without intensity: its terms are zero, and adding them leaves `irr`.
#[inline(always)]
fn is_dark(light: &Light) -> bool {
    light.intensity.iter().all(|&i| i == 0.0)
}

/// Adds `light`'s term `I · w` into `irr` (`w`: its `cosθ / r² · V` at a point, or the
/// texel's mean of it).
#[inline(always)]
fn add_term(irr: &mut [f64; 3], light: &Light, w: f64) {
    for (e, i) in irr.iter_mut().zip(light.intensity) {
        *e += i * w;
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
/// Inlined: out of line, its caller's freshly built `TexelAt` was copied through memory, each
/// copy stalling on the stores just made (a third of this function's time in a profile).
#[inline(always)]
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

/// Irradiance `Σ I · cosθ / r² · V` (W/m², per channel) of point `lights` at each `(x, n)`
/// of `points` (a point and its unit normal, in the world frame), with shadow rays against
/// `occluders` and `r²` clamped as at texels (`scale`: [`direct_scale`]). For surfaces that are
/// not layout texels, e.g. the corners of a posed dynamic object's triangles.
pub fn point_irradiance(
    occluders: &Occluders,
    lights: &[Light],
    scale: f64,
    points: impl IntoIterator<Item = ([f32; 3], [f32; 3])>,
) -> Vec<[f64; 3]> {
    let lighting = Lighting::new(lights, Shadows::Occluders(occluders), scale);
    points
        .into_iter()
        .map(|(x, n)| {
            let mut irr = [0.0f64; 3];
            for li in 0..lights.len() {
                lighting.add_point(li, x, n, &mut irr);
            }
            irr
        })
        .collect()
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
        if is_dark(light) {
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
        add_term(&mut irr, light, w);
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
            if let Some(axes) = clear_run::axes(lighting, layout, &texels, m) {
                return clear_run::values(lighting, layout, (texels, m, axes), &mut samples, out);
            }
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
                .all(|t| faces_away(&layout.positions[t], &layout.normals[t], light))
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
                    // Texel by texel, the listed occluders against the texel's own box: most
                    // texels of such a run lie wholly in or out of the shadow.
                    let mut clear_from = run.start;
                    let extent = texel_extent(layout, run.clone(), m);
                    for t in run.clone() {
                        let (lo, hi) = run_box(layout, t..t + 1, extent);
                        let answer = query.refine(occluders, buffer.light(), lo, hi);
                        if answer == BoxShadow::Clear {
                            continue;
                        }
                        if clear_from < t {
                            each(Some(&clear), clear_from..t);
                        }
                        clear_from = t + 1;
                        if answer == BoxShadow::Dark {
                            each(None, t..t + 1);
                        } else {
                            let listed = Shadows::Listed(occluders, query.refined());
                            each(Some(&lighting.with_shadows(listed)), t..t + 1);
                        }
                    }
                    if clear_from < run.end {
                        each(Some(&clear), clear_from..run.end);
                    }
                }
                BoxShadow::Unknown => each(Some(lighting), run),
            }
        }
    }
}

/// One texel of [`direct_from_point_lights_adaptive`] (`2 ≤ m ≤ ADAPTIVE_MAX_SAMPLES_PER_EDGE`,
/// a texel with a size).
#[inline(always)]
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
        if faces_away(&t.x, &t.n, &lighting.lights[li]) {
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
    if is_dark(light) {
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
    add_term(irr, light, w);
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
            if !every_sample {
                if let Some(axes) = clear_run::axes(lighting, layout, &texels, m) {
                    return clear_run::terms(lighting, layout, (texels, axes), irr);
                }
            }
            for t in texels {
                let at = TexelAt::of(layout, t);
                // Every sample's term is zero when the light faces away (`faces_away`): what the
                // samples would add.
                if faces_away(&at.x, &at.n, light) {
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
    if is_dark(light) {
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
    add_term(irr, light, w);
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

mod clear_run;
#[cfg(test)]
pub(crate) mod tests;
