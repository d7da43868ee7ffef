//! Status codes of the C ABI and the errors behind them.
//!
//! Invariants: [`LfStatus::Ok`] is 0 and every failure is negative, so C can test `< 0`; the
//! values are part of the ABI and never change meaning (new codes get new numbers). Every
//! [`CapiError`] maps to exactly one failure code through [`CapiError::status`], and its
//! `Display` text is what [`crate::lf_last_error`] hands to C.

use lightfarm_client::{ApplyError, BundleError, ObjectLightError};

/// What an `lf_*` call returned (as `int32_t`).
#[repr(i32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum LfStatus {
    /// Success.
    Ok = 0,
    /// A required pointer argument was NULL.
    NullPointer = -1,
    /// A buffer length (in elements) is not its per-texel count times the texels (`3 x texels`
    /// floats for an RGB vector), or a capacity is below what is to be written
    /// (`lf_runtime_light_reach`).
    BadLength = -2,
    /// The method is not one of `LfMethod`.
    BadMethod = -3,
    /// The bundle lacks the operators of the requested method (DRT without clutter, FULL
    /// without `--full`), its probe volume, or a DNRT grid for a placed dynamic object.
    MissingOperator = -4,
    /// A light has a non-finite position or a negative or non-finite intensity.
    InvalidLight = -5,
    /// The bytes are not a usable bundle.
    BadBundle = -6,
    /// An internal panic was caught at the boundary (a bug in lightfarm).
    Panic = -7,
    /// The bounce mode is not one of `LfBounces`, or its tolerance is outside `[0, 1)`.
    BadBounces = -8,
    /// The bounces did not converge (albedo near 1 in a closed room) or produced a non-finite
    /// value; the output was not written (`lf_last_error` says which).
    NotConverging = -9,
    /// An index is not below its count (`lf_runtime_surface` past `lf_runtime_surface_count`),
    /// or a texel span is not a range of the layout's texels.
    BadIndex = -10,
    /// A pose names no dynamic object of the bundle (or its id is NULL or not UTF-8), or has a
    /// non-finite translation or rotation (`lf_runtime_set_poses`).
    InvalidPose = -11,
}

/// Why an `lf_*` call failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CapiError {
    #[error("{0} is NULL")]
    NullPointer(&'static str),
    #[error("{what} holds {got} {unit} but this bundle needs {expected} ({per_texel} per texel)")]
    BadLength {
        what: &'static str,
        /// What the buffer holds: `floats` or `integers`.
        unit: &'static str,
        per_texel: usize,
        expected: usize,
        got: usize,
    },
    #[error("{what} holds {got} but {needed} are needed")]
    TooFew {
        what: &'static str,
        needed: usize,
        got: usize,
    },
    #[error("spans[{index}] = [{start}, {end}) is not a range of this bundle's {texels} texels")]
    BadSpan {
        index: usize,
        start: usize,
        end: usize,
        texels: usize,
    },
    #[error("{what} index {index} is out of range: this bundle has {count} {what}s")]
    BadIndex {
        what: &'static str,
        index: usize,
        count: usize,
    },
    #[error("unknown method {0}: use LF_METHOD_MRT, LF_METHOD_DRT or LF_METHOD_FULL")]
    BadMethod(i32),
    #[error(
        "unknown bounce mode {0}: use LF_BOUNCES_ONE, LF_BOUNCES_CONVERGED or LF_BOUNCES_FEEDBACK"
    )]
    BadBounces(i32),
    #[error("tolerance {0}: LF_BOUNCES_CONVERGED takes 0 (the default) or a value in (0, 1)")]
    BadTolerance(f32),
    /// A call that cannot run in the chosen bounce mode (`lf_runtime_apply_delta` with
    /// `LF_BOUNCES_FEEDBACK`).
    #[error(transparent)]
    BounceMode(ApplyError),
    #[error(transparent)]
    NotConverging(ApplyError),
    #[error(transparent)]
    MissingOperator(ApplyError),
    /// A placed dynamic object without its DNRT grid (`lf_runtime_object_light`).
    #[error(transparent)]
    ObjectLight(ObjectLightError),
    #[error("lights[{index}]: {reason}")]
    InvalidLight { index: usize, reason: &'static str },
    #[error("poses[{index}]: {reason}")]
    InvalidPose { index: usize, reason: String },
    #[error("cannot load bundle: {0}")]
    BadBundle(#[from] BundleError),
    #[error("internal panic: {0}")]
    Panic(String),
}

impl CapiError {
    /// The (negative) code C sees for this error.
    pub fn status(&self) -> LfStatus {
        match self {
            CapiError::NullPointer(_) => LfStatus::NullPointer,
            CapiError::BadLength { .. } | CapiError::TooFew { .. } => LfStatus::BadLength,
            CapiError::BadIndex { .. } | CapiError::BadSpan { .. } => LfStatus::BadIndex,
            CapiError::BadMethod(_) => LfStatus::BadMethod,
            CapiError::BadBounces(_) | CapiError::BadTolerance(_) | CapiError::BounceMode(_) => {
                LfStatus::BadBounces
            }
            CapiError::NotConverging(_) => LfStatus::NotConverging,
            CapiError::MissingOperator(_) | CapiError::ObjectLight(_) => LfStatus::MissingOperator,
            CapiError::InvalidLight { .. } => LfStatus::InvalidLight,
            CapiError::InvalidPose { .. } => LfStatus::InvalidPose,
            CapiError::BadBundle(_) => LfStatus::BadBundle,
            CapiError::Panic(_) => LfStatus::Panic,
        }
    }
}

impl From<ApplyError> for CapiError {
    /// `DirectLength` cannot reach here (lengths are checked before `apply`), but is mapped
    /// to `CapiError::BadLength` all the same; nor can `NoBounces` (C cannot ask for zero
    /// bounces), which falls to `MissingOperator`. `ProbeFieldSize` (a change added before
    /// `lf_runtime_apply_probes` filled the field) is `TooFew` (`probes::not_filled`).
    fn from(e: ApplyError) -> CapiError {
        match e {
            ApplyError::DirectLength { expected, got } => CapiError::BadLength {
                what: "direct light",
                unit: "floats",
                per_texel: 3,
                expected: 3 * expected,
                got: 3 * got,
            },
            e @ (ApplyError::NotConverging { .. } | ApplyError::NonFinite { .. }) => {
                CapiError::NotConverging(e)
            }
            ApplyError::BadTolerance(t) => CapiError::BadTolerance(t),
            e @ ApplyError::DeltaFeedback => CapiError::BounceMode(e),
            ApplyError::ProbeFieldSize { expected, got } => {
                crate::probes::not_filled(expected, got)
            }
            other => CapiError::MissingOperator(other),
        }
    }
}

impl From<ObjectLightError> for CapiError {
    /// A field not filled yet is `TooFew` (`probes::not_filled`), a bundle without a probe
    /// volume `MissingOperator` as for the probe calls; the rest (no grid for a placed object)
    /// `ObjectLight`.
    fn from(e: ObjectLightError) -> CapiError {
        match e {
            ObjectLightError::FieldSize { expected, got } => {
                crate::probes::not_filled(expected, got)
            }
            ObjectLightError::NoProbeVolume => CapiError::from(ApplyError::MissingProbes),
            other => CapiError::ObjectLight(other),
        }
    }
}
