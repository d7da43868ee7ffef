//! What every C ABI test file shares: the status code of success, a guard that frees its
//! runtime (and loads it, and places a dynamic object), and the thread's last error read through `lf_last_error` with its size contract
//! checked.

#![allow(dead_code)] // each test file uses its own part

use std::ffi::{CStr, CString};
use std::ptr::null_mut;

use lightfarm::*;
use lightfarm_proto::lights::Pose;

pub const OK: i32 = LfStatus::Ok as i32;

/// Owns a runtime for the length of a test.
pub struct Rt(pub *mut LfRuntime);

impl Rt {
    /// The runtime of the bundle `bytes` (panics with the library's reason if refused).
    pub fn from_bytes(bytes: &[u8]) -> Rt {
        // SAFETY: `bytes.len()` readable bytes.
        let rt = unsafe { lf_runtime_new(bytes.as_ptr(), bytes.len()) };
        assert!(!rt.is_null(), "{}", last_error());
        Rt(rt)
    }

    /// Places the dynamic object `id` at `at` (no rotation) through C; the same pose for the
    /// client.
    pub fn place(&self, id: &CString, at: [f32; 3]) -> Pose {
        let pose = LfPose {
            id: id.as_ptr(),
            translation: at,
            rotation: [0.0, 0.0, 0.0, 1.0],
        };
        // SAFETY: one readable pose with a NUL-terminated id.
        let status = unsafe { lf_runtime_set_poses(self.0, &pose, 1) };
        assert_eq!(status, OK, "{}", last_error());
        Pose {
            id: id.to_str().unwrap().into(),
            translation: at.map(f64::from),
            rotation: [0.0, 0.0, 0.0, 1.0],
        }
    }
}

impl Drop for Rt {
    fn drop(&mut self) {
        // SAFETY: from lf_runtime_new, freed once.
        unsafe { lf_runtime_free(self.0) }
    }
}

/// This thread's last error through `lf_last_error`, checking its size contract.
pub fn last_error() -> String {
    // SAFETY: NULL with cap 0 asks for the size only.
    let needed = unsafe { lf_last_error(null_mut(), 0) };
    let mut buf = vec![0x55u8; needed.max(1)];
    // SAFETY: `buf.len()` writable bytes.
    let again = unsafe { lf_last_error(buf.as_mut_ptr().cast(), buf.len()) };
    assert_eq!(again, needed);
    let text = CStr::from_bytes_with_nul(&buf).expect("NUL exactly at the end");
    assert_eq!(text.to_bytes().len() + 1, needed.max(1));
    text.to_str().unwrap().to_owned()
}
