//! One light's direct light on the texels it reaches, shadowed by the occluders its reach can
//! meet: what relighting by the change computes when a light moves, at a cost set by the
//! light's neighbourhood rather than by the level.
//!
//! [`ReachDirect::light`] walks the light's reach ([`LightReach::texels`]) and traces the
//! adaptive texel average's shadow rays ([`direct_from_point_lights_adaptive_in`]) against only
//! the level's occluders that touch a reached room, instead of the whole level's: a
//! [`LightBuffer`] of the light over them, rebuilt per call, which lists per direction from the
//! light the occluders nearest first (it answers what a hierarchy over the same occluders
//! answers).
//!
//! Why that answers exactly what the level's occluders answer, on the reached texels: rooms are
//! closed boxes that meet only through whole open faces, and a walk that runs to its end
//! without leaving the level reaches every room a straight segment from the light can enter
//! ([`crate::light_reach`]'s invariant). A shadow segment from the light to a point of a
//! reached texel therefore stays inside reached rooms' closed boxes up to its first blocker
//! (a wall of the room it is in, or an object in it), and that blocker's bounds meet the room:
//! it is in the subset. The subset is part of the level's occluders and is tested with their
//! margins, so it never reports a hit the level's would not. Where the walk gives up or leaves
//! the level (a `Void` face, a light outside every room) the level's occluders are used whole:
//! a buffer over all of them up to [`WHOLE_LEVEL_MAX_OCCLUDERS`], else their hierarchy.
//!
//! [`ReachDirect::all_lights`] does the same for every light of a level and sums their terms
//! per texel in light order, as the whole-level adaptive average sums them; a light adds
//! nothing where it cannot reach (its direct light there is exactly zero), so relighting
//! everything costs what the lights reach rather than lights × texels.
//!
//! Units: metres, world frame. Invariants: `light` writes `out` on its spans only, bit-identical
//! to [`direct_from_point_lights_adaptive_in`] with the level's occluders on the same spans;
//! `all_lights` is bit-identical to [`direct_from_point_lights_adaptive`].
//!
//! [`direct_from_point_lights_adaptive_in`]: crate::direct_from_point_lights_adaptive_in

use lightfarm_proto::bundle::{Bundle, Layout};

use crate::box_shadows::BoxShadows;
use crate::direct::{
    adaptive_in_with, add_light_term_in, direct_from_point_lights_adaptive,
    direct_from_point_lights_averaged, direct_scale, finish_irradiance, DirectLight, Shadows,
    TexelSpan, ADAPTIVE_MAX_SAMPLES_PER_EDGE,
};
use crate::dynamic_shadows::PosedObjects;
use crate::light_buffer::{LightBuffer, WHOLE_LEVEL_MAX_OCCLUDERS};
use crate::light_reach::LightReach;
use crate::occluders::Occluders;
use lightfarm_proto::lights::Light;

/// Room padding when gathering a room's occluders, relative to the occluders' scale: far above
/// f32 rounding, and harmless when larger (an extra occluder never changes an answer).
const ROOM_PAD_REL: f64 = 1e-4;

/// Builds `buffer` for a light at `at` over the level's occluders its reach can meet: `prims`
/// (the reached rooms', [`ReachDirect::reached_prims`]) or, with `None` (the walk left the
/// level), all of them when there are at most [`WHOLE_LEVEL_MAX_OCCLUDERS`]. False, with
/// `buffer` left as it was, when the level is too large for that: trace its hierarchy.
pub(crate) fn reach_buffer(
    buffer: &mut LightBuffer,
    level: &Occluders,
    at: [f32; 3],
    prims: Option<&[u32]>,
) -> bool {
    if prims.is_none() && level.len() > WHOLE_LEVEL_MAX_OCCLUDERS {
        return false;
    }
    buffer.build(level, at, prims);
    true
}

/// A bundle's light reach with, per room, the level's occluders that touch it.
#[derive(Clone, Debug)]
pub struct ReachDirect {
    reach: LightReach,
    /// Per room: indices (the level occluders' order) of the occluders whose bounds meet the
    /// room's box, padded.
    room_prims: Vec<Vec<u32>>,
    // Scratch, reset per call.
    picked: Vec<bool>,
    list: Vec<u32>,
    buffer: LightBuffer,
    /// The box queries' scratch ([`crate::box_shadows`]), kept so that a call allocates
    /// nothing once it has seen as many occluders.
    boxes: BoxShadows,
    /// Occluders the last call traced against (the level's count when it used them whole).
    last_occluders: usize,
    /// Posed dynamic objects' occluders are in the rooms' lists ([`ReachDirect::with_posed`]).
    posed: bool,
}

/// [`direct_from_point_lights_averaged`] over a whole bundle (every sample traced, `1`: the
/// texel centres), to float rounding: with rooms each light is traced only on the texels it
/// reaches, against the occluders there ([`ReachDirect::all_lights_every_sample`]), so the cost
/// follows what the lights reach rather than lights × texels (a generated 1,000-block level's
/// 164 lights: 137 s over the whole level, under 2 s this way); without rooms, that function.
/// `occluders` are the bundle layout's ([`Occluders::from_layout`]); with posed dynamic objects
/// ([`crate::occluders_with_poses`]) build the reach with [`ReachDirect::new_posed`] and call
/// [`every_sample_by_reach`], so that the rooms they stand in are not taken to be empty. What
/// `lightfarm eval` feeds the operators and reports, and what the C ABI's direct light computes.
pub fn direct_from_point_lights_by_reach(
    bundle: &Bundle,
    occluders: &Occluders,
    lights: &[Light],
    samples_per_edge: u32,
) -> DirectLight {
    let layout = &bundle.layout;
    every_sample_by_reach(
        ReachDirect::new(bundle, occluders).as_mut(),
        layout,
        occluders,
        lights,
        samples_per_edge,
        direct_scale(layout, occluders),
    )
}

/// [`direct_from_point_lights_by_reach`] with the bundle's reach (`None`: it has no rooms) and
/// [`direct_scale`] kept by the caller, which reuses them across calls.
pub fn every_sample_by_reach(
    reach: Option<&mut ReachDirect>,
    layout: &Layout,
    occluders: &Occluders,
    lights: &[Light],
    samples_per_edge: u32,
    scale: f64,
) -> DirectLight {
    match reach {
        Some(r) => r.all_lights_every_sample(layout, occluders, lights, samples_per_edge, scale),
        None => direct_from_point_lights_averaged(layout, occluders, lights, samples_per_edge),
    }
}

impl ReachDirect {
    /// For `bundle` and its layout's occluders `level` (`Occluders::from_layout`); `None` when
    /// the bundle has no rooms (then every texel must be lit against the level's occluders).
    pub fn new(bundle: &Bundle, level: &Occluders) -> Option<ReachDirect> {
        let reach = LightReach::new(bundle)?;
        let pad = ROOM_PAD_REL * level.scale() as f64;
        let room_prims = reach
            .room_boxes()
            .map(|(lo, hi)| {
                let mut ix = Vec::new();
                level.prims_in_box(
                    lo.map(|x| (x - pad) as f32),
                    hi.map(|x| (x + pad) as f32),
                    &mut ix,
                );
                ix
            })
            .collect();
        Some(ReachDirect {
            reach,
            room_prims,
            picked: vec![false; level.len()],
            list: Vec::new(),
            buffer: LightBuffer::new(),
            boxes: BoxShadows::new(),
            last_occluders: 0,
            posed: false,
        })
    }

    /// This reach (made by [`ReachDirect::new`] over the level's occluders) with posed dynamic
    /// objects in (`posed`, from [`crate::occluders_with_poses`] over the same level): each
    /// object's triangles, numbered after the level's occluders, join the lists of the rooms
    /// their bounds meet (padded as [`ReachDirect::new`] pads rooms), and the rooms the
    /// objects' boxes meet are no longer taken to hold nothing but walls
    /// ([`LightReach::occupy`]). The same lists, as sets, and so the same answers as
    /// [`ReachDirect::new_posed`] built from scratch, at a cost set by the objects and a copy
    /// of the rooms' lists rather than a search of the level per room.
    pub fn with_posed(&self, posed: &PosedObjects) -> ReachDirect {
        assert!(!self.posed, "with_posed starts from the level's reach");
        let occluders = &posed.occluders;
        let level = self.picked.len();
        assert!(
            occluders.len() >= level,
            "the posed occluders hold the level's first"
        );
        let mut reach = self.reach.clone();
        let mut room_prims = self.room_prims.clone();
        let pad = ROOM_PAD_REL * occluders.scale() as f64;
        let rooms: Vec<([f64; 3], [f64; 3])> = self
            .reach
            .room_boxes()
            .map(|(lo, hi)| {
                (
                    lo.map(|x| (x - pad) as f32 as f64),
                    hi.map(|x| (x + pad) as f32 as f64),
                )
            })
            .collect();
        let meets = |(a, b): ([f64; 3], [f64; 3]), (lo, hi): ([f64; 3], [f64; 3])| {
            (0..3).all(|k| a[k] <= hi[k] && b[k] >= lo[k])
        };
        // The rooms an object's box meets, then its triangles against those rooms only.
        let mut near = Vec::new();
        for &(lo, hi) in &posed.boxes {
            reach.occupy(lo, hi);
        }
        for (r, room) in rooms.iter().enumerate() {
            if posed.boxes.iter().any(|&b| meets(b, *room)) {
                near.push(r);
            }
        }
        for p in level..occluders.len() {
            let (lo, hi) = occluders.prim_bounds(p);
            let bounds = (lo.map(f64::from), hi.map(f64::from));
            for &r in &near {
                if meets(bounds, rooms[r]) {
                    room_prims[r].push(p as u32);
                }
            }
        }
        ReachDirect {
            reach,
            room_prims,
            picked: vec![false; occluders.len()],
            list: Vec::new(),
            buffer: LightBuffer::new(),
            boxes: BoxShadows::new(),
            last_occluders: 0,
            posed: true,
        }
    }

    /// [`ReachDirect::new`] over the level's occluders `level`, with posed dynamic objects in
    /// when there are some (`posed`, [`crate::dynamic_shadows::PosedObjects`],
    /// [`ReachDirect::with_posed`]): the rooms the objects lie in are no longer taken to hold
    /// nothing but walls ([`LightReach::occupy`]), so their shadows are traced.
    pub fn new_posed(
        bundle: &Bundle,
        level: &Occluders,
        posed: Option<&PosedObjects>,
    ) -> Option<ReachDirect> {
        let reach = ReachDirect::new(bundle, level)?;
        Some(match posed {
            Some(posed) => reach.with_posed(posed),
            None => reach,
        })
    }

    /// Sets `spans` to the texels `light` reaches ([`LightReach::texels`]) and writes its
    /// direct light there into `out` (one entry per layout texel; the adaptive
    /// `samples_per_edge²` texel average, `scale` = [`crate::direct_scale`]), leaving every
    /// other texel of `out` untouched. Bit-identical to
    /// [`crate::direct_from_point_lights_adaptive_in`] with `level` on the same spans.
    #[allow(clippy::too_many_arguments)]
    pub fn light(
        &mut self,
        layout: &Layout,
        level: &Occluders,
        light: &Light,
        samples_per_edge: u32,
        scale: f64,
        spans: &mut Vec<TexelSpan>,
        out: &mut [[f32; 3]],
    ) {
        let mut boxes = std::mem::take(&mut self.boxes);
        let shadows = self.walk(layout, level, light, spans);
        adaptive_in_with(
            layout,
            shadows,
            std::slice::from_ref(light),
            samples_per_edge,
            scale,
            spans,
            &mut boxes,
            out,
        );
        self.boxes = boxes;
    }

    /// Every light's direct light at every texel, bit-identical to
    /// [`direct_from_point_lights_adaptive`] with `level` (`scale` = [`crate::direct_scale`]),
    /// with each light traced only on the texels it reaches and against the occluders there:
    /// the cost follows what the lights reach, not the lights times the level's texels.
    /// Beyond [`ADAPTIVE_MAX_SAMPLES_PER_EDGE`] samples per edge (an average over every light
    /// at once) it is that function.
    pub fn all_lights(
        &mut self,
        layout: &Layout,
        level: &Occluders,
        lights: &[Light],
        samples_per_edge: u32,
        scale: f64,
    ) -> DirectLight {
        if samples_per_edge > ADAPTIVE_MAX_SAMPLES_PER_EDGE {
            return direct_from_point_lights_adaptive(layout, level, lights, samples_per_edge);
        }
        self.each_where_it_reaches(layout, level, lights, samples_per_edge, scale, false)
    }

    /// [`direct_from_point_lights_averaged`] (every sample traced) for every light at every
    /// texel, to float rounding (the lights' terms are summed per texel here, per sample
    /// there), each light traced only where it reaches: the reference the adaptive average is
    /// measured against, at a cost that follows what the lights reach. Beyond
    /// [`ADAPTIVE_MAX_SAMPLES_PER_EDGE`] samples per edge it is that function.
    pub fn all_lights_every_sample(
        &mut self,
        layout: &Layout,
        level: &Occluders,
        lights: &[Light],
        samples_per_edge: u32,
        scale: f64,
    ) -> DirectLight {
        if samples_per_edge > ADAPTIVE_MAX_SAMPLES_PER_EDGE {
            return direct_from_point_lights_averaged(layout, level, lights, samples_per_edge);
        }
        self.each_where_it_reaches(layout, level, lights, samples_per_edge, scale, true)
    }

    /// Every light's terms ([`add_light_term_in`], adaptive or `every_sample`) summed per
    /// texel in light order, each light on the texels it reaches, finished with the albedo.
    fn each_where_it_reaches(
        &mut self,
        layout: &Layout,
        level: &Occluders,
        lights: &[Light],
        samples_per_edge: u32,
        scale: f64,
        every_sample: bool,
    ) -> DirectLight {
        let mut irr = vec![[0.0f64; 3]; layout.n_texels()];
        let mut spans = Vec::new();
        let mut boxes = std::mem::take(&mut self.boxes);
        for light in lights {
            let shadows = self.walk(layout, level, light, &mut spans);
            add_light_term_in(
                layout,
                shadows,
                light,
                samples_per_edge,
                scale,
                &spans,
                every_sample,
                &mut boxes,
                &mut irr,
            );
        }
        self.boxes = boxes;
        finish_irradiance(layout, &irr)
    }

    /// Walks `light`'s reach into `spans`; its shadow queries: the light's buffer over the
    /// occluders of the rooms it reached, or the level's hierarchy when the level must be used
    /// whole (module doc).
    fn walk<'s>(
        &'s mut self,
        layout: &Layout,
        level: &'s Occluders,
        light: &Light,
        spans: &mut Vec<TexelSpan>,
    ) -> Shadows<'s> {
        let light_at = light.position.map(|x| x as f32);
        let mut list = std::mem::take(&mut self.list);
        let in_rooms = self.reached_prims(layout, light.position, spans, &mut list);
        self.list = list;
        let prims = in_rooms.then_some(self.list.as_slice());
        self.last_occluders = prims.map_or(level.len(), <[u32]>::len);
        if reach_buffer(&mut self.buffer, level, light_at, prims) {
            Shadows::Buffers(level, std::slice::from_ref(&self.buffer))
        } else {
            Shadows::Occluders(level)
        }
    }

    /// Walks the reach of a light at `position` into `spans` and lists in `prims` the
    /// occluders of the rooms it reached (each once, in the order met): all its shadow rays
    /// there can meet (module doc). False, with `prims` left as it was, when the walk gave up
    /// or left the level: then every occluder can.
    pub(crate) fn reached_prims(
        &mut self,
        layout: &Layout,
        position: [f64; 3],
        spans: &mut Vec<TexelSpan>,
        prims: &mut Vec<u32>,
    ) -> bool {
        self.reach.texels(layout, position, spans);
        let Some(rooms) = self.reach.rooms_of_last_walk() else {
            return false;
        };
        prims.clear();
        for &r in rooms {
            for &p in &self.room_prims[r as usize] {
                if !std::mem::replace(&mut self.picked[p as usize], true) {
                    prims.push(p);
                }
            }
        }
        for &p in prims.iter() {
            self.picked[p as usize] = false;
        }
        true
    }

    /// Sets `spans` to the texels a light at `position` reaches ([`LightReach::texels`]),
    /// without lighting them: the spans [`ReachDirect::light`] writes for a light there.
    pub fn texels(&mut self, layout: &Layout, position: [f64; 3], spans: &mut Vec<TexelSpan>) {
        self.reach.texels(layout, position, spans);
    }

    /// Rooms the last [`ReachDirect::light`] call reached.
    pub fn rooms_reached(&self) -> usize {
        self.reach.rooms_reached()
    }

    /// Occluders the last [`ReachDirect::light`] call traced its shadow rays against.
    pub fn occluders_traced(&self) -> usize {
        self.last_occluders
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::direct::tests::light;
    use crate::direct::{direct_from_point_lights, direct_from_point_lights_adaptive};
    use crate::light_reach::tests::{bundle_with, level, Rng};
    use lightfarm_proto::bundle::{Rect, Rooms, SurfaceInfo, SurfacePlace};
    use lightfarm_proto::Face;

    /// Adds a box `[lo, hi]` lying in `rooms_in` (clutter): its six faces as object surfaces of
    /// 2 × 2 texels facing out, and as occluders.
    fn add_box(
        rooms: &mut Rooms,
        layout: &mut Layout,
        rooms_in: Vec<u32>,
        lo: [f64; 3],
        hi: [f64; 3],
    ) {
        for face in Face::ALL {
            let a = face.axis();
            let coord = if face.outward_normal()[a] < 0.0 {
                lo[a]
            } else {
                hi[a]
            };
            let (u, v) = face.tangent_axes();
            layout.surfaces.push(SurfaceInfo {
                name: format!("object/{face:?}"),
                texel_offset: layout.positions.len() as u32,
                texel_count: 4,
            });
            rooms.surfaces.push(SurfacePlace::Object {
                rooms: rooms_in.clone(),
                outside: false,
            });
            let size = [(hi[u] - lo[u]) / 2.0, (hi[v] - lo[v]) / 2.0];
            for j in 0..2 {
                for i in 0..2 {
                    let mut p = [0.0; 3];
                    p[a] = coord;
                    p[u] = lo[u] + (i as f64 + 0.5) * size[0];
                    p[v] = lo[v] + (j as f64 + 0.5) * size[1];
                    layout.positions.push(p.map(|x| x as f32));
                    layout.normals.push(face.outward_normal().map(|x| x as f32));
                    layout.albedo.push([0.6, 0.5, 0.4]);
                    layout.texel_size.push(size.map(|x| x as f32));
                }
            }
            layout.rects.push(Rect {
                axis: a as u8,
                coord: coord as f32,
                min: [lo[u] as f32, lo[v] as f32],
                max: [hi[u] as f32, hi[v] as f32],
            });
        }
    }

    /// The adaptive direct light of every texel traced against the level's hierarchy (not the
    /// light buffers every other path here uses).
    fn by_tree(
        layout: &Layout,
        occluders: &Occluders,
        lights: &[Light],
        scale: f64,
    ) -> DirectLight {
        let mut radiance = vec![[0.0f32; 3]; layout.n_texels()];
        let all = [TexelSpan {
            texels: 0..layout.n_texels(),
            in_sight: false,
        }];
        adaptive_in_with(
            layout,
            Shadows::Occluders(occluders),
            lights,
            4,
            scale,
            &all,
            &mut BoxShadows::new(),
            &mut radiance,
        );
        DirectLight { radiance }
    }

    /// Asserts `got` holds `want`'s bits on every texel of `spans`.
    fn same_bits_on(spans: &[TexelSpan], want: &DirectLight, got: &[[f32; 3]], what: &str) {
        for t in spans.iter().flat_map(|s| s.texels.clone()) {
            assert_eq!(
                want.radiance[t].map(f32::to_bits),
                got[t].map(f32::to_bits),
                "{what}: texel {t}"
            );
        }
    }

    /// On random levels with boxes in a third of the rooms (some of them pillars from the
    /// floor nearly to the ceiling, which split a room's view), open ceilings and lights now and then above the
    /// level: one light's direct light traced against the reached rooms' occluders (its light
    /// buffer over them) is bit-identical to the level's hierarchy's on its spans, every light
    /// at once lit light by light where each reaches is bit-identical to lighting every texel
    /// against the hierarchy, and most lights trace against far fewer occluders than the level
    /// holds.
    #[test]
    fn the_reached_rooms_occluders_answer_what_the_levels_answer() {
        let mut rng = Rng(0x0dd_ba11_5eed_0019);
        let (mut cut, mut calls, mut lit) = (0, 0, 0usize);
        for case in 0..24 {
            let (mut rooms, mut layout, _) = level(&mut rng, 5, 4, 3);
            for r in 0..rooms.rooms.len() {
                if rng.next() < 0.35 {
                    let room = rooms.rooms[r].clone();
                    let pillar = rng.next() < 0.5;
                    let mut lo = [0.0; 3];
                    let mut hi = [0.0; 3];
                    for k in 0..3 {
                        let (a, b) = (room.min[k], room.max[k]);
                        let c = rng.range(a + 0.3 * (b - a), a + 0.7 * (b - a));
                        let half = 0.15 * (b - a);
                        lo[k] = c - half;
                        hi[k] = c + half;
                    }
                    if pillar {
                        // Standing on the floor, just short of the ceiling: a top face flush
                        // with a closed ceiling would be lit from above the level through the
                        // ceiling's plane, a degenerate case the reach does not model.
                        lo[1] = room.min[1];
                        hi[1] = room.max[1] - 0.01;
                    }
                    add_box(&mut rooms, &mut layout, vec![r as u32], lo, hi);
                }
            }
            let occluders = Occluders::from_layout(&layout);
            let bundle = bundle_with(Some(rooms.clone()), layout.clone());
            let mut reach = ReachDirect::new(&bundle, &occluders).unwrap();
            let scale = direct_scale(&layout, &occluders);
            let mut lights = Vec::new();
            let mut spans = Vec::new();
            for _ in 0..6 {
                let p = if rng.next() < 0.1 {
                    [rng.range(0.0, 10.0), 2.5, rng.range(0.0, 10.0)]
                } else {
                    let r = &rooms.rooms[(rng.next() * rooms.rooms.len() as f64) as usize];
                    [0, 1, 2].map(|k| rng.range(r.min[k] + 0.05, r.max[k] - 0.05))
                };
                let l = light(p, [rng.range(0.5, 2.0), 1.0, rng.range(0.0, 1.0)]);
                let whole = by_tree(&layout, &occluders, std::slice::from_ref(&l), scale);
                let mut part = vec![[f32::NAN; 3]; layout.n_texels()];
                reach.light(&layout, &occluders, &l, 4, scale, &mut spans, &mut part);
                calls += 1;
                cut += usize::from(reach.occluders_traced() * 2 < occluders.len());
                same_bits_on(
                    &spans,
                    &whole,
                    &part,
                    &format!("case {case}, light at {p:?}"),
                );
                lit += spans
                    .iter()
                    .flat_map(|s| s.texels.clone())
                    .filter(|&t| part[t] != [0.0; 3])
                    .count();
                lights.push(l);
            }
            let whole = by_tree(&layout, &occluders, &lights, scale);
            let by_reach = reach.all_lights(&layout, &occluders, &lights, 4, scale);
            for (t, (w, r)) in whole.radiance.iter().zip(&by_reach.radiance).enumerate() {
                assert_eq!(
                    w.map(f32::to_bits),
                    r.map(f32::to_bits),
                    "case {case}: texel {t}, every light at once against light by light"
                );
            }
            // Every sample traced, light by light where each reaches: the whole-level average
            // to float rounding.
            let every = reach.all_lights_every_sample(&layout, &occluders, &lights, 4, scale);
            let averaged = direct_from_point_lights_averaged(&layout, &occluders, &lights, 4);
            for (t, (e, a)) in every.radiance.iter().zip(&averaged.radiance).enumerate() {
                for c in 0..3 {
                    assert!(
                        (e[c] - a[c]).abs() <= 1e-6 * a[c].abs() + 1e-12,
                        "case {case}: texel {t}, {e:?} against {a:?}"
                    );
                }
            }
            // The same at texel centres (one sample per texel, as `eval` reports direct
            // light).
            let every = reach.all_lights_every_sample(&layout, &occluders, &lights, 1, scale);
            let centres = direct_from_point_lights(&layout, &occluders, &lights);
            for (t, (e, a)) in every.radiance.iter().zip(&centres.radiance).enumerate() {
                for c in 0..3 {
                    assert!(
                        (e[c] - a[c]).abs() <= 1e-6 * a[c].abs() + 1e-12,
                        "case {case}: texel {t} centre, {e:?} against {a:?}"
                    );
                }
            }
            if case == 0 {
                // More samples than the adaptive average holds: the whole-level average.
                let many = reach.all_lights(&layout, &occluders, &lights, 9, scale);
                let whole = direct_from_point_lights_adaptive(&layout, &occluders, &lights, 9);
                assert_eq!(many, whole);
            }
        }
        assert!(lit > 5_000, "{lit} texels lit");
        // Measured: 36 of 144 calls (the walks that stay inside these small, leaky levels).
        assert!(
            cut * 5 > calls,
            "{cut} of {calls} calls cut the occluders to under half"
        );
    }

    /// Posed objects (a random block of triangles in a random room of random levels) through
    /// [`ReachDirect::with_posed`] and the two-level occluders: one light's direct light on its
    /// spans is bit-identical to tracing every texel against one hierarchy over the level and
    /// the objects together, and the spans are those of a reach built from scratch over the
    /// posed occluders.
    #[test]
    fn posed_objects_added_to_the_levels_reach_answer_what_one_hierarchy_answers() {
        let mut rng = Rng(0x5eed_0b1e_c7ed_0020);
        let mut shadowed = 0usize;
        for case in 0..16 {
            let (rooms, layout, _) = level(&mut rng, 5, 4, 3);
            let occluders = Occluders::from_layout(&layout);
            let bundle = bundle_with(Some(rooms.clone()), layout.clone());
            let level_reach = ReachDirect::new(&bundle, &occluders).unwrap();
            // A box of 12 triangles, slanted, inside a random room.
            let room = &rooms.rooms[(rng.next() * rooms.rooms.len() as f64) as usize];
            let c = [0, 1, 2].map(|k| rng.range(room.min[k] + 0.6, room.max[k] - 0.6));
            let h = rng.range(0.1, 0.4);
            let corner = |i: usize| {
                let s = |b: usize| if i >> b & 1 == 0 { -h } else { h };
                [
                    c[0] + s(0) + 0.3 * s(1),
                    c[1] + s(1),
                    c[2] + s(2) - 0.2 * s(0),
                ]
                .map(|x| x as f32)
            };
            let tris = lightfarm_proto::testing::hexahedron(corner);
            let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
            for v in tris.iter().flatten() {
                for k in 0..3 {
                    lo[k] = lo[k].min(v[k] as f64);
                    hi[k] = hi[k].max(v[k] as f64);
                }
            }
            let posed = PosedObjects {
                occluders: occluders.with_triangles(&tris),
                boxes: vec![(lo, hi)],
            };
            assert_eq!(posed.occluders.len(), occluders.len() + tris.len());
            let mut all_triangles = layout.triangles.clone();
            all_triangles.extend_from_slice(&tris);
            let one_tree = Occluders::new(&layout.rects, &all_triangles);
            let mut derived = level_reach.with_posed(&posed);
            let mut scratch = ReachDirect::new(&bundle, &posed.occluders).unwrap();
            for &(lo, hi) in &posed.boxes {
                scratch.reach.occupy(lo, hi);
            }
            let scale = direct_scale(&layout, &occluders);
            let (mut spans, mut expected_spans) = (Vec::new(), Vec::new());
            for _ in 0..4 {
                let p = [0, 1, 2].map(|k| rng.range(room.min[k] + 0.05, room.max[k] - 0.05));
                let l = light(p, [1.0, rng.range(0.5, 2.0), 1.0]);
                let whole = by_tree(&layout, &one_tree, std::slice::from_ref(&l), scale);
                let level_only = by_tree(&layout, &occluders, std::slice::from_ref(&l), scale);
                let mut part = vec![[f32::NAN; 3]; layout.n_texels()];
                derived.light(
                    &layout,
                    &posed.occluders,
                    &l,
                    4,
                    scale,
                    &mut spans,
                    &mut part,
                );
                scratch.texels(&layout, p, &mut expected_spans);
                assert_eq!(spans, expected_spans, "case {case}: the spans from scratch");
                same_bits_on(
                    &spans,
                    &whole,
                    &part,
                    &format!("case {case}, light at {p:?}"),
                );
                shadowed += spans
                    .iter()
                    .flat_map(|s| s.texels.clone())
                    .filter(|&t| whole.radiance[t] != level_only.radiance[t])
                    .count();
            }
        }
        // The objects do shadow: texels whose light they change.
        assert!(shadowed > 100, "{shadowed} texels shadowed by the objects");
    }
}
