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
//!
//! **Panics.** A panic in either half reaches the caller of [`join`] with its payload (the helper
//! catches it, hands it back and stays alive for the next join), after both halves stopped touching
//! their borrows. If the helper thread cannot be started at all, the first `join` logs a warning
//! (the joins then run serially, and [`helper_tasks`] stays 0).
//!
//! **Scheduling policy (real-time callers on a 2-core machine).** The helper never runs at real-time
//! priority: it puts itself under `SCHED_OTHER` when it starts, whatever the policy of the thread
//! that spawned it, so a `SCHED_FIFO` rig I/O or publisher thread always preempts it. It spins for
//! at most [`SPIN`] after its last task, then parks (0 CPU between fluid steps). A caller whose half
//! the helper is running waits by spinning [`YIELD_AFTER_POLLS`] polls, then `yield_now`, then
//! sleeping [`WAIT_SLEEP`] at a time: a `SCHED_FIFO` caller's `yield_now` only lets threads of its
//! own priority run, the sleep lets the (preempted) helper or anyone else have the core.
//!
//! **Contention (the guard).** When a third thread wants one of the two cores (a renderer on the
//! same machine), the helper, spinning for work, takes turns with the caller on a core, and it is
//! preempted in the middle of its half while the caller waits for it. Measured on the 0.6 mm scene
//! beside one busy process: two threads took 7.6-11.6 ms a step against 5.6-8.1 ms for one
//! (BENCHMARKS.md, "Fork-join under contention"). So every join is timed (three clock reads), and
//! each window of [`WINDOW_JOINS`] joins is judged: the helper pays when the joins' wall time is
//! below [`PAYS_BELOW`] of the caller's own halves twice over (what it would have spent doing both
//! at the speed it saw) and the caller had at least [`MIN_CPU_SHARE`] of a core in its busy spans
//! (its thread CPU time over each fluid step, [`BusySpan`]: not over the window's wall
//! time, which holds the daemon's sleeps between frames). A window in which it does not runs the next
//! [`SERIAL_WINDOWS_MIN`] windows of joins in the caller, so the helper parks; the window after
//! them probes the helper again, and each probe that fails doubles the serial stretch (up to
//! [`SERIAL_WINDOWS_MAX`]). Results never depend on which thread runs a half, so they do not
//! depend on the guard; [`guard_serial_joins`] counts the joins it ran in the caller.
//!
//! **Why home-made, and not `chili` or `rayon::join`** (issue 31, measured 2026-11-28 on the Xeon
//! 2-core machine, dev profile, `hydrometra scene bench --voxels-mm 0.6,1.2 --fork-join
//! helper,rayon,chili --repeats 3`, 3 interleaved runs of each, 200 timed steps, the same final
//! state in all of them; BENCHMARKS.md, "Fluid solver", [F6]). Scene step, mean ms:
//!
//! | | helper | rayon | chili |
//! |---|---|---|---|
//! | 0.6 mm, quiet | 26.2 | 30.2 | 35.6 |
//! | 1.2 mm, quiet | 1.89 | 2.24 | 2.28 |
//! | 0.6 mm, one busy thread | 46.0 | 56.9 | 36.0 |
//! | 1.2 mm, one busy thread | 2.37 | 2.61 | 2.34 |
//!
//! On a machine whose two cores are the scene's, the helper is 13-27 % faster than either; beside
//! a busy process chili is 22 % faster at 0.6 mm and level at 1.2 mm, where the guard has made
//! the helper's joins serial. The helper stays for the quiet case. Where it stands in the product:
//! on a 2-core machine the daemon gives the scene one core, and its rayon pool of one thread runs
//! every join serially whichever fork-join is chosen; the comparison decides for `hydrometra`'s
//! offline commands and for machines with more cores.

use std::any::Any;
use std::cell::UnsafeCell;
use std::panic::{catch_unwind, resume_unwind, AssertUnwindSafe};
use std::ptr::NonNull;
use std::sync::atomic::{AtomicBool, AtomicI32, AtomicU32, AtomicU64, AtomicU8, Ordering};
use std::sync::{Mutex, OnceLock};
use std::thread::{self, Thread};
use std::time::{Duration, Instant};

/// How long the helper spins for new work after a task before it parks.
pub const SPIN: Duration = Duration::from_micros(300);

/// Polls of a running task's state before the caller yields its core instead (a few tens of
/// microseconds; a half-kernel takes 1-50 us).
pub const YIELD_AFTER_POLLS: u32 = 4096;

/// `yield_now` calls of a waiting caller before it sleeps instead.
const SLEEP_AFTER_YIELDS: u32 = 64;

/// One sleep of a caller waiting for a preempted helper.
pub const WAIT_SLEEP: Duration = Duration::from_micros(20);

/// Joins over which the guard judges whether the helper pays (a 0.6 mm fluid step makes about
/// 210; a 1.2 mm one only the topology rebuild's, its levels being below the split threshold).
pub const WINDOW_JOINS: u32 = 256;

/// The helper pays when a window's joins take less than this fraction of the caller's own halves
/// twice over.
pub const PAYS_BELOW: f64 = 0.9;

/// The helper is judged not to pay when the caller had less than this share of a core over the
/// window (Linux): a third runnable thread takes turns with the two, and the spinning helper
/// then takes the caller's time.
pub const MIN_CPU_SHARE: f64 = 0.8;

/// Windows of joins run in the caller after a window in which the helper did not pay.
pub const SERIAL_WINDOWS_MIN: u32 = 4;

/// The longest serial stretch, in windows, after probes that failed one after the other.
pub const SERIAL_WINDOWS_MAX: u32 = 64;

/// What a window of joins decides: `None` keeps the helper; `Some(n)` runs the next `n` windows of
/// joins in the caller. The window's joins took `wall_ns`, the caller's own halves twice over
/// `serial_estimate_ns`, and the caller ran `cpu_share` of the window's time (1 where unknown);
/// `probing`: the window followed a serial stretch of `last` windows.
fn verdict(
    wall_ns: u64,
    serial_estimate_ns: u64,
    cpu_share: f64,
    probing: bool,
    last: u32,
) -> Option<u32> {
    if (wall_ns as f64) < PAYS_BELOW * serial_estimate_ns as f64 && cpu_share >= MIN_CPU_SHARE {
        return None;
    }
    Some(if probing {
        last.saturating_mul(2)
            .clamp(SERIAL_WINDOWS_MIN, SERIAL_WINDOWS_MAX)
    } else {
        SERIAL_WINDOWS_MIN
    })
}

/// Which CPU-time clock [`cpu_time_ns`] reads.
#[derive(Clone, Copy, Debug)]
pub(crate) enum CpuClock {
    /// Every thread of the process.
    #[cfg_attr(not(feature = "harness"), allow(dead_code))]
    Process,
    /// The calling thread.
    Thread,
}

/// CPU time consumed so far on `clock`, ns (`None` where the clock cannot be read). A thread's
/// CPU clock has no vDSO path: each read is a system call.
pub(crate) fn cpu_time_ns(clock: CpuClock) -> Option<u64> {
    let id = match clock {
        CpuClock::Process => libc::CLOCK_PROCESS_CPUTIME_ID,
        CpuClock::Thread => libc::CLOCK_THREAD_CPUTIME_ID,
    };
    let mut t = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: a valid clock id and a timespec to write.
    (unsafe { libc::clock_gettime(id, &mut t) } == 0)
        .then(|| t.tv_sec as u64 * 1_000_000_000 + t.tv_nsec as u64)
}

/// The guard's state (module doc, "Contention"). Updated with relaxed atomics: concurrent callers
/// (only when two solvers run at once) can blur one window's figures, never a result.
struct Guard {
    enabled: AtomicBool,
    /// Joins left to run in the caller before the helper is tried again.
    serial_left: AtomicU32,
    /// Length of the last serial stretch, windows.
    serial_windows: AtomicU32,
    /// Whether the window being measured follows a serial stretch.
    probing: AtomicBool,
    joins: AtomicU32,
    wall_ns: AtomicU64,
    serial_estimate_ns: AtomicU64,
    /// Wall time and the caller's CPU time over the [`BusySpan`]s that ended in the window, ns.
    busy_wall_ns: AtomicU64,
    busy_cpu_ns: AtomicU64,
    serial_joins: AtomicU64,
}

static GUARD: Guard = Guard::new();

impl Guard {
    const fn new() -> Guard {
        Guard {
            enabled: AtomicBool::new(true),
            serial_left: AtomicU32::new(0),
            serial_windows: AtomicU32::new(0),
            probing: AtomicBool::new(false),
            joins: AtomicU32::new(0),
            wall_ns: AtomicU64::new(0),
            serial_estimate_ns: AtomicU64::new(0),
            busy_wall_ns: AtomicU64::new(0),
            busy_cpu_ns: AtomicU64::new(0),
            serial_joins: AtomicU64::new(0),
        }
    }

    /// Whether this join runs in the caller (the guard's serial stretch; counts it).
    fn serial(&self) -> bool {
        let serial = self
            .serial_left
            .fetch_update(Ordering::Relaxed, Ordering::Relaxed, |v| v.checked_sub(1))
            .is_ok();
        if serial {
            self.serial_joins.fetch_add(1, Ordering::Relaxed);
        }
        serial
    }

    /// Adds a busy span of `wall` in which the caller ran `cpu`.
    fn record_busy(&self, wall: Duration, cpu: Duration) {
        self.busy_wall_ns
            .fetch_add(wall.as_nanos() as u64, Ordering::Relaxed);
        self.busy_cpu_ns
            .fetch_add(cpu.as_nanos() as u64, Ordering::Relaxed);
    }

    /// Records a join whose caller spent `own` on its half and `wall` in all.
    fn record(&self, own: Duration, wall: Duration) {
        if !self.enabled.load(Ordering::Relaxed) {
            return;
        }
        let add = |a: &AtomicU64, v: u64| a.fetch_add(v, Ordering::Relaxed) + v;
        let wall_ns = add(&self.wall_ns, wall.as_nanos() as u64);
        let estimate_ns = add(&self.serial_estimate_ns, 2 * own.as_nanos() as u64);
        if self.joins.fetch_add(1, Ordering::Relaxed) + 1 < WINDOW_JOINS {
            return;
        }
        let busy_wall = self.busy_wall_ns.swap(0, Ordering::Relaxed);
        let busy_cpu = self.busy_cpu_ns.swap(0, Ordering::Relaxed);
        for a in [&self.wall_ns, &self.serial_estimate_ns] {
            a.store(0, Ordering::Relaxed);
        }
        self.joins.store(0, Ordering::Relaxed);
        // The share of a core the caller had in its busy spans (1 where none ended).
        let share = if busy_wall > 0 {
            busy_cpu as f64 / busy_wall as f64
        } else {
            1.0
        };
        let probing = self.probing.load(Ordering::Relaxed);
        let last = self.serial_windows.load(Ordering::Relaxed);
        match verdict(wall_ns, estimate_ns, share, probing, last) {
            None => self.probing.store(false, Ordering::Relaxed),
            Some(n) => {
                self.serial_windows.store(n, Ordering::Relaxed);
                self.probing.store(true, Ordering::Relaxed);
                self.serial_left
                    .store(n.saturating_mul(WINDOW_JOINS), Ordering::Relaxed);
            }
        }
    }
}

/// Turns the guard on (the default) or off (every join offered to the helper; for benchmarks).
#[cfg(any(test, feature = "harness"))]
pub fn set_guard(enabled: bool) {
    GUARD.enabled.store(enabled, Ordering::Relaxed);
    if !enabled {
        GUARD.serial_left.store(0, Ordering::Relaxed);
    }
}

/// A stretch of work in which the calling thread never waits for anything but the helper (a fluid
/// step): while it lives, its wall time and the thread's CPU time are measured (two clock reads and
/// two system calls), and the guard judges the caller's share of a core over such spans, not over
/// the sleeps between them (a daemon's scene thread sleeps between frames).
pub(crate) struct BusySpan {
    start: Option<(Instant, u64)>,
}

impl BusySpan {
    pub(crate) fn start() -> BusySpan {
        let on = GUARD.enabled.load(Ordering::Relaxed) && rayon::current_num_threads() >= 2;
        BusySpan {
            start: on
                .then(|| cpu_time_ns(CpuClock::Thread).map(|cpu| (Instant::now(), cpu)))
                .flatten(),
        }
    }
}

impl Drop for BusySpan {
    fn drop(&mut self) {
        if let (Some((wall, cpu)), Some(now)) = (self.start, cpu_time_ns(CpuClock::Thread)) {
            GUARD.record_busy(
                wall.elapsed(),
                Duration::from_nanos(now.saturating_sub(cpu)),
            );
        }
    }
}

/// Joins the guard ran in the caller since the process started.
pub fn guard_serial_joins() -> u64 {
    GUARD.serial_joins.load(Ordering::Relaxed)
}

/// Which fork-join runs the two halves: the home-made helper; the others are there to measure it
/// against (`hydrometra fluid bench --fork-join`, `hydrometra scene bench --fork-join`), and exist
/// only with the `harness` feature (without it every join goes to the helper).
#[cfg(feature = "harness")]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backend {
    /// The spinning helper thread of this module.
    Helper,
    /// `rayon::join` on rayon's global pool.
    Rayon,
    /// `chili::Scope::join` (heartbeat scheduling) on chili's global pool.
    Chili,
}

#[cfg(feature = "harness")]
static BACKEND: AtomicU8 = AtomicU8::new(0);

/// Selects the fork-join of every later [`join`] (process-wide; for benchmarks).
#[cfg(feature = "harness")]
pub fn set_backend(backend: Backend) {
    let v = match backend {
        Backend::Helper => 0,
        Backend::Rayon => 1,
        Backend::Chili => 2,
    };
    BACKEND.store(v, Ordering::Relaxed);
}

/// Tasks the helper thread has run since the process started (0 if it never ran one).
pub fn helper_tasks() -> u64 {
    HELPER_TASKS.load(Ordering::Relaxed)
}

static HELPER_TASKS: AtomicU64 = AtomicU64::new(0);

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
    /// The payload of a panic in the helper's task, for the caller to resume.
    panic: Mutex<Option<Box<dyn Any + Send>>>,
    panicked: AtomicBool,
    helper: OnceLock<Thread>,
    /// The helper's kernel thread id (0 until it started; read by the tests).
    #[cfg_attr(not(test), allow(dead_code))]
    tid: AtomicI32,
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
            panic: Mutex::new(None),
            panicked: AtomicBool::new(false),
            helper: OnceLock::new(),
            tid: AtomicI32::new(0),
        }));
        let handle = match thread::Builder::new()
            .name("hydrometra-fj".into())
            .spawn(move || helper(s))
        {
            Ok(h) => h,
            Err(e) => {
                tracing::warn!(
                    "cannot start the fork-join helper thread ({e}): joins run serially"
                );
                return None;
            }
        };
        // Only `join` unparks, and the helper's first wait is a bounded park, so setting the
        // handle after the spawn loses nothing.
        let _ = s.helper.set(handle.thread().clone());
        tracing::trace!("fork-join helper thread started");
        Some(s)
    })
}

/// Puts the calling thread under SCHED_OTHER, nice 0 (the policy in the module doc).
fn leave_realtime() {
    #[cfg(target_os = "linux")]
    {
        let param = libc::sched_param { sched_priority: 0 };
        // SAFETY: the calling thread, a valid sched_param; failure leaves the policy unchanged.
        let rc =
            unsafe { libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_OTHER, &param) };
        if rc != 0 {
            tracing::warn!(rc, "fork-join helper: cannot leave real-time scheduling");
        }
    }
}

/// The helper's kernel thread id once it started (Linux), for checks of its scheduling.
#[cfg(test)]
fn helper_tid() -> Option<i32> {
    shared()
        .map(|s| s.tid.load(Ordering::Acquire))
        .filter(|&t| t != 0)
}

fn helper(s: &'static Shared) {
    leave_realtime();
    #[cfg(target_os = "linux")]
    // SAFETY: gettid has no preconditions.
    s.tid.store(unsafe { libc::gettid() }, Ordering::Release);
    loop {
        let mut last = Instant::now();
        let mut polls = 0u32;
        loop {
            if s.state.load(Ordering::Acquire) == POSTED
                && s.state
                    .compare_exchange(POSTED, RUNNING, Ordering::Acquire, Ordering::Relaxed)
                    .is_ok()
            {
                // SAFETY: reading the slot: it is ours (we moved it POSTED -> RUNNING, acquiring
                // the caller's write of `task` made before its release of POSTED), and no one
                // writes `task` until the caller has seen DONE.
                if let Some(mut task) = unsafe { *s.task.get() } {
                    // SAFETY: calling the task: the caller keeps the closure behind the pointer
                    // alive and untouched until it sees DONE (`Finish` waits for it, on return and
                    // on unwind), and only this thread calls it while the state is RUNNING.
                    let run = catch_unwind(AssertUnwindSafe(|| unsafe { (task.as_mut())() }));
                    if let Err(payload) = run {
                        if let Ok(mut slot) = s.panic.lock() {
                            *slot = Some(payload);
                        }
                        s.panicked.store(true, Ordering::Relaxed);
                    }
                    HELPER_TASKS.fetch_add(1, Ordering::Relaxed);
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
            // SAFETY: reading the slot: taken back (POSTED -> TAKEN) before the helper started
            // the task, so the helper will not read it; we wrote it ourselves.
            if let Some(mut task) = unsafe { *s.task.get() } {
                if !thread::panicking() {
                    // SAFETY: the pointer is to `join`'s closure, alive in the frame that owns this
                    // `Finish`, and no other thread can call it any more (TAKEN).
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
                } else if polls < YIELD_AFTER_POLLS + SLEEP_AFTER_YIELDS {
                    thread::yield_now();
                } else {
                    thread::sleep(WAIT_SLEEP);
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
pub(crate) fn join<RA: Send, RB: Send>(
    a: impl FnOnce() -> RA + Send,
    b: impl FnOnce() -> RB + Send,
) -> (RA, RB) {
    if rayon::current_num_threads() < 2 {
        return (a(), b());
    }
    #[cfg(feature = "harness")]
    match BACKEND.load(Ordering::Relaxed) {
        1 => return rayon::join(a, b),
        2 => return chili_join(a, b),
        _ => {}
    }
    let Some(s) = shared() else {
        return (a(), b());
    };
    if GUARD.serial() {
        return (a(), b());
    }
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
        // SAFETY: only the trait object's lifetime bound changes (same pointer, same vtable). The
        // 'static is never relied on: the pointer lives in the slot, which the helper reads only
        // while the state is POSTED or RUNNING, and `Finish` (created below, dropped before
        // `task` on return and on unwind) does not return until the state is DONE or TAKEN,
        // after which nobody dereferences it; so every use happens while `task` is alive.
        let ptr: *mut (dyn FnMut() + Send + 'static) = unsafe { std::mem::transmute(ptr) };
        // SAFETY: writing the slot: we own it (our IDLE -> POSTING exchange succeeded), and the
        // helper reads it only after our release store of POSTED below.
        unsafe { *s.task.get() = NonNull::new(ptr) };
        s.state.store(POSTED, Ordering::SeqCst);
        if s.sleeping.load(Ordering::SeqCst) {
            if let Some(t) = s.helper.get() {
                t.unpark();
            }
        }
        let finish = Finish { s };
        let start = Instant::now();
        ra = a();
        let own = start.elapsed();
        drop(finish);
        GUARD.record(own, start.elapsed());
    }
    if s.panicked.swap(false, Ordering::Relaxed) {
        let payload = s.panic.lock().ok().and_then(|mut p| p.take());
        match payload {
            Some(p) => resume_unwind(p),
            None => panic!("a task on the fork-join helper thread panicked"),
        }
    }
    match rb {
        Some(rb) => (ra, rb),
        // The task ran (by the helper or here) unless it panicked, handled above.
        None => panic!("fork-join task did not run"),
    }
}

#[cfg(feature = "harness")]
fn chili_join<RA: Send, RB: Send>(
    a: impl FnOnce() -> RA + Send,
    b: impl FnOnce() -> RB + Send,
) -> (RA, RB) {
    use std::cell::RefCell;
    thread_local! {
        static SCOPE: RefCell<Option<chili::Scope<'static>>> = const { RefCell::new(None) };
    }
    let mut a = Some(a);
    let mut b = Some(b);
    let joined = SCOPE.with(|cell| {
        let Ok(mut scope) = cell.try_borrow_mut() else {
            return None; // nested: the outer join already owns this thread's scope
        };
        let scope = scope.get_or_insert_with(chili::Scope::global);
        let (a, b) = (a.take()?, b.take()?);
        Some(scope.join(move |_| a(), move |_| b()))
    });
    match (joined, a, b) {
        (Some(r), _, _) => r,
        (None, Some(a), Some(b)) => (a(), b()),
        // unreachable: the closures are taken only when the join runs
        _ => panic!("fork-join: chili join lost its halves"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Records `n` joins through `guard` that took `wall_us` with the caller's half `own_us`
    /// (each offered to the helper), the caller having `share` of a core in a busy span of each.
    fn window(guard: &Guard, n: u32, own_us: u64, wall_us: u64, share: f64) {
        for _ in 0..n {
            assert!(!guard.serial(), "a join of a measured window ran serially");
            let wall = Duration::from_micros(wall_us);
            guard.record_busy(wall, wall.mul_f64(share));
            guard.record(Duration::from_micros(own_us), wall);
        }
    }

    /// The joins `guard` runs in the caller from now until it offers one to the helper again.
    fn serial_stretch(guard: &Guard) -> u32 {
        let mut n = 0;
        while guard.serial() {
            n += 1;
        }
        n
    }

    #[test]
    fn the_guard_runs_joins_serially_while_the_helper_does_not_pay_and_probes_again() {
        let guard = Guard::new();
        // The helper pays (wall 0.6 of the caller's half twice over): every join is offered.
        window(&guard, 3 * WINDOW_JOINS, 10, 12, 1.0);
        assert_eq!(serial_stretch(&guard), 0);
        // Just at the threshold it does not (wall = PAYS_BELOW of 2 x 10 us).
        let at = (PAYS_BELOW * 20.0).round() as u64;
        window(&guard, WINDOW_JOINS, 10, at, 1.0);
        let mut total = serial_stretch(&guard);
        assert_eq!(total, SERIAL_WINDOWS_MIN * WINDOW_JOINS);
        // Failed probes double the stretch up to the maximum.
        let mut expected = SERIAL_WINDOWS_MIN;
        for _ in 0..8 {
            window(&guard, WINDOW_JOINS, 10, 25, 1.0);
            expected = (2 * expected).min(SERIAL_WINDOWS_MAX);
            let n = serial_stretch(&guard);
            assert_eq!(n, expected * WINDOW_JOINS);
            total += n;
        }
        assert_eq!(expected, SERIAL_WINDOWS_MAX);
        // A probe that pays keeps the helper; the next failure starts from the shortest stretch.
        window(&guard, 2 * WINDOW_JOINS, 10, 12, 1.0);
        assert_eq!(serial_stretch(&guard), 0);
        window(&guard, WINDOW_JOINS, 10, 25, 1.0);
        let n = serial_stretch(&guard);
        assert_eq!(n, SERIAL_WINDOWS_MIN * WINDOW_JOINS);
        total += n;
        // The joins pay, but the caller had too little of its core: a third thread takes turns
        // with the two (the probe after the stretch fails too: doubled).
        window(&guard, WINDOW_JOINS, 10, 12, 0.95 * MIN_CPU_SHARE);
        let n = serial_stretch(&guard);
        assert_eq!(n, 2 * SERIAL_WINDOWS_MIN * WINDOW_JOINS);
        total += n;
        window(&guard, WINDOW_JOINS, 10, 12, 1.05 * MIN_CPU_SHARE);
        assert_eq!(serial_stretch(&guard), 0);
        assert_eq!(guard.serial_joins.load(Ordering::Relaxed), u64::from(total));
        // Switched off, it neither measures nor runs anything serially.
        guard.enabled.store(false, Ordering::Relaxed);
        window(&guard, 2 * WINDOW_JOINS, 10, 25, 0.1);
        assert_eq!(serial_stretch(&guard), 0);
    }

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
    /// Whether this machine can run the two halves in parallel at all; prints the skip if not.
    fn two_cores_or_skip(test: &str) -> bool {
        if rayon::current_num_threads() < 2 || shared().is_none() {
            eprintln!("SKIP {test}: fewer than 2 cores, join runs both halves in the caller");
            return false;
        }
        true
    }

    /// Waits (at most 2 s) until `flag` is set: holds the caller's half until the helper took
    /// the other one, so the test sees the helper run it instead of the caller taking it back.
    fn wait_for(flag: &AtomicBool) -> bool {
        let t = Instant::now();
        while !flag.load(Ordering::Acquire) {
            if t.elapsed() > Duration::from_secs(2) {
                return false;
            }
            std::hint::spin_loop();
        }
        true
    }

    #[test]
    fn the_second_half_runs_on_the_helper_thread_where_available() {
        if !two_cores_or_skip("the_second_half_runs_on_the_helper_thread_where_available") {
            return;
        }
        // Every join offered to the helper, whatever other tests in this process measured.
        set_guard(false);
        let caller = thread::current().id();
        let before = helper_tasks();
        let mut on_helper = 0;
        for _ in 0..20 {
            let started = AtomicBool::new(false);
            let (seen, id) = join(
                || wait_for(&started),
                || {
                    started.store(true, Ordering::Release);
                    thread::current().id()
                },
            );
            if seen && id != caller {
                on_helper += 1;
            }
        }
        assert_eq!(
            on_helper, 20,
            "the helper ran {on_helper} of 20 second halves"
        );
        assert!(helper_tasks() >= before + 20);
    }

    #[test]
    fn a_panic_on_the_helper_reaches_the_caller_and_the_helper_keeps_working_where_available() {
        if !two_cores_or_skip(
            "a_panic_on_the_helper_reaches_the_caller_and_the_helper_keeps_working_where_available",
        ) {
            return;
        }
        set_guard(false);
        let started = AtomicBool::new(false);
        let r = catch_unwind(AssertUnwindSafe(|| {
            join(
                || wait_for(&started),
                || -> u32 {
                    started.store(true, Ordering::Release);
                    panic!("half b failed with 42")
                },
            )
        }));
        let payload = r.expect_err("the helper's panic must reach the caller");
        let msg = payload
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_default();
        assert_eq!(msg, "half b failed with 42");
        // The next join still runs on the helper: not silently serial.
        let started = AtomicBool::new(false);
        let before = helper_tasks();
        let caller = thread::current().id();
        let (seen, id) = join(
            || wait_for(&started),
            || {
                started.store(true, Ordering::Release);
                thread::current().id()
            },
        );
        assert!(seen && id != caller && helper_tasks() > before);
    }

    #[test]
    fn a_panic_in_the_callers_half_propagates_after_the_other_half_finished() {
        let done = AtomicBool::new(false);
        let r = catch_unwind(AssertUnwindSafe(|| {
            join(
                || -> u32 { panic!("half a failed") },
                || done.store(true, Ordering::Release),
            )
        }));
        assert!(r.is_err());
        // Either the helper ran b, or the caller took it back and (unwinding) skipped it; the
        // slot is free again either way.
        let (a, b) = join(|| 1, || 2);
        assert_eq!((a, b), (1, 2));
    }

    /// The policy of the module doc: the helper leaves SCHED_FIFO even when a real-time thread
    /// spawned it, and parks once idle for longer than SPIN.
    #[cfg(target_os = "linux")]
    #[test]
    fn helper_is_not_real_time_and_parks_when_idle_where_available() {
        let name = "helper_is_not_real_time_and_parks_when_idle_where_available";
        if !two_cores_or_skip(name) {
            return;
        }
        set_guard(false);
        // Spawn the helper from a SCHED_FIFO thread if this process may use it.
        let fifo = thread::spawn(|| {
            let param = libc::sched_param { sched_priority: 1 };
            // SAFETY: the calling thread, a valid sched_param.
            let rc = unsafe {
                libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param)
            };
            let started = AtomicBool::new(false);
            join(
                || wait_for(&started),
                || started.store(true, Ordering::Release),
            );
            rc == 0
        })
        .join()
        .unwrap_or(false);
        if !fifo {
            eprintln!("SKIP {name} (part): no SCHED_FIFO permission; checking the policy only");
        }
        let tid = (0..200)
            .find_map(|_| {
                thread::sleep(Duration::from_millis(1));
                helper_tid()
            })
            .expect("helper thread id");
        // SAFETY: a plain query of another thread's policy.
        let policy = unsafe { libc::sched_getscheduler(tid) };
        assert_eq!(policy, libc::SCHED_OTHER, "helper policy {policy}");
        // Idle: after SPIN the helper parks (a 500 ms park timeout wakes it for one more SPIN).
        thread::sleep(SPIN * 4 + Duration::from_millis(5));
        let s = shared().expect("helper");
        let parked = (0..10)
            .filter(|_| {
                thread::sleep(Duration::from_millis(10));
                s.sleeping.load(Ordering::SeqCst)
            })
            .count();
        assert!(
            parked >= 9,
            "the idle helper was parked in {parked} of 10 looks"
        );
    }
}
