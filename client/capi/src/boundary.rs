//! The FFI edge: every `extern "C"` entry point runs its body through one of these, so no
//! panic unwinds into C and every failure is recorded for [`crate::lf_last_error`].
//!
//! Invariants:
//! - [`status_call`] returns [`LfStatus::Ok`] (0) exactly when its body returned `Ok`; every
//!   error or caught panic gives a negative code and sets the thread's last error.
//! - [`pointer_call`] returns a non-NULL pointer exactly when its body returned `Ok`.
//! - [`size_call`] returns a size (>= 0) exactly when its body returned `Ok`, else a negative
//!   [`LfStatus`] as `int64_t`.
//! - [`slice`] / [`slice_mut`] never build a slice from a NULL pointer; a zero length gives
//!   an empty slice whatever the pointer.
//! - [`write_c_string`] always leaves a NUL-terminated string holding no other NUL when it
//!   writes at all.
//! - Bodies run under `AssertUnwindSafe`: after a caught panic an `LfRuntime` stays usable
//!   because the client runtime refills every scratch buffer it reads on each call.

use std::any::Any;
use std::ffi::c_char;
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

/// For entry points that return a size (bytes a string needs) as `int64_t`, or a negative
/// `LfStatus` on error or panic.
pub(crate) fn size_call(
    function: &'static str,
    body: impl FnOnce() -> Result<usize, CapiError>,
) -> i64 {
    match guarded(function, body) {
        // A size fits: it counts bytes of one allocation, at most `isize::MAX`.
        Ok(size) => size as i64,
        Err(e) => e.status() as i64,
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

/// Copies `text` into `buf` as a NUL-terminated C string, cut to `cap - 1` bytes at a UTF-8
/// character boundary if it is longer, each NUL byte of `text` written as a space (so C sees
/// the whole text as one string); writes nothing when `buf` is NULL or `cap` is 0.
///
/// Returns the buffer size the whole text needs, NUL included: `text.len() + 1`.
///
/// # Safety
/// `buf` must be NULL or point to `cap` writable bytes.
pub(crate) unsafe fn write_c_string(text: &str, buf: *mut c_char, cap: usize) -> usize {
    if !buf.is_null() && cap > 0 {
        let mut n = text.len().min(cap - 1);
        while !text.is_char_boundary(n) {
            n -= 1;
        }
        // SAFETY: the caller guarantees `cap` writable bytes at `buf`, and n + 1 <= cap.
        let out = unsafe { std::slice::from_raw_parts_mut(buf.cast::<u8>(), n + 1) };
        for (o, &b) in out.iter_mut().zip(&text.as_bytes()[..n]) {
            *o = if b == 0 { b' ' } else { b };
        }
        out[n] = 0;
    }
    text.len() + 1
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
    fn sizes_and_statuses_share_one_return_value() {
        assert_eq!(size_call("lf_s", || Ok(12)), 12);
        assert_eq!(
            size_call("lf_s", || Err(CapiError::NullPointer("name"))),
            LfStatus::NullPointer as i64
        );
        assert_eq!(last_error(), "lf_s: name is NULL");
        assert_eq!(size_call("lf_s", || panic!("size boom")), -7);
    }

    #[test]
    fn c_strings_are_cut_at_a_character_and_always_terminated() {
        let mut buf = [0x55u8; 8];
        let mut write = |text: &str, cap: usize| {
            buf.fill(0x55);
            // SAFETY: `cap` <= 8 writable bytes.
            let needed = unsafe { write_c_string(text, buf.as_mut_ptr().cast(), cap) };
            (needed, buf)
        };
        assert_eq!(write("abc", 8), (4, *b"abc\0\x55\x55\x55\x55"));
        assert_eq!(write("abcdefghij", 8), (11, *b"abcdefg\0"));
        // "é" is two bytes: cutting inside it drops it whole.
        assert_eq!(write("abcdeé", 7), (8, *b"abcde\0\x55\x55"));
        assert_eq!(write("a\0b", 8), (4, *b"a b\0\x55\x55\x55\x55"));
        assert_eq!(write("abc", 0), (4, [0x55; 8]));
        // SAFETY: NULL: nothing is written.
        assert_eq!(unsafe { write_c_string("abc", std::ptr::null_mut(), 8) }, 4);
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
