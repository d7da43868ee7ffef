//! The lightfarm thin client: decode an operator bundle, compute direct light from point lights
//! with shadow rays, and turn it into indirect light every frame.
//!
//! Typical frame loop:
//!
//! ```no_run
//! # fn frame(bytes: &[u8], lights: &[lightfarm_proto::lights::Light]) -> Result<(), Box<dyn std::error::Error>> {
//! use lightfarm_client::{decode, direct_from_point_lights, irradiance_at, IndirectLight, Method,
//!     Occluders, ProbeField, Runtime};
//! let bundle = decode(bytes)?;
//! let occluders = Occluders::from_layout(&bundle.layout);
//! let direct = direct_from_point_lights(&bundle.layout, &occluders, lights);
//! let mut runtime = Runtime::new(bundle);
//! let mut indirect = IndirectLight::default();
//! runtime.apply(Method::Mrt, &direct, &mut indirect)?;
//! // Dynamic objects: irradiance at any point and normal from the probe volume.
//! let mut field = ProbeField::default();
//! if runtime.has_probes() {
//!     runtime.apply_probes(&direct, &mut field)?;
//!     let volume = runtime.probe_volume().expect("has_probes");
//!     let _rgb = irradiance_at(volume, &field, [1.0, 0.5, 2.0], [0.0, 1.0, 0.0]);
//! }
//! # Ok(()) }
//! ```
//!
//! # Layout
//! - [`occluders`]: a BVH over the bundle's occluder rects and triangles; shadow-ray queries.
//! - [`direct`]: direct radiance from point lights at every texel (`ρ/π · I · cosθ / r² · V`).
//! - [`runtime`]: the per-frame, allocation-free application of the bundle's operators
//!   ([`Method::Mrt`] block operators and transport, [`Method::Drt`] MRT plus the clutter
//!   deltas of the bundle's DRT section, or the dense [`Method::Full`] operator), and
//!   [`Runtime::apply_probes`], the SH radiance of the bundle's probe volume.
//! - [`dnrt`]: Deferred Neighbouring Radiance Transfer: a dynamic object's reflection and
//!   occlusion on the receivers around it (G-buffer or lightmap texels), from its baked grid.
//! - [`probes`]: the probe field ([`ProbeField`]: n_probes × 3 channels × 9 SH coefficients)
//!   and [`irradiance_at`], trilinear probe interpolation and irradiance for any point and
//!   normal (dynamic objects, clutter).
//!
//! Invariants: this crate depends only on `lightfarm-proto` and `thiserror` (and `rayon` behind
//! the optional `rayon` feature); it does no I/O;
//! every per-texel vector is in layout order with one RGB value per layout texel; operators are
//! albedo-free and the receiving texel's albedo is multiplied in last.

pub mod direct;
pub mod dnrt;
pub mod occluders;
pub mod probes;
pub mod runtime;

pub use direct::{
    direct_from_point_lights, direct_from_point_lights_averaged, point_light_irradiance_sh,
    DirectLight,
};
pub use dnrt::{DnrtError, DnrtInstance, DnrtVolume};
pub use lightfarm_proto::bundle::{Bundle, BundleError};
pub use lightfarm_proto::lights::Light;
pub use occluders::Occluders;
pub use probes::{irradiance_at, irradiance_sh_at, ProbeField};
pub use runtime::{ApplyError, IndirectLight, Method, Runtime};

/// Decodes and validates a bundle (`Bundle::decode`): `Ok` only for a bundle [`Runtime::new`]
/// accepts; never panics.
pub fn decode(bytes: &[u8]) -> Result<Bundle, BundleError> {
    Bundle::decode(bytes)
}
