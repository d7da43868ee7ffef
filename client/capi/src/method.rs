//! The C names of the client's methods ([`lightfarm_client::Method`]).
//!
//! Invariants: the values are part of the ABI and never change; C passes a method as
//! `int32_t` (a C enum may hold any value), so [`LfMethod::from_raw`] refuses unknown values
//! instead of trusting them.

use lightfarm_client::Method;

use crate::status::CapiError;

/// Which operator turns direct into indirect light (passed as `int32_t`).
#[repr(i32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum LfMethod {
    /// Modular radiance transfer: every bundle has it.
    Mrt = 0,
    /// MRT plus the clutter operators; needs `lf_runtime_has_drt`.
    Drt = 1,
    /// The dense one-bounce operator; needs `lf_runtime_has_full`.
    Full = 2,
}

impl LfMethod {
    /// The method C passed, or `CapiError::BadMethod`.
    pub fn from_raw(raw: i32) -> Result<LfMethod, CapiError> {
        [LfMethod::Mrt, LfMethod::Drt, LfMethod::Full]
            .into_iter()
            .find(|m| *m as i32 == raw)
            .ok_or(CapiError::BadMethod(raw))
    }

    /// The client's method.
    pub fn method(self) -> Method {
        match self {
            LfMethod::Mrt => Method::Mrt,
            LfMethod::Drt => Method::Drt,
            LfMethod::Full => Method::Full,
        }
    }
}
