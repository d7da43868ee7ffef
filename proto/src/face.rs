//! The six faces of an axis-aligned box and the texel frame on each.
//!
//! Invariant: every crate names faces by these strings (`-x +x -y +y -z +z`) and lays texels
//! out with [`Face::tangent_axes`]: texel `(i, j)` of a `T×T` face has index `j * T + i`, with
//! `i` running along the first tangent axis and `j` along the second (both ascending world
//! axes). Block faces are lit from the inside (normal points into the block); clutter box faces
//! are lit from the outside (normal points away from the box).

use serde::{Deserialize, Serialize};

/// The two world axes other than `axis` (0 = x, 1 = y, 2 = z; any larger value is taken as
/// z), ascending: the tangent axes of every face, rect or texel plane perpendicular to `axis`,
/// in the order the texel frame uses. The one definition every crate uses.
#[inline]
pub const fn tangent_axes(axis: usize) -> (usize, usize) {
    match axis {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    }
}

/// One face of an axis-aligned box.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum Face {
    #[serde(rename = "-x")]
    NegX,
    #[serde(rename = "+x")]
    PosX,
    #[serde(rename = "-y")]
    NegY,
    #[serde(rename = "+y")]
    PosY,
    #[serde(rename = "-z")]
    NegZ,
    #[serde(rename = "+z")]
    PosZ,
}

impl schemars::JsonSchema for Face {
    fn schema_name() -> std::borrow::Cow<'static, str> {
        "Face".into()
    }
    fn json_schema(_: &mut schemars::SchemaGenerator) -> schemars::Schema {
        schemars::json_schema!({ "type": "string", "enum": ["-x", "+x", "-y", "+y", "-z", "+z"] })
    }
}

impl Face {
    /// All faces in canonical order (the order texels are laid out in).
    pub const ALL: [Face; 6] = [
        Face::NegX,
        Face::PosX,
        Face::NegY,
        Face::PosY,
        Face::NegZ,
        Face::PosZ,
    ];

    /// Index in [`Face::ALL`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// The world axis the face is perpendicular to (0 = x, 1 = y, 2 = z).
    pub fn axis(self) -> usize {
        self.index() / 2
    }

    /// True for the `+` face (at the box's max along its axis).
    pub fn is_max_side(self) -> bool {
        self.index() % 2 == 1
    }

    /// The two tangent axes, ascending ([`tangent_axes`] of [`Face::axis`]).
    pub fn tangent_axes(self) -> (usize, usize) {
        tangent_axes(self.axis())
    }

    /// The face on the other side of a shared plane (`+x` ↔ `-x`).
    pub fn opposite(self) -> Face {
        Face::ALL[self.index() ^ 1]
    }

    /// Outward normal of the box at this face (unit, along the axis).
    pub fn outward_normal(self) -> [f64; 3] {
        let mut n = [0.0; 3];
        n[self.axis()] = if self.is_max_side() { 1.0 } else { -1.0 };
        n
    }

    /// The face's name as used in JSON and surface names.
    pub fn name(self) -> &'static str {
        ["-x", "+x", "-y", "+y", "-z", "+z"][self.index()]
    }

    /// Parses a face name.
    pub fn from_name(name: &str) -> Option<Face> {
        Face::ALL.into_iter().find(|f| f.name() == name)
    }
}

impl std::fmt::Display for Face {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_opposites_pair_up() {
        for face in Face::ALL {
            assert_eq!(Face::from_name(face.name()), Some(face));
            assert_eq!(face.opposite().opposite(), face);
            assert_eq!(face.opposite().axis(), face.axis());
            assert_ne!(face.opposite().is_max_side(), face.is_max_side());
            let (u, v) = face.tangent_axes();
            assert!(u < v && u != face.axis() && v != face.axis());
        }
    }
}
