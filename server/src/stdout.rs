//! Lines on the process's stdout that outlive their reader: [`say!`](crate::say), the
//! `println!` of every command's report ([`crate::cli`]) and of the service's and farm worker's
//! announcements ([`crate::service`]).
//!
//! Why: Rust ignores SIGPIPE, so a write to a pipe whose reader has gone fails with
//! `BrokenPipe`, and `println!` panics on it ("failed printing to stdout"). `lightfarm inspect B
//! | head` then exited 101, `lightfarm bake … | head` after writing its bundle, and a farm
//! worker whose log reader had gone would panic on its next unit. Invariant: a line whose
//! reader has gone is dropped and the caller goes on as if it had been read; any other error
//! writing stdout still panics, as with `println!`. No light transport, no HTTP.

/// `println!` that drops the line when stdout's reader has gone (see the module doc).
#[macro_export]
macro_rules! say {
    ($($arg:tt)*) => {
        $crate::stdout::say_line(::std::format_args!($($arg)*))
    };
}

/// What [`say!`](crate::say) runs: one line to stdout, a closed pipe ignored.
pub fn say_line(line: std::fmt::Arguments<'_>) {
    use std::io::Write;
    match writeln!(std::io::stdout().lock(), "{line}") {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => {
            panic!("failed printing to stdout: {e}")
        }
        _ => {}
    }
}
