//! The level's rooms (section kind 15, format 2.1): each block's box and where each of its faces
//! leads, and the blocks each layout surface lies in. This is what a client needs to tell, from
//! a light's position alone, which texels the light can reach (the portal walk in
//! `lightfarm_client::light_reach`), so that moving one light recomputes the direct light of its
//! neighbourhood only.
//!
//! Frames and units: world space, metres, f64 (the scene's own coordinates, so the walk decides
//! on the same numbers the bake does). Faces are indexed `-x +x -y +y -z +z` ([`Face::ALL`]).
//!
//! Invariants (checked by [`Rooms::check`], which `Bundle::validate` runs):
//! - one room per bundle block, in bundle order, with finite `min < max`;
//! - a face's [`FaceLink::Neighbour`] names another room, whose opposite face leads back;
//! - one [`SurfacePlace`] per layout surface, in layout order: a block face names a room and a
//!   closed face of it; an object lists rooms in strictly ascending order.

use crate::wire::{Reader, Writer};
use crate::Face;

use super::BundleError;

/// Where a face of a room leads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FaceLink {
    /// A wall: light stops here (from either side).
    Closed,
    /// Open onto the coincident open face of another room (index into [`Rooms::rooms`]).
    Neighbour(u32),
    /// Open out of the level: light leaves (and may come back in through another `Void` face).
    Void,
}

/// One block's box and its faces.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Room {
    pub min: [f64; 3],
    pub max: [f64; 3],
    /// In [`Face::ALL`] order.
    pub faces: [FaceLink; 6],
}

/// Where the texels of one layout surface lie.
#[derive(Clone, Debug, PartialEq)]
pub enum SurfacePlace {
    /// A closed face of a room (a block wall's lit side, inside the room).
    Face { room: u32, face: u8 },
    /// An object (clutter box or mesh): the rooms its bounds overlap, ascending, and whether
    /// some of it may lie outside every room (its bounds are not inside one room).
    Object { rooms: Vec<u32>, outside: bool },
}

/// The level's rooms (module doc).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Rooms {
    pub rooms: Vec<Room>,
    /// One per layout surface, in layout order.
    pub surfaces: Vec<SurfacePlace>,
}

const CLOSED: u32 = u32::MAX;
const VOID: u32 = u32::MAX - 1;

impl Rooms {
    pub(super) fn write(&self, w: &mut Writer) {
        w.u32(self.rooms.len() as u32);
        for r in &self.rooms {
            for x in r.min.iter().chain(&r.max) {
                w.f64(*x);
            }
            for link in r.faces {
                w.u32(match link {
                    FaceLink::Closed => CLOSED,
                    FaceLink::Void => VOID,
                    FaceLink::Neighbour(k) => k,
                });
            }
        }
        w.u32(self.surfaces.len() as u32);
        for s in &self.surfaces {
            match s {
                SurfacePlace::Face { room, face } => {
                    w.u8(0);
                    w.u32(*room);
                    w.u8(*face);
                }
                SurfacePlace::Object { rooms, outside } => {
                    w.u8(1);
                    w.u8(u8::from(*outside));
                    w.u32s(rooms);
                }
            }
        }
    }

    pub(super) fn read(r: &mut Reader) -> Result<Rooms, BundleError> {
        let n = r.u32()? as usize;
        // 48 bytes of box and 24 of links per room.
        let mut rooms = Vec::with_capacity(n.min(r.remaining() / 72));
        for _ in 0..n {
            let mut v = [0.0; 6];
            for x in &mut v {
                *x = r.f64()?;
            }
            let mut faces = [FaceLink::Closed; 6];
            for f in &mut faces {
                *f = match r.u32()? {
                    CLOSED => FaceLink::Closed,
                    VOID => FaceLink::Void,
                    k => FaceLink::Neighbour(k),
                };
            }
            rooms.push(Room {
                min: [v[0], v[1], v[2]],
                max: [v[3], v[4], v[5]],
                faces,
            });
        }
        let n = r.u32()? as usize;
        let mut surfaces = Vec::with_capacity(n.min(r.remaining() / 6));
        for k in 0..n {
            surfaces.push(match r.u8()? {
                0 => SurfacePlace::Face {
                    room: r.u32()?,
                    face: r.u8()?,
                },
                1 => {
                    let outside = match r.u8()? {
                        0 => false,
                        1 => true,
                        o => {
                            return Err(BundleError::Invalid(format!(
                                "rooms: surface {k} has outside flag {o}"
                            )))
                        }
                    };
                    SurfacePlace::Object {
                        outside,
                        rooms: r.u32s()?,
                    }
                }
                t => {
                    return Err(BundleError::Invalid(format!(
                        "rooms: surface {k} has place tag {t}"
                    )))
                }
            });
        }
        Ok(Rooms { rooms, surfaces })
    }

    /// The invariants of the module doc, for `blocks` bundle blocks and `surfaces` layout
    /// surfaces.
    pub fn check(&self, blocks: usize, surfaces: usize) -> Result<(), String> {
        if self.rooms.len() != blocks {
            return Err(format!(
                "rooms: {} rooms for {blocks} blocks",
                self.rooms.len()
            ));
        }
        let n = self.rooms.len() as u32;
        for (k, r) in self.rooms.iter().enumerate() {
            if (0..3)
                .any(|a| !(r.min[a].is_finite() && r.max[a].is_finite() && r.min[a] < r.max[a]))
            {
                return Err(format!("rooms: room {k} has an empty or non-finite box"));
            }
            for (f, link) in r.faces.iter().enumerate() {
                if let FaceLink::Neighbour(j) = *link {
                    let back = Face::ALL[f].opposite().index();
                    if j >= n || j as usize == k {
                        return Err(format!("rooms: room {k} face {f} leads to room {j}"));
                    }
                    if self.rooms[j as usize].faces[back] != FaceLink::Neighbour(k as u32) {
                        return Err(format!(
                            "rooms: room {k} face {f} leads to room {j}, which does not lead back"
                        ));
                    }
                }
            }
        }
        if self.surfaces.len() != surfaces {
            return Err(format!(
                "rooms: {} surface places for {surfaces} layout surfaces",
                self.surfaces.len()
            ));
        }
        for (k, s) in self.surfaces.iter().enumerate() {
            match s {
                SurfacePlace::Face { room, face } => {
                    let closed = self
                        .rooms
                        .get(*room as usize)
                        .and_then(|r| r.faces.get(*face as usize))
                        .is_some_and(|l| *l == FaceLink::Closed);
                    if !closed {
                        return Err(format!(
                            "rooms: surface {k} is face {face} of room {room}, not a closed face"
                        ));
                    }
                }
                SurfacePlace::Object { rooms, .. } => {
                    if rooms.iter().any(|&r| r >= n) || rooms.windows(2).any(|w| w[0] >= w[1]) {
                        return Err(format!(
                            "rooms: surface {k} lists rooms out of range or not ascending"
                        ));
                    }
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_rooms() -> Rooms {
        let mut a = Room {
            min: [0.0; 3],
            max: [1.0; 3],
            faces: [FaceLink::Closed; 6],
        };
        let mut b = Room {
            min: [1.0, 0.0, 0.0],
            max: [2.0, 1.0, 1.0],
            faces: [FaceLink::Closed; 6],
        };
        a.faces[1] = FaceLink::Neighbour(1);
        b.faces[0] = FaceLink::Neighbour(0);
        b.faces[3] = FaceLink::Void;
        Rooms {
            rooms: vec![a, b],
            surfaces: vec![
                SurfacePlace::Face { room: 0, face: 2 },
                SurfacePlace::Object {
                    rooms: vec![0, 1],
                    outside: true,
                },
            ],
        }
    }

    #[test]
    fn rooms_round_trip_and_check() {
        let rooms = two_rooms();
        rooms.check(2, 2).unwrap();
        let mut w = Writer::new();
        rooms.write(&mut w);
        let mut r = Reader::new(&w.bytes);
        assert_eq!(Rooms::read(&mut r).unwrap(), rooms);
        assert_eq!(r.remaining(), 0);
    }

    #[test]
    fn inconsistent_rooms_are_refused_with_the_room_named() {
        let mut one_way = two_rooms();
        one_way.rooms[1].faces[0] = FaceLink::Closed;
        let e = one_way.check(2, 2).unwrap_err();
        assert!(
            e.contains("room 0 face 1") && e.contains("lead back"),
            "{e}"
        );
        let mut open_wall = two_rooms();
        open_wall.surfaces[0] = SurfacePlace::Face { room: 1, face: 3 };
        assert!(open_wall.check(2, 2).unwrap_err().contains("surface 0"));
        let mut unsorted = two_rooms();
        unsorted.surfaces[1] = SurfacePlace::Object {
            rooms: vec![1, 0],
            outside: false,
        };
        assert!(unsorted.check(2, 2).unwrap_err().contains("surface 1"));
        assert!(two_rooms().check(3, 2).unwrap_err().contains("3 blocks"));
        let mut flat = two_rooms();
        flat.rooms[0].max[2] = 0.0;
        assert!(flat.check(2, 2).unwrap_err().contains("room 0"));
        // Truncated payloads are errors, never panics.
        let mut w = Writer::new();
        two_rooms().write(&mut w);
        for cut in 0..w.bytes.len() {
            assert!(Rooms::read(&mut Reader::new(&w.bytes[..cut])).is_err());
        }
    }
}
