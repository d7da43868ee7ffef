//! The lightfarm thin client: decode an operator bundle, compute direct light from point lights
//! with shadow rays, and turn it into indirect light every frame.
//!
//! Typical frame loop:
//!
//! ```no_run
//! # fn frame(bytes: &[u8], lights: &[lightfarm_proto::lights::Light],
//! #     poses: &[lightfarm_proto::lights::Pose]) -> Result<(), Box<dyn std::error::Error>> {
//! use lightfarm_client::{decode, direct_from_point_lights_by_reach, irradiance_at, Bounces,
//!     DirectLight, IndirectLight, Method, ObjectLight, Occluders, ProbeField, Runtime};
//! let bundle = decode(bytes)?;
//! let occluders = Occluders::from_layout(&bundle.layout);
//! // Texel averages, shadows from 4 × 4 samples (what `eval` feeds the operators), each light traced
//! // only on the texels it reaches.
//! let direct = direct_from_point_lights_by_reach(&bundle, &occluders, lights, 4);
//! let mut runtime = Runtime::new(bundle);
//! let mut indirect = IndirectLight::default();
//! // All bounces (the default Converged mode); `Bounces::Warm` (Converged from the previous
//! // frame's answer) and `Bounces::Feedback` cost one application a frame while lights hold
//! // still.
//! runtime.apply(Method::Mrt, Bounces::default(), &direct, &mut indirect)?;
//! // Dynamic objects: the probe volume, fed the light leaving the texels (direct plus
//! // indirect at all bounces; the direct light alone at one), gives irradiance at any point
//! // and normal.
//! let mut field = ProbeField::default();
//! if runtime.has_probes() {
//!     let leaving = DirectLight {
//!         radiance: (direct.radiance.iter().zip(&indirect.radiance))
//!             .map(|(d, i)| [d[0] + i[0], d[1] + i[1], d[2] + i[2]])
//!             .collect(),
//!     };
//!     runtime.apply_probes(&leaving, &mut field)?;
//!     let volume = runtime.probe_volume().expect("has_probes");
//!     let _rgb = irradiance_at(volume, &field, [1.0, 0.5, 2.0], [0.0, 1.0, 0.0]);
//!     // Their light on the lightmap around them (DNRT; made once at load, `true`: the field
//!     // holds bounced light), added to the indirect light with its bounces.
//!     let mut objects = ObjectLight::new(runtime.bundle())?;
//!     objects.update(runtime.bundle(), &field, true, &occluders, lights, poses)?;
//!     objects.bounce(&mut runtime, Method::Mrt, Bounces::default(), &mut indirect)?;
//!     let _with_objects = objects.light();
//! }
//! # Ok(()) }
//! ```
//!
//! # Layout
//! - [`occluders`] (a folder: `mod.rs` the queries, `tree.rs` the primitives and the BVH,
//!   `box_cross.rs` a primitive against a box's shadow segments, `tests.rs`): a BVH over the
//!   bundle's occluder rects and triangles; shadow-ray queries.
//! - [`light_buffer`]: one point light's shadow rays answered from a cube of direction cells
//!   listing the occluders nearest first (rebuilt per frame for a moving light; the same
//!   answers as the BVH).
//! - `box_shadows` (private): one light's shadows on a run of texels at once (seen whole,
//!   hidden whole, or the few occluders that may cross its segments), from a light buffer.
//! - [`light_reach`]: which texels a point light can reach, by a portal walk over the bundle's
//!   rooms (block boxes and openings), so one light's direct light is recomputed where it
//!   reaches only.
//! - [`reach_direct`]: one light's direct light on the texels it reaches, shadow rays traced
//!   against only the occluders of the rooms it reaches (exactly the level's answer there);
//!   every light's over a whole bundle the same way (`direct_from_point_lights_by_reach`).
//! - [`dynamic_shadows`]: posed dynamic objects' triangles added to the occluders, for their
//!   direct shadows ([`occluders_with_poses`]).
//! - [`shadow_change`]: [`ShadowChange`], the change of direct light when posed objects move,
//!   computed only on the texels whose shadow rays a moved object can cross, where it was or
//!   is, for the lights whose reach it stands in (what `Runtime::apply_delta_in` relights by).
//! - [`direct`]: direct radiance from point lights at every texel (`ρ/π · I · cosθ / r² · V`).
//! - `texel_samples` (private): a texel's sample points and each one's unshadowed term, the
//!   adaptive average's scratch and the exact mean near a light; what [`direct`] shadows and
//!   averages.
//! - [`light_sh`]: the direct irradiance point lights give an object at a point, as SH
//!   ([`point_light_irradiance_sh`], DNRT's light-probe input).
//! - [`runtime`]: the per-frame, allocation-free application of the bundle's operators
//!   ([`Method::Mrt`] block operators and transport, [`Method::Drt`] MRT plus the clutter
//!   deltas of the bundle's DRT section, or the dense [`Method::Full`] operator) over one,
//!   n or all bounces ([`Bounces`]; all bounces by restarted GMRES in `runtime/krylov.rs`), and
//!   [`Runtime::apply_probes`], the SH radiance of the bundle's probe volume, and
//!   [`Runtime::apply_sh`], per-texel SH incident radiance for normal-mapped surfaces
//!   ([`ShLight::shade`] at a perturbed normal).
//! - [`dnrt`]: Deferred Neighbouring Radiance Transfer: a dynamic object's reflection and
//!   occlusion on the receivers around it (G-buffer or lightmap texels, the latter on the
//!   surfaces within its reach only, [`DnrtNear`] contracting the grid only where they read
//!   it), from its baked grid.
//! - [`object_light`]: [`ObjectLight`], posed dynamic objects' light on the lightmap per frame
//!   (each object's DNRT on the surfaces within its reach, fed by the probe field and the
//!   point lights at its centre) and its bounces through the operators.
//! - [`surface_bounds`]: [`SurfaceBounds`], the box of each surface's texel centres: the
//!   surfaces within reach of a point.
//! - [`probes`]: the probe field ([`ProbeField`]: n_probes × 3 channels × 9 SH coefficients)
//!   and [`irradiance_at`], trilinear probe interpolation and irradiance for any point and
//!   normal (dynamic objects, clutter).
//! - [`packed`], [`packed_gather`]: operator matrices and the DRT exact gather in the form the
//!   per-frame kernels read (row panels, narrow indices, 8-bit where the bundle stored 8 bits).
//! - [`lightmap`]: per-texel radiance as an atlas image (8-bit sRGB for PNG, raw f16).
//! - [`compare`]: [`relative_l2`], [`relative_l1`], how far one per-texel lighting is from
//!   another.
//! - `fetch` (feature `fetch`, off by default; `fetch-tls` adds https): `BundleFetcher`, a
//!   blocking HTTP download of a bundle at level load with an on-disk cache (`If-None-Match`),
//!   resumed downloads (`Range`/`If-Range`) and [`decode`] before anything is cached.
//! - `service` (feature `fetch`): `ServiceClient`, the bake service's `/v1` API for editor
//!   plugins and CI (upload assets and scenes, submit and watch bakes, cancel).
//!
//! Invariants: without features this crate depends only on `lightfarm-proto`, `thiserror` and
//! `half` and does no I/O (feature `rayon` adds rayon for `Runtime::set_parallel`; `fetch`
//! adds `ureq`, `serde` and `serde_json`, and HTTP plus its cache directory are its only I/O); every per-texel vector is
//! in layout order with one RGB value per layout texel; operators are albedo-free and the
//! receiving texel's albedo is multiplied in last.

mod box_shadows;
pub mod compare;
pub mod direct;
pub mod dnrt;
pub mod dynamic_shadows;
#[cfg(feature = "fetch")]
pub mod fetch;
pub mod light_buffer;
pub mod light_reach;
pub mod light_sh;
pub mod lightmap;
pub mod object_light;
pub mod occluders;
pub mod packed;
pub mod packed_gather;
pub mod probes;
pub mod reach_direct;
pub mod runtime;
#[cfg(feature = "fetch")]
pub mod service;
pub mod shadow_change;
pub mod surface_bounds;
mod texel_samples;

pub use compare::{relative_l1, relative_l2};
pub use direct::{
    direct_from_point_lights, direct_from_point_lights_adaptive,
    direct_from_point_lights_adaptive_in, direct_from_point_lights_averaged, direct_scale,
    point_irradiance, DirectLight, TexelSpan,
};
pub use dnrt::{DnrtError, DnrtInstance, DnrtNear, DnrtVolume};
pub use dynamic_shadows::{
    frame_occluders, occluders_with_poses, posed_triangles, shadowing_poses, PosedObjects,
};
#[cfg(feature = "fetch")]
pub use fetch::{BundleFetcher, FetchError, Fetched};
pub use light_reach::LightReach;
pub use light_sh::point_light_irradiance_sh;
pub use lightfarm_proto::bundle::{Bundle, BundleError};
pub use lightfarm_proto::lights::Light;
pub use lightmap::{auto_exposure, Atlas};
pub use object_light::{ObjectLight, ObjectLightError};
pub use occluders::Occluders;
pub use probes::{irradiance_at, irradiance_sh_at, radiance_sh_at, ProbeField};
pub use reach_direct::{direct_from_point_lights_by_reach, every_sample_by_reach, ReachDirect};
pub use runtime::{
    merge_spans, Applied, ApplyError, Bounces, DeltaApplied, IndirectLight, Method, Runtime,
    ShLight, DEFAULT_TOLERANCE, MAX_BOUNCES,
};
#[cfg(feature = "fetch")]
pub use service::{ServiceClient, ServiceError};
pub use shadow_change::{ShadowChange, ShadowChangeError};
pub use surface_bounds::SurfaceBounds;

/// Decodes and validates a bundle (`Bundle::decode`): `Ok` only for a bundle [`Runtime::new`]
/// accepts; never panics.
pub fn decode(bytes: &[u8]) -> Result<Bundle, BundleError> {
    Bundle::decode(bytes)
}
