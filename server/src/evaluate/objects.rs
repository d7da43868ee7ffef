//! The light leaving posed dynamic objects' own surfaces, for drawing them (the glTF export and
//! the dashboard's preview): per triangle corner, `ρ/π · E`, with `E` the point lights'
//! irradiance at the corner (shadow rays against the level and the posed objects) plus the
//! probe volume's irradiance there (the light the walls send, as an engine shades a moving
//! object from its light probes), `ρ` the object's albedo (bundle section `dynamic shapes`).
//!
//! The point lights' part is the texels' rule (`lightfarm_client::point_irradiance`: the same
//! `r²` clamp, so a light on an object's surface gives a finite value).
//!
//! Frames and units: world frame, metres; outgoing radiance W/(sr·m²) per RGB channel. A
//! corner is shaded with its triangle's normal (flat, from the winding; the export draws the
//! triangle from both sides).

use lightfarm_client::{
    irradiance_at, point_irradiance, posed_triangles, Bundle, Occluders, ProbeField,
};
use lightfarm_proto::glam::DVec3;
use lightfarm_proto::lights::LightSet;

/// One posed object and the radiance leaving each corner of its triangles.
#[derive(Clone, Debug, PartialEq)]
pub struct ShadedObject {
    /// The scene's dynamic-object id.
    pub id: String,
    /// World-frame triangles at this frame's pose.
    pub triangles: Vec<[[f32; 3]; 3]>,
    /// Per triangle corner (three per triangle, in order), outgoing radiance from the point
    /// lights.
    pub direct: Vec<[f32; 3]>,
    /// The same from the probe volume's irradiance (the light the surfaces around it send).
    pub indirect: Vec<[f32; 3]>,
}

/// Every posed object with a shape in the bundle, shaded under `lights`; `field` is the probe
/// volume fed the radiance leaving the texels (as for DNRT; `None`: no light from the probes),
/// `shadows` the level's occluders with the posed objects in them, `scale` the texels' `r²`
/// clamp ([`lightfarm_client::direct_scale`] of the level).
pub fn shade_objects(
    bundle: &Bundle,
    field: Option<&ProbeField>,
    shadows: &Occluders,
    lights: &LightSet,
    scale: f64,
) -> Vec<ShadedObject> {
    let probes = bundle.probes.as_ref().zip(field);
    let mut out = Vec::new();
    for pose in &lights.poses {
        let Some(shape) = bundle.dynamic_shapes.iter().find(|s| s.object == pose.id) else {
            continue;
        };
        let triangles = posed_triangles(shape, pose);
        let rho = shape.albedo.map(|a| a as f64 * std::f64::consts::FRAC_1_PI);
        // Each corner with its triangle's normal (flat).
        let corners: Vec<([f32; 3], [f32; 3])> = triangles
            .iter()
            .flat_map(|tri| {
                let [a, b, c] = tri.map(|v| DVec3::from_array(v.map(f64::from)));
                let n = (b - a)
                    .cross(c - a)
                    .normalize_or_zero()
                    .as_vec3()
                    .to_array();
                tri.map(|p| (p, n))
            })
            .collect();
        let irradiance = point_irradiance(shadows, &lights.lights, scale, corners.iter().copied());
        let direct = irradiance
            .iter()
            .map(|e| [0, 1, 2].map(|k| (rho[k] * e[k]) as f32))
            .collect();
        let indirect = corners
            .iter()
            .map(|&(p, n)| {
                let walls = probes.map_or([0.0; 3], |(volume, field)| {
                    irradiance_at(volume, field, p, n)
                });
                [0, 1, 2].map(|k| (rho[k] * walls[k] as f64) as f32)
            })
            .collect();
        out.push(ShadedObject {
            id: pose.id.clone(),
            triangles,
            direct,
            indirect,
        });
    }
    out
}
