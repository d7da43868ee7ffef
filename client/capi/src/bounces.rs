//! The C names of the client's bounce modes ([`lightfarm_client::Bounces`]) and the setter
//! that picks one for a runtime.
//!
//! Invariants: the values are part of the ABI and never change; C passes a mode as `int32_t`,
//! so [`LfBounces::from_raw`] refuses unknown values instead of trusting them. A new runtime
//! sums all bounces (`LF_BOUNCES_CONVERGED` at the default tolerance), like the Rust client.

use lightfarm_client::{Bounces, DEFAULT_TOLERANCE};

use crate::status::CapiError;

/// How many bounces of indirect light `lf_runtime_apply` sums (passed as `int32_t`).
#[repr(i32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum LfBounces {
    /// The first bounce only (the papers' light).
    One = 0,
    /// Bounces until the last adds less than the tolerance times the light so far (default).
    Converged = 1,
    /// One application per call of the direct light plus the previous call's indirect light:
    /// all bounces for the cost of one once lights hold still (a moving light lags a few frames).
    /// Relighting by the change (`lf_runtime_apply_delta`, `lf_runtime_apply_delta_in_spans`):
    /// one bounce of the change and of the light not yet bounced where it matters, settling to
    /// all bounces within the tolerance (`lf_runtime_feedback_due` says when).
    Feedback = 2,
    /// All bounces to the tolerance like `Converged`, starting from the previous call's answer:
    /// one application a frame while lights hold still, a few while they move, as accurate as
    /// `Converged` either way.
    Warm = 3,
}

impl LfBounces {
    /// The mode C passed, or `CapiError::BadBounces`.
    pub fn from_raw(raw: i32) -> Result<LfBounces, CapiError> {
        [
            LfBounces::One,
            LfBounces::Converged,
            LfBounces::Feedback,
            LfBounces::Warm,
        ]
        .into_iter()
        .find(|m| *m as i32 == raw)
        .ok_or(CapiError::BadBounces(raw))
    }

    /// The client's mode and its tolerance (`Converged`'s and `Warm`'s, or for `Feedback` the
    /// one relighting by the change settles to, `Runtime::set_feedback_tolerance`; None for
    /// `One`, which ignores it): 0 means the default and anything outside `[0, 1)` (or NaN)
    /// is refused.
    pub fn bounces(self, tolerance: f32) -> Result<(Bounces, Option<f32>), CapiError> {
        let tolerance = match self {
            LfBounces::One => return Ok((Bounces::One, None)),
            _ if tolerance == 0.0 => DEFAULT_TOLERANCE,
            _ if tolerance > 0.0 && tolerance < 1.0 => tolerance,
            _ => return Err(CapiError::BadTolerance(tolerance)),
        };
        let bounces = match self {
            LfBounces::Warm => Bounces::Warm { tolerance },
            LfBounces::Feedback => Bounces::Feedback,
            _ => Bounces::Converged { tolerance },
        };
        Ok((bounces, Some(tolerance)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn modes_map_and_bad_values_are_refused() {
        assert_eq!(LfBounces::from_raw(0).unwrap(), LfBounces::One);
        assert_eq!(LfBounces::from_raw(2).unwrap(), LfBounces::Feedback);
        assert_eq!(LfBounces::from_raw(3).unwrap(), LfBounces::Warm);
        assert_eq!(
            LfBounces::Warm.bounces(0.0).unwrap().0,
            Bounces::Warm {
                tolerance: DEFAULT_TOLERANCE
            }
        );
        assert_eq!(
            LfBounces::Warm.bounces(0.01).unwrap().0,
            Bounces::Warm { tolerance: 0.01 }
        );
        assert_eq!(
            LfBounces::Feedback.bounces(0.0).unwrap(),
            (Bounces::Feedback, Some(DEFAULT_TOLERANCE))
        );
        assert_eq!(
            LfBounces::Feedback.bounces(0.01).unwrap(),
            (Bounces::Feedback, Some(0.01))
        );
        assert!(LfBounces::Feedback.bounces(2.0).is_err());
        assert!(LfBounces::Warm.bounces(1.5).is_err());
        assert!(matches!(
            LfBounces::from_raw(7),
            Err(CapiError::BadBounces(7))
        ));
        assert_eq!(
            LfBounces::Converged.bounces(0.0).unwrap().0,
            Bounces::default()
        );
        assert_eq!(
            LfBounces::Converged.bounces(0.01).unwrap().0,
            Bounces::Converged { tolerance: 0.01 }
        );
        for bad in [-0.1, 1.0, f32::NAN, f32::INFINITY] {
            assert!(LfBounces::Converged.bounces(bad).is_err(), "{bad}");
        }
        // The tolerance is ignored where it means nothing.
        assert_eq!(
            LfBounces::One.bounces(f32::NAN).unwrap(),
            (Bounces::One, None)
        );
    }
}
