//! Section kinds: the numbers in a section header ([`section`]), their report names
//! ([`section_name`]) and which of them this reader knows.
//!
//! Invariant: a kind, once given a meaning, keeps it: a newer minor version only adds kinds, so
//! a reader skips the kinds it does not know ([`is_known_section`] is what
//! [`crate::container::read_sections`] asks) and decodes the rest.

/// Section kinds.
pub mod section {
    pub const LAYOUT: u32 = 1;
    pub const SHAPES: u32 = 2;
    pub const BLOCKS: u32 = 3;
    pub const TRANSPORT: u32 = 4;
    pub const FULL: u32 = 5;
    /// The DRT section of 1.x minor 0–1. Read, no longer written (see [`DRT_REPLACING`]).
    pub const DRT: u32 = 6;
    pub const PROBES: u32 = 7;
    /// DNRT grids with `t_j` and `k_j` apart (minor 1). Kind 8 held the paper's `m_j` (minor 0)
    /// and is no longer read: such a bundle decodes without grids.
    pub const DNRT: u32 = 9;
    /// SH incident-radiance responses for normal-mapped surfaces (minor 2).
    pub const SH: u32 = 10;
    /// The DRT section in the layout of 1.x minor 2, which adds low-rank entries and direct-light
    /// sources (see [`crate::bundle::DeltaEntry`]). Read, no longer written (see
    /// [`DRT_REPLACING`]).
    pub const DRT_LOW_RANK: u32 = 11;
    /// Where mesh surfaces' texels sit in their own lightmap images (minor 2).
    pub const LIGHTMAP: u32 = 12;
    /// The DRT section of 1.x minor 3: the minor-2 layout followed by the block texels whose MRT
    /// light the exact gather replaces ([`crate::bundle::DrtOps::replaced`]). A reader that does not know it skips it and lights the scene by MRT
    /// alone rather than adding the gather on top of MRT. Since 2.0 the only DRT kind written
    /// (with an empty list when nothing is replaced); [`DRT`] and [`DRT_LOW_RANK`] are read.
    pub const DRT_REPLACING: u32 = 13;
    /// Blocks of format 2: [`BLOCKS`]' records plus each block's box symmetry and closed faces
    /// ([`crate::bundle::BlockSymmetry`]). Written instead of [`BLOCKS`] by 2.x writers.
    pub const BLOCKS_SYMMETRIC: u32 = 14;
    /// The level's rooms (format 2.1, [`crate::bundle::Rooms`]): block boxes, where each face
    /// leads, where each surface lies. Written right after the blocks.
    pub const ROOMS: u32 = 15;
    /// Compact transport with shared source bases (format 2.2, transport kind 3,
    /// [`crate::bundle::SourceBases`]): written instead of [`TRANSPORT`] when some source has a
    /// basis. A 2.0 or 2.1 reader skips it and lights the level without light between blocks.
    pub const TRANSPORT_SOURCE_BASES: u32 = 16;
    /// The probe volume with low-rank entries (format 2.3, [`crate::bundle::ProbeVolume`]):
    /// [`PROBES`]' layout, where an entry may carry a `mix` (as DRT entries do). Written
    /// instead of [`PROBES`] when some entry is low-rank. A 2.2 or older reader skips it and
    /// reads the bundle without a probe volume (dynamic objects then get no light from it).
    pub const PROBES_LOW_RANK: u32 = 17;
    /// DNRT grids with 8-bit values in their planar, differenced form (format 2.3, codec tag 3,
    /// [`crate::dnrt_grid::DnrtGrid::write_planar`]): [`DNRT`]'s layout otherwise. Written
    /// instead of [`DNRT`] when some grid is 8-bit. A 2.2 or older reader skips it and reads the
    /// bundle without grids (dynamic objects then add no DNRT light).
    pub const DNRT_PLANAR: u32 = 18;
    /// The dynamic objects' triangles in their own frames (format 2.4,
    /// [`crate::bundle::DynamicShape`]), for a client to pose and cast their direct shadows.
    /// Written after the DNRT grids when the scene has dynamic objects; a 2.3 or older reader
    /// skips it and shades direct light without the objects' shadows.
    pub const DYNAMIC_SHAPES: u32 = 19;
    /// The DRT section of format 2.5: [`DRT_REPLACING`]'s layout, whose exact gather may keep
    /// its weights as escaped counts (weight form 2, `gather_encoding`): written instead of
    /// [`DRT_REPLACING`] when some weight is a count over 255 (more than form 1's byte holds),
    /// which a 2.4 writer stored as f32. A 2.4 or older reader skips it and lights the scene by MRT alone.
    pub const DRT_WIDE_COUNTS: u32 = 20;
    /// The DRT section of format 2.6: [`DRT_WIDE_COUNTS`]' layout followed by the tiles its
    /// exact gather reads (`start:u32s texels:u32s`, [`crate::bundle::GatherTiles`]); written
    /// instead of kinds 13 and 20 when the gather has tiles. A 2.5 or older reader skips it and
    /// lights the scene by MRT alone.
    pub const DRT_TILED_GATHER: u32 = 21;
    /// The DRT section of format 2.7: [`DRT_TILED_GATHER`]'s layout (its tiles always present,
    /// possibly none) with every texel index list — the entries' rows, the buried texels, the
    /// gather's rows and row starts, the replaced texels, the tiles' starts and texels —
    /// packed as zigzag varints of their steps (`index_lists`); the only DRT kind a 2.7 writer
    /// writes before 2.8. A 2.6 or older reader skips it and lights the scene by MRT alone.
    pub const DRT_PACKED_LISTS: u32 = 22;
    /// The DRT section of format 2.8: [`DRT_PACKED_LISTS`]' layout whose exact gather may be
    /// in form 3, each row's columns and hit counts range-coded under contexts from the rows
    /// next to and above it (`gather_model`); the only DRT kind a 2.8 writer writes. A 2.7 or
    /// older reader skips it and lights the scene by MRT alone.
    pub const DRT_MODELLED_GATHER: u32 = 23;
}

/// Report name of a section kind.
pub fn section_name(kind: u32) -> &'static str {
    match kind {
        section::LAYOUT => "layout",
        section::SHAPES => "shapes",
        section::BLOCKS => "blocks",
        section::TRANSPORT => "transport",
        section::FULL => "full",
        section::DRT => "drt",
        section::PROBES => "probes",
        section::DNRT => "dnrt",
        section::SH => "sh",
        section::DRT_LOW_RANK => "drt",
        section::LIGHTMAP => "lightmap",
        section::DRT_REPLACING => "drt",
        section::DRT_WIDE_COUNTS => "drt",
        section::DRT_TILED_GATHER => "drt",
        section::DRT_PACKED_LISTS => "drt",
        section::DRT_MODELLED_GATHER => "drt",
        section::BLOCKS_SYMMETRIC => "blocks",
        section::ROOMS => "rooms",
        section::TRANSPORT_SOURCE_BASES => "transport",
        section::PROBES_LOW_RANK => "probes",
        section::DNRT_PLANAR => "dnrt",
        section::DYNAMIC_SHAPES => "dynamic shapes",
        _ => "unknown",
    }
}

pub(super) fn is_known_section(kind: u32) -> bool {
    section_name(kind) != "unknown"
}
