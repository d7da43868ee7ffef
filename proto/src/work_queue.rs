//! One parallel map for the bundle writer's pieces of work (matrix encodings, a section's zstd
//! frames): scoped threads take jobs from a shared counter, so long and short jobs share the
//! threads, and the results come back in job order. This crate has no thread pool dependency;
//! its users are a handful of coarse jobs per write.
//!
//! Invariant: the output is `jobs.map(f)` in order, whatever the number of threads, as long as
//! `f` is a pure function of its arguments.

use std::sync::atomic::{AtomicUsize, Ordering};

/// `f(k, &jobs[k])` for every job, on up to `threads` threads (at least one, at most one per
/// job), in job order. A panic in `f` is re-raised here.
pub fn map_in_order<T: Sync, R: Send>(
    jobs: &[T],
    threads: usize,
    f: impl Fn(usize, &T) -> R + Sync,
) -> Vec<R> {
    let next = AtomicUsize::new(0);
    let threads = threads.clamp(1, jobs.len().max(1));
    let mut done: Vec<(usize, R)> = std::thread::scope(|scope| {
        let workers: Vec<_> = (0..threads)
            .map(|_| {
                scope.spawn(|| {
                    let mut mine = Vec::new();
                    loop {
                        let k = next.fetch_add(1, Ordering::Relaxed);
                        let Some(job) = jobs.get(k) else {
                            break mine;
                        };
                        mine.push((k, f(k, job)));
                    }
                })
            })
            .collect();
        workers
            .into_iter()
            .flat_map(|w| match w.join() {
                Ok(mine) => mine,
                Err(panic) => std::panic::resume_unwind(panic),
            })
            .collect()
    });
    done.sort_unstable_by_key(|(k, _)| *k);
    done.into_iter().map(|(_, r)| r).collect()
}

/// The threads a writer uses: one per core.
pub fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Results are in job order for any thread count, uneven jobs included, and an empty list
    /// is an empty result.
    #[test]
    fn results_come_back_in_job_order_on_any_number_of_threads() {
        let jobs: Vec<u64> = (0..37).map(|i| (i * 7919) % 101).collect();
        let slow_square = |k: usize, x: &u64| {
            // Uneven work: some jobs spin longer.
            let mut y = *x;
            for _ in 0..(x % 5) * 1000 {
                y = std::hint::black_box(y);
            }
            (k, y * y)
        };
        let expected: Vec<(usize, u64)> =
            jobs.iter().enumerate().map(|(k, x)| (k, x * x)).collect();
        for threads in [0, 1, 2, 3, 8, 64] {
            assert_eq!(map_in_order(&jobs, threads, slow_square), expected);
        }
        assert!(map_in_order(&[] as &[u8], 4, |_, x| *x).is_empty());
    }
}
