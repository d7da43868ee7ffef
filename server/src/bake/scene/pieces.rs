//! Long blocks baked as pieces: the scene the bake engine works on.
//!
//! `texels_per_face` (T) cuts every face into T × T texels whatever its size, so a long block's
//! texels are long too: a 30 × 1.2 × 4 m room at T = 16 has 1.9 m texels along its floor, and
//! a lamp half a metre from its wall lights a spot far smaller than one texel (56%, 43% and 10%
//! off Mitsuba at one bounce at T = 8, 16, 32; `Settings::texels_per_face`). [`baked_scene`]
//! therefore cuts a block into equal pieces along each axis on which it is more than
//! [`MAX_ASPECT`] times as long as its narrowest other side, the cuts open faces between the
//! pieces, so that every piece's faces have texels of the room's own scale. Light crosses the
//! cuts as it crosses any opening between blocks. A block that would need more than
//! [`MAX_PIECES_PER_AXIS`] pieces on an axis (over 64 times as long as its narrowest side)
//! stays whole on it: light crossing dozens of openings in a row loses more than the long
//! texels cost.
//!
//! The rule reads ratios of the block's own sides, never absolute lengths, so a scene scaled
//! as a whole is cut alike. Rooms meet only through whole open faces, so a cut that runs
//! across an open face cuts the neighbour behind it the same way: blocks joined by an open
//! face take, along each axis that face runs along, the same number of pieces (the most any
//! of them needs; their faces share their extent, so the cuts coincide). A level of blocks of
//! at most [`MAX_ASPECT`] on every axis, as generated levels of 2–6 m rooms are, is left as it
//! is (the scene is returned unchanged, its bake byte for byte what it was).
//!
//! Names: a piece's id is `<block id>/<n>` ('/' never appears in a scene's ids, so it cannot
//! clash), and [`Block::piece`] keeps the scene block's id, so the piece's texels are named
//! `block:<block id>/<face>` like the block's, their indices following on from the pieces
//! before it on that face ([`BlockPiece::index_on_face`]).
//!
//! Pieces of one size are one shape: the engine keys and bakes their shape operators by the
//! nominal extent ([`BlockPiece::extent`]), since their own `max − min` differ in the last
//! bits. A 30 m room cut in 7 is 2 shapes (the ends, mirror images, and the middle), not 7.
//!
//! Invariants: the pieces tile the block exactly (shared cut coordinates are computed once,
//! so neighbouring pieces' faces coincide bit for bit); a piece has the block's albedo and
//! per-face albedo, its outer faces the block's open/closed state, its cut faces open.

use std::borrow::Cow;

use lightfarm_proto::scene::{Block, BlockPiece, Opening, Scene, SceneError};
use lightfarm_proto::Face;

/// A block longer than this many times its narrowest other side along an axis is cut along
/// it.
pub const MAX_ASPECT: f64 = 4.0;

/// A block that would need more pieces than this along an axis is not cut along it: with
/// dozens of openings in a row, light crossing them loses more accuracy than the long texels
/// cost. A 10 × 0.1 × 10 m crawlspace with its lamp inside was 0.084 off the reference's
/// texel averages cut 16 × 16 (capped) against 0.023 whole (`tests/stability_geometry.rs`),
/// where a 5 × 0.5 × 5 m one cut 3 × 3 went from 0.126 to 0.072.
pub const MAX_PIECES_PER_AXIS: u32 = 16;

/// The scene as the bake engine bakes it: `scene` with every long block cut into pieces (see
/// the module doc), blocks in the scene's order with each cut block's pieces in its place.
/// Other fields unchanged; a scene with nothing to cut (already cut, or whose openings do not
/// resolve: its bake reports why) is borrowed as it is, not copied.
pub fn baked_scene(scene: &Scene) -> Cow<'_, Scene> {
    let Ok(cells) = cells(scene) else {
        return Cow::Borrowed(scene);
    };
    if cells.iter().all(|n| *n == [1, 1, 1]) {
        return Cow::Borrowed(scene);
    }
    let mut out = scene.clone();
    out.blocks = scene
        .blocks
        .iter()
        .zip(&cells)
        .flat_map(|(b, n)| pieces(b, *n))
        .collect();
    Cow::Owned(out)
}

/// Pieces along each axis of each block of `scene` (1 where it is not cut): per block and
/// axis as many as [`needed`], made equal (the most any needs) across blocks whose open faces
/// meet on a face the axis runs along, so that the cut faces keep meeting whole; repeated
/// until no piece needs more, since a cut forced on a block by its neighbour makes its pieces
/// narrower across that axis (counts only grow and stop at [`MAX_PIECES_PER_AXIS`]).
pub fn cells(scene: &Scene) -> Result<Vec<[u32; 3]>, SceneError> {
    let n_blocks = scene.blocks.len();
    if scene.blocks.iter().all(|b| wanted(b) == [1, 1, 1]) {
        return Ok(vec![[1, 1, 1]; n_blocks]);
    }
    // Union-find over (block, axis).
    let mut parent: Vec<usize> = (0..3 * n_blocks).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    for (b, faces) in scene.openings()?.iter().enumerate() {
        for face in Face::ALL {
            if let Some(Opening::Neighbour { block: c, .. }) = faces[face.index()] {
                for a in (0..3).filter(|a| *a != face.axis()) {
                    let (x, y) = (root(&mut parent, 3 * b + a), root(&mut parent, 3 * c + a));
                    parent[x] = y;
                }
            }
        }
    }
    let roots: Vec<usize> = (0..3 * n_blocks).map(|i| root(&mut parent, i)).collect();
    let mut group_cells = vec![1u32; 3 * n_blocks];
    loop {
        let mut changed = false;
        for (b, block) in scene.blocks.iter().enumerate() {
            if block.piece.is_some() {
                continue;
            }
            let n: [u32; 3] = std::array::from_fn(|a| group_cells[roots[3 * b + a]]);
            for a in 0..3 {
                let need = needed(block, n, a);
                let g = &mut group_cells[roots[3 * b + a]];
                if need > *g {
                    *g = need;
                    changed = true;
                }
            }
        }
        if !changed {
            break;
        }
    }
    Ok((0..n_blocks)
        .map(|b| std::array::from_fn(|a| group_cells[roots[3 * b + a]]))
        .collect())
}

/// The pieces `block` needs along each axis on its own ([`needed`] with the block whole);
/// `[1, 1, 1]` for a block that already is a piece.
pub fn wanted(block: &Block) -> [u32; 3] {
    if block.piece.is_some() {
        return [1, 1, 1];
    }
    std::array::from_fn(|a| needed(block, [1, 1, 1], a))
}

/// The pieces `block`, cut into `n` per axis otherwise, needs along axis `a`: `⌈length /
/// (MAX_ASPECT · its pieces' narrowest other side)⌉`, or `n[a]` (never fewer) when that is
/// more than [`MAX_PIECES_PER_AXIS`].
fn needed(block: &Block, n: [u32; 3], a: usize) -> u32 {
    let side = |k: usize| (block.max[k] - block.min[k]) / n[k] as f64;
    let narrow = side((a + 1) % 3).min(side((a + 2) % 3));
    let length = block.max[a] - block.min[a];
    if narrow.is_nan() || narrow <= 0.0 || length <= MAX_ASPECT * narrow * n[a] as f64 {
        return n[a];
    }
    let need = (length / (MAX_ASPECT * narrow)).ceil();
    if need > MAX_PIECES_PER_AXIS as f64 {
        return n[a];
    }
    (need as u32).max(n[a])
}

/// `block` cut into `n` pieces per axis, x fastest, then y, then z.
fn pieces(block: &Block, n: [u32; 3]) -> Vec<Block> {
    if n == [1, 1, 1] {
        return vec![block.clone()];
    }
    // The cut coordinates per axis, each computed once (ends exactly the block's).
    let cuts: [Vec<f64>; 3] = std::array::from_fn(|a| {
        (0..=n[a])
            .map(|k| match k {
                0 => block.min[a],
                k if k == n[a] => block.max[a],
                k => block.min[a] + (block.max[a] - block.min[a]) * k as f64 / n[a] as f64,
            })
            .collect()
    });
    let extent: [f64; 3] = std::array::from_fn(|a| (block.max[a] - block.min[a]) / n[a] as f64);
    let mut out = Vec::with_capacity((n[0] * n[1] * n[2]) as usize);
    for z in 0..n[2] {
        for y in 0..n[1] {
            for x in 0..n[0] {
                let cell = [x, y, z];
                let open = Face::ALL
                    .into_iter()
                    .filter(|f| {
                        let a = f.axis();
                        let outer = if f.is_max_side() {
                            cell[a] + 1 == n[a]
                        } else {
                            cell[a] == 0
                        };
                        !outer || block.is_open(*f)
                    })
                    .collect();
                out.push(Block {
                    id: format!("{}/{}", block.id, out.len()),
                    min: std::array::from_fn(|a| cuts[a][cell[a] as usize]),
                    max: std::array::from_fn(|a| cuts[a][cell[a] as usize + 1]),
                    open,
                    albedo: block.albedo,
                    face_albedo: block.face_albedo.clone(),
                    piece: Some(BlockPiece {
                        of: block.id.clone(),
                        cell,
                        cells: n,
                        extent,
                    }),
                });
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    fn block(id: &str, min: [f64; 3], max: [f64; 3], open: &[Face]) -> Block {
        Block {
            id: id.into(),
            min,
            max,
            open: open.to_vec(),
            albedo: [0.5, 0.6, 0.7],
            face_albedo: BTreeMap::from([(Face::NegY, [0.2, 0.3, 0.4])]),
            piece: None,
        }
    }

    fn scene(blocks: Vec<Block>) -> Scene {
        let mut s = Scene::from_json(
            r#"{"format":"lightfarm.scene/1","name":"t","blocks":[{"id":"a","min":[0,0,0],"max":[1,1,1],"albedo":[0.5,0.5,0.5]}]}"#,
        )
        .unwrap();
        s.blocks = blocks;
        s
    }

    #[test]
    fn rooms_of_a_few_metres_are_left_whole() {
        // The maze's corridors (6 × 3 × 2 m) and generated levels' rooms (2–6 m, 3 m high).
        let s = scene(vec![
            block("c", [6.0, 0.0, 4.0], [12.0, 3.0, 6.0], &[]),
            block("r", [0.0, 0.0, 10.0], [6.0, 3.0, 12.0], &[]),
            block("cube", [20.0, 0.0, 0.0], [21.0, 1.0, 1.0], &[]),
        ]);
        assert!(matches!(baked_scene(&s), Cow::Borrowed(_)));
    }

    #[test]
    fn a_long_room_is_cut_into_pieces_that_tile_it() {
        // 30 × 1.2 × 4 m: x is 25 times the narrowest other side, so ceil(30 / 4.8) = 7
        // pieces along x; z (4 m) is 3.3 times 1.2 m, under the limit.
        let b = block("hall", [0.0, 0.0, 0.0], [30.0, 1.2, 4.0], &[Face::PosX]);
        assert_eq!(wanted(&b), [7, 1, 1]);
        let s = baked_scene(&scene(vec![b.clone()])).into_owned();
        assert_eq!(s.blocks.len(), 7);
        s.validate().unwrap();
        let mut volume = 0.0;
        for (k, p) in s.blocks.iter().enumerate() {
            assert_eq!(p.id, format!("hall/{k}"));
            let piece = p.piece.as_ref().unwrap();
            assert_eq!(
                (piece.of.as_str(), piece.cell, piece.cells),
                ("hall", [k as u32, 0, 0], [7, 1, 1])
            );
            assert_eq!(piece.extent, [30.0 / 7.0, 1.2, 4.0]);
            assert_eq!(
                (p.min[1], p.max[1], p.min[2], p.max[2]),
                (0.0, 1.2, 0.0, 4.0)
            );
            assert_eq!(p.albedo, b.albedo);
            assert_eq!(p.face_albedo, b.face_albedo);
            // Neighbours share their cut coordinate exactly.
            if k > 0 {
                assert_eq!(p.min[0], s.blocks[k - 1].max[0]);
            }
            // Cut faces open; the outer ends as the block's (-x closed, +x open).
            assert_eq!(p.is_open(Face::NegX), k > 0);
            assert!(p.is_open(Face::PosX));
            for f in [Face::NegY, Face::PosY, Face::NegZ, Face::PosZ] {
                assert!(!p.is_open(f));
            }
            volume += (p.max[0] - p.min[0]) * 1.2 * 4.0;
            // Every piece is within the limit.
            let mut whole = p.clone();
            whole.piece = None;
            assert_eq!(wanted(&whole), [1, 1, 1], "{}", p.id);
        }
        assert_eq!(s.blocks[0].min[0], 0.0);
        assert_eq!(s.blocks[6].max[0], 30.0);
        assert!((volume - 30.0 * 1.2 * 4.0).abs() < 1e-9);
        // The cut faces connect the pieces in a row; the +x end opens onto nothing.
        let openings = s.openings().unwrap();
        assert_eq!(openings.len(), 7);
        for (k, faces) in openings.iter().enumerate() {
            let next = faces[Face::PosX.index()];
            if k < 6 {
                assert_eq!(
                    next,
                    Some(Opening::Neighbour {
                        block: k + 1,
                        face: Face::NegX
                    })
                );
            } else {
                assert_eq!(next, Some(Opening::Void));
            }
        }
        // Cutting again changes nothing.
        assert!(matches!(baked_scene(&s), Cow::Borrowed(_)));
    }

    #[test]
    fn scaling_the_scene_cuts_it_alike() {
        for scale in [0.01, 1.0, 1000.0] {
            let b = block(
                "h",
                [0.0; 3],
                [20.0 * scale, 3.0 * scale, 20.0 * scale],
                &[],
            );
            assert_eq!(wanted(&b), [2, 1, 2], "scale {scale}");
        }
    }

    #[test]
    fn a_cut_across_an_opening_cuts_the_neighbour_behind_it_alike() {
        // A 30 m hall under a 30 m shaft, open to each other through the hall's ceiling, and
        // a closet at the hall's +x end. The x cut (7, the hall's) runs across the ceiling, so
        // the shaft takes it too; the closet (0.6 m deep, 4 m along z) wants 2 along z, and a
        // z cut runs across the hall's +x face and the hall's ceiling: all three take 2.
        // Without the shaft's y cut (its pieces 6 times as tall as deep) this level was 0.10
        // off Mitsuba at all bounces with a lamp in the shaft (0.035 with it). Most of that
        // was the 8-bit `T_d→b`'s rounding (since kept from the flux, `mrt::flux`): stored
        // losslessly, the uncut level (all albedos 0.8) was 0.051 off our reference, 0.104
        // in 8 bits.
        let s = scene(vec![
            block(
                "hall",
                [0.0; 3],
                [30.0, 1.2, 4.0],
                &[Face::PosX, Face::PosY],
            ),
            block("closet", [30.0, 0.0, 0.0], [30.6, 1.2, 4.0], &[Face::NegX]),
            block("shaft", [0.0, 1.2, 0.0], [30.0, 13.2, 4.0], &[Face::NegY]),
        ]);
        assert_eq!(wanted(&s.blocks[1]), [1, 1, 2]);
        // The shaft's pieces, 30/7 × 12 × 2 m, are then 6 times as tall as deep: 2 along y.
        assert_eq!(cells(&s).unwrap(), vec![[7, 1, 2], [1, 1, 2], [7, 2, 2]]);
        let baked = baked_scene(&s);
        assert_eq!(baked.blocks.len(), 14 + 2 + 28);
        baked.validate().unwrap();
        // Every open face still meets a neighbour's whole open face (openings() refuses
        // partial overlaps), and only the pieces' own cuts and the scene's openings are open.
        let openings = baked.openings().unwrap();
        for (b, faces) in openings.iter().enumerate() {
            for f in Face::ALL {
                assert_eq!(faces[f.index()].is_some(), baked.blocks[b].is_open(f));
                assert_ne!(
                    faces[f.index()],
                    Some(Opening::Void),
                    "{} {f}",
                    baked.blocks[b].id
                );
            }
        }
    }

    #[test]
    fn pieces_on_a_face_are_numbered_once_each() {
        let b = block("h", [0.0; 3], [20.0, 3.0, 30.0], &[]);
        let n = wanted(&b);
        assert_eq!(n, [2, 1, 3]);
        for face in Face::ALL {
            let mut seen = Vec::new();
            for p in pieces(&b, n) {
                if !p.is_open(face) {
                    seen.push(p.piece.unwrap().index_on_face(face));
                }
            }
            seen.sort_unstable();
            let expect: Vec<u32> = (0..seen.len() as u32).collect();
            assert_eq!(seen, expect, "{face}");
        }
    }

    #[test]
    fn a_room_that_would_need_too_many_pieces_stays_whole() {
        // 1:100 (25 pieces of 4) is over the limit; 1:64 (16) is the most that is cut.
        let b = block("duct", [0.0; 3], [100.0, 1.0, 1.0], &[]);
        assert_eq!(wanted(&b), [1, 1, 1]);
        let b = block("duct", [0.0; 3], [64.0, 1.0, 1.0], &[]);
        assert_eq!(wanted(&b), [MAX_PIECES_PER_AXIS, 1, 1]);
    }
}
