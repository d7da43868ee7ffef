//! Handing the memory of a finished bake stage back to the operating system.
//!
//! glibc's allocator keeps freed heap memory for reuse: after the transport's propagation
//! drops the shapes' lightfields (and DRT's inpainting the f64 transport), the process still
//! holds those pages, and a bake's resident memory stays at its high-water mark (measured on a
//! 1,000-block level: 3.9 GB resident with 2.5 GB live). [`release_freed`] asks glibc to return
//! the free pages (`malloc_trim`), so the next stage grows into memory the operating system can
//! count as free. Elsewhere (other C libraries, other systems) it does nothing.
//!
//! Invariant: only returns memory that is already free; it never changes a result.

/// Returns the allocator's free pages to the operating system (glibc on Linux; a no-op elsewhere).
pub fn release_freed() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only releases memory the allocator holds as free; it takes no
    // pointers and is safe to call from any thread at any time.
    unsafe {
        libc::malloc_trim(0);
    }
}
