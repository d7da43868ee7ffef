//! The change of direct light when posed dynamic objects move ([`ShadowChange`]): the texels
//! whose shadow rays an object can cross, where it was or where it is now, relit for the lights
//! whose reach it stands in, so that a frame in which an object moves costs what its shadows
//! touch rather than the level's direct light and a whole apply (`Runtime::apply_delta_in` of
//! the change, like a moving light's).
//!
//! Which texels: a texel's light from a point light `L` can change only if a segment from one
//! of its samples to `L` crosses a moved object's triangles, where it was or where it is (an
//! object placed as before changes no segment's answer); they lie in the object's box. With
//! the texel's samples within `r_t` of a centre `x` (the ball around their box) and the
//! object's box within `ρ` of `c`, every such segment point `p + s (L − p)` lies within
//! `(1 − s) r_t ≤ r_t` of `x + s (L − x)`, so the segment can meet the object only if the
//! segment from `x` to `L` passes within `ρ + r_t` of `c`. That test (per group of
//! `RUNS_PER_GROUP` (16) runs of texels, per run, then per texel) is conservative: a texel it
//! drops keeps its light bit for bit. Lights are first kept only when the object's ball meets
//! the box around the light and the samples of every texel it reaches (its reach is fixed at
//! [`ShadowChange::new`]: objects only take light away, they never let a light reach another
//! room).
//!
//! On the texels kept, each light's direct light is made twice with the adaptive texel average
//! of the direct-light module (`samples_per_edge`, the level's [`crate::direct_scale`]): with
//! the occluders of the objects' last poses (kept from the last update where it relit the same
//! texels of that light) and with this frame's, and the change adds their difference. Each
//! is bit-identical to the same light's term over the whole level with those occluders
//! (`ReachDirect::with_posed(…).all_lights`), so the change summed into the direct light a
//! game keeps equals that direct light to float rounding (the whole-level sum adds the lights'
//! terms per texel, the change adds per-light differences).
//!
//! Units: radiance leaving the texels (W/m²/sr per channel), metres, world frame.
//!
//! Memory: per light, its reach's runs of texels (80 bytes a run) and occluder list; three
//! RGB values per texel (the change, and one light's term before and after a move). The
//! 1,000-block level with a ball (165 lights): 82,515 runs and 26,805 listed occluders, 7.0 MB,
//! and 9.7 MB per texel.
//!
//! Invariants: [`ShadowChange::change`] is zero outside [`ShadowChange::spans`] (ascending,
//! disjoint); each [`ShadowChange::update`] first clears what the last one wrote; a refused
//! call changes nothing. The first update's change is from the poses [`ShadowChange::new`] was
//! given (those the caller's direct light was made with), so a game feeds that direct light at
//! load and every change after it. Results do not depend on the order of the poses.

use std::ops::Range;

use lightfarm_proto::bundle::Bundle;
use lightfarm_proto::glam::DVec3;
use lightfarm_proto::lights::{Light, Pose};

use crate::box_shadows::{run_bounds, runs, texel_extent, BoxShadows};
use crate::direct::{adaptive_in_with, direct_scale, DirectLight, Shadows, TexelSpan};
use crate::dynamic_shadows::{occluders_with_poses, shadowing_poses, PosedObjects};
use crate::light_buffer::LightBuffer;
use crate::occluders::Occluders;
use crate::reach_direct::{reach_buffer, ReachDirect};
use crate::runtime::merge_spans;

/// An object's ball is widened by this much of the level's scale before the test (far above
/// f32 rounding of the posed triangles and of the shadow segments' margins).
const PAD_REL: f64 = 1e-4;

/// Why a change of shadows could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ShadowChangeError {
    #[error("this ShadowChange was made for a layout of {expected} texels, not {got}")]
    OtherBundle { expected: usize, got: usize },
}

/// A ball: centre and radius (metres).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Ball {
    centre: DVec3,
    radius: f64,
}

impl Ball {
    /// The ball around a box (an infinite ball around a box that is not finite).
    fn around((lo, hi): ([f64; 3], [f64; 3])) -> Ball {
        let (lo, hi) = (DVec3::from_array(lo), DVec3::from_array(hi));
        if !(lo.is_finite() && hi.is_finite()) {
            return Ball {
                centre: DVec3::ZERO,
                radius: f64::INFINITY,
            };
        }
        Ball {
            centre: 0.5 * (lo + hi),
            radius: 0.5 * (hi - lo).length(),
        }
    }

    /// Whether a segment from a point of this ball to `light` can meet `object` (module doc).
    fn shadow_meets(&self, light: DVec3, object: &Ball) -> bool {
        segment_distance(object.centre, self.centre, light) <= object.radius + self.radius
    }
}

/// Distance from `p` to the segment `a`–`b`.
fn segment_distance(p: DVec3, a: DVec3, b: DVec3) -> f64 {
    let ab = b - a;
    let len2 = ab.length_squared();
    let s = if len2 > 0.0 {
        ((p - a).dot(ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (a + s * ab - p).length()
}

/// Runs of a light's reach tested together before their own tests.
const RUNS_PER_GROUP: usize = 16;

/// A run of texels on one face ([`runs`]) in a light's reach.
#[derive(Clone, Debug)]
struct Run {
    texels: Range<usize>,
    /// Around every sample of the run's texels.
    ball: Ball,
    /// Every sample of texel t lies within `texel_radius` of `positions[t] + texel_offset`.
    texel_offset: DVec3,
    texel_radius: f64,
}

/// One light's reach, as [`ShadowChange::update`] walks it.
#[derive(Clone, Debug)]
struct LightRuns {
    position: DVec3,
    /// The box around the light and every sample of the texels it reaches.
    lo: DVec3,
    hi: DVec3,
    /// The runs of texels it reaches, in layout order, and groups of [`RUNS_PER_GROUP`]
    /// consecutive runs with the ball around all their samples.
    runs: Vec<Run>,
    groups: Vec<(Range<usize>, Ball)>,
    /// The level's occluders its shadow rays on those texels can meet (those of the rooms it
    /// reaches, `ReachDirect`'s argument); None: any of them (the walk left the level, or
    /// the bundle has no rooms).
    prims: Option<Vec<u32>>,
}

impl LightRuns {
    /// Whether `object` meets this light's box.
    fn meets(&self, object: &Ball) -> bool {
        let nearest = object.centre.clamp(self.lo, self.hi);
        (nearest - object.centre).length() <= object.radius
    }
}

/// What the last update kept of a light it relit: the light's buffer over the level's
/// occluders (the light never moves; None: the level is traced by its hierarchy), and its
/// direct light on the texels it relit with the objects where they then were (this update's
/// light before the move there).
#[derive(Clone, Debug, Default)]
struct Relit {
    light: usize,
    buffer: Option<LightBuffer>,
    spans: Vec<Range<usize>>,
    values: Vec<[f32; 3]>,
}

/// The change of direct light as posed dynamic objects move (see the module doc).
#[derive(Clone, Debug)]
pub struct ShadowChange {
    lights: Vec<Light>,
    reach: Vec<LightRuns>,
    samples_per_edge: u32,
    scale: f64,
    pad: f64,
    /// The objects as of the last update (None: none posed yet, or none with a shape).
    last: Option<PosedObjects>,
    /// The objects placed as of the last update (those with a shape) and their balls.
    placed: Vec<(Pose, Ball)>,
    /// The lights the last update relit.
    relit: Vec<Relit>,
    /// One RGB value per texel: the last update's change, zero outside `spans`.
    change: DirectLight,
    spans: Vec<Range<usize>>,
    // Scratch, kept between calls.
    placed_now: Vec<(Pose, Ball)>,
    matched: Vec<bool>,
    /// The moved objects' balls, where they were and where they are.
    both: Vec<Ball>,
    next: Vec<Relit>,
    kept: Vec<TexelSpan>,
    fresh: Vec<TexelSpan>,
    now: Vec<[f32; 3]>,
    was: Vec<[f32; 3]>,
    boxes: BoxShadows,
}

impl ShadowChange {
    /// For `bundle`, its layout's occluders `level` (`Occluders::from_layout`) and the level's
    /// `lights`, texel-averaged over `samples_per_edge²` samples (what `eval` feeds the
    /// operators: 4), starting from the objects at `poses` (none: the level alone), the poses
    /// the caller's direct light was made with. Walks each light's reach once (every texel for
    /// a bundle without rooms).
    pub fn new(
        bundle: &Bundle,
        level: &Occluders,
        lights: &[Light],
        samples_per_edge: u32,
        poses: &[Pose],
    ) -> ShadowChange {
        let layout = &bundle.layout;
        let n = layout.n_texels();
        let m = samples_per_edge.max(1) as usize;
        let mut reach = ReachDirect::new(bundle, level);
        let mut spans = Vec::new();
        let reach = lights
            .iter()
            .map(|light| {
                let mut prims = Vec::new();
                let in_rooms = match reach.as_mut() {
                    Some(r) => r.reached_prims(layout, light.position, &mut spans, &mut prims),
                    None => {
                        spans.clear();
                        spans.push(TexelSpan {
                            texels: 0..n,
                            in_sight: false,
                        });
                        false
                    }
                };
                let position = DVec3::from_array(light.position);
                let (mut lo, mut hi) = (position, position);
                let mut light_runs = Vec::new();
                let mut boxes = Vec::new();
                for span in &spans {
                    for texels in runs(layout, span.texels.clone()) {
                        let (a, b) = run_bounds(layout, texels.clone(), m);
                        let (a, b) = (DVec3::from_array(a), DVec3::from_array(b));
                        lo = lo.min(a);
                        hi = hi.max(b);
                        boxes.push((a, b));
                        let (wlo, whi) = texel_extent(layout, texels.clone(), m);
                        let (wlo, whi) = (DVec3::from_array(wlo), DVec3::from_array(whi));
                        // The rounding `run_bounds` pads the centres' coordinates for.
                        let mag = (a.abs().max(b.abs())).max_element();
                        light_runs.push(Run {
                            texels,
                            ball: Ball::around((a.to_array(), b.to_array())),
                            texel_offset: 0.5 * (wlo + whi),
                            texel_radius: 0.5 * (whi - wlo).length() + 1e-5 * mag,
                        });
                    }
                }
                let groups = (0..light_runs.len())
                    .step_by(RUNS_PER_GROUP)
                    .map(|g| {
                        let group = g..(g + RUNS_PER_GROUP).min(light_runs.len());
                        let (a, b) = (boxes[group.clone()].iter())
                            .fold((boxes[g].0, boxes[g].1), |(a, b), &(c, d)| {
                                (a.min(c), b.max(d))
                            });
                        (group, Ball::around((a.to_array(), b.to_array())))
                    })
                    .collect();
                LightRuns {
                    position,
                    lo,
                    hi,
                    runs: light_runs,
                    groups,
                    prims: in_rooms.then_some(prims),
                }
            })
            .collect();
        let pad = PAD_REL * level.scale() as f64;
        let last = occluders_with_poses(level, bundle, poses);
        let mut placed = Vec::new();
        placed_balls(bundle, poses, last.as_ref(), pad, &mut placed);
        ShadowChange {
            lights: lights.to_vec(),
            reach,
            samples_per_edge,
            scale: direct_scale(layout, level),
            pad,
            last,
            placed,
            relit: Vec::new(),
            change: DirectLight {
                radiance: vec![[0.0; 3]; n],
            },
            spans: Vec::new(),
            placed_now: Vec::new(),
            matched: Vec::new(),
            both: Vec::new(),
            next: Vec::new(),
            kept: Vec::new(),
            fresh: Vec::new(),
            now: vec![[0.0; 3]; n],
            was: vec![[0.0; 3]; n],
            boxes: BoxShadows::new(),
        }
    }

    /// Moves the posed objects to `poses` (a pose whose object has no shape in `bundle` casts
    /// no shadow, as in [`crate::occluders_with_poses`]) and makes the change of direct light
    /// since the last update ([`ShadowChange::change`] on [`ShadowChange::spans`]). `bundle`
    /// and `level` must be the ones this was made with.
    pub fn update(
        &mut self,
        bundle: &Bundle,
        level: &Occluders,
        poses: &[Pose],
    ) -> Result<(), ShadowChangeError> {
        let layout = &bundle.layout;
        let n = self.change.radiance.len();
        if layout.n_texels() != n {
            return Err(ShadowChangeError::OtherBundle {
                expected: n,
                got: layout.n_texels(),
            });
        }
        for r in self.spans.drain(..) {
            self.change.radiance[r].fill([0.0; 3]);
        }
        let posed = occluders_with_poses(level, bundle, poses);
        let before = self.last.as_ref().map_or(level, |p| &p.occluders);
        let after = posed.as_ref().map_or(level, |p| &p.occluders);
        // The objects that moved (a pose not placed the same before, matched one to one),
        // where they were and where they are: an object that stayed changes no segment's
        // answer.
        placed_balls(
            bundle,
            poses,
            posed.as_ref(),
            self.pad,
            &mut self.placed_now,
        );
        self.matched.clear();
        self.matched.resize(self.placed.len(), false);
        self.both.clear();
        for (pose, ball) in &self.placed_now {
            let same = (self.placed.iter().enumerate())
                .position(|(k, (p, _))| !self.matched[k] && p == pose);
            match same {
                Some(k) => self.matched[k] = true,
                None => self.both.push(*ball),
            }
        }
        for ((_, ball), matched) in self.placed.iter().zip(&self.matched) {
            if !matched {
                self.both.push(*ball);
            }
        }
        for (i, (light, reach)) in self.lights.iter().zip(&self.reach).enumerate() {
            let objects = || self.both.iter();
            if !objects().any(|o| reach.meets(o)) {
                continue;
            }
            // The texels whose samples' segments to the light may meet an object.
            let at = reach.position;
            self.kept.clear();
            for (group, ball) in &reach.groups {
                if !objects().any(|o| ball.shadow_meets(at, o)) {
                    continue;
                }
                for run in &reach.runs[group.clone()] {
                    if !objects().any(|o| run.ball.shadow_meets(at, o)) {
                        continue;
                    }
                    for t in run.texels.clone() {
                        let texel = Ball {
                            centre: DVec3::from_array(layout.positions[t].map(f64::from))
                                + run.texel_offset,
                            radius: run.texel_radius,
                        };
                        if !objects().any(|o| texel.shadow_meets(at, o)) {
                            continue;
                        }
                        match self.kept.last_mut() {
                            Some(last) if last.texels.end == t => last.texels.end = t + 1,
                            _ => self.kept.push(TexelSpan {
                                texels: t..t + 1,
                                in_sight: false,
                            }),
                        }
                    }
                }
            }
            if self.kept.is_empty() {
                continue;
            }
            // The light's buffer and its light before the move, from the last update when it
            // relit this light too.
            let mut relit = match self.relit.iter().position(|r| r.light == i) {
                Some(k) => self.relit.swap_remove(k),
                None => {
                    let mut buffer = LightBuffer::new();
                    let at = light.position.map(|x| x as f32);
                    let prims = reach.prims.as_deref();
                    Relit {
                        light: i,
                        buffer: reach_buffer(&mut buffer, level, at, prims).then_some(buffer),
                        ..Relit::default()
                    }
                }
            };
            let shadows = |occluders| match &relit.buffer {
                // The level's occluders through the buffer, the objects' triangles through
                // their own hierarchy.
                Some(b) => Shadows::BuffersAndPosed(occluders, std::slice::from_ref(b)),
                None => Shadows::Occluders(occluders),
            };
            let mut k = 0;
            for r in &relit.spans {
                for t in r.clone() {
                    self.was[t] = relit.values[k];
                    k += 1;
                }
            }
            subtract(&self.kept, &relit.spans, &mut self.fresh);
            let one = std::slice::from_ref(light);
            for (occluders, spans, out) in [
                (after, &self.kept, &mut self.now),
                (before, &self.fresh, &mut self.was),
            ] {
                adaptive_in_with(
                    layout,
                    shadows(occluders),
                    one,
                    self.samples_per_edge,
                    self.scale,
                    spans,
                    &mut self.boxes,
                    out,
                );
            }
            relit.spans.clear();
            relit.values.clear();
            for span in &self.kept {
                for t in span.texels.clone() {
                    let (a, b, c) = (self.now[t], self.was[t], &mut self.change.radiance[t]);
                    for k in 0..3 {
                        c[k] += a[k] - b[k];
                    }
                    relit.values.push(a);
                }
                relit.spans.push(span.texels.clone());
                self.spans.push(span.texels.clone());
            }
            self.next.push(relit);
        }
        merge_spans(&mut self.spans);
        self.last = posed;
        std::mem::swap(&mut self.placed, &mut self.placed_now);
        // Lights not relit now keep nothing: their light before the next move is not known.
        std::mem::swap(&mut self.relit, &mut self.next);
        self.next.clear();
        Ok(())
    }

    /// The last update's change of direct light (zero outside [`ShadowChange::spans`]): add it
    /// to the direct light, and relight by it (`Runtime::apply_delta_in`).
    pub fn change(&self) -> &DirectLight {
        &self.change
    }

    /// The texel ranges the last update's change lies in (ascending, disjoint).
    pub fn spans(&self) -> &[Range<usize>] {
        &self.spans
    }

    /// The lights this was made for.
    pub fn lights(&self) -> &[Light] {
        &self.lights
    }

    /// Lights the last update relit on some texels (those whose reach an object's ball met
    /// where it was or where it is, and with texels its shadows may cross).
    pub fn lights_relit(&self) -> usize {
        self.relit.len()
    }
}

/// Each pose of `poses` that casts a shadow, with the ball around its posed triangles (their
/// box in `posed`, made by `occluders_with_poses` from the same poses) widened by `pad`, into
/// `out`.
fn placed_balls(
    bundle: &Bundle,
    poses: &[Pose],
    posed: Option<&PosedObjects>,
    pad: f64,
    out: &mut Vec<(Pose, Ball)>,
) {
    out.clear();
    let boxes = posed.map_or(&[][..], |p| &p.boxes);
    for ((pose, _), &b) in shadowing_poses(bundle, poses).zip(boxes) {
        let ball = Ball::around(b);
        let radius = ball.radius + pad;
        out.push((pose.clone(), Ball { radius, ..ball }));
    }
}

/// The texels of `a` not in `b` (each ascending and disjoint), as spans not in sight.
fn subtract(a: &[TexelSpan], b: &[Range<usize>], out: &mut Vec<TexelSpan>) {
    out.clear();
    let mut j = 0;
    for span in a {
        let mut start = span.texels.start;
        let end = span.texels.end;
        while j < b.len() && b[j].end <= start {
            j += 1;
        }
        let mut k = j;
        while start < end {
            match b.get(k) {
                Some(r) if r.start < end => {
                    if r.start > start {
                        out.push(TexelSpan {
                            texels: start..r.start,
                            in_sight: false,
                        });
                    }
                    start = start.max(r.end);
                    k += 1;
                }
                _ => {
                    out.push(TexelSpan {
                        texels: start..end,
                        in_sight: false,
                    });
                    start = end;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::direct::tests::light;
    use crate::dynamic_shadows::frame_occluders;
    use crate::light_reach::tests::{bundle_with, level, Rng};
    use lightfarm_proto::bundle::Layout;
    use lightfarm_proto::testing::cube;

    /// Every light's direct light with the objects at `poses`, over the whole level (what a
    /// frame relit whole feeds the operators).
    fn whole(
        bundle: &Bundle,
        level: &Occluders,
        lights: &[Light],
        poses: &[Pose],
    ) -> Vec<[f32; 3]> {
        let layout = &bundle.layout;
        let posed = occluders_with_poses(level, bundle, poses);
        let mut reach = ReachDirect::new_posed(bundle, level, posed.as_ref()).unwrap();
        let occluders = frame_occluders(level, posed.as_ref());
        let scale = direct_scale(layout, level);
        reach
            .all_lights(layout, occluders, lights, 4, scale)
            .radiance
    }

    fn in_spans(spans: &[Range<usize>], t: usize) -> bool {
        spans.iter().any(|r| r.contains(&t))
    }

    /// A random point of a random room of `layout`'s level, `margin` m inside it.
    fn somewhere(rng: &mut Rng, bundle: &Bundle, margin: f64) -> [f64; 3] {
        let rooms = &bundle.rooms.as_ref().unwrap().rooms;
        let room = &rooms[(rng.next() * rooms.len() as f64) as usize];
        [0, 1, 2].map(|k| rng.range(room.min[k] + margin, room.max[k] - margin))
    }

    fn crate_at(translation: [f64; 3], rng: &mut Rng) -> Pose {
        let q = [0, 1, 2, 3].map(|_| rng.range(-1.0, 1.0));
        Pose {
            id: "crate".into(),
            translation,
            rotation: q,
        }
    }

    /// An object moving through a generated level (from nothing placed, or from a first pose),
    /// taken away and put back: after every update
    /// the direct light kept by adding the changes is the whole level's direct light with the
    /// objects where they now are (to float rounding), and every texel outside the change's
    /// spans has, bit for bit, the light it had.
    #[test]
    fn the_changes_add_up_to_the_direct_light_at_each_pose_and_miss_no_texel() {
        let mut rng = Rng(0x5eed_5add_0b1e_c701);
        let (mut changed, mut spanned, mut texels) = (0usize, 0usize, 0usize);
        for case in 0..6 {
            let (rooms, layout, _) = level(&mut rng, 5, 4, 3);
            let occluders = Occluders::from_layout(&layout);
            let mut bundle = bundle_with(Some(rooms), layout);
            bundle.dynamic_shapes = vec![cube("crate", 0.3), cube("stool", 0.25)];
            // A second object that stays where it is (from case 2 on): its shadow never moves.
            let stool = (case >= 2).then(|| Pose {
                id: "stool".into(),
                translation: somewhere(&mut rng, &bundle, 0.4),
                rotation: [0.0, 0.0, 0.0, 1.0],
            });
            let lights: Vec<Light> = (0..3)
                .map(|_| light(somewhere(&mut rng, &bundle, 0.05), [1.0, 0.8, 0.6]))
                .collect();
            let n = bundle.layout.n_texels();
            // Starting from the level alone, or (odd cases) with the object placed.
            let mut at = somewhere(&mut rng, &bundle, 0.5);
            let mut start = match case % 2 {
                0 => Vec::new(),
                _ => vec![crate_at(at, &mut rng)],
            };
            start.extend(stool.clone());
            let mut shadows = ShadowChange::new(&bundle, &occluders, &lights, 4, &start);
            let mut kept = whole(&bundle, &occluders, &lights, &start);
            for step in 0..6 {
                // Small moves, a jump, then the object taken away and put back.
                let mut poses = match step {
                    3 => Vec::new(),
                    4 => vec![crate_at(somewhere(&mut rng, &bundle, 0.5), &mut rng)],
                    _ => {
                        at = at.map(|x| x + rng.range(-0.1, 0.1));
                        vec![crate_at(at, &mut rng)]
                    }
                };
                // The stool listed first or last: the objects are matched by pose, not place.
                match (&stool, step % 2) {
                    (Some(s), 0) => poses.insert(0, s.clone()),
                    (Some(s), _) => poses.push(s.clone()),
                    (None, _) => {}
                }
                shadows.update(&bundle, &occluders, &poses).unwrap();
                let want = whole(&bundle, &occluders, &lights, &poses);
                let (change, spans) = (&shadows.change().radiance, shadows.spans());
                assert!(spans.windows(2).all(|w| w[0].end < w[1].start));
                let scale = want.iter().flatten().fold(0.0f32, |m, &v| m.max(v.abs()));
                for t in 0..n {
                    if !in_spans(spans, t) {
                        assert_eq!(change[t], [0.0; 3], "case {case} step {step} texel {t}");
                        assert_eq!(
                            want[t], kept[t],
                            "case {case} step {step}: texel {t} missed"
                        );
                        continue;
                    }
                    spanned += 1;
                    for k in 0..3 {
                        kept[t][k] += change[t][k];
                        let tolerance = 1e-5 * scale.max(1e-30);
                        assert!(
                            (kept[t][k] - want[t][k]).abs() <= tolerance,
                            "case {case} step {step} texel {t}: {:?} vs {:?}",
                            kept[t],
                            want[t]
                        );
                    }
                    changed += usize::from(change[t] != [0.0; 3]);
                    // The kept light is the whole level's from here on (no drift carried).
                    kept[t] = want[t];
                }
                texels += n;
            }
        }
        // The objects do shadow, and the spans are a small part of the level.
        assert!(changed > 100, "{changed} texels changed");
        assert!(
            spanned * 4 < texels,
            "{spanned} of {texels} texel-steps spanned"
        );
    }

    /// `subtract` keeps exactly the texels of `a` outside `b`, as ascending disjoint spans.
    #[test]
    fn subtracting_spans_keeps_the_texels_outside() {
        let mut rng = Rng(0x5b7);
        let mut out = Vec::new();
        for _ in 0..500 {
            let spans = |rng: &mut Rng| {
                let mut v = Vec::new();
                let mut t = 0;
                while t < 60 {
                    t += (rng.next() * 6.0) as usize;
                    let end = t + 1 + (rng.next() * 6.0) as usize;
                    v.push(t..end);
                    t = end + 1;
                }
                v
            };
            let a: Vec<TexelSpan> = (spans(&mut rng).into_iter())
                .map(|texels| TexelSpan {
                    texels,
                    in_sight: false,
                })
                .collect();
            let b = spans(&mut rng);
            subtract(&a, &b, &mut out);
            let want: Vec<usize> = (a.iter().flat_map(|s| s.texels.clone()))
                .filter(|t| !in_spans(&b, *t))
                .collect();
            let got: Vec<usize> = out.iter().flat_map(|s| s.texels.clone()).collect();
            assert_eq!(got, want, "{a:?} minus {b:?}");
            assert!(out.iter().all(|s| !s.texels.is_empty() && !s.in_sight));
        }
    }

    /// Nothing moved, or only objects without a shape: no span and no light relit.
    #[test]
    fn objects_that_stay_change_nothing() {
        let mut rng = Rng(11);
        let (rooms, layout, _) = level(&mut rng, 3, 3, 3);
        let occluders = Occluders::from_layout(&layout);
        let mut bundle = bundle_with(Some(rooms), layout);
        bundle.dynamic_shapes = vec![cube("crate", 0.3)];
        let lights = [light(somewhere(&mut rng, &bundle, 0.1), [1.0; 3])];
        let poses = [crate_at(somewhere(&mut rng, &bundle, 0.5), &mut rng)];
        let mut shadows = ShadowChange::new(&bundle, &occluders, &lights, 4, &poses);
        shadows.update(&bundle, &occluders, &poses).unwrap();
        assert!(shadows.spans().is_empty() && shadows.lights_relit() == 0);
        // The same pose again after a move and back: two changes that cancel.
        let moved = [crate_at(somewhere(&mut rng, &bundle, 0.5), &mut rng)];
        shadows.update(&bundle, &occluders, &moved).unwrap();
        shadows.update(&bundle, &occluders, &moved).unwrap();
        assert!(shadows.spans().is_empty());
    }

    #[test]
    fn a_pose_without_a_shape_changes_nothing_and_another_layout_is_refused() {
        let mut rng = Rng(7);
        let (rooms, layout, _) = level(&mut rng, 3, 3, 2);
        let occluders = Occluders::from_layout(&layout);
        let bundle = bundle_with(Some(rooms), layout);
        let lights = [light(somewhere(&mut rng, &bundle, 0.1), [1.0; 3])];
        let mut shadows = ShadowChange::new(&bundle, &occluders, &lights, 4, &[]);
        let ghost = crate_at(somewhere(&mut rng, &bundle, 0.5), &mut rng);
        shadows.update(&bundle, &occluders, &[ghost]).unwrap();
        assert!(shadows.spans().is_empty());
        let other = Bundle {
            layout: Layout::default(),
            ..bundle.clone()
        };
        assert_eq!(
            shadows.update(&other, &occluders, &[]),
            Err(ShadowChangeError::OtherBundle {
                expected: bundle.layout.n_texels(),
                got: 0
            })
        );
    }
}
