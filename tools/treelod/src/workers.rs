//! The worker loop that `batch` and `verify` share: a list of items done side by side, each worker
//! taking the next one in list order.

use std::num::NonZeroUsize;
use std::sync::atomic::{AtomicUsize, Ordering};

use treelod_format::ErrorClass;

use crate::report::{self, Failed};

/// Calls `work(index)` once for every index in `0..count`, on a pool of `jobs` threads (default:
/// the available cores).
///
/// At most `min(jobs, count)` workers run `work`, each taking the next index in order, so at most
/// that many items are in flight and an interrupted run has done a prefix of the list (give or
/// take the items in flight). The pool keeps all `jobs` threads, so parallel work inside `work`
/// (a build's cells) has the cores that idle workers leave. A pool that cannot start is reported
/// as `error: cannot start N worker thread(s): reason`.
pub fn on_workers(jobs: Option<u32>, count: usize, work: impl Fn(usize) + Sync) -> Result<(), Failed> {
    let threads = jobs.map_or_else(
        || std::thread::available_parallelism().map_or(1, NonZeroUsize::get),
        |n| usize::try_from(n).unwrap_or(1).max(1),
    );
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().map_err(|e| {
        report::print_error(&format!("cannot start {threads} worker thread(s): {e}"));
        Failed { class: ErrorClass::Io }
    })?;
    let next = AtomicUsize::new(0);
    pool.install(|| {
        rayon::scope(|scope| {
            for _ in 0..threads.min(count) {
                scope.spawn(|_| {
                    loop {
                        let index = next.fetch_add(1, Ordering::Relaxed);
                        if index >= count {
                            break;
                        }
                        work(index);
                    }
                });
            }
        });
    });
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::sync::Mutex;

    use super::*;

    #[test]
    fn every_index_is_done_once_whatever_the_jobs() {
        for jobs in [None, Some(1), Some(2), Some(3), Some(64)] {
            for count in [0, 1, 5, 40] {
                let seen = Mutex::new(vec![0u32; count]);
                on_workers(jobs, count, |i| seen.lock().expect("lock")[i] += 1).expect("a pool");
                assert_eq!(seen.into_inner().expect("lock"), vec![1; count], "jobs {jobs:?}, count {count}");
            }
        }
    }

    #[test]
    fn one_job_takes_the_items_in_order() {
        let order = Mutex::new(Vec::new());
        on_workers(Some(1), 6, |i| order.lock().expect("lock").push(i)).expect("a pool");
        assert_eq!(order.into_inner().expect("lock"), [0, 1, 2, 3, 4, 5]);
    }
}
