//! Where the daemon's threads run and at which priority: the safety path first, the picture
//! second.
//!
//! The rig I/O thread and the 1 kHz loop (which carries the hydraulics, the deficit and its alarms
//! and publishes status) are the *real-time side*; the scene (deformation, voxelization, fluid,
//! particles, with its helper threads), the recorder and the control plane are the *rest*.
//!
//! - **Priority.** The real-time side runs under `SCHED_FIFO` at `loop.realtime_priority` where the
//!   system allows it (the systemd unit grants `LimitRTPRIO`); where it does not, it asks for a
//!   raised nice value instead (`LimitNICE`/`Nice=`), and where that is refused too it runs at normal
//!   priority. The daemon says which of these it got once at start ([`RealtimeMode`], logged and
//!   published in status as `realtime_mode`). The rest never runs at real-time priority.
//! - **Cores.** With two or more CPUs the real-time side gets one CPU of its own (the last one the
//!   process may use, or `loop.realtime_cpu`) and every other thread of the daemon is kept off it:
//!   on a 2-core machine the scene runs on the other core alone, so no scene thread, helper or
//!   rayon worker can take the loop's core, whatever the scheduling policy. Other processes can
//!   still run there; only `SCHED_FIFO` protects the loop from them.
//!
//! Threads inherit the CPU set and policy of the thread that creates them, so the daemon sets them
//! on its main thread around the spawns ([`Placement::enter_realtime`] before starting the rig
//! and the loop, [`Placement::enter_rest`] before anything else).

use std::fmt;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// What the real-time side got from the system.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum RealtimeMode {
    /// Normal scheduling (no privilege, or `loop.realtime_priority = 0`): degraded, other
    /// processes can delay the loop.
    Normal = 0,
    /// Normal scheduling with a raised nice value (`loop.fallback_nice`).
    Nice = 1,
    /// `SCHED_FIFO`: the loop preempts every ordinary thread of the machine.
    Fifo = 2,
}

impl fmt::Display for RealtimeMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            RealtimeMode::Normal => "normal scheduling (degraded: other processes can delay the 1 kHz loop)",
            RealtimeMode::Nice => "raised nice value (degraded: real-time processes and equal-priority load can delay the 1 kHz loop)",
            RealtimeMode::Fifo => "SCHED_FIFO",
        })
    }
}

/// A set of CPUs (Linux `cpu_set_t`).
#[derive(Clone, Copy)]
pub struct CpuSet(libc::cpu_set_t);

impl CpuSet {
    fn empty() -> CpuSet {
        // SAFETY: cpu_set_t is a plain bit array; all zeros is the empty set.
        CpuSet(unsafe { std::mem::zeroed() })
    }

    /// The CPUs the calling thread may run on.
    pub fn of_current_thread() -> Option<CpuSet> {
        let mut set = CpuSet::empty();
        // SAFETY: pid 0 is the calling thread; `set` is a valid cpu_set_t of the size passed.
        let rc = unsafe {
            libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set.0)
        };
        (rc == 0).then_some(set)
    }

    /// The CPUs in the set, ascending.
    pub fn cpus(&self) -> Vec<usize> {
        (0..libc::CPU_SETSIZE as usize)
            // SAFETY: `cpu` is below CPU_SETSIZE.
            .filter(|&cpu| unsafe { libc::CPU_ISSET(cpu, &self.0) })
            .collect()
    }

    /// The set of these CPUs (those at or above `CPU_SETSIZE` are left out).
    pub fn from_cpus(cpus: &[usize]) -> CpuSet {
        let mut set = CpuSet::empty();
        for &cpu in cpus {
            if cpu < libc::CPU_SETSIZE as usize {
                // SAFETY: `cpu` is below CPU_SETSIZE.
                unsafe { libc::CPU_SET(cpu, &mut set.0) };
            }
        }
        set
    }

    /// Restricts the calling thread (and the threads it creates from now on) to this set.
    pub fn apply_to_current_thread(&self) -> std::io::Result<()> {
        // SAFETY: pid 0 is the calling thread; `self.0` is a valid cpu_set_t of the size passed.
        let rc =
            unsafe { libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &self.0) };
        if rc == 0 {
            Ok(())
        } else {
            Err(std::io::Error::last_os_error())
        }
    }
}

impl fmt::Debug for CpuSet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.cpus()).finish()
    }
}

/// How the process's CPUs are shared out.
#[derive(Debug, Clone)]
pub struct Placement {
    /// The real-time side's CPU set (one CPU), or `None` when the process has a single CPU.
    realtime_cpus: Option<CpuSet>,
    /// Every other thread's set (all the process's CPUs when there is no split).
    rest_cpus: Option<CpuSet>,
    /// CPUs the rest may use.
    rest_count: usize,
    priority: u8,
    fallback_nice: i32,
}

/// A thread that keeps the real-time CPU busy while nothing else wants it, so the CPU never halts
/// between ticks ([`Placement::keep_realtime_cpu_awake`]). It polls only while
/// [`KeepAwake::set_wanted`] says so (a procedure is live) and sleeps otherwise; stopped and
/// joined on drop.
#[derive(Debug)]
pub struct KeepAwake {
    shared: Arc<KeepAwakeFlags>,
    thread: Option<std::thread::JoinHandle<()>>,
}

#[derive(Debug, Default)]
struct KeepAwakeFlags {
    wanted: AtomicBool,
    stop: AtomicBool,
}

impl KeepAwake {
    /// Polls (true) or lets the CPU sleep (false); returns whether this changed it.
    pub fn set_wanted(&self, wanted: bool) -> bool {
        let was = self.shared.wanted.swap(wanted, Ordering::Relaxed);
        if wanted && !was {
            if let Some(t) = &self.thread {
                t.thread().unpark();
            }
        }
        was != wanted
    }
}

impl Drop for KeepAwake {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            thread.thread().unpark();
            let _ = thread.join();
        }
    }
}

/// Which CPU the real-time side gets from the CPUs the process may use: `wanted` if it is one of
/// them, else the last one (CPU 0 takes most device interrupts on a typical PC). `None` with fewer
/// than two CPUs (nothing to split).
pub fn choose_realtime_cpu(allowed: &[usize], wanted: Option<usize>) -> Option<usize> {
    if allowed.len() < 2 {
        return None;
    }
    match wanted {
        Some(cpu) if allowed.contains(&cpu) => Some(cpu),
        _ => allowed.last().copied(),
    }
}

impl Placement {
    /// Plans the split for this process: `isolate` keeps the rest off the real-time CPU
    /// (`loop.isolate_realtime_cpu`), `wanted` names that CPU (`loop.realtime_cpu`).
    pub fn plan(isolate: bool, wanted: Option<usize>, priority: u8, fallback_nice: i32) -> Self {
        let allowed = CpuSet::of_current_thread()
            .map(|s| s.cpus())
            .unwrap_or_default();
        let rt = if isolate {
            choose_realtime_cpu(&allowed, wanted)
        } else {
            None
        };
        let (realtime_cpus, rest_cpus, rest_count) = match rt {
            Some(cpu) => {
                let rest: Vec<usize> = allowed.iter().copied().filter(|&c| c != cpu).collect();
                (
                    Some(CpuSet::from_cpus(&[cpu])),
                    Some(CpuSet::from_cpus(&rest)),
                    rest.len(),
                )
            }
            None => (None, None, allowed.len().max(1)),
        };
        Placement {
            realtime_cpus,
            rest_cpus,
            rest_count,
            priority,
            fallback_nice,
        }
    }

    /// CPUs the scene and the other non-real-time threads share.
    pub fn rest_cpu_count(&self) -> usize {
        self.rest_count
    }

    /// Puts the calling thread on the real-time side: its CPU and `SCHED_FIFO` (or the fallback).
    /// Threads it creates inherit both.
    pub fn enter_realtime(&self, thread: &str) -> RealtimeMode {
        if let Some(set) = &self.realtime_cpus {
            if let Err(e) = set.apply_to_current_thread() {
                tracing::warn!(thread, "cannot move to the real-time CPU {set:?}: {e}");
            }
        }
        if self.priority == 0 {
            return RealtimeMode::Normal;
        }
        match set_current_thread_fifo(self.priority) {
            Ok(()) => RealtimeMode::Fifo,
            Err(_) if self.fallback_nice < 0 && set_current_thread_nice(self.fallback_nice) => {
                RealtimeMode::Nice
            }
            Err(_) => RealtimeMode::Normal,
        }
    }

    /// Puts the calling thread with the rest: off the real-time CPU, normal scheduling, nice 0.
    pub fn enter_rest(&self, thread: &str) {
        if let Some(set) = &self.rest_cpus {
            if let Err(e) = set.apply_to_current_thread() {
                tracing::warn!(thread, "cannot leave the real-time CPU: {e}");
            }
        }
        if let Err(e) = set_current_thread_normal() {
            tracing::warn!(thread, "{e}");
        }
        set_current_thread_nice(0);
    }

    /// Keeps the real-time CPU from halting while the loop sleeps: a thread on that CPU alone,
    /// under `SCHED_IDLE`, that polls a flag while [`KeepAwake::set_wanted`] says so. `None`
    /// without a CPU of its own (nothing to keep awake) or when the thread cannot be started
    /// (logged).
    ///
    /// Why: a halted CPU is woken by its timer interrupt, and on a virtual machine that wake-up is
    /// the hypervisor's. Traced on the 2-core KVM machines (ftrace `sched_wakeup` of `hm-sim`):
    /// the loop's core idle, no event on it at all, and the timer's wake-up 1 to 4 ms late, about
    /// a dozen times a minute, each one deadline misses and a gap in status. A running CPU is
    /// interrupted on time. The poller gives way at once: every `SCHED_FIFO` thread preempts it
    /// on wake-up, and under `SCHED_IDLE` any other thread of the machine does too (the kernel's
    /// per-CPU workers, which the loop's pty relies on). It uses no `pause` hint: a pause loop
    /// makes KVM deschedule the vCPU (pause-loop exiting), the very delay it avoids. The price is
    /// that core's idle time while it polls, so the daemon polls only while a procedure is live
    /// and lets the core sleep at rest (`loop.keep_realtime_cpu_awake = false`: never polls).
    pub fn keep_realtime_cpu_awake(&self) -> Option<KeepAwake> {
        let set = self.realtime_cpus?;
        let shared = Arc::new(KeepAwakeFlags::default());
        let flags = shared.clone();
        let spawned = std::thread::Builder::new()
            .name("hm-rt-awake".into())
            .spawn(move || {
                if let Err(e) = set.apply_to_current_thread() {
                    tracing::warn!("the keep-awake thread cannot move to CPU {set:?}: {e}");
                    return;
                }
                if let Err(e) = set_current_thread_idle_policy() {
                    tracing::warn!("the keep-awake thread stops: {e}");
                    return;
                }
                while !flags.stop.load(Ordering::Relaxed) {
                    if flags.wanted.load(Ordering::Relaxed) {
                        continue;
                    }
                    std::thread::park();
                }
            });
        match spawned {
            Ok(thread) => Some(KeepAwake {
                shared,
                thread: Some(thread),
            }),
            Err(e) => {
                tracing::warn!("cannot start the keep-awake thread: {e}");
                None
            }
        }
    }

    /// Says once what the real-time side got, and how to get more.
    pub fn report(&self, mode: RealtimeMode) {
        let cpus = match (&self.realtime_cpus, &self.rest_cpus) {
            (Some(rt), Some(rest)) => format!("real-time CPU {rt:?}, everything else on {rest:?}"),
            _ => "one CPU: no core of its own for the loop".to_string(),
        };
        match mode {
            RealtimeMode::Fifo => tracing::info!(
                priority = self.priority,
                "rig I/O and the 1 kHz loop run under SCHED_FIFO; {cpus}"
            ),
            _ if self.priority == 0 => tracing::warn!(
                "degraded real-time mode: loop.realtime_priority = 0, the rig I/O and the 1 kHz loop \
                 run at normal priority ({mode}); {cpus}"
            ),
            _ => tracing::warn!(
                "degraded real-time mode: SCHED_FIFO priority {} refused (no CAP_SYS_NICE, \
                 RLIMIT_RTPRIO too low), so the rig I/O and the 1 kHz loop run with {mode}; grant it \
                 with LimitRTPRIO={} in the systemd unit (udev/hydrometrad.service does) or \
                 `ulimit -r {}`; {cpus}",
                self.priority,
                self.priority,
                self.priority
            ),
        }
    }
}

/// Puts the calling thread under `policy` at `priority` (`libc::SCHED_*`); the error names
/// `what` and the system's reason.
fn set_current_thread_policy(policy: i32, priority: i32, what: &str) -> Result<(), String> {
    let param = libc::sched_param {
        sched_priority: priority,
    };
    // SAFETY: pthread_self() is the calling thread; `param` is a valid sched_param.
    let rc = unsafe { libc::pthread_setschedparam(libc::pthread_self(), policy, &param) };
    if rc == 0 {
        Ok(())
    } else {
        Err(format!(
            "cannot {what}: {}",
            std::io::Error::from_raw_os_error(rc)
        ))
    }
}

/// Puts the calling thread under SCHED_FIFO at `priority` (1..=99).
/// Returns an error message when the system refuses (no CAP_SYS_NICE or RLIMIT_RTPRIO too low).
pub fn set_current_thread_fifo(priority: u8) -> Result<(), String> {
    set_current_thread_policy(
        libc::SCHED_FIFO,
        i32::from(priority),
        &format!("use SCHED_FIFO priority {priority}"),
    )
}

/// Sets the calling thread's nice value (Linux: per thread); false when refused.
fn set_current_thread_nice(nice: i32) -> bool {
    // SAFETY: gettid has no preconditions; setpriority on our own thread id.
    let rc = unsafe {
        let tid = libc::gettid();
        libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, nice)
    };
    rc == 0
}

/// Puts the calling thread back under normal scheduling (SCHED_OTHER): for threads that inherit
/// SCHED_FIFO but must never preempt the real-time loop (the scene thread and its helpers).
pub fn set_current_thread_normal() -> Result<(), String> {
    set_current_thread_policy(libc::SCHED_OTHER, 0, "leave real-time scheduling")
}

/// Puts the calling thread under `SCHED_IDLE`: it runs only when no other thread wants its CPU
/// (needs no privilege).
fn set_current_thread_idle_policy() -> Result<(), String> {
    set_current_thread_policy(libc::SCHED_IDLE, 0, "use SCHED_IDLE")
}

/// Sleeps until `CLOCK_MONOTONIC` reads `deadline_ns` (returns at once if it has passed). An
/// absolute deadline needs no clock read before the sleep, and the wake-up does not drift by
/// the time between such a read and the system call.
pub fn sleep_until_monotonic_ns(deadline_ns: u64) {
    const NS_PER_S: u64 = 1_000_000_000;
    let deadline = libc::timespec {
        tv_sec: (deadline_ns / NS_PER_S) as libc::time_t,
        tv_nsec: (deadline_ns % NS_PER_S) as libc::c_long,
    };
    // clock_nanosleep returns the error number; with TIMER_ABSTIME a signal just means "again".
    // SAFETY: `deadline` is a valid timespec; no remainder is asked for with an absolute time.
    while unsafe {
        libc::clock_nanosleep(
            libc::CLOCK_MONOTONIC,
            libc::TIMER_ABSTIME,
            &deadline,
            std::ptr::null_mut(),
        )
    } == libc::EINTR
    {}
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_loop_gets_the_last_allowed_cpu_unless_one_is_named() {
        assert_eq!(choose_realtime_cpu(&[0], None), None);
        assert_eq!(choose_realtime_cpu(&[], Some(0)), None);
        assert_eq!(choose_realtime_cpu(&[0, 1], None), Some(1));
        assert_eq!(choose_realtime_cpu(&[0, 1, 2, 3], Some(0)), Some(0));
        // A CPU the process may not use is ignored.
        assert_eq!(choose_realtime_cpu(&[2, 5], Some(3)), Some(5));
    }

    /// A thread that enters the rest is off the real-time CPU and its children inherit that;
    /// one that enters the real-time side is on that CPU alone.
    #[test]
    fn threads_land_on_their_side_and_children_inherit_it_where_available() {
        let allowed = CpuSet::of_current_thread()
            .map(|s| s.cpus())
            .unwrap_or_default();
        if allowed.len() < 2 {
            println!(
                "SKIP threads_land_on_their_side_and_children_inherit_it_where_available: one CPU"
            );
            return;
        }
        let placement = Placement::plan(true, None, 0, 0);
        let rt = *allowed.last().unwrap();
        let (rest_of_child, rt_of_child) = std::thread::spawn(move || {
            placement.enter_rest("test-rest");
            let rest_child = std::thread::spawn(|| CpuSet::of_current_thread().unwrap().cpus())
                .join()
                .unwrap();
            let mode = placement.enter_realtime("test-rt");
            assert_eq!(mode, RealtimeMode::Normal, "priority 0 asks for no FIFO");
            let rt_child = std::thread::spawn(|| CpuSet::of_current_thread().unwrap().cpus())
                .join()
                .unwrap();
            (rest_child, rt_child)
        })
        .join()
        .unwrap();
        assert!(!rest_of_child.contains(&rt), "{rest_of_child:?} holds {rt}");
        assert_eq!(rest_of_child.len(), allowed.len() - 1);
        assert_eq!(rt_of_child, vec![rt]);
    }

    /// The `stat` fields (from field 3, the state) of this process's threads named `name`.
    fn threads_named(name: &str) -> Vec<Vec<String>> {
        let mut out = Vec::new();
        for task in std::fs::read_dir("/proc/self/task").unwrap().flatten() {
            let comm = std::fs::read_to_string(task.path().join("comm")).unwrap_or_default();
            if comm.trim() != name {
                continue;
            }
            let stat = std::fs::read_to_string(task.path().join("stat")).unwrap_or_default();
            let after = stat.rsplit_once(") ").map(|(_, r)| r).unwrap_or("");
            out.push(after.split_whitespace().map(str::to_string).collect());
        }
        out
    }

    /// Waits up to 5 s for the one `hm-rt-awake` thread to be in `state` ("R" polling, "S"
    /// parked) on CPU `cpu` under SCHED_IDLE.
    fn wait_keep_awake(state: &str, cpu: usize) {
        // Indices from field 3: processor is field 39, policy field 41.
        let (processor, policy) = (39 - 3, 41 - 3);
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(5);
        loop {
            let threads = threads_named("hm-rt-awake");
            if threads.len() == 1
                && threads[0][0] == state
                && threads[0][processor] == cpu.to_string()
                && threads[0][policy] == libc::SCHED_IDLE.to_string()
            {
                return;
            }
            assert!(
                std::time::Instant::now() < deadline,
                "the keep-awake thread is not {state} on CPU {cpu} under SCHED_IDLE: {threads:?}"
            );
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
    }

    #[test]
    fn the_keep_awake_thread_polls_the_realtime_cpu_under_sched_idle_only_while_wanted_where_available(
    ) {
        let allowed = CpuSet::of_current_thread().unwrap().cpus();
        if allowed.len() < 2 {
            println!(
                "SKIP the_keep_awake_thread_polls_the_realtime_cpu_under_sched_idle_only_while_wanted_where_available: one CPU"
            );
            return;
        }
        let rt = *allowed.last().unwrap();
        assert!(
            Placement::plan(false, None, 0, 0)
                .keep_realtime_cpu_awake()
                .is_none(),
            "no CPU of its own: nothing to keep awake"
        );
        let awake = Placement::plan(true, None, 0, 0)
            .keep_realtime_cpu_awake()
            .expect("a CPU of its own");
        wait_keep_awake("S", rt);
        assert!(awake.set_wanted(true));
        assert!(!awake.set_wanted(true), "no change");
        wait_keep_awake("R", rt);
        assert!(awake.set_wanted(false));
        wait_keep_awake("S", rt);
        drop(awake);
        assert!(
            threads_named("hm-rt-awake").is_empty(),
            "still there after drop"
        );
    }
}
