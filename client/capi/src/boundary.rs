//! The FFI edge: every `extern "C"` entry point runs its body through one of these, so no
//! panic unwinds into C and every failure is recorded for [`crate::lf_last_error`].
//!
//! Invariants:
//! - [`status_call`] returns [`LfStatus::Ok`] (0) exactly when its body returned `Ok`; every
//!   error or caught panic gives a negative code and sets the thread's last error.
//! - [`pointer_call`] returns a non-NULL pointer exactly when its body returned `Ok`.
//! - [`slice`] / [`slice_mut`] never build a slice from a NULL pointer; a zero length gives
//!   an empty slice whatever the pointer.
//! - Bodies run under `AssertUnwindSafe`: after a caught panic an `LfRuntime` stays usable
//!   because the client runtime refills every scratch buffer it reads on each call.

use std::any::Any;
use std::panic::{catch_unwind, AssertUnwindSafe};

use crate::last_error::set_last_error;
use crate::status::{CapiError, LfStatus};

/// The text of a panic payload (`panic!` with a literal or a formatted message).
fn panic_message(payload: &(dyn Any + Send)) -> String {
    if let Some(s) = payload.downcast_ref::<&str>() {
        (*s).to_owned()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "unknown panic payload".to_owned()
    }
}

/// Runs `body`; an error or a caught panic is recorded as the thread's last error.
fn guarded<T>(
    function: &'static str,
    body: impl FnOnce() -> Result<T, CapiError>,
) -> Result<T, CapiError> {
    catch_unwind(AssertUnwindSafe(body))
        .unwrap_or_else(|payload| Err(CapiError::Panic(panic_message(payload.as_ref()))))
        .inspect_err(|e| set_last_error(&format!("{function}: {e}")))
}

/// For entry points that return an `LfStatus` as `int32_t`.
pub(crate) fn status_call(
    function: &'static str,
    body: impl FnOnce() -> Result<(), CapiError>,
) -> i32 {
    match guarded(function, body) {
        Ok(()) => LfStatus::Ok as i32,
        Err(e) => e.status() as i32,
    }
}

/// For entry points that return a pointer: NULL on error or panic.
pub(crate) fn pointer_call<T>(
    function: &'static str,
    body: impl FnOnce() -> Result<*mut T, CapiError>,
) -> *mut T {
    guarded(function, body).unwrap_or(std::ptr::null_mut())
}

/// For queries that cannot fail but must still not unwind: `fallback` on panic.
pub(crate) fn value_call<T>(function: &'static str, fallback: T, body: impl FnOnce() -> T) -> T {
    guarded(function, || Ok(body())).unwrap_or(fallback)
}

/// `len` values at `ptr` as a slice; `what` names the argument in the error.
///
/// # Safety
/// When `len > 0` and `ptr` is not NULL, `ptr` must point to `len` readable, initialised,
/// aligned values of `T` that nothing writes while the slice lives.
pub(crate) unsafe fn slice<'a, T>(
    ptr: *const T,
    len: usize,
    what: &'static str,
) -> Result<&'a [T], CapiError> {
    if len == 0 {
        Ok(&[])
    } else if ptr.is_null() {
        Err(CapiError::NullPointer(what))
    } else {
        // SAFETY: non-NULL, and the caller guarantees the rest.
        Ok(unsafe { std::slice::from_raw_parts(ptr, len) })
    }
}

/// `len` values at `ptr` as a mutable slice; `what` names the argument in the error.
///
/// # Safety
/// When `len > 0` and `ptr` is not NULL, `ptr` must point to `len` writable, aligned values of
/// `T` (any bit pattern valid) that nothing else reads or writes while the slice lives.
pub(crate) unsafe fn slice_mut<'a, T>(
    ptr: *mut T,
    len: usize,
    what: &'static str,
) -> Result<&'a mut [T], CapiError> {
    if len == 0 {
        Ok(&mut [])
    } else if ptr.is_null() {
        Err(CapiError::NullPointer(what))
    } else {
        // SAFETY: non-NULL, and the caller guarantees the rest.
        Ok(unsafe { std::slice::from_raw_parts_mut(ptr, len) })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lf_last_error;

    fn last_error() -> String {
        let mut buf = [0u8; 256];
        // SAFETY: 256 writable bytes.
        let needed = unsafe { lf_last_error(buf.as_mut_ptr().cast(), buf.len()) };
        assert!(needed <= buf.len());
        std::ffi::CStr::from_bytes_until_nul(&buf)
            .unwrap()
            .to_str()
            .unwrap()
            .to_owned()
    }

    #[test]
    fn a_panic_becomes_the_panic_status_and_a_message() {
        assert_eq!(status_call("lf_boom", || panic!("boom {}", 7)), -7);
        assert_eq!(last_error(), "lf_boom: internal panic: boom 7");
        let null: *mut u8 = pointer_call("lf_boom_ptr", || panic!("static boom"));
        assert!(null.is_null());
        assert_eq!(last_error(), "lf_boom_ptr: internal panic: static boom");
        assert_eq!(value_call("lf_boom_value", 42usize, || panic!()), 42);
        assert_eq!(
            last_error(),
            "lf_boom_value: internal panic: explicit panic"
        );
    }

    #[test]
    fn errors_map_to_their_status_and_success_keeps_the_last_error() {
        assert_eq!(
            status_call("lf_x", || Err(CapiError::NullPointer("rt"))),
            LfStatus::NullPointer as i32
        );
        assert_eq!(last_error(), "lf_x: rt is NULL");
        assert_eq!(status_call("lf_y", || Ok(())), 0);
        assert_eq!(
            last_error(),
            "lf_x: rt is NULL",
            "success leaves the message"
        );
        let p = pointer_call("lf_z", || Ok(Box::into_raw(Box::new(5u8))));
        // SAFETY: from Box::into_raw just above.
        assert_eq!(*unsafe { Box::from_raw(p) }, 5);
    }

    #[test]
    fn zero_lengths_give_empty_slices_and_null_is_refused() {
        // SAFETY: zero lengths and NULL pointers only.
        unsafe {
            assert!(slice::<f32>(std::ptr::null(), 0, "a").unwrap().is_empty());
            assert!(slice_mut::<f32>(std::ptr::null_mut(), 0, "b")
                .unwrap()
                .is_empty());
            assert_eq!(
                slice::<f32>(std::ptr::null(), 3, "c"),
                Err(CapiError::NullPointer("c"))
            );
            assert!(slice_mut::<f32>(std::ptr::null_mut(), 3, "d").is_err());
        }
    }
}
