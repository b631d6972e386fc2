//! A counting global allocator for hostile-input tests: how many heap bytes a reader had live at
//! its peak, so a lying length or a decompression bomb shows as a number, not as an aborted run.
//!
//! Each test binary that measures declares it as its allocator:
//!
//! ```
//! use treelod_tests::alloc::{CountingAllocator, peak_during};
//!
//! #[global_allocator]
//! static ALLOCATOR: CountingAllocator = CountingAllocator;
//!
//! fn main() {
//!     let (buffer, peak) = peak_during(|| vec![0u8; 1 << 20]);
//!     assert!(peak.thread >= 1 << 20 && peak.process >= 1 << 20);
//!     drop(buffer);
//! }
//! ```
//!
//! and wraps the code under test in [`peak_during`]. Two peaks are kept: the calling thread's
//! (exact whatever other threads do, but blind to work handed to other threads) and the whole
//! process's (which sees rayon's workers too). Measurements take a process-wide lock; a test that
//! relies on the process peak also takes [`exclusive`] for its whole run, so that under
//! `cargo test`'s parallel threads no other test allocates meanwhile (nextest runs each test in a
//! process of its own anyway).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicIsize, Ordering};
use std::sync::{Mutex, MutexGuard, PoisonError};

/// The system allocator, counting live bytes per thread and per process.
#[derive(Clone, Copy, Debug, Default)]
pub struct CountingAllocator;

static LIVE: AtomicIsize = AtomicIsize::new(0);
static PEAK: AtomicIsize = AtomicIsize::new(0);
static MEASURING: Mutex<()> = Mutex::new(());
static SERIAL: Mutex<()> = Mutex::new(());

thread_local! {
    static THREAD_LIVE: Cell<isize> = const { Cell::new(0) };
    static THREAD_PEAK: Cell<isize> = const { Cell::new(0) };
}

fn note(delta: isize) {
    let now = LIVE.fetch_add(delta, Ordering::Relaxed) + delta;
    PEAK.fetch_max(now, Ordering::Relaxed);
    let _ = THREAD_LIVE.try_with(|live| {
        let now = live.get() + delta;
        live.set(now);
        let _ = THREAD_PEAK.try_with(|peak| peak.set(peak.get().max(now)));
    });
}

#[expect(clippy::cast_possible_wrap, reason = "no allocation is larger than isize::MAX")]
fn signed(n: usize) -> isize {
    n as isize
}

// SAFETY: every method forwards to the system allocator with the caller's arguments unchanged and
// only updates atomics and thread-local counters (const-initialised `Cell`s, which never allocate).
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded with the caller's guarantees.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            note(signed(layout.size()));
        }
        p
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // SAFETY: forwarded with the caller's guarantees.
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            note(signed(layout.size()));
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded with the caller's guarantees.
        unsafe { System.dealloc(ptr, layout) };
        note(-signed(layout.size()));
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: forwarded with the caller's guarantees.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            note(signed(new_size) - signed(layout.size()));
        }
        p
    }
}

/// Peak heap bytes live during a [`peak_during`] call, above what was live when it started.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Peak {
    /// On the calling thread.
    pub thread: usize,
    /// In the whole process.
    pub process: usize,
}

#[expect(clippy::cast_sign_loss, reason = "clamped to 0 first")]
fn unsigned(n: isize) -> usize {
    n.max(0) as usize
}

/// Runs `f` and returns its result with the peak heap use meanwhile. All zero when the binary
/// does not use [`CountingAllocator`] (see [`counting`]).
///
/// Not reentrant: `f` must not call `peak_during` (measurements hold a process-wide lock).
pub fn peak_during<R>(f: impl FnOnce() -> R) -> (R, Peak) {
    let _guard = MEASURING.lock().unwrap_or_else(PoisonError::into_inner);
    let base = LIVE.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let thread_base = THREAD_LIVE.with(Cell::get);
    THREAD_PEAK.with(|p| p.set(thread_base));
    let result = f();
    let peak = Peak {
        thread: unsigned(THREAD_PEAK.with(Cell::get) - thread_base),
        process: unsigned(PEAK.load(Ordering::Relaxed) - base),
    };
    (result, peak)
}

/// Whether this binary's global allocator is [`CountingAllocator`]: measurements are meaningful.
#[must_use]
pub fn counting() -> bool {
    let (_, peak) = peak_during(|| std::hint::black_box(vec![0u8; 4096]));
    peak.thread >= 4096
}

/// Serialises whole tests of a binary: a test holding the guard runs alone among those that take
/// it, so the process peak of its [`peak_during`] calls does not include the allocations of tests
/// running beside it under `cargo test` (nextest runs each test in a process of its own anyway).
pub fn exclusive() -> MutexGuard<'static, ()> {
    SERIAL.lock().unwrap_or_else(PoisonError::into_inner)
}
