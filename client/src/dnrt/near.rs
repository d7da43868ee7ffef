//! [`DnrtNear`]: a posed object's DNRT on the lightmap texels near it, with its grid contracted
//! only at the points those texels read.
//!
//! [`DnrtInstance::new`] contracts every grid point with the frame's light (`res³` points, each
//! `3 · n_sh` multiply-adds per slot pair): on ball_corridor's 32³ grid that is 1.2 ms, while
//! the lightmap texels within the object's reach read a fraction of the points (there the
//! 2,304 texels around the ball read 5,761 of 32,768). A receiver reads the
//! 8 corners of one cell ([`DnrtInstance::lookup`], [`DnrtInstance::cell`]), so this marks the
//! corners every texel on the surfaces within reach reads, contracts those (each with the same
//! code and order as the whole grid's), then shades.
//!
//! Invariant: [`DnrtNear::apply_texels_near`] adds exactly what
//! [`DnrtInstance::apply_texels_near`] adds, bit for bit (a receiver reads only points it
//! marked; a point's value does not depend on which others are contracted).

use std::ops::Range;

use lightfarm_proto::bundle::Layout;
use lightfarm_proto::sh::SH_COEFFS;

use super::{DnrtError, DnrtInstance, DnrtVolume};
use crate::surface_bounds::SurfaceBounds;

/// A posed object under this frame's light whose grid is contracted where lightmap texels near
/// it read it (see the module doc).
#[derive(Clone, Debug)]
pub struct DnrtNear<'a> {
    instance: DnrtInstance<'a>,
    /// Per grid point: contracted.
    ready: Vec<bool>,
    /// Scratch: points marked by the current call.
    marked: Vec<u32>,
}

impl<'a> DnrtNear<'a> {
    /// As [`DnrtInstance::new`], contracting no point yet.
    pub fn new(
        volume: &'a DnrtVolume,
        translation: [f64; 3],
        rotation: [f64; 4],
        irradiance: [[f32; SH_COEFFS]; 3],
        hidden: [[f32; SH_COEFFS]; 3],
    ) -> DnrtNear<'a> {
        let instance =
            DnrtInstance::uncontracted(volume, translation, rotation, irradiance, hidden);
        DnrtNear {
            ready: vec![false; instance.n_points()],
            instance,
            marked: Vec::new(),
        }
    }

    /// The object's bounding-sphere centre in the world.
    pub fn centre_world(&self) -> [f32; 3] {
        self.instance.centre_world()
    }

    /// Grid points contracted so far.
    pub fn contracted_points(&self) -> usize {
        self.ready.iter().filter(|&&r| r).count()
    }

    /// [`DnrtInstance::apply_texels_near`]: adds the object's effect to the texels of `layout`
    /// on the surfaces within its reach (`bounds` made from `layout`, `ranges` scratch, left
    /// holding those surfaces' texel ranges), contracting first the grid points they read.
    pub fn apply_texels_near(
        &mut self,
        layout: &Layout,
        bounds: &SurfaceBounds,
        ranges: &mut Vec<Range<usize>>,
        out: &mut [[f32; 3]],
    ) -> Result<(), DnrtError> {
        let instance = &mut self.instance;
        instance.near_ranges(layout, bounds, ranges, out)?;
        let n = out.len();
        let res = instance.volume.grid.resolution as usize;
        self.marked.clear();
        for t in ranges.iter().flat_map(|r| r.start.min(n)..r.end.min(n)) {
            let Some(at) = instance.lookup(layout.positions[t], layout.normals[t]) else {
                continue;
            };
            let (i0, _) = instance.cell(at.local);
            for corner in 0..8usize {
                let (cx, cy, cz) = (corner & 1, corner >> 1 & 1, corner >> 2 & 1);
                let p = ((i0[2] + cz) * res + i0[1] + cy) * res + i0[0] + cx;
                if !std::mem::replace(&mut self.ready[p], true) {
                    self.marked.push(p as u32);
                }
            }
        }
        for &p in &self.marked {
            instance.contract_point(p as usize);
        }
        instance.apply_ranges(layout, ranges, out)
    }
}
