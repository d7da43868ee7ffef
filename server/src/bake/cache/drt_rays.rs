//! On-disk cache of DRT ray-pass units and clutter prior bases, which
//! [`crate::bake::drt::rays`] reuses across bakes (its doc says when a cached texel is taken).
//!
//! Owns the entries' kind ([`ENTRY`]: `<dir>/drt/<key>.lfrays`; keys are made by `drt::rays`)
//! and the payloads: a [`Unit`] header (the spheres guided rays aimed at, the scene's clutter as
//! it was, the texel count), then per texel a [`BlockTexelRays`] or [`ClutterTexelRays`]; or,
//! for a prior basis, the header (no spheres, one "texel" per basis row) then the basis. Framing,
//! atomic writes, verification and marking use are [`crate::bake::cache::entry`]'s.
//!
//! Invariants: a hit decodes to exactly what was stored (f64 bits kept); an entry that does not
//! decode, or holds another texel count than asked for, is corrupt — deleted and missed — so
//! the unit is traced again. A stale entry (older format or version) is a miss.

use std::path::Path;

use lightfarm_proto::wire::{Reader, WireError, Writer};

use crate::bake::cache::entry::{EntryKind, EntryStore};
use crate::bake::drt::clutter_basis::ClutterBasisOps;
use crate::bake::drt::clutter_sampling::Sphere;
use crate::bake::drt::rays::{BlockTexelRays, ClutterTexelRays, CODE_VERSION};
use crate::bake::drt::reach::RayReach;
use crate::bake::scene::geometry::ClutterShape;

/// Where ray units live and their version (the ray passes' code version, also in every key).
pub const ENTRY: EntryKind = EntryKind {
    subdir: "drt",
    extension: "lfrays",
    version: CODE_VERSION,
};

/// The scene's clutter as a unit records it: (shape, texel offset, texel count) per object.
pub type ClutterList = Vec<(ClutterShape, u32, u32)>;

/// A cached unit: the scene's clutter as it was, and its texels' results.
pub struct Unit<T> {
    /// The clutter spheres guided rays chose from (block units; empty for clutter units).
    pub spheres: Vec<Sphere>,
    pub clutter: ClutterList,
    pub texels: Vec<T>,
}

/// A directory of ray units and prior bases.
#[derive(Clone, Debug)]
pub struct DrtRayCache {
    store: EntryStore,
}

fn write_reach(w: &mut Writer, reach: &RayReach) {
    w.u32(reach.cells.len() as u32);
    for (cell, len) in &reach.cells {
        w.u8(*cell);
        w.f32(*len);
    }
}

fn read_reach(r: &mut Reader) -> Result<RayReach, WireError> {
    let n = r.u32()? as usize;
    let mut cells = Vec::with_capacity(n.min(r.remaining() / 5));
    for _ in 0..n {
        cells.push((r.u8()?, r.f32()?));
    }
    Ok(RayReach { cells })
}

fn write_header<T>(w: &mut Writer, unit: &Unit<T>) {
    w.u32(unit.spheres.len() as u32);
    for s in &unit.spheres {
        w.f64s(&[s.center[0], s.center[1], s.center[2], s.radius]);
    }
    w.u32(unit.clutter.len() as u32);
    for (shape, start, count) in &unit.clutter {
        w.bytes.extend_from_slice(&shape.fingerprint);
        for x in shape.bounds.iter().flatten() {
            w.f64(*x);
        }
        w.u32(*start);
        w.u32(*count);
    }
    w.u32(unit.texels.len() as u32);
}

type Header = (Vec<Sphere>, ClutterList, usize);

fn read_header(r: &mut Reader) -> Result<Header, WireError> {
    let n = r.u32()? as usize;
    let mut spheres = Vec::with_capacity(n.min(r.remaining() / 32));
    for _ in 0..n {
        let v = r.f64s()?;
        if v.len() != 4 {
            return Err(WireError::Invalid("sphere".into()));
        }
        spheres.push(Sphere {
            center: [v[0], v[1], v[2]],
            radius: v[3],
        });
    }
    let n = r.u32()? as usize;
    let mut clutter = Vec::with_capacity(n.min(r.remaining() / 88));
    for _ in 0..n {
        let fingerprint: [u8; 32] = r.take(32)?.try_into().expect("32 bytes");
        let mut bounds = [[0.0; 3]; 2];
        for x in bounds.iter_mut().flatten() {
            *x = r.f64()?;
        }
        clutter.push((
            ClutterShape {
                bounds,
                fingerprint,
            },
            r.u32()?,
            r.u32()?,
        ));
    }
    Ok((spheres, clutter, r.u32()? as usize))
}

impl DrtRayCache {
    /// Opens (and creates) `<dir>/drt`.
    pub fn open(dir: &Path) -> std::io::Result<DrtRayCache> {
        Ok(DrtRayCache {
            store: EntryStore::open(dir, ENTRY)?,
        })
    }

    /// A unit of `texels` texels, each read by `read_texel`; a unit that does not decode (or
    /// has another texel count) is deleted and missed.
    fn get_unit<T>(
        &self,
        key: &str,
        texels: usize,
        mut read_texel: impl FnMut(&mut Reader) -> Result<T, WireError>,
    ) -> Option<Unit<T>> {
        let mut decode = |bytes: &[u8]| -> Result<Unit<T>, WireError> {
            let mut r = Reader::new(bytes);
            let (spheres, clutter, n) = read_header(&mut r)?;
            if n != texels {
                return Err(WireError::Invalid("texel count".into()));
            }
            let texels = (0..n)
                .map(|_| read_texel(&mut r))
                .collect::<Result<Vec<T>, WireError>>()?;
            Ok(Unit {
                spheres,
                clutter,
                texels,
            })
        };
        self.store.get(key, |bytes| decode(bytes).ok()).hit()
    }

    /// Stores a unit, each texel written by `write_texel`.
    fn put_unit<T>(
        &self,
        key: &str,
        unit: &Unit<T>,
        write_texel: impl Fn(&mut Writer, &T),
    ) -> std::io::Result<()> {
        let mut w = Writer::new();
        write_header(&mut w, unit);
        for t in &unit.texels {
            write_texel(&mut w, t);
        }
        self.store.put(key, &w.bytes)
    }

    /// Block unit `key` of `texels` texels, if cached.
    pub fn get_block(&self, key: &str, texels: usize) -> Option<Unit<BlockTexelRays>> {
        self.get_unit(key, texels, |r| {
            let mut pairs = || -> Result<Vec<(u32, f64)>, WireError> {
                let ts = r.u32s()?;
                let ws = r.f64s()?;
                if ts.len() != ws.len() {
                    return Err(WireError::Invalid("hit list".into()));
                }
                Ok(ts.into_iter().zip(ws).collect())
            };
            let occluded = pairs()?;
            let reflected = pairs()?;
            let clutter_hits = r.f64()?;
            let back_hits = r.f64()?;
            let ts = r.u32s()?;
            let ns = r.u32s()?;
            if ts.len() != ns.len() {
                return Err(WireError::Invalid("hit list".into()));
            }
            Ok(BlockTexelRays {
                occluded,
                reflected,
                clutter_hits,
                back_hits,
                hits: ts.into_iter().zip(ns).collect(),
                reach: read_reach(r)?,
            })
        })
    }

    pub fn put_block(&self, key: &str, unit: &Unit<BlockTexelRays>) -> std::io::Result<()> {
        self.put_unit(key, unit, |w, t| {
            for list in [&t.occluded, &t.reflected] {
                w.u32s(&list.iter().map(|p| p.0).collect::<Vec<_>>());
                w.f64s(&list.iter().map(|p| p.1).collect::<Vec<_>>());
            }
            w.f64(t.clutter_hits);
            w.f64(t.back_hits);
            w.u32s(&t.hits.iter().map(|p| p.0).collect::<Vec<_>>());
            w.u32s(&t.hits.iter().map(|p| p.1).collect::<Vec<_>>());
            write_reach(w, &t.reach);
        })
    }

    /// Clutter unit `key` of `texels` texels, if cached.
    pub fn get_clutter(&self, key: &str, texels: usize) -> Option<Unit<ClutterTexelRays>> {
        self.get_unit(key, texels, |r| {
            let ts = r.u32s()?;
            let ns = r.u32s()?;
            if ts.len() != ns.len() {
                return Err(WireError::Invalid("hit list".into()));
            }
            Ok(ClutterTexelRays {
                hits: ts.into_iter().zip(ns).collect(),
                back: r.f64()?,
                reach: read_reach(r)?,
            })
        })
    }

    pub fn put_clutter(&self, key: &str, unit: &Unit<ClutterTexelRays>) -> std::io::Result<()> {
        self.put_unit(key, unit, |w, t| {
            w.u32s(&t.hits.iter().map(|p| p.0).collect::<Vec<_>>());
            w.u32s(&t.hits.iter().map(|p| p.1).collect::<Vec<_>>());
            w.f64(t.back);
            write_reach(w, &t.reach);
        })
    }

    /// Prior basis `key`, with the clutter it was computed for, if cached.
    pub fn get_basis(&self, key: &str) -> Option<(ClutterList, ClutterBasisOps)> {
        let decode = |bytes: &[u8]| -> Result<_, WireError> {
            let mut r = Reader::new(bytes);
            let (_, clutter, rows) = read_header(&mut r)?;
            let cols = r.u32()? as usize;
            let data = r.f64s()?;
            if data.len() != rows * cols {
                return Err(WireError::Invalid("basis size".into()));
            }
            let dropped_energy = r.f64()?;
            let basis = faer::Mat::from_fn(rows, cols, |i, j| data[i * cols + j]);
            Ok((
                clutter,
                ClutterBasisOps {
                    basis,
                    dropped_energy,
                },
            ))
        };
        self.store.get(key, |bytes| decode(bytes).ok()).hit()
    }

    pub fn put_basis(
        &self,
        key: &str,
        clutter: &[(ClutterShape, u32, u32)],
        basis: &ClutterBasisOps,
    ) -> std::io::Result<()> {
        let mut w = Writer::new();
        write_header::<()>(
            &mut w,
            &Unit {
                spheres: Vec::new(),
                clutter: clutter.to_vec(),
                texels: vec![(); basis.basis.nrows()],
            },
        );
        let m = &basis.basis;
        w.u32(m.ncols() as u32);
        let mut data = Vec::with_capacity(m.nrows() * m.ncols());
        for i in 0..m.nrows() {
            data.extend((0..m.ncols()).map(|j| m[(i, j)]));
        }
        w.f64s(&data);
        w.f64(basis.dropped_energy);
        self.store.put(key, &w.bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cache(test: &str) -> (std::path::PathBuf, DrtRayCache) {
        let root = std::env::temp_dir().join(format!("lf-drt-rays-{test}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let cache = DrtRayCache::open(&root).unwrap();
        (root, cache)
    }

    fn clutter() -> ClutterList {
        vec![(
            ClutterShape {
                bounds: [[0.1, 0.2, 0.3], [0.4, 0.5, 0.6]],
                fingerprint: [7; 32],
            },
            40,
            3,
        )]
    }

    fn reach() -> RayReach {
        RayReach {
            cells: vec![(3, 0.25), (9, f32::INFINITY)],
        }
    }

    #[test]
    fn ray_units_round_trip_bit_exact_and_check_their_texel_count() {
        let (root, cache) = cache("units");
        let block = Unit {
            spheres: vec![Sphere {
                center: [1.0, 2.0, 3.0],
                radius: 0.1 + 0.2,
            }],
            clutter: clutter(),
            texels: vec![
                BlockTexelRays {
                    occluded: vec![(1, 0.5), (4, 1.0 / 3.0)],
                    reflected: vec![(41, 0.125)],
                    clutter_hits: 0.7,
                    back_hits: 0.01,
                    hits: vec![(2, 5)],
                    reach: reach(),
                },
                BlockTexelRays::default(),
            ],
        };
        cache.put_block("b", &block).unwrap();
        assert_eq!(
            root.join(ENTRY.relative_path("b")),
            root.join("drt/b.lfrays")
        );
        let back = cache.get_block("b", 2).unwrap();
        assert_eq!(back.texels, block.texels);
        assert_eq!(back.clutter, block.clutter);
        assert_eq!(back.spheres[0].radius.to_bits(), (0.1f64 + 0.2).to_bits());
        // Another texel count is corrupt: deleted and missed.
        assert!(cache.get_block("b", 3).is_none());
        assert!(!root.join("drt/b.lfrays").exists());

        let unit = Unit {
            spheres: Vec::new(),
            clutter: clutter(),
            texels: vec![ClutterTexelRays {
                hits: vec![(0, 3), (40, 1)],
                back: 0.25,
                reach: reach(),
            }],
        };
        cache.put_clutter("c", &unit).unwrap();
        assert_eq!(cache.get_clutter("c", 1).unwrap().texels, unit.texels);
        let _ = std::fs::remove_dir_all(&root);
    }

    #[test]
    fn prior_basis_round_trips_bit_exact() {
        let (root, cache) = cache("basis");
        let basis = ClutterBasisOps {
            basis: faer::Mat::from_fn(3, 2, |i, j| (i as f64 + 0.1) / (j as f64 + 3.0)),
            dropped_energy: 1e-7,
        };
        cache.put_basis("p", &clutter(), &basis).unwrap();
        let (old, back) = cache.get_basis("p").unwrap();
        assert_eq!(old, clutter());
        assert_eq!(back.dropped_energy, basis.dropped_energy);
        assert_eq!((back.basis.nrows(), back.basis.ncols()), (3, 2));
        for i in 0..3 {
            for j in 0..2 {
                assert_eq!(back.basis[(i, j)].to_bits(), basis.basis[(i, j)].to_bits());
            }
        }
        let _ = std::fs::remove_dir_all(&root);
    }
}
