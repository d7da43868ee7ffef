//! The scene as the bake engine sees it: lit surfaces divided into texels, and the primitives
//! rays can hit (axis-aligned rectangles for block walls and clutter boxes, triangles for meshes).
//!
//! Frames and units: world coordinates in metres. A block face's lit side faces into the block;
//! a clutter box face's lit side faces out of the box; a mesh triangle's lit side is its
//! counter-clockwise side (the outside of a closed glTF or OBJ mesh). Texel `(i, j)` of a `T×T`
//! face is global texel `surface.texel_offset + j*T + i`, `i` along the face's first tangent
//! axis (see `lightfarm_proto::Face`). Global texel order: blocks in scene order (closed faces
//! in canonical order), then clutter objects in scene order — a box's six faces, or a mesh's
//! lightmap atlas texels in row-major atlas order ([`crate::bake::scene::mesh_atlas`]).
//!
//! Invariant: `texels[k].surface` indexes `surfaces`; every rectangle primitive with a
//! `surface` maps hit points back to that surface's texels with [`Geometry::texel_at`], and
//! every mesh-clutter triangle (`lightmap: Some`) to its atlas's texels with
//! [`Geometry::mesh_texel_at`]. A mesh surface (owner [`SurfaceOwner::ClutterMesh`]) is not a
//! rectangle: its rectangle fields are zero and `t` is 0; its texels are `n_texels` from
//! `texel_offset`.

use std::ops::Range;
use std::path::Path;

use lightfarm_proto::scene::{Aabb, Block, Scene, Transform};
use lightfarm_proto::Face;

use crate::bake::scene::mesh::{self, MeshError, TriangleMesh};
use crate::bake::scene::mesh_atlas::{closed_pieces, AtlasError, MeshAtlas};
use crate::bake::scene::pieces::baked_scene;

/// Who owns a lit surface.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SurfaceOwner {
    Block {
        block: usize,
        face: Face,
    },
    ClutterBox {
        clutter: usize,
        face: Face,
    },
    /// A mesh clutter object's lightmap atlas (`Geometry::mesh_atlases[atlas]`).
    ClutterMesh {
        clutter: usize,
        atlas: usize,
    },
}

/// An axis-aligned lit rectangle divided into `t × t` texels.
#[derive(Clone, Debug)]
pub struct Surface {
    /// `block:<id>/<face>` or `clutter:<id>`.
    pub name: String,
    pub owner: SurfaceOwner,
    pub axis: usize,
    pub coord: f64,
    pub min: [f64; 2],
    pub max: [f64; 2],
    /// The lit side's normal is `normal_sign · e_axis`.
    pub normal_sign: f64,
    pub t: usize,
    pub texel_offset: usize,
    /// Texels of the surface (`t²` for a rectangle).
    pub n_texels: usize,
    /// Index (in RESULT.json) of this surface's first texel within its name.
    pub index_offset: u32,
    pub albedo: [f64; 3],
}

impl Surface {
    pub fn normal(&self) -> [f64; 3] {
        let mut n = [0.0; 3];
        n[self.axis] = self.normal_sign;
        n
    }
    pub fn tangent_axes(&self) -> (usize, usize) {
        lightfarm_proto::face::tangent_axes(self.axis)
    }
    /// Centre of texel `(i, j)`.
    pub fn texel_center(&self, i: usize, j: usize) -> [f64; 3] {
        let (u, v) = self.tangent_axes();
        let mut p = [0.0; 3];
        p[self.axis] = self.coord;
        p[u] = self.min[0] + (i as f64 + 0.5) / self.t as f64 * (self.max[0] - self.min[0]);
        p[v] = self.min[1] + (j as f64 + 0.5) / self.t as f64 * (self.max[1] - self.min[1]);
        p
    }
    /// Area of one texel.
    pub fn texel_area(&self) -> f64 {
        (self.max[0] - self.min[0]) * (self.max[1] - self.min[1]) / (self.t * self.t) as f64
    }
    /// Local texel index of a point on the surface (clamped to the surface).
    pub fn local_texel(&self, p: [f64; 3]) -> usize {
        let (u, v) = self.tangent_axes();
        let cell = |x: f64, lo: f64, hi: f64| {
            (((x - lo) / (hi - lo) * self.t as f64).floor().max(0.0) as usize).min(self.t - 1)
        };
        cell(p[v], self.min[1], self.max[1]) * self.t + cell(p[u], self.min[0], self.max[0])
    }
}

/// One lightmap texel.
#[derive(Clone, Copy, Debug)]
pub struct Texel {
    pub position: [f64; 3],
    pub normal: [f64; 3],
    pub albedo: [f64; 3],
    pub surface: u32,
    pub index: u32,
}

/// Something a ray can hit.
#[derive(Clone, Copy, Debug)]
pub enum Primitive {
    /// Two-sided axis-aligned rectangle; `surface` is its lit side (if lightmapped).
    Rect {
        axis: usize,
        coord: f64,
        min: [f64; 2],
        max: [f64; 2],
        surface: Option<u32>,
        albedo: [f64; 3],
    },
    /// Two-sided triangle; `lightmap` when it belongs to mesh clutter with texels.
    Triangle {
        v: [[f64; 3]; 3],
        albedo: [f64; 3],
        lightmap: Option<MeshTriangle>,
    },
}

/// A mesh-clutter triangle's place in its lightmap atlas.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MeshTriangle {
    /// Index into [`Geometry::mesh_atlases`].
    pub atlas: u32,
    /// The triangle's index in that mesh.
    pub triangle: u32,
    /// The triangle is part of a closed piece (outward-wound): a ray reaching its back side
    /// is inside the mesh.
    pub closed: bool,
}

/// Surfaces, texels and primitives of a scene (or of a lone shape).
#[derive(Clone, Debug, Default)]
pub struct Geometry {
    pub surfaces: Vec<Surface>,
    pub texels: Vec<Texel>,
    pub primitives: Vec<Primitive>,
    /// Global texel range of each block (empty for blocks with every face open).
    pub block_texels: Vec<Range<usize>>,
    /// Global texel range of each clutter object.
    pub clutter_texels: Vec<Range<usize>>,
    /// Bounds and content fingerprint of each clutter object, in scene order.
    pub clutter_shapes: Vec<ClutterShape>,
    /// Lightmap atlases of mesh clutter, in scene order, with the surface each belongs to.
    pub mesh_atlases: Vec<(MeshAtlas, u32)>,
}

/// Where a clutter object is and what it is, for telling which objects changed between bakes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClutterShape {
    /// World-space bounds `[min, max]` of the box or of every triangle of the mesh.
    pub bounds: [[f64; 3]; 2],
    /// blake3 of the geometry rays can hit (box corners or every triangle) and its texels
    /// (count for a box; every texel's atlas cell and position for a mesh).
    pub fingerprint: [u8; 32],
}

impl ClutterShape {
    fn of_box(aabb: &Aabb, t: usize) -> ClutterShape {
        let mut h = blake3::Hasher::new();
        h.update(b"box");
        for x in aabb.min.iter().chain(&aabb.max) {
            h.update(&x.to_bits().to_le_bytes());
        }
        h.update(&(t as u64).to_le_bytes());
        ClutterShape {
            bounds: [aabb.min, aabb.max],
            fingerprint: *h.finalize().as_bytes(),
        }
    }

    fn of_triangles(triangles: &[[[f64; 3]; 3]], atlas: &MeshAtlas) -> ClutterShape {
        let mut h = blake3::Hasher::new();
        h.update(b"mesh");
        let bounds = triangle_bounds(triangles);
        for v in triangles.iter().flatten() {
            for x in v {
                h.update(&x.to_bits().to_le_bytes());
            }
        }
        h.update(&(atlas.texels.len() as u64).to_le_bytes());
        for t in &atlas.texels {
            h.update(&t.x.to_le_bytes());
            h.update(&t.y.to_le_bytes());
            for x in t.position {
                h.update(&x.to_bits().to_le_bytes());
            }
        }
        ClutterShape {
            bounds,
            fingerprint: *h.finalize().as_bytes(),
        }
    }
}

/// World bounds `[min, max]` of triangles.
pub fn triangle_bounds(triangles: &[[[f64; 3]; 3]]) -> [[f64; 3]; 2] {
    let mut bounds = [[f64::INFINITY; 3], [f64::NEG_INFINITY; 3]];
    for v in triangles.iter().flatten() {
        for k in 0..3 {
            bounds[0][k] = bounds[0][k].min(v[k]);
            bounds[1][k] = bounds[1][k].max(v[k]);
        }
    }
    bounds
}

/// Why a scene's geometry could not be built.
#[derive(Debug, thiserror::Error)]
pub enum GeometryError {
    #[error(transparent)]
    Mesh(#[from] MeshError),
    #[error(transparent)]
    Atlas(#[from] AtlasError),
}

impl Geometry {
    /// Adds an axis-aligned lit rectangle with `t × t` texels.
    #[allow(clippy::too_many_arguments)]
    pub fn add_surface(
        &mut self,
        name: String,
        owner: SurfaceOwner,
        rect: ([f64; 2], [f64; 2], f64),
        axis: usize,
        normal_sign: f64,
        t: usize,
        index_offset: u32,
        albedo: [f64; 3],
    ) {
        let surface_index = self.surfaces.len() as u32;
        let surface = Surface {
            name,
            owner,
            axis,
            coord: rect.2,
            min: rect.0,
            max: rect.1,
            normal_sign,
            t,
            texel_offset: self.texels.len(),
            n_texels: t * t,
            index_offset,
            albedo,
        };
        for j in 0..t {
            for i in 0..t {
                self.texels.push(Texel {
                    position: surface.texel_center(i, j),
                    normal: surface.normal(),
                    albedo,
                    surface: surface_index,
                    index: index_offset + (j * t + i) as u32,
                });
            }
        }
        self.primitives.push(Primitive::Rect {
            axis,
            coord: rect.2,
            min: rect.0,
            max: rect.1,
            surface: Some(surface_index),
            albedo,
        });
        self.surfaces.push(surface);
    }

    /// Adds the closed faces of a block (lit from inside).
    pub fn add_block(
        &mut self,
        block: usize,
        id: &str,
        aabb: &Aabb,
        closed: &[Face],
        albedo: impl Fn(Face) -> [f64; 3],
        t: usize,
    ) -> Range<usize> {
        self.add_block_faces(block, id, aabb, closed, albedo, t, |_| 0)
    }

    /// Adds scene block `b` ([`Geometry::add_block`]); a piece of a long block
    /// ([`crate::bake::scene::pieces`]) takes its block's surface names, its texel indices
    /// following on from the pieces before it on each face.
    pub fn add_scene_block(&mut self, b: usize, block: &Block, t: usize) -> Range<usize> {
        let (id, piece) = match &block.piece {
            Some(piece) => (piece.of.as_str(), Some(piece)),
            None => (block.id.as_str(), None),
        };
        self.add_block_faces(
            b,
            id,
            &block.aabb(),
            &block.closed_faces(),
            |f| block.face_albedo(f),
            t,
            |f| piece.map_or(0, |p| p.index_on_face(f) * (t * t) as u32),
        )
    }

    #[allow(clippy::too_many_arguments)]
    fn add_block_faces(
        &mut self,
        block: usize,
        id: &str,
        aabb: &Aabb,
        closed: &[Face],
        albedo: impl Fn(Face) -> [f64; 3],
        t: usize,
        index_offset: impl Fn(Face) -> u32,
    ) -> Range<usize> {
        let start = self.texels.len();
        for face in closed {
            let normal_sign = if face.is_max_side() { -1.0 } else { 1.0 };
            self.add_surface(
                format!("block:{id}/{face}"),
                SurfaceOwner::Block { block, face: *face },
                aabb.face_rect(*face),
                face.axis(),
                normal_sign,
                t,
                index_offset(*face),
                albedo(*face),
            );
        }
        start..self.texels.len()
    }

    /// The blocks alone (what MRT transport sees); block texels come first in every geometry
    /// of a scene, so their indices agree with [`Geometry::from_scene`]. Long blocks are
    /// the pieces the bake cuts them into ([`baked_scene`], which leaves a scene it has cut
    /// as it is), so every caller sees the bake's texels.
    pub fn blocks_only(scene: &Scene) -> Geometry {
        let cut = baked_scene(scene);
        let scene = &cut;
        let t = scene.settings.texels_per_face as usize;
        let mut g = Geometry::default();
        for (b, block) in scene.blocks.iter().enumerate() {
            let range = g.add_scene_block(b, block, t);
            g.block_texels.push(range);
        }
        g
    }

    /// Builds the full scene: blocks, clutter (boxes with texels, meshes as triangles).
    pub fn from_scene(scene: &Scene, scene_dir: &Path) -> Result<Geometry, GeometryError> {
        let t = scene.settings.texels_per_face as usize;
        let mut g = Geometry::blocks_only(scene);
        for (c, clutter) in scene.clutter.iter().enumerate() {
            let start = g.texels.len();
            if let Some(aabb) = &clutter.box_ {
                g.clutter_shapes.push(ClutterShape::of_box(aabb, t));
                for face in Face::ALL {
                    let normal_sign = if face.is_max_side() { 1.0 } else { -1.0 };
                    let offset = (face.index() * t * t) as u32;
                    g.add_surface(
                        format!("clutter:{}", clutter.id),
                        SurfaceOwner::ClutterBox { clutter: c, face },
                        aabb.face_rect(face),
                        face.axis(),
                        normal_sign,
                        t,
                        offset,
                        clutter.albedo,
                    );
                }
            } else if let Some(path) = &clutter.mesh {
                let transform = clutter.transform.unwrap_or_default();
                let mut mesh = mesh::load_mesh(
                    &format!("clutter \"{}\"", clutter.id),
                    scene_dir,
                    path,
                    &transform,
                )?;
                // Closed pieces wound inside-out are turned outside-out.
                let (pieces, volumes) = closed_pieces(&mesh.triangles);
                for (k, (piece, closed)) in pieces.iter().enumerate() {
                    if *closed && volumes[*piece as usize] < 0.0 {
                        mesh.flip(k);
                    }
                }
                let closed: Vec<bool> = pieces.iter().map(|p| p.1).collect();
                let object = format!("clutter \"{}\"", clutter.id);
                // Resolution: a box of the mesh's size would get T texels along its longest
                // side (module doc of `mesh_atlas`).
                let bounds = triangle_bounds(&mesh.triangles);
                let extent = (0..3)
                    .map(|k| bounds[1][k] - bounds[0][k])
                    .fold(0.0, f64::max);
                let h = extent / t as f64;
                let uv = mesh.full_lightmap_uv();
                let atlas = MeshAtlas::build(&object, &mesh.triangles, uv.as_deref(), h)?;
                g.clutter_shapes
                    .push(ClutterShape::of_triangles(&mesh.triangles, &atlas));
                g.add_mesh_clutter(c, &clutter.id, &mesh, &closed, atlas, clutter.albedo);
            }
            g.clutter_texels.push(start..g.texels.len());
        }
        Ok(g)
    }

    /// Adds dynamic objects at the given poses (geometry only; each triangle's albedo is the
    /// mesh's own colour at its centroid where it has one, else the object's albedo).
    pub fn add_posed_dynamic(
        &mut self,
        scene: &Scene,
        scene_dir: &Path,
        poses: &[lightfarm_proto::lights::Pose],
    ) -> Result<(), GeometryError> {
        for pose in poses {
            let Some(object) = scene.dynamic.iter().find(|d| d.id == pose.id) else {
                continue;
            };
            let transform = Transform {
                translation: pose.translation,
                rotation: pose.rotation,
                scale: [1.0; 3],
            };
            let mesh = mesh::load_mesh(
                &format!("dynamic \"{}\"", object.id),
                scene_dir,
                &object.mesh,
                &transform,
            )?;
            // The mesh's own colours (vertex colours, base-colour texture) at each
            // triangle's centroid: the reference's triangles carry one albedo each.
            for (k, tri) in mesh.triangles.iter().enumerate() {
                let albedo = mesh.albedo.at(k, [1.0 / 3.0; 3], object.albedo);
                self.primitives.push(Primitive::Triangle {
                    v: *tri,
                    albedo,
                    lightmap: None,
                });
            }
        }
        Ok(())
    }

    /// Adds triangles without texels (occluders).
    pub fn add_triangles(&mut self, triangles: &[[[f64; 3]; 3]], albedo: [f64; 3]) {
        for tri in triangles {
            self.primitives.push(Primitive::Triangle {
                v: *tri,
                albedo,
                lightmap: None,
            });
        }
    }

    /// Adds mesh clutter `clutter` with its lightmap atlas (`closed`: per triangle, whether its
    /// piece is closed): one surface `clutter:<id>`, the atlas texels (albedo: the mesh's own colour at the texel, else `albedo`), and its
    /// triangles (albedo at the centroid, as the reference reads one per triangle).
    pub fn add_mesh_clutter(
        &mut self,
        clutter: usize,
        id: &str,
        mesh: &TriangleMesh,
        closed: &[bool],
        atlas: MeshAtlas,
        albedo: [f64; 3],
    ) {
        let surface = self.surfaces.len() as u32;
        let atlas_index = self.mesh_atlases.len();
        self.surfaces.push(Surface {
            name: format!("clutter:{id}"),
            owner: SurfaceOwner::ClutterMesh {
                clutter,
                atlas: atlas_index,
            },
            axis: 0,
            coord: 0.0,
            min: [0.0; 2],
            max: [0.0; 2],
            normal_sign: 1.0,
            t: 0,
            texel_offset: self.texels.len(),
            n_texels: atlas.texels.len(),
            index_offset: 0,
            albedo,
        });
        for (k, texel) in atlas.texels.iter().enumerate() {
            self.texels.push(Texel {
                position: texel.position,
                normal: texel.normal,
                albedo: mesh.albedo.at(texel.triangle as usize, texel.bary, albedo),
                surface,
                index: k as u32,
            });
        }
        for (k, tri) in mesh.triangles.iter().enumerate() {
            self.primitives.push(Primitive::Triangle {
                v: *tri,
                albedo: mesh.albedo.at(k, [1.0 / 3.0; 3], albedo),
                lightmap: Some(MeshTriangle {
                    atlas: atlas_index as u32,
                    triangle: k as u32,
                    closed: closed[k],
                }),
            });
        }
        self.mesh_atlases.push((atlas, surface));
    }

    /// The global texel a hit at `p` on a mesh-clutter triangle lands in.
    pub fn mesh_texel_at(&self, m: MeshTriangle, p: [f64; 3]) -> usize {
        let (atlas, surface) = &self.mesh_atlases[m.atlas as usize];
        self.surfaces[*surface as usize].texel_offset + atlas.texel_at(m.triangle as usize, p)
    }

    /// The global texel a hit on `surface` at point `p` lands in.
    pub fn texel_at(&self, surface: u32, p: [f64; 3]) -> usize {
        let s = &self.surfaces[surface as usize];
        s.texel_offset + s.local_texel(p)
    }

    /// Area of texel `x` (square metres): its surface's texel area.
    pub fn texel_area(&self, x: usize) -> f64 {
        self.surfaces[self.texels[x].surface as usize].texel_area()
    }

    /// Largest absolute coordinate (sets ray epsilons).
    pub fn scale(&self) -> f64 {
        let mut m: f64 = 1e-3;
        for p in &self.primitives {
            match p {
                Primitive::Rect {
                    coord, min, max, ..
                } => {
                    m = m
                        .max(coord.abs())
                        .max(min[0].abs())
                        .max(min[1].abs())
                        .max(max[0].abs())
                        .max(max[1].abs());
                }
                Primitive::Triangle { v, .. } => {
                    for x in v.iter().flatten() {
                        m = m.max(x.abs());
                    }
                }
            }
        }
        m
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn texel_centres_map_back_to_their_own_texels() {
        let mut g = Geometry::default();
        let aabb = Aabb {
            min: [0.0, 0.0, 0.0],
            max: [4.0, 3.0, 2.0],
        };
        g.add_block(0, "a", &aabb, &Face::ALL, |_| [0.5; 3], 5);
        assert_eq!(g.texels.len(), 6 * 25);
        for (k, t) in g.texels.iter().enumerate() {
            assert_eq!(g.texel_at(t.surface, t.position), k);
            // Lit side faces into the block.
            let centre = [2.0, 1.5, 1.0];
            let to_centre: f64 = (0..3)
                .map(|a| (centre[a] - t.position[a]) * t.normal[a])
                .sum();
            assert!(to_centre > 0.0);
        }
    }
}
