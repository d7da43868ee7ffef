//! The direct irradiance point lights give a small object at a point, as SH: what an engine's
//! light probe holds besides the probe field's bounced light, the input of DNRT (module
//! [`crate::dnrt`]) and of the service's evaluation of posed dynamic objects.
//!
//! Units: metres, world frame; intensities in W/sr, coefficients of irradiance (W/m²) over
//! normals in the `lightfarm_proto::sh` convention (9 per channel). Invariant: a light adds
//! nothing when the shadow ray from the point to it is occluded or it sits on the point; `r²`
//! is clamped as for texels ([`crate::direct`]).

use lightfarm_proto::lights::{Light, LightKind};
use lightfarm_proto::sh::{irradiance_weights, sh_basis, SH_COEFFS};

use crate::direct::R_MIN_REL;
use crate::occluders::Occluders;

/// SH coefficients (per channel, `E(n) = Σ c_j Y_j(n)`, 9 per channel) of the direct irradiance
/// the point lights give a small object at `position`: each visible light adds the clamped
/// cosine lobe `I/r² · (n·ω)₊` toward it, whose coefficients are `Â_l · I/r² · Y_lm(ω)`
/// (`lightfarm_proto::sh` convention). Visibility is a shadow ray from `position`; `r²` is
/// clamped as for texels. Added to the probe field's irradiance this is the full irradiance an
/// engine's light probe holds (the input of DNRT).
pub fn point_light_irradiance_sh(
    occluders: &Occluders,
    lights: &[Light],
    position: [f32; 3],
) -> [[f32; SH_COEFFS]; 3] {
    let occluded = |a, b| occluders.occluded(a, b);
    point_light_irradiance_sh_with(occluded, occluders.scale(), lights, position)
}

/// [`point_light_irradiance_sh`] with the shadow query `occluded(position, light)` of
/// occluders of scale `scale`.
pub(crate) fn point_light_irradiance_sh_with(
    occluded: impl Fn([f32; 3], [f32; 3]) -> bool,
    scale: f32,
    lights: &[Light],
    position: [f32; 3],
) -> [[f32; SH_COEFFS]; 3] {
    let mut out = [[0.0f64; SH_COEFFS]; 3];
    let min_r2 = (R_MIN_REL * scale as f64).powi(2);
    let a = irradiance_weights();
    for light in lights {
        let LightKind::Point = light.kind;
        let d: [f64; 3] = std::array::from_fn(|k| light.position[k] - position[k] as f64);
        let dist2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        if !(dist2 > 0.0 && dist2.is_finite()) {
            continue;
        }
        let target = light.position.map(|x| x as f32);
        if occluded(position, target) {
            continue;
        }
        let dist = dist2.sqrt();
        let y = sh_basis(d.map(|x| x / dist));
        let r2 = dist2.max(min_r2);
        for (c, o) in out.iter_mut().enumerate() {
            for k in 0..SH_COEFFS {
                o[k] += a[k] * light.intensity[c] / r2 * y[k];
            }
        }
    }
    out.map(|c| c.map(|x| x as f32))
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::point_light_irradiance_sh;
    use crate::direct::tests::{floor, light};
    use crate::occluders::Occluders;

    /// The SH of a point light's irradiance are the projection of `I/r² (n·ω)₊` over normals
    /// n (Funk–Hecke gives `Â_l Y_lm(ω)`), here checked by numerical projection; a shadowed
    /// light adds nothing.
    #[test]
    fn point_light_irradiance_sh_is_the_projected_clamped_cosine() {
        use lightfarm_proto::sh::sh_basis;
        let layout = floor(&[[1.0, 1.0, 0.0]]);
        let occluders = Occluders::from_layout(&layout);
        let p = [1.5f32, 2.0, 1.0];
        let l = light([2.5, 2.5, 3.0], [4.0, 2.0, 1.0]);
        let c = point_light_irradiance_sh(&occluders, std::slice::from_ref(&l), p);
        let d: [f64; 3] = std::array::from_fn(|k| l.position[k] - p[k] as f64);
        let r2 = d.iter().map(|x| x * x).sum::<f64>();
        let w = d.map(|x| x / r2.sqrt());
        let n_pts = 40000;
        let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
        let mut proj = [0.0f64; 9];
        for i in 0..n_pts {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n_pts as f64;
            let s = (1.0 - z * z).sqrt();
            let phi = golden * i as f64;
            let n = [s * phi.cos(), s * phi.sin(), z];
            let e = (n[0] * w[0] + n[1] * w[1] + n[2] * w[2]).max(0.0) / r2;
            let y = sh_basis(n);
            for k in 0..9 {
                proj[k] += e * y[k] * 4.0 * std::f64::consts::PI / n_pts as f64;
            }
        }
        for ch in 0..3 {
            for k in 0..9 {
                let want = proj[k] * l.intensity[ch];
                assert!(
                    (c[ch][k] as f64 - want).abs() < 2e-3 * l.intensity[ch] / r2,
                    "{ch} {k}: {} vs {want}",
                    c[ch][k]
                );
            }
        }
        // Below the floor the light is hidden by it.
        let hidden = point_light_irradiance_sh(&occluders, &[l], [1.5, 2.0, -1.0]);
        assert_eq!(hidden, [[0.0; 9]; 3]);
    }
}
