//! The calling thread's last error message, as `errno` + `strerror` in one: every failing
//! `lf_*` call records why, [`lf_last_error`] copies it out.
//!
//! Invariants: the message belongs to the thread that made the failing call (threads never see
//! each other's); only failures write it (a successful call leaves the previous message); it
//! never contains a NUL byte, so the copy C receives is one whole C string.

use std::cell::RefCell;
use std::ffi::c_char;

use crate::boundary::write_c_string;

thread_local! {
    static LAST_ERROR: RefCell<String> = const { RefCell::new(String::new()) };
}

/// Records `message` as this thread's last error (interior NULs become spaces).
pub(crate) fn set_last_error(message: &str) {
    let _ = LAST_ERROR.try_with(|last| {
        let mut last = last.borrow_mut();
        last.clear();
        last.extend(message.chars().map(|c| if c == '\0' { ' ' } else { c }));
    });
}

/// Copies this thread's last error message into `buf` as a NUL-terminated string, cut to
/// `cap - 1` bytes (at a UTF-8 character boundary) if it is longer.
///
/// Returns the buffer size the whole message needs, NUL included (so the copy is complete
/// when the result is <= `cap`), or 0 if no `lf_*` call on this thread has failed yet (then
/// `buf[0]` is set to NUL when `cap > 0`). Call it with `cap == 0` to ask for the size only.
///
/// # Safety
/// `buf` must be NULL or point to `cap` writable bytes. With `buf == NULL` nothing is written
/// whatever `cap` is.
#[no_mangle]
pub unsafe extern "C" fn lf_last_error(buf: *mut c_char, cap: usize) -> usize {
    std::panic::catch_unwind(|| {
        LAST_ERROR
            .try_with(|last| {
                let last = last.borrow();
                // SAFETY: NULL or `cap` writable bytes, per the contract.
                let needed = unsafe { write_c_string(&last, buf, cap) };
                if last.is_empty() {
                    0
                } else {
                    needed
                }
            })
            .unwrap_or(0)
    })
    .unwrap_or(0)
}
