//! Format 2.6's DRT section (kind 21): an exact gather whose columns past the layout's texels
//! read the mean direct light of tiles of texels ([`GatherTiles`]). The bundle decodes to the
//! same gather and tiles; a 2.6 writer wrote a gather without tiles as kind 13 or 20; and every
//! broken tile table or tile column is refused by name (a 2.5 reader skips kind 21 and lights
//! by MRT, so the tiles never reach a reader that would index past its texels). Format 2.7
//! wrote kind 22 instead (the same layout, its index lists packed), which decodes to the same
//! bundle as kind 21 and is smaller; 2.8 writes kind 23 (`modelled_gather.rs`).

use lightfarm_proto::bundle::{section, Bundle, GatherTiles};
use lightfarm_proto::testing::{drt_bundle, join_sections, with_gather, with_tiles, Lcg};

/// A DRT test bundle with a gather pooled by tile (counts up to `max_count`).
fn tiled(seed: u64, max_count: u32) -> Bundle {
    let mut rng = Lcg(seed);
    let mut b = drt_bundle(&mut rng, false, true, true);
    with_gather(&mut rng, &mut b, max_count);
    with_tiles(&mut b, 2);
    b
}

/// The kind of `b`'s DRT section as a 2.6 writer wrote it.
fn drt_kind(b: &Bundle) -> u32 {
    let kinds: Vec<u32> = b
        .raw_sections_as_2_6()
        .into_iter()
        .map(|(k, _)| k)
        .filter(|k| {
            [
                section::DRT_REPLACING,
                section::DRT_WIDE_COUNTS,
                section::DRT_TILED_GATHER,
            ]
            .contains(k)
        })
        .collect();
    assert_eq!(kinds.len(), 1, "one DRT section");
    kinds[0]
}

fn gather_tiles(b: &mut Bundle) -> &mut lightfarm_proto::bundle::TexelGather {
    b.drt.as_mut().unwrap().direct_gather.as_mut().unwrap()
}

#[test]
fn a_tiled_gather_is_kind_21_and_decodes_to_the_same_gather_and_tiles() {
    for (seed, max_count) in [(81, 4), (82, 255), (83, 700)] {
        let mut b = tiled(seed, max_count);
        let n = b.layout.n_texels() as u32;
        let g = gather_tiles(&mut b);
        assert!(!g.tiles.is_empty());
        assert!(g.cols.iter().any(|&c| c >= n), "some column reads a tile");
        assert_eq!(drt_kind(&b), section::DRT_TILED_GATHER);
        let decoded = Bundle::decode(&join_sections(&b.raw_sections_as_2_6())).expect("decodes");
        assert_eq!(decoded, b, "seed {seed}");
    }
}

/// The payload of `b`'s DRT section in `sections`.
fn drt_payload(sections: &[(u32, Vec<u8>)]) -> &[u8] {
    let drt = [
        section::DRT_REPLACING,
        section::DRT_WIDE_COUNTS,
        section::DRT_TILED_GATHER,
        section::DRT_PACKED_LISTS,
        section::DRT_MODELLED_GATHER,
    ];
    &sections.iter().find(|s| drt.contains(&s.0)).unwrap().1
}

#[test]
fn a_2_7_writer_packed_every_index_list_into_kind_22_which_decodes_to_the_same_bundle() {
    for (seed, max_count, tiles) in [(91, 4, true), (92, 700, true), (93, 200, false)] {
        let mut rng = Lcg(seed);
        let mut b = drt_bundle(&mut rng, false, true, true);
        with_gather(&mut rng, &mut b, max_count);
        if tiles {
            with_tiles(&mut b, 2);
        }
        b.drt.as_mut().unwrap().replaced = vec![0, 1, 2, 7];
        let sections = b.raw_sections_as_2_7();
        assert!(sections.iter().any(|s| s.0 == section::DRT_PACKED_LISTS));
        let decoded = Bundle::decode(&join_sections(&sections)).expect("decodes");
        assert_eq!(decoded, b, "seed {seed}");
        assert_eq!(
            Bundle::decode(&b.encode()).expect("decodes"),
            b,
            "seed {seed}"
        );
        // Every step in this small bundle's lists is under 8,192 texels: at most two bytes an
        // index against four. A packed list's header is 16 bytes against 8, and kind 22 holds
        // the two tile lists even when they are empty (a 2.6 writer then wrote kind 13 or 20).
        let d = b.drt.as_ref().unwrap();
        let g = d.direct_gather.as_ref().unwrap();
        let indices = d.entries.iter().map(|e| e.rows.len()).sum::<usize>()
            + d.buried.len()
            + d.replaced.len()
            + g.rows.len()
            + g.row_start.len()
            + g.tiles.start.len()
            + g.tiles.texels.len();
        let lists = d.entries.len() + 6;
        let plain_lists = if tiles { lists } else { lists - 2 };
        let plain = drt_payload(&b.raw_sections_as_2_6()).len();
        let packed = drt_payload(&sections).len();
        assert!(
            packed + 2 * indices <= plain + 16 * lists - 8 * plain_lists,
            "seed {seed}: {plain} B plain, {packed} B packed, {indices} indices"
        );
        // (So small a bundle can come out larger packed, by those headers: seed 93.)
        assert!(indices > 40, "seed {seed}: {indices} indices");
    }
}

#[test]
fn a_gather_without_tiles_keeps_kinds_13_and_20() {
    let mut rng = Lcg(84);
    let mut b = drt_bundle(&mut rng, false, true, true);
    with_gather(&mut rng, &mut b, 200);
    assert_eq!(drt_kind(&b), section::DRT_REPLACING);
    with_gather(&mut rng, &mut b, 600);
    assert_eq!(drt_kind(&b), section::DRT_WIDE_COUNTS);
}

/// `b` re-encoded with its DRT section's kind replaced.
fn relabelled(b: &Bundle, from: u32, to: u32) -> Vec<u8> {
    let mut sections = b.raw_sections_as_2_6();
    for s in sections.iter_mut().filter(|s| s.0 == from) {
        s.0 = to;
    }
    join_sections(&sections)
}

/// A way to break a tiled bundle.
type Break = fn(&mut Bundle);

#[test]
fn broken_tiles_and_tile_columns_are_refused_by_name() {
    let cases: [(&str, Break); 6] = [
        ("a gather tile spans two surfaces", |b| {
            // Texels 3 (block a) and 4 (block b).
            gather_tiles(b).tiles = tiles(&[&[0, 1, 2], &[3, 4], &[5]]);
        }),
        ("gather tiles are not ordered by their first texel", |b| {
            gather_tiles(b).tiles = tiles(&[&[4, 5, 6], &[0, 1, 2], &[3], &[7, 8, 9]]);
        }),
        ("a gather tile's texels do not ascend", |b| {
            gather_tiles(b).tiles = tiles(&[&[1, 0], &[2, 3], &[4, 5, 6], &[7, 8, 9]]);
        }),
        ("a gather tile names a texel outside the layout", |b| {
            let n = b.layout.n_texels() as u32;
            let g = gather_tiles(b);
            let last = g.tiles.len() - 1;
            let mut t: Vec<Vec<u32>> = (0..last).map(|i| g.tiles.texels(i).to_vec()).collect();
            t.push(vec![n]);
            g.tiles = tiles(&t.iter().map(Vec::as_slice).collect::<Vec<_>>());
        }),
        (
            "gather tile starts do not ascend from 0 to the texel count",
            |b| {
                gather_tiles(b).tiles.start[1] = 0;
            },
        ),
        ("drt: direct gather is inconsistent", |b| {
            // A column past the last tile.
            let n = (b.layout.n_texels() + gather_tiles(b).tiles.len()) as u32;
            *gather_tiles(b).cols.last_mut().unwrap() = n;
        }),
    ];
    for (why, break_it) in cases {
        let mut b = tiled(85, 4);
        break_it(&mut b);
        let err = Bundle::decode(&b.encode()).expect_err(why);
        assert!(err.to_string().contains(why), "{why}: {err}");
    }
    // Kind 21's payload read as kind 20 leaves the tile table unread (trailing bytes) or, past
    // that, tile columns without tiles: refused either way.
    let b = tiled(86, 600);
    let bytes = relabelled(&b, section::DRT_TILED_GATHER, section::DRT_WIDE_COUNTS);
    Bundle::decode(&bytes).expect_err("kind 20 with tile columns");
    // Tiles without a gather.
    let mut b = tiled(87, 4);
    let t = gather_tiles(&mut b).tiles.clone();
    let mut sections = b.raw_sections_as_2_6();
    b.drt.as_mut().unwrap().direct_gather = None;
    let without = b.raw_sections_as_2_6();
    let drt_of = |s: &[(u32, Vec<u8>)]| {
        s.iter()
            .position(|s| s.0 == section::DRT_TILED_GATHER || s.0 == section::DRT_REPLACING)
            .unwrap()
    };
    let (i, j) = (drt_of(&sections), drt_of(&without));
    let mut payload = without[j].1.clone();
    payload.extend(tile_bytes(&t));
    sections[i] = (section::DRT_TILED_GATHER, payload);
    let err = Bundle::decode(&join_sections(&sections)).expect_err("tiles without a gather");
    assert!(
        err.to_string().contains("gather tiles without a gather"),
        "{err}"
    );
}

fn tiles(list: &[&[u32]]) -> GatherTiles {
    let mut t = GatherTiles::default();
    for tile in list {
        t.push(tile);
    }
    t
}

/// `start:u32s texels:u32s` as the writer stores them (u32s: a u64 length, then the values).
fn tile_bytes(t: &GatherTiles) -> Vec<u8> {
    let mut out = Vec::new();
    for list in [&t.start, &t.texels] {
        out.extend((list.len() as u64).to_le_bytes());
        for v in list.iter() {
            out.extend(v.to_le_bytes());
        }
    }
    out
}
