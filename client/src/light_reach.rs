//! Which texels a point light can reach, from the bundle's rooms ([`Rooms`], section kind 15):
//! the texels whose direct light a light can change, so that moving one light recomputes its
//! neighbourhood only, whatever the level's size.
//!
//! Geometry: every room (block) is a box whose faces are walls (closed), open onto exactly one
//! neighbour's coincident face, or open out of the level (`Void`). A straight segment from the
//! light to a texel crosses from room to room only through open faces, so a walk from the
//! light's room through open faces finds every room a segment can enter. The walk is a portal
//! walk: a room entered through window `W` (part of an open face) passes light on through
//! another open face `O` only along rays from the light through `W`, so `O`'s window is the
//! box around `O ∩ cone(light, W)` beyond `W` (central projection of `W`'s corners onto `O`'s
//! plane: a convex quad, whose box is conservative). Windows of one room face are merged into
//! their box, and a room is walked again only when a window grew. Light leaving through a
//! `Void` face may come back in through any other `Void` face its cone meets.
//!
//! What the light reaches ([`LightReach::texels`]): in every room reached, the texels of each
//! closed face that overlap the window's cone on that face (the whole face in the light's own
//! room), and every object (clutter) surface listed in a reached room, or outside when the walk
//! left the level (or the light is outside every room).
//!
//! Conservative: every window is padded by `1e-7 ·` the level's diagonal, degenerate
//! projections (the light in a window's plane, a cone reaching to infinity) take the whole
//! face, and a walk that would visit more than [`MAX_VISITS_PER_ROOM`] windows per room gives
//! up and returns every texel. So a texel left out has no straight segment to the light that
//! avoids every wall: its direct light is exactly 0 (walls are opaque from both sides).
//!
//! In sight: when the light is strictly inside exactly one room and nothing but walls lies in
//! that room (no object surface lists it), every segment from the light to a point of the
//! room's walls stays inside the convex room and crosses nothing, so those spans are marked
//! [`TexelSpan::in_sight`] and their direct light needs no shadow ray. Objects the bundle does
//! not list (posed dynamic objects) are made known with [`LightReach::occupy`].
//!
//! Units: metres, world frame, f64 (the rooms' own numbers). Invariant: the spans returned are
//! ascending, disjoint texel ranges of the layout.
//!
//! [`Rooms`]: lightfarm_proto::bundle::Rooms

use std::ops::Range;

use lightfarm_proto::bundle::{Bundle, FaceLink, Layout, Room, SurfacePlace};
use lightfarm_proto::Face;

use crate::direct::TexelSpan;

/// Walk visits allowed per room before the walk gives up (and reaches everything).
pub const MAX_VISITS_PER_ROOM: usize = 16;
/// Window padding, relative to the level's diagonal.
const PAD_REL: f64 = 1e-7;

/// An axis-aligned rectangle in 3D: `lo[axis] == hi[axis]` is its plane.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Window {
    axis: usize,
    lo: [f64; 3],
    hi: [f64; 3],
}

impl Window {
    fn face(room: &Room, face: Face) -> Window {
        let a = face.axis();
        let (mut lo, mut hi) = (room.min, room.max);
        let c = if face.is_max_side() {
            room.max[a]
        } else {
            room.min[a]
        };
        lo[a] = c;
        hi[a] = c;
        Window { axis: a, lo, hi }
    }

    /// `self ∩ other` (same plane), padded by `pad`; None when they do not meet.
    fn clip(mut self, target: &Window, pad: f64) -> Option<Window> {
        for k in 0..3 {
            if k == self.axis {
                continue;
            }
            self.lo[k] = self.lo[k].max(target.lo[k] - pad) - pad;
            self.hi[k] = self.hi[k].min(target.hi[k] + pad) + pad;
            if self.lo[k] > self.hi[k] {
                return None;
            }
        }
        self.lo[self.axis] = target.lo[self.axis];
        self.hi[self.axis] = target.lo[self.axis];
        Some(self)
    }

    /// Grows `self` to hold `other` (same plane); whether it grew by more than `pad`.
    fn merge(&mut self, other: &Window, pad: f64) -> bool {
        let mut grew = false;
        for k in 0..3 {
            if other.lo[k] < self.lo[k] - pad || other.hi[k] > self.hi[k] + pad {
                grew = true;
            }
            self.lo[k] = self.lo[k].min(other.lo[k]);
            self.hi[k] = self.hi[k].max(other.hi[k]);
        }
        grew
    }

    fn overlaps(&self, lo: [f64; 3], hi: [f64; 3]) -> bool {
        (0..3).all(|k| k == self.axis || (lo[k] <= self.hi[k] && hi[k] >= self.lo[k]))
    }
}

/// The part of `target` (a face) that rays from `light` through `window`, beyond it, can
/// reach: the box around the central projection, clipped to `target` (module doc). `None`
/// when no such ray meets `target`.
fn project(light: [f64; 3], window: &Window, target: &Window, pad: f64) -> Option<Window> {
    let (a, b) = (window.axis, target.axis);
    let o = target.lo[b];
    let d_l = o - light[b];
    let mut lo = window.lo;
    let mut hi = window.hi;
    if a == b {
        let denom = window.lo[a] - light[a];
        if denom.abs() <= pad || d_l.abs() <= pad {
            return Some(*target);
        }
        let t = d_l / denom;
        if t < 1.0 - 1e-12 {
            return None;
        }
        for k in 0..3 {
            lo[k] = light[k] + t * (window.lo[k] - light[k]);
            hi[k] = light[k] + t * (window.hi[k] - light[k]);
        }
        return Window { axis: b, lo, hi }.clip(target, pad);
    }
    if d_l.abs() <= pad {
        return Some(*target);
    }
    // Window points q with a ray beyond q reaching the plane: q_b between the light and o.
    let (from, to) = if d_l > 0.0 {
        (lo[b].max(light[b]), hi[b].min(o + pad))
    } else {
        (lo[b].max(o - pad), hi[b].min(light[b]))
    };
    if from > to {
        return None;
    }
    if (from - light[b]).abs() <= pad || (to - light[b]).abs() <= pad {
        // The cone reaches to infinity along the target plane.
        return Some(*target);
    }
    lo[b] = from;
    hi[b] = to;
    let c = 3 - a - b;
    let mut out = Window {
        axis: b,
        lo: [f64::INFINITY; 3],
        hi: [f64::NEG_INFINITY; 3],
    };
    for qb in [from, to] {
        for qc in [lo[c], hi[c]] {
            let mut q = [0.0; 3];
            q[a] = window.lo[a];
            q[b] = qb;
            q[c] = qc;
            let t = d_l / (qb - light[b]);
            for k in 0..3 {
                let p = if k == b {
                    o
                } else {
                    light[k] + t * (q[k] - light[k])
                };
                out.lo[k] = out.lo[k].min(p);
                out.hi[k] = out.hi[k].max(p);
            }
        }
    }
    out.clip(target, pad)
}

/// How the walk entered a room.
#[derive(Clone, Copy, Debug)]
enum Entry {
    /// The light is inside: every point of the room is in sight (a box is convex).
    Inside,
    /// Through the window on face `face` (merged over arrivals).
    Through(usize),
}

/// A point light's reach over a bundle's rooms (module doc). Built once per bundle; each
/// [`LightReach::texels`] call reuses its scratch.
#[derive(Clone, Debug)]
pub struct LightReach {
    rooms: Vec<Room>,
    /// Per room: the surfaces lying in it (closed faces and objects), ascending.
    room_surfaces: Vec<Vec<u32>>,
    /// Per surface: the room face it is, if it is one.
    surface_face: Vec<Option<(u32, u8)>>,
    /// Object surfaces that may lie outside every room.
    outside_surfaces: Vec<u32>,
    /// Per room: some object surface lies (partly) in it.
    room_has_objects: Vec<bool>,
    /// Every `Void` face (room, face).
    void_faces: Vec<(u32, u8)>,
    pad: f64,
    // Scratch, reset per call.
    inside: Vec<bool>,
    windows: Vec<[Option<Window>; 6]>,
    visits: Vec<usize>,
    touched: Vec<u32>,
    stack: Vec<(u32, Entry)>,
    surface_seen: Vec<bool>,
    surfaces: Vec<u32>,
    /// The last walk left the level (or started outside it).
    left_level: bool,
    /// The last walk ran to its end (it did not give up).
    complete: bool,
}

impl LightReach {
    /// The reach over `bundle`'s rooms; `None` when the bundle has no rooms section (format
    /// before 2.1): then every texel must be lit.
    pub fn new(bundle: &Bundle) -> Option<LightReach> {
        let rooms = bundle.rooms.as_ref()?;
        let n = rooms.rooms.len();
        let mut room_surfaces = vec![Vec::new(); n];
        let mut surface_face = vec![None; rooms.surfaces.len()];
        let mut outside_surfaces = Vec::new();
        let mut room_has_objects = vec![false; n];
        for (s, place) in rooms.surfaces.iter().enumerate() {
            match place {
                SurfacePlace::Face { room, face } => {
                    room_surfaces[*room as usize].push(s as u32);
                    surface_face[s] = Some((*room, *face));
                }
                SurfacePlace::Object { rooms, outside } => {
                    for r in rooms {
                        room_surfaces[*r as usize].push(s as u32);
                        room_has_objects[*r as usize] = true;
                    }
                    if *outside {
                        outside_surfaces.push(s as u32);
                    }
                }
            }
        }
        let void_faces = rooms
            .rooms
            .iter()
            .enumerate()
            .flat_map(|(k, r)| {
                (0..6)
                    .filter(|&f| r.faces[f] == FaceLink::Void)
                    .map(move |f| (k as u32, f as u8))
            })
            .collect();
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for r in &rooms.rooms {
            for k in 0..3 {
                lo[k] = lo[k].min(r.min[k]);
                hi[k] = hi[k].max(r.max[k]);
            }
        }
        let diag = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
        let pad = PAD_REL
            * if diag.is_finite() && diag > 0.0 {
                diag
            } else {
                1.0
            };
        Some(LightReach {
            rooms: rooms.rooms.clone(),
            room_surfaces,
            surface_face,
            outside_surfaces,
            room_has_objects,
            void_faces,
            pad,
            inside: vec![false; n],
            windows: vec![[None; 6]; n],
            visits: vec![0; n],
            touched: Vec::new(),
            stack: Vec::new(),
            surface_seen: vec![false; rooms.surfaces.len()],
            surfaces: Vec::new(),
            left_level: false,
            complete: false,
        })
    }

    /// Rooms the last [`LightReach::texels`] call reached.
    pub fn rooms_reached(&self) -> usize {
        self.touched.len()
    }

    /// The rooms (indices into the bundle's rooms) the last [`LightReach::texels`] call's walk
    /// reached, when that walk ran to its end without leaving the level: then a segment from
    /// the light to any point of a reached texel stays inside these rooms' closed boxes up to
    /// its first wall or object. `None` when the walk gave up, left the level or started
    /// outside it (segments may then pass anywhere).
    pub fn rooms_of_last_walk(&self) -> Option<&[u32]> {
        (self.complete && !self.left_level).then_some(&self.touched[..])
    }

    /// Marks every room whose closed box, padded, meets the box `[lo, hi]` as holding an
    /// object (a posed dynamic object the bundle's rooms do not list), so that no span in it is
    /// [`TexelSpan::in_sight`]. Lasts until the reach is built again.
    pub fn occupy(&mut self, lo: [f64; 3], hi: [f64; 3]) {
        let pad = self.pad;
        for (r, has) in self.rooms.iter().zip(&mut self.room_has_objects) {
            if (0..3).all(|a| lo[a] <= r.max[a] + pad && hi[a] >= r.min[a] - pad) {
                *has = true;
            }
        }
    }

    /// The bundle's rooms, as boxes `(min, max)` in metres.
    pub fn room_boxes(&self) -> impl Iterator<Item = ([f64; 3], [f64; 3])> + '_ {
        self.rooms.iter().map(|r| (r.min, r.max))
    }

    /// Sets `out` to the texel spans of `layout` (the bundle's) the light at `light` can reach
    /// (module doc): ascending, disjoint ranges, those the light surely sees `in_sight`.
    pub fn texels(&mut self, layout: &Layout, light: [f64; 3], out: &mut Vec<TexelSpan>) {
        out.clear();
        for &r in &self.touched {
            self.inside[r as usize] = false;
            self.windows[r as usize] = [None; 6];
            self.visits[r as usize] = 0;
        }
        self.touched.clear();
        self.stack.clear();
        let finite = light.iter().all(|x| x.is_finite());
        let complete = finite && self.walk(light);
        self.complete = complete;
        if !complete {
            push_span(out, 0..layout.n_texels(), false);
            return;
        }
        // The one room holding the light strictly inside, when it holds nothing but walls (the
        // walk pushes the rooms holding the light first).
        let holding = self
            .touched
            .iter()
            .take_while(|&&r| self.inside[r as usize])
            .count();
        let clear_room = self.touched.first().copied().filter(|&r| {
            let room = &self.rooms[r as usize];
            holding == 1
                && !self.room_has_objects[r as usize]
                && (0..3).all(|a| light[a] > room.min[a] && light[a] < room.max[a])
        });
        // Surfaces in reached rooms (and outside ones when the walk left the level).
        self.surfaces.clear();
        for i in 0..self.touched.len() {
            let r = self.touched[i] as usize;
            for j in 0..self.room_surfaces[r].len() {
                let s = self.room_surfaces[r][j];
                if !self.surface_seen[s as usize] {
                    self.surface_seen[s as usize] = true;
                    self.surfaces.push(s);
                }
            }
        }
        if self.left_level {
            for &s in &self.outside_surfaces {
                if !self.surface_seen[s as usize] {
                    self.surface_seen[s as usize] = true;
                    self.surfaces.push(s);
                }
            }
        }
        self.surfaces.sort_unstable();
        for &s in &self.surfaces {
            self.surface_seen[s as usize] = false;
            let info = &layout.surfaces[s as usize];
            let start = info.texel_offset as usize;
            let range = start..start + info.texel_count as usize;
            match self.surface_face[s as usize] {
                Some((room, face)) if !self.inside[room as usize] => {
                    self.face_texels(layout, light, room as usize, face as usize, range, out)
                }
                Some((room, _)) => push_span(out, range, clear_room == Some(room)),
                None => push_span(out, range, false),
            }
        }
    }

    /// The portal walk from the light (module doc): fills `inside`, `windows` and `touched`;
    /// false when it gave up (a room visited more than [`MAX_VISITS_PER_ROOM`] times).
    fn walk(&mut self, light: [f64; 3]) -> bool {
        self.left_level = false;
        let pad = self.pad;
        for (k, r) in self.rooms.iter().enumerate() {
            if (0..3).all(|a| light[a] >= r.min[a] - pad && light[a] <= r.max[a] + pad) {
                self.inside[k] = true;
                self.touched.push(k as u32);
                self.stack.push((k as u32, Entry::Inside));
            }
        }
        if self.touched.is_empty() {
            // Outside every room: light may come in through every Void face.
            self.left_level = true;
            for i in 0..self.void_faces.len() {
                let (room, face) = self.void_faces[i];
                let w = Window::face(&self.rooms[room as usize], Face::ALL[face as usize]);
                if !self.arrive(room, face as usize, w) {
                    return false;
                }
            }
        }
        while let Some((room, entry)) = self.stack.pop() {
            let r = self.rooms[room as usize];
            let window = match entry {
                Entry::Inside => None,
                Entry::Through(f) => self.windows[room as usize][f],
            };
            for f in 0..6 {
                if matches!(entry, Entry::Through(e) if e == f) || r.faces[f] == FaceLink::Closed {
                    continue;
                }
                let target = Window::face(&r, Face::ALL[f]);
                let passed = match &window {
                    None => Some(target),
                    Some(w) => project(light, w, &target, pad),
                };
                let Some(passed) = passed else {
                    continue;
                };
                match r.faces[f] {
                    FaceLink::Neighbour(j) => {
                        if !self.arrive(j, f ^ 1, passed) {
                            return false;
                        }
                    }
                    FaceLink::Void => {
                        self.left_level = true;
                        for i in 0..self.void_faces.len() {
                            let (k, g) = self.void_faces[i];
                            if (k, g as usize) == (room, f) {
                                continue;
                            }
                            let t = Window::face(&self.rooms[k as usize], Face::ALL[g as usize]);
                            if let Some(w) = project(light, &passed, &t, pad) {
                                if !self.arrive(k, g as usize, w) {
                                    return false;
                                }
                            }
                        }
                    }
                    FaceLink::Closed => {}
                }
            }
        }
        true
    }

    /// Light arrives in `room` through window `w` on its face `face`: merged into that face's
    /// window, and the room is walked again when the window grew. False when the room was
    /// walked too often.
    fn arrive(&mut self, room: u32, face: usize, w: Window) -> bool {
        let r = room as usize;
        if self.inside[r] {
            return true;
        }
        if self.windows[r].iter().all(Option::is_none) {
            self.touched.push(room);
        }
        let grew = match &mut self.windows[r][face] {
            Some(old) => old.merge(&w, self.pad),
            slot @ None => {
                *slot = Some(w);
                true
            }
        };
        if grew {
            self.visits[r] += 1;
            if self.visits[r] > MAX_VISITS_PER_ROOM {
                return false;
            }
            self.stack.push((room, Entry::Through(face)));
        }
        true
    }

    /// The texels of closed face `face` of `room` (entered through windows) that overlap what
    /// the windows' cones reach on the face.
    fn face_texels(
        &self,
        layout: &Layout,
        light: [f64; 3],
        room: usize,
        face: usize,
        range: Range<usize>,
        out: &mut Vec<TexelSpan>,
    ) {
        let target = Window::face(&self.rooms[room], Face::ALL[face]);
        let mut clip: Option<Window> = None;
        for w in self.windows[room].iter().flatten() {
            if let Some(p) = project(light, w, &target, self.pad) {
                match &mut clip {
                    Some(c) => {
                        c.merge(&p, 0.0);
                    }
                    None => clip = Some(p),
                }
            }
        }
        let Some(clip) = clip else {
            return;
        };
        let (u, v) = Face::ALL[face].tangent_axes();
        let mut run: Option<usize> = None;
        for t in range.clone() {
            let p = layout.positions[t].map(f64::from);
            let size = layout.texel_size[t];
            let (mut lo, mut hi) = (p, p);
            for (k, s) in [(u, size[0]), (v, size[1])] {
                lo[k] -= 0.5 * s as f64;
                hi[k] += 0.5 * s as f64;
            }
            let lit = clip.overlaps(lo, hi);
            match (lit, run) {
                (true, None) => run = Some(t),
                (false, Some(s)) => {
                    push_span(out, s..t, false);
                    run = None;
                }
                _ => {}
            }
        }
        if let Some(s) = run {
            push_span(out, s..range.end, false);
        }
    }
}

/// Appends `r` to ascending spans, merging with the last when they touch and agree on
/// `in_sight`.
fn push_span(out: &mut Vec<TexelSpan>, r: Range<usize>, in_sight: bool) {
    if r.is_empty() {
        return;
    }
    match out.last_mut() {
        Some(last) if last.texels.end == r.start && last.in_sight == in_sight => {
            last.texels.end = r.end
        }
        _ => out.push(TexelSpan {
            texels: r,
            in_sight,
        }),
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::occluders::Occluders;
    use lightfarm_proto::bundle::{Rect, Rooms, SurfaceInfo};
    use lightfarm_proto::face::tangent_axes;

    /// xorshift64*: a seeded stream for the tests.
    pub(crate) struct Rng(pub(crate) u64);
    impl Rng {
        pub(crate) fn next(&mut self) -> f64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) as f64 / (1u64 << 53) as f64
        }
        pub(crate) fn range(&mut self, lo: f64, hi: f64) -> f64 {
            lo + (hi - lo) * self.next()
        }
    }

    /// Every point a ray from the light through the window (beyond it) puts on the target face
    /// lies in what `project` returns, over random lights, windows and faces; and `project`
    /// rules something out often enough to matter.
    #[test]
    fn projection_holds_every_ray_through_the_window() {
        let mut rng = Rng(0x5eed_1234_abcd_0001);
        let (mut ruled_out, mut hits) = (0, 0);
        for _ in 0..4000 {
            let light = [0, 1, 2].map(|_| rng.range(-1.0, 1.0));
            let face = |rng: &mut Rng| {
                let axis = (rng.next() * 3.0) as usize % 3;
                let c = rng.range(-2.0, 2.0);
                let mut lo = [0.0; 3];
                let mut hi = [0.0; 3];
                for k in 0..3 {
                    if k == axis {
                        lo[k] = c;
                        hi[k] = c;
                    } else {
                        let (a, b) = (rng.range(-2.0, 2.0), rng.range(-2.0, 2.0));
                        lo[k] = a.min(b);
                        hi[k] = a.max(b);
                    }
                }
                Window { axis, lo, hi }
            };
            let (window, target) = (face(&mut rng), face(&mut rng));
            let got = project(light, &window, &target, 1e-9);
            if got.is_none() {
                ruled_out += 1;
            }
            for _ in 0..300 {
                let mut q = window.lo;
                for k in 0..3 {
                    q[k] = rng.range(window.lo[k], window.hi[k]);
                }
                let b = target.axis;
                let denom = q[b] - light[b];
                if denom == 0.0 {
                    continue;
                }
                let t = (target.lo[b] - light[b]) / denom;
                if !(t >= 1.0) {
                    continue;
                }
                let p: [f64; 3] = [0, 1, 2].map(|k| light[k] + t * (q[k] - light[k]));
                let on_target =
                    (0..3).all(|k| k == b || (p[k] >= target.lo[k] && p[k] <= target.hi[k]));
                if !on_target {
                    continue;
                }
                hits += 1;
                let w = got.unwrap_or_else(|| {
                    panic!("ruled out, yet {p:?} from {light:?} through {window:?} hits {target:?}")
                });
                assert!(
                    (0..3).all(|k| k == b || (p[k] >= w.lo[k] - 1e-9 && p[k] <= w.hi[k] + 1e-9)),
                    "{p:?} outside {w:?} (light {light:?}, window {window:?}, target {target:?})"
                );
            }
        }
        assert!(
            ruled_out > 500 && hits > 10_000,
            "{ruled_out} ruled out, {hits} hits"
        );
    }

    /// A level of `nx × nz` cells (random widths, so faces coincide), random openings between
    /// cells and to the outside, `t × t` texels on every closed face, occluders the closed faces.
    pub(crate) fn level(
        rng: &mut Rng,
        nx: usize,
        nz: usize,
        t: usize,
    ) -> (Rooms, Layout, Occluders) {
        let mut xs = vec![0.0];
        let mut zs = vec![0.0];
        for _ in 0..nx {
            xs.push(xs.last().unwrap() + rng.range(1.0, 3.0));
        }
        for _ in 0..nz {
            zs.push(zs.last().unwrap() + rng.range(1.0, 3.0));
        }
        let h = 2.0;
        let index = |i: usize, k: usize| (k * nx + i) as u32;
        let mut rooms: Vec<Room> = Vec::new();
        for k in 0..nz {
            for i in 0..nx {
                rooms.push(Room {
                    min: [xs[i], 0.0, zs[k]],
                    max: [xs[i + 1], h, zs[k + 1]],
                    faces: [FaceLink::Closed; 6],
                });
            }
        }
        for k in 0..nz {
            for i in 0..nx {
                let a = index(i, k) as usize;
                if i + 1 < nx && rng.next() < 0.5 {
                    let b = index(i + 1, k);
                    rooms[a].faces[1] = FaceLink::Neighbour(b);
                    rooms[b as usize].faces[0] = FaceLink::Neighbour(a as u32);
                }
                if k + 1 < nz && rng.next() < 0.5 {
                    let b = index(i, k + 1);
                    rooms[a].faces[5] = FaceLink::Neighbour(b);
                    rooms[b as usize].faces[4] = FaceLink::Neighbour(a as u32);
                }
                // Some ceilings and outer walls open to the outside.
                if rng.next() < 0.15 {
                    rooms[a].faces[3] = FaceLink::Void;
                }
                if i == 0 && rng.next() < 0.3 {
                    rooms[a].faces[0] = FaceLink::Void;
                }
            }
        }
        let mut layout = Layout::default();
        let mut places = Vec::new();
        for (r, room) in rooms.iter().enumerate() {
            for (f, face) in Face::ALL.into_iter().enumerate() {
                if room.faces[f] != FaceLink::Closed {
                    continue;
                }
                let w = Window::face(room, face);
                let (u, v) = face.tangent_axes();
                layout.surfaces.push(SurfaceInfo {
                    name: format!("block:{r}/{f}"),
                    texel_offset: layout.positions.len() as u32,
                    texel_count: (t * t) as u32,
                });
                places.push(SurfacePlace::Face {
                    room: r as u32,
                    face: f as u8,
                });
                let size = [
                    (w.hi[u] - w.lo[u]) / t as f64,
                    (w.hi[v] - w.lo[v]) / t as f64,
                ];
                for j in 0..t {
                    for i in 0..t {
                        let mut p = w.lo;
                        p[u] += (i as f64 + 0.5) * size[0];
                        p[v] += (j as f64 + 0.5) * size[1];
                        let n = face.outward_normal().map(|x| -x as f32);
                        layout.positions.push(p.map(|x| x as f32));
                        layout.normals.push(n);
                        layout.albedo.push([0.5; 3]);
                        layout.texel_size.push(size.map(|x| x as f32));
                    }
                }
                layout.rects.push(Rect {
                    axis: w.axis as u8,
                    coord: w.lo[w.axis] as f32,
                    min: [w.lo[u] as f32, w.lo[v] as f32],
                    max: [w.hi[u] as f32, w.hi[v] as f32],
                });
            }
        }
        let rooms = Rooms {
            rooms,
            surfaces: places,
        };
        rooms
            .check(rooms.rooms.len(), layout.surfaces.len())
            .unwrap();
        let occluders = Occluders::from_layout(&layout);
        (rooms, layout, occluders)
    }

    pub(crate) fn bundle_with(rooms: Option<Rooms>, layout: Layout) -> Bundle {
        Bundle {
            layout,
            rooms,
            ..Bundle::default()
        }
    }

    /// On random levels, every texel the walk leaves out is dark: no sample of a 5 × 5 grid
    /// over it has an unoccluded segment to the light on its lit side. And the walk leaves out
    /// most of a level.
    #[test]
    fn texels_out_of_reach_see_no_light() {
        let mut rng = Rng(0xfeed_beef_0042_0007);
        let (mut left_out, mut total, mut in_sight) = (0usize, 0usize, 0usize);
        for case in 0..60 {
            let (rooms, layout, occluders) = level(&mut rng, 5, 4, 3);
            let bundle = bundle_with(Some(rooms.clone()), layout.clone());
            let mut reach = LightReach::new(&bundle).unwrap();
            let mut spans = Vec::new();
            for _ in 0..8 {
                // Inside a random room, away from its walls; now and then above the level.
                let light = if rng.next() < 0.1 {
                    [rng.range(0.0, 10.0), 2.5, rng.range(0.0, 10.0)]
                } else {
                    let r = &rooms.rooms[(rng.next() * rooms.rooms.len() as f64) as usize];
                    [0, 1, 2].map(|k| rng.range(r.min[k] + 0.05, r.max[k] - 0.05))
                };
                reach.texels(&layout, light, &mut spans);
                assert!(spans
                    .windows(2)
                    .all(|w| w[0].texels.end <= w[1].texels.start));
                let mut inside = vec![false; layout.n_texels()];
                let lp = light.map(|x| x as f32);
                for s in &spans {
                    inside[s.texels.clone()].fill(true);
                    // In sight: no sample of the span's texels has anything in the way.
                    for t in s.texels.clone().filter(|_| s.in_sight) {
                        in_sight += 1;
                        assert!(
                            !occluders.occluded(layout.positions[t], lp),
                            "case {case}: texel {t} marked in sight of {light:?} is occluded"
                        );
                    }
                }
                for t in 0..layout.n_texels() {
                    total += 1;
                    if inside[t] {
                        continue;
                    }
                    left_out += 1;
                    let (p, n, size) =
                        (layout.positions[t], layout.normals[t], layout.texel_size[t]);
                    let axis = (0..3).find(|&k| n[k] != 0.0).unwrap();
                    let (u, v) = tangent_axes(axis);
                    for j in 0..5 {
                        for i in 0..5 {
                            let mut q = p;
                            q[u] += ((i as f32 + 0.5) / 5.0 - 0.5) * size[0];
                            q[v] += ((j as f32 + 0.5) / 5.0 - 0.5) * size[1];
                            let facing = (0..3).map(|k| n[k] * (lp[k] - q[k])).sum::<f32>() > 0.0;
                            assert!(
                                !facing || occluders.occluded(q, lp),
                                "case {case}: texel {t} at {q:?} sees the light at {light:?} \
                                 but is out of reach"
                            );
                        }
                    }
                }
            }
        }
        assert!(
            left_out * 2 > total && in_sight > 1000,
            "only {left_out} of {total} texels left out, {in_sight} in sight"
        );
    }

    /// Without a rooms section there is no reach (every texel must be lit).
    #[test]
    fn a_bundle_without_rooms_has_no_reach() {
        assert!(LightReach::new(&bundle_with(None, Layout::default())).is_none());
    }
}
