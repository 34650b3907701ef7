//! A two-way fork-join for the solver's short kernels: one helper thread that spins while work is
//! coming, so handing it half a kernel costs a cache-line round trip instead of a thread-pool
//! wake-up (with rayon's fork-join the split multigrid was slower than one thread on the 2-core
//! target). A fluid step runs hundreds of kernels of 1-30 us each (a half-sweep of the 1.2 and
//! 0.6 mm benchmark cavities); that overhead decides whether the second core helps at all.
//!
//! [`join`] never waits for a helper that is not running: after its own half, the caller takes the
//! other half back if the helper has not started it, so a parked, busy or missing helper costs at
//! most the caller doing both halves itself. The helper spins for [`SPIN`] after its last task and
//! then parks, so it costs nothing between steps. Nested or concurrent calls (another solver on
//! another thread) find the slot taken and run both halves in the caller. Rayon's thread count is
//! the one switch: with a pool of one thread (`--threads 1`) both halves run in the caller.

use std::cell::UnsafeCell;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::ptr::NonNull;
use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::sync::OnceLock;
use std::thread::{self, Thread};
use std::time::{Duration, Instant};

/// How long the helper spins for new work after a task before it parks.
const SPIN: Duration = Duration::from_micros(300);

/// Polls of a running task's state before the caller yields its core instead (a few tens of
/// microseconds; a half-kernel takes 1-50 us).
const YIELD_AFTER_POLLS: u32 = 4096;

/// Slot states.
const IDLE: u8 = 0;
const POSTING: u8 = 1;
const POSTED: u8 = 2;
const RUNNING: u8 = 3;
const DONE: u8 = 4;
const TAKEN: u8 = 5;

type Task = NonNull<dyn FnMut() + Send>;

struct Shared {
    state: AtomicU8,
    /// The posted task, valid while the state is POSTED or RUNNING (written only by the caller
    /// that moved the state IDLE -> POSTING).
    task: UnsafeCell<Option<Task>>,
    sleeping: AtomicBool,
    panicked: AtomicBool,
    helper: OnceLock<Thread>,
}

// SAFETY: `task` is written only by the one caller that owns the slot (state POSTING) and read by
// the helper only after it won the slot (state RUNNING), with release/acquire on `state` between
// them; the task itself is `Send`.
unsafe impl Sync for Shared {}

fn shared() -> Option<&'static Shared> {
    static HELPER: OnceLock<Option<&'static Shared>> = OnceLock::new();
    *HELPER.get_or_init(|| {
        if thread::available_parallelism().map_or(1, |n| n.get()) < 2 {
            return None;
        }
        let s: &'static Shared = Box::leak(Box::new(Shared {
            state: AtomicU8::new(IDLE),
            task: UnsafeCell::new(None),
            sleeping: AtomicBool::new(false),
            panicked: AtomicBool::new(false),
            helper: OnceLock::new(),
        }));
        let handle = thread::Builder::new()
            .name("hydrometra-fj".into())
            .spawn(move || helper(s))
            .ok()?;
        // Only `join` unparks, and the helper's first wait is a bounded park, so setting the
        // handle after the spawn loses nothing.
        let _ = s.helper.set(handle.thread().clone());
        tracing::trace!("fork-join helper thread started");
        Some(s)
    })
}

fn helper(s: &'static Shared) {
    loop {
        let mut last = Instant::now();
        let mut polls = 0u32;
        loop {
            if s.state.load(Ordering::Acquire) == POSTED
                && s.state
                    .compare_exchange(POSTED, RUNNING, Ordering::Acquire, Ordering::Relaxed)
                    .is_ok()
            {
                // SAFETY: the slot is ours (RUNNING) and the caller keeps the task alive until it
                // sees DONE.
                if let Some(mut task) = unsafe { *s.task.get() } {
                    let run = catch_unwind(AssertUnwindSafe(|| unsafe { (task.as_mut())() }));
                    if run.is_err() {
                        s.panicked.store(true, Ordering::Relaxed);
                    }
                }
                s.state.store(DONE, Ordering::Release);
                last = Instant::now();
                continue;
            }
            std::hint::spin_loop();
            polls = polls.wrapping_add(1);
            if polls.is_multiple_of(256) && last.elapsed() > SPIN {
                break;
            }
        }
        s.sleeping.store(true, Ordering::SeqCst);
        if s.state.load(Ordering::SeqCst) != POSTED {
            thread::park_timeout(Duration::from_millis(500));
        }
        s.sleeping.store(false, Ordering::SeqCst);
    }
}

/// Gives the slot back once the posted task is finished (by the helper) or taken back (and run
/// here, unless unwinding), so the task's borrows end before the caller's frame does.
struct Finish<'a> {
    s: &'a Shared,
}

impl Drop for Finish<'_> {
    fn drop(&mut self) {
        let s = self.s;
        if s.state
            .compare_exchange(POSTED, TAKEN, Ordering::Acquire, Ordering::Relaxed)
            .is_ok()
        {
            // SAFETY: taken back before the helper started it: the task is ours alone.
            if let Some(mut task) = unsafe { *s.task.get() } {
                if !thread::panicking() {
                    unsafe { (task.as_mut())() };
                }
            }
        } else {
            // The helper is running the task. If it takes long, it was likely preempted (another
            // process on its core, or on ours): yield so it can finish instead of spinning
            // against it.
            let mut polls = 0u32;
            while s.state.load(Ordering::Acquire) != DONE {
                polls = polls.saturating_add(1);
                if polls < YIELD_AFTER_POLLS {
                    std::hint::spin_loop();
                } else {
                    thread::yield_now();
                }
            }
        }
        // SAFETY: the slot is still ours (DONE or TAKEN); nobody else reads the task now.
        unsafe { *s.task.get() = None };
        s.state.store(IDLE, Ordering::Release);
    }
}

/// Runs `a` here and `b` on the helper thread (or here, after `a`, if the helper has not started
/// it by then), and returns both results.
pub(crate) fn join<RA, RB: Send>(
    a: impl FnOnce() -> RA,
    b: impl FnOnce() -> RB + Send,
) -> (RA, RB) {
    if rayon::current_num_threads() < 2 {
        return (a(), b());
    }
    let Some(s) = shared() else {
        return (a(), b());
    };
    if s.state
        .compare_exchange(IDLE, POSTING, Ordering::Acquire, Ordering::Relaxed)
        .is_err()
    {
        return (a(), b());
    }
    let mut b = Some(b);
    let mut rb = None;
    let ra;
    {
        let mut task = || {
            if let Some(b) = b.take() {
                rb = Some(b());
            }
        };
        let ptr: *mut (dyn FnMut() + Send + '_) = &mut task;
        // SAFETY: the lifetime is erased only for the slot; `Finish` below does not return until
        // the helper is done with the task or the task was taken back, and `task` outlives it.
        let ptr: *mut (dyn FnMut() + Send + 'static) = unsafe { std::mem::transmute(ptr) };
        unsafe { *s.task.get() = NonNull::new(ptr) };
        s.state.store(POSTED, Ordering::SeqCst);
        if s.sleeping.load(Ordering::SeqCst) {
            if let Some(t) = s.helper.get() {
                t.unpark();
            }
        }
        let finish = Finish { s };
        ra = a();
        drop(finish);
    }
    if s.panicked.swap(false, Ordering::Relaxed) {
        panic!("a task on the fork-join helper thread panicked");
    }
    match rb {
        Some(rb) => (ra, rb),
        // The task ran (by the helper or here) unless it panicked, handled above.
        None => panic!("fork-join task did not run"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn join_runs_both_halves_with_borrowed_data() {
        let mut v = vec![0u64; 1000];
        for round in 0..2000u64 {
            let (lo, hi) = v.split_at_mut(500);
            let (a, b) = join(
                || {
                    lo.iter_mut().for_each(|x| *x += round);
                    lo.len()
                },
                || {
                    hi.iter_mut().for_each(|x| *x += 2 * round);
                    hi.len()
                },
            );
            assert_eq!((a, b), (500, 500));
        }
        let s: u64 = (0..2000).sum();
        assert!(v[..500].iter().all(|&x| x == s));
        assert!(v[500..].iter().all(|&x| x == 2 * s));
    }

    #[test]
    fn concurrent_and_nested_joins_complete() {
        let total: u64 = std::thread::scope(|sc| {
            let hs: Vec<_> = (0..4)
                .map(|t| {
                    sc.spawn(move || {
                        let mut acc = 0u64;
                        for i in 0..500u64 {
                            let (a, (b, c)) = join(|| i + t, || join(|| i, || 1u64));
                            acc += a + b + c;
                        }
                        acc
                    })
                })
                .collect();
            hs.into_iter().map(|h| h.join().unwrap_or(0)).sum()
        });
        let per: u64 = (0..500u64).map(|i| 2 * i + 1).sum();
        assert_eq!(total, 4 * per + 500 * 6); // t = 0..4 adds 500 t each
    }
}
