//! The dynamic objects' shapes (section kind 19, format 2.4): each dynamic object's triangles in
//! its own frame and its albedo, so that a client can pose them each frame, cast their direct
//! shadows and draw them (the glTF export). The
//! DNRT grids carry the light an object adds and takes from the light between surfaces; a point
//! light the object hides is direct light, which only the object's own geometry can shadow.
//!
//! Frames and units: the object frame the scene's mesh is authored in (the frame the DNRT grid
//! and a LIGHTS.json pose use: `x_world = R x_obj + t`), metres, f32.
//!
//! Invariants (checked by [`check`], which `Bundle::validate` runs): object ids are unique,
//! every vertex is finite and every albedo in `[0, 1]`.

use crate::wire::{Reader, Writer};

use super::BundleError;

/// One dynamic object's triangles in its own frame.
#[derive(Clone, Debug, PartialEq)]
pub struct DynamicShape {
    /// The scene's dynamic-object id (as in its DNRT grid and the poses).
    pub object: String,
    /// The scene's albedo of the object (linear RGB; a mesh's own colours are not kept).
    pub albedo: [f32; 3],
    pub triangles: Vec<[[f32; 3]; 3]>,
}

pub(super) fn write(w: &mut Writer, shapes: &[DynamicShape]) {
    w.u32(shapes.len() as u32);
    for s in shapes {
        w.str(&s.object);
        for a in s.albedo {
            w.f32(a);
        }
        let flat: Vec<f32> = s.triangles.iter().flatten().flatten().copied().collect();
        w.f32s(&flat);
    }
}

pub(super) fn read(r: &mut Reader) -> Result<Vec<DynamicShape>, BundleError> {
    let n = r.u32()? as usize;
    // An id's length and a list's length: at least 8 bytes per shape.
    let mut shapes = Vec::with_capacity(n.min(r.remaining() / 8));
    for k in 0..n {
        let object = r.str()?;
        let albedo = [r.f32()?, r.f32()?, r.f32()?];
        let flat = r.f32s()?;
        if flat.len() % 9 != 0 {
            return Err(BundleError::Invalid(format!(
                "dynamic shapes: shape {k} (\"{object}\") has {} values, not 9 per triangle",
                flat.len()
            )));
        }
        let triangles = flat
            .chunks_exact(9)
            .map(|c| [[c[0], c[1], c[2]], [c[3], c[4], c[5]], [c[6], c[7], c[8]]])
            .collect();
        shapes.push(DynamicShape {
            object,
            albedo,
            triangles,
        });
    }
    Ok(shapes)
}

/// Ids unique, vertices finite, albedo in `[0, 1]`.
pub(super) fn check(shapes: &[DynamicShape]) -> Result<(), String> {
    for (k, s) in shapes.iter().enumerate() {
        if shapes[..k].iter().any(|o| o.object == s.object) {
            return Err(format!(
                "dynamic shapes: two shapes for object \"{}\"",
                s.object
            ));
        }
        if !s
            .triangles
            .iter()
            .flatten()
            .flatten()
            .all(|x| x.is_finite())
        {
            return Err(format!(
                "dynamic shapes: object \"{}\" has a non-finite vertex",
                s.object
            ));
        }
        if !s.albedo.iter().all(|a| (0.0..=1.0).contains(a)) {
            return Err(format!(
                "dynamic shapes: object \"{}\" has albedo {:?} outside [0, 1]",
                s.object, s.albedo
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shapes() -> Vec<DynamicShape> {
        vec![
            DynamicShape {
                object: "ball".into(),
                albedo: [0.8, 0.1, 0.08],
                triangles: vec![[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.5]]; 3],
            },
            DynamicShape {
                object: "empty".into(),
                albedo: [0.5; 3],
                triangles: vec![],
            },
        ]
    }

    #[test]
    fn shapes_round_trip_and_truncations_are_errors() {
        let mut w = Writer::new();
        write(&mut w, &shapes());
        let mut r = Reader::new(&w.bytes);
        assert_eq!(read(&mut r).unwrap(), shapes());
        assert_eq!(r.remaining(), 0);
        for cut in 0..w.bytes.len() {
            assert!(
                read(&mut Reader::new(&w.bytes[..cut])).is_err(),
                "cut {cut}"
            );
        }
    }

    #[test]
    fn duplicate_ids_and_non_finite_vertices_are_refused() {
        assert!(check(&shapes()).is_ok());
        let mut twice = shapes();
        twice[1].object = "ball".into();
        assert!(check(&twice)
            .unwrap_err()
            .contains("two shapes for object \"ball\""));
        let mut nan = shapes();
        nan[0].triangles[1][2][0] = f32::NAN;
        assert!(check(&nan)
            .unwrap_err()
            .contains("\"ball\" has a non-finite"));
        let mut bright = shapes();
        bright[1].albedo[2] = 1.5;
        assert!(check(&bright).unwrap_err().contains("\"empty\" has albedo"));
        // A list whose length is not a multiple of 9 is refused on reading.
        let mut w = Writer::new();
        w.u32(1);
        w.str("odd");
        for _ in 0..3 {
            w.f32(0.5);
        }
        w.f32s(&[0.0; 10]);
        let err = read(&mut Reader::new(&w.bytes)).unwrap_err().to_string();
        assert!(err.contains("\"odd\") has 10 values"), "{err}");
    }
}
