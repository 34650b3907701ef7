//! What the machine took from the daemon's real-time CPU, so a real-time check judges the daemon
//! and not the machine it runs on.
//!
//! A 1 kHz loop cannot keep its deadlines while its CPU is not running it, whatever the daemon
//! does: on a virtual machine the host deschedules a virtual CPU for milliseconds at a time (another
//! guest, the host's own work), and wakes a halted one late. Two witnesses say when that happened,
//! on the CPU the daemon gives its loop (the daemon's own rule, [`choose_realtime_cpu`], from the
//! CPUs this process may use, which the daemon it starts inherits):
//!
//! - **The probe**: a `SCHED_FIFO` thread of the test process on that CPU, one priority level above
//!   the daemon's loop, waking every [`PROBE_PERIOD_NS`]. Whatever keeps a `SCHED_FIFO` thread off
//!   the CPU (the host descheduling it, accounted as steal or not; a late wake-up from a halt; the
//!   kernel's own non-preemptible work) makes the probe late as much as the loop. What only the
//!   daemon does (its work, a lock it waits for, a blocking call, a page fault of its thread)
//!   makes the loop late and not the probe, which preempts it. A stretch is *interfered with*
//!   when the probe woke more than [`PROBE_STALL_NS`] late in it. The probe costs its CPU a few
//!   microseconds per wake-up (about 1 %).
//! - **Steal time** (`/proc/stat`, eighth value of the `cpuN` line, in 1/100 s and accounted when
//!   the CPU next takes a tick or leaves idle): the witness where the probe cannot have
//!   `SCHED_FIFO` (no privilege); a stretch counts as stolen within [`STEAL_MARGIN_NS`] of a rise.
//!   The host also takes the CPU in bursts that steal does not show (seen on the AMD EPYC machine
//!   kind): where the probe runs, it is the judge and steal is only reported beside it.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc, Mutex};
use std::time::Duration;

use hydrometra_daemon::service::config::LoopConfig;
use hydrometra_daemon::service::realtime::{
    choose_realtime_cpu, set_current_thread_fifo, sleep_until_monotonic_ns, CpuSet,
};
use hydrometra_drivers::transport::monotonic_ns;

/// The probe's period. A stall of the CPU of `L` holds up the probe's first wake-up inside it by
/// more than `L - PROBE_PERIOD_NS`, so every stall longer than `PROBE_PERIOD_NS + PROBE_STALL_NS`
/// (0.95 ms) is seen: every stall that alone makes the 1 ms loop miss a tick (a tick at least
/// 1 ms late).
pub const PROBE_PERIOD_NS: u64 = 500_000;

/// A probe wake-up later than this is a stall of the CPU. A `SCHED_FIFO` thread that preempts
/// the `SCHED_IDLE` poller on a running CPU wakes within tens of microseconds (the summary prints
/// the probe's median and 99th percentile); far below this, and this far below a miss.
pub const PROBE_STALL_NS: u64 = 450_000;

/// The probe's lateness histogram: buckets of this width up to [`PROBE_STALL_NS`]'s range.
const LATENESS_BUCKET_NS: u64 = 10_000;
const LATENESS_BUCKETS: usize = 100;

/// How often `/proc/stat` is read for steal.
const STEAL_SAMPLE_PERIOD: Duration = Duration::from_millis(50);

/// Steal shows up to a tick after it happened, and a sample may hold one from just before: a
/// stretch counts as stolen when any rise was seen within this margin of it.
const STEAL_MARGIN_NS: u64 = 100_000_000;

/// `/proc/stat` counts in USER_HZ ticks.
const STEAL_TICK_S: f64 = 0.01;

/// Room for this many stalls without allocating on the probe's thread.
const STALL_CAPACITY: usize = 1 << 16;

/// Watches the loop's CPU from now until dropped.
/// What [`HostWatch::judge`] found.
#[derive(Debug, Clone, Copy, Default)]
pub struct LoopRecord {
    /// Pairs of consecutive statuses.
    pub pairs: usize,
    /// Longest time between two consecutive statuses, s.
    pub gap_max_s: f64,
    /// Ticks and deadline misses between the judged pairs.
    pub judged_ticks: u64,
    pub judged_misses: u64,
    /// Longest time between two judged consecutive statuses, s.
    pub judged_gap_max_s: f64,
    /// Time between the judged pairs, s (publish stamps): the loop's tick rate where the machine
    /// took nothing is `judged_ticks / judged_s`.
    pub judged_s: f64,
}

pub struct HostWatch {
    cpu: Option<usize>,
    probe: Result<Probe, String>,
    steal: StealSampler,
}

impl HostWatch {
    /// Starts both witnesses on the CPU the daemon will give its loop.
    pub fn start() -> Self {
        let allowed = CpuSet::of_current_thread()
            .map(|s| s.cpus())
            .unwrap_or_default();
        let cpu = choose_realtime_cpu(&allowed, None);
        let probe = match cpu {
            Some(cpu) => Probe::start(cpu, LoopConfig::default().realtime_priority),
            None => Err("one CPU: the loop shares it with everything".into()),
        };
        HostWatch {
            cpu,
            probe,
            steal: StealSampler::start(cpu),
        }
    }

    /// Whether the machine kept the loop's CPU from a `SCHED_FIFO` thread between the two
    /// CLOCK_MONOTONIC instants (the probe's judgement; steal's where there is no probe).
    pub fn interfered_between(&self, from_ns: u64, to_ns: u64) -> bool {
        match &self.probe {
            Ok(probe) => probe.stalled_between(from_ns, to_ns),
            Err(_) => self.steal.stolen_between(from_ns, to_ns),
        }
    }

    /// The 1 kHz loop's record over consecutive statuses (pairs whose sequences follow; a gap in
    /// a subscriber's own reading is not the daemon's): all of it, and the part judged, where
    /// the machine took nothing from the loop's CPU between the two statuses.
    pub fn judge(&self, statuses: &[hydrometra_ipc::Status]) -> LoopRecord {
        let mut r = LoopRecord::default();
        for w in statuses
            .windows(2)
            .filter(|w| w[1].sequence == w[0].sequence + 1)
        {
            let (a, b) = (w[0].publish_monotonic_ns, w[1].publish_monotonic_ns);
            let gap_s = b.saturating_sub(a) as f64 * 1e-9;
            let (ticks, misses) = (
                w[1].ticks - w[0].ticks,
                w[1].deadline_misses - w[0].deadline_misses,
            );
            r.pairs += 1;
            r.gap_max_s = r.gap_max_s.max(gap_s);
            if !self.interfered_between(a, b) {
                r.judged_ticks += ticks;
                r.judged_misses += misses;
                r.judged_gap_max_s = r.judged_gap_max_s.max(gap_s);
                r.judged_s += gap_s;
            }
        }
        r
    }

    /// Seconds of steal on the loop's CPU since the start.
    pub fn stolen_s(&self) -> f64 {
        self.steal.stolen_s()
    }

    /// One line for a test's report: what each witness saw.
    pub fn summary(&self) -> String {
        let cpu = self
            .cpu
            .map_or_else(|| "the machine".to_string(), |c| format!("CPU {c}"));
        let probe = match &self.probe {
            Ok(p) => {
                let s = p.stats();
                format!(
                    "the probe on {cpu} ({} wake-ups, late by p50 {:.2} p99 {:.2} ms) stalled {} \
                     times (later than {:.2} ms), longest {:.3} ms, {:.3} s in all",
                    s.wakes,
                    s.p50_late_ns as f64 * 1e-6,
                    s.p99_late_ns as f64 * 1e-6,
                    s.stalls,
                    PROBE_STALL_NS as f64 * 1e-6,
                    s.longest_ns as f64 * 1e-6,
                    s.stalled_ns as f64 * 1e-9
                )
            }
            Err(why) => format!("no probe ({why}): judged by steal alone"),
        };
        format!("{probe}; steal on {cpu} {:.2} s", self.stolen_s())
    }
}

/// What the probe saw so far.
#[derive(Debug, Clone, Copy, Default)]
pub struct ProbeStats {
    pub wakes: u64,
    pub stalls: u64,
    pub longest_ns: u64,
    pub stalled_ns: u64,
    /// Median and 99th percentile of every wake-up's lateness (10 us buckets; 1 ms and more in
    /// the last).
    pub p50_late_ns: u64,
    pub p99_late_ns: u64,
}

struct Probe {
    /// (scheduled, woke) CLOCK_MONOTONIC ns of each late wake-up, in time order.
    stalls: Arc<Mutex<Vec<(u64, u64)>>>,
    /// Every wake-up's lateness, by [`LATENESS_BUCKET_NS`].
    lateness: Arc<[AtomicU64; LATENESS_BUCKETS]>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Probe {
    /// Starts the probe on `cpu` at one level above `loop_priority`; the reason where the
    /// system refuses the CPU or the policy.
    fn start(cpu: usize, loop_priority: u8) -> Result<Probe, String> {
        let stalls = Arc::new(Mutex::new(Vec::with_capacity(STALL_CAPACITY)));
        let lateness = Arc::new(std::array::from_fn(|_| AtomicU64::new(0)));
        let stop = Arc::new(AtomicBool::new(false));
        let (ready_tx, ready_rx) = mpsc::channel::<Result<(), String>>();
        let thread = {
            let (stalls, lateness, stop) = (stalls.clone(), lateness.clone(), stop.clone());
            std::thread::Builder::new()
                .name("host-probe".into())
                .spawn(move || {
                    let entered = CpuSet::from_cpus(&[cpu])
                        .apply_to_current_thread()
                        .map_err(|e| format!("cannot move to CPU {cpu}: {e}"))
                        .and_then(|()| set_current_thread_fifo(loop_priority.saturating_add(1)));
                    let ok = entered.is_ok();
                    let _ = ready_tx.send(entered);
                    if ok {
                        probe_loop(&stalls, &lateness, &stop);
                    }
                })
                .map_err(|e| format!("cannot start the probe: {e}"))?
        };
        match ready_rx.recv() {
            Ok(Ok(())) => Ok(Probe {
                stalls,
                lateness,
                stop,
                thread: Some(thread),
            }),
            Ok(Err(why)) => {
                let _ = thread.join();
                Err(why)
            }
            Err(_) => Err("the probe thread ended before it started".into()),
        }
    }

    fn stalled_between(&self, from_ns: u64, to_ns: u64) -> bool {
        // A stall just outside the stretch can still hold up its first or last status.
        let (lo, hi) = (
            from_ns.saturating_sub(PROBE_PERIOD_NS),
            to_ns + PROBE_PERIOD_NS,
        );
        let stalls = self.stalls.lock().unwrap_or_else(|e| e.into_inner());
        // Stalls are in time order and never overlap: the first one ending at or after `lo`
        // is the only one that can start by `hi` first.
        let i = stalls.partition_point(|s| s.1 < lo);
        stalls.get(i).is_some_and(|s| s.0 <= hi)
    }

    fn stats(&self) -> ProbeStats {
        let stalls = self.stalls.lock().unwrap_or_else(|e| e.into_inner());
        let late = stalls.iter().map(|s| s.1 - s.0);
        let counts: Vec<u64> = self
            .lateness
            .iter()
            .map(|c| c.load(Ordering::Relaxed))
            .collect();
        let wakes: u64 = counts.iter().sum();
        // The upper edge of the bucket holding the q-th wake-up.
        let quantile = |q: f64| {
            let rank = (q * wakes as f64).ceil() as u64;
            let mut seen = 0;
            let i = counts
                .iter()
                .position(|&c| {
                    seen += c;
                    seen >= rank.max(1)
                })
                .unwrap_or(LATENESS_BUCKETS - 1);
            (i as u64 + 1) * LATENESS_BUCKET_NS
        };
        ProbeStats {
            wakes,
            stalls: stalls.len() as u64,
            longest_ns: late.clone().max().unwrap_or(0),
            stalled_ns: late.sum(),
            p50_late_ns: quantile(0.5),
            p99_late_ns: quantile(0.99),
        }
    }
}

/// The probe's thread: wakes every period on an absolute deadline and keeps the late wake-ups.
/// It never waits for the test's thread (stalls it cannot hand over at once wait for the next
/// one) and never allocates while it runs.
fn probe_loop(
    stalls: &Mutex<Vec<(u64, u64)>>,
    lateness: &[AtomicU64; LATENESS_BUCKETS],
    stop: &AtomicBool,
) {
    let mut pending: Vec<(u64, u64)> = Vec::with_capacity(STALL_CAPACITY);
    let mut next_ns = monotonic_ns() + PROBE_PERIOD_NS;
    while !stop.load(Ordering::Relaxed) {
        sleep_until_monotonic_ns(next_ns);
        let woke_ns = monotonic_ns();
        let late_ns = woke_ns.saturating_sub(next_ns);
        let bucket = ((late_ns / LATENESS_BUCKET_NS) as usize).min(LATENESS_BUCKETS - 1);
        lateness[bucket].fetch_add(1, Ordering::Relaxed);
        if late_ns > PROBE_STALL_NS && pending.len() < pending.capacity() {
            pending.push((next_ns, woke_ns));
        }
        if !pending.is_empty() {
            if let Ok(mut shared) = stalls.try_lock() {
                let room = shared.capacity() - shared.len();
                let n = pending.len().min(room);
                shared.extend(pending.drain(..n));
            }
        }
        // The next deadline after this wake-up: a long stall is one stall, not a burst of them.
        next_ns += PROBE_PERIOD_NS * (1 + late_ns / PROBE_PERIOD_NS);
    }
}

impl Drop for Probe {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Samples the steal time of one CPU's `/proc/stat` line on a thread of its own until dropped.
struct StealSampler {
    /// (CLOCK_MONOTONIC ns, steal ticks so far) per sample.
    samples: Arc<Mutex<Vec<(u64, u64)>>>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

/// The `/proc/stat` line of `cpu` (`cpuN `), or the machine's (`cpu `).
fn stat_line_prefix(cpu: Option<usize>) -> String {
    match cpu {
        Some(cpu) => format!("cpu{cpu} "),
        None => "cpu ".to_string(),
    }
}

/// The steal ticks of the `/proc/stat` line starting with `prefix` (`None` where there is none).
fn steal_ticks(prefix: &str) -> Option<u64> {
    let stat = std::fs::read_to_string("/proc/stat").ok()?;
    let line = stat.lines().find(|l| l.starts_with(prefix))?;
    line.split_whitespace().nth(8)?.parse().ok()
}

impl StealSampler {
    fn start(cpu: Option<usize>) -> Self {
        let samples = Arc::new(Mutex::new(Vec::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (samples, stop) = (samples.clone(), stop.clone());
            let prefix = stat_line_prefix(cpu);
            std::thread::spawn(move || {
                while !stop.load(Ordering::Relaxed) {
                    if let Some(ticks) = steal_ticks(&prefix) {
                        let now = monotonic_ns();
                        samples
                            .lock()
                            .unwrap_or_else(|e| e.into_inner())
                            .push((now, ticks));
                    }
                    std::thread::sleep(STEAL_SAMPLE_PERIOD);
                }
            })
        };
        StealSampler {
            samples,
            stop,
            thread: Some(thread),
        }
    }

    fn stolen_between(&self, from_ns: u64, to_ns: u64) -> bool {
        let samples = self.samples.lock().unwrap_or_else(|e| e.into_inner());
        let (lo, hi) = (
            from_ns.saturating_sub(STEAL_MARGIN_NS),
            to_ns + STEAL_MARGIN_NS,
        );
        samples
            .windows(2)
            .any(|w| w[1].1 > w[0].1 && w[1].0 >= lo && w[0].0 <= hi)
    }

    fn stolen_s(&self) -> f64 {
        let samples = self.samples.lock().unwrap_or_else(|e| e.into_inner());
        match (samples.first(), samples.last()) {
            (Some(a), Some(b)) => (b.1 - a.1) as f64 * STEAL_TICK_S,
            _ => 0.0,
        }
    }
}

impl Drop for StealSampler {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sampler(samples: Vec<(u64, u64)>) -> StealSampler {
        StealSampler {
            samples: Arc::new(Mutex::new(samples)),
            stop: Arc::new(AtomicBool::new(true)),
            thread: None,
        }
    }

    fn probe(stalls: Vec<(u64, u64)>) -> Probe {
        Probe {
            stalls: Arc::new(Mutex::new(stalls)),
            lateness: Arc::new(std::array::from_fn(|i| AtomicU64::new(u64::from(i < 2)))),
            stop: Arc::new(AtomicBool::new(true)),
            thread: None,
        }
    }

    #[test]
    fn a_stretch_is_stolen_only_near_a_rise_in_steal() {
        let s = sampler(vec![
            (1_000_000_000, 5),
            (1_050_000_000, 5),
            (1_100_000_000, 7),
            (1_150_000_000, 7),
        ]);
        assert!(s.stolen_between(1_060_000_000, 1_070_000_000));
        assert!(
            s.stolen_between(1_190_000_000, 1_200_000_000),
            "within the margin"
        );
        assert!(!s.stolen_between(1_300_000_000, 1_400_000_000));
        assert!(!s.stolen_between(0, 900_000_000));
        assert!((s.stolen_s() - 0.02).abs() < 1e-12);
        // The sampled line exists; the sampler runs and stops on drop.
        if std::path::Path::new("/proc/stat").exists() {
            assert!(steal_ticks(&stat_line_prefix(None)).is_some());
        }
        let live = StealSampler::start(None);
        std::thread::sleep(STEAL_SAMPLE_PERIOD * 3);
        assert!(live.stolen_s() >= 0.0);
    }

    #[test]
    fn a_stretch_is_interfered_with_only_where_a_stall_overlaps_it() {
        const MS: u64 = 1_000_000;
        let p = probe(vec![(10 * MS, 13 * MS), (20 * MS, 20 * MS + 500_000)]);
        // Overlapping, inside, around.
        assert!(p.stalled_between(12 * MS, 14 * MS));
        assert!(p.stalled_between(11 * MS, 12 * MS));
        assert!(p.stalled_between(5 * MS, 25 * MS));
        // Within a period of either end.
        assert!(p.stalled_between(13 * MS + PROBE_PERIOD_NS, 15 * MS));
        assert!(p.stalled_between(19 * MS, 20 * MS - PROBE_PERIOD_NS));
        // Clear of both.
        assert!(!p.stalled_between(14 * MS, 19 * MS));
        assert!(!p.stalled_between(22 * MS, 30 * MS));
        assert!(!p.stalled_between(0, 9 * MS));
        let s = p.stats();
        assert_eq!(
            (s.stalls, s.longest_ns, s.stalled_ns),
            (2, 3 * MS, 3_500_000)
        );
        // One wake-up in each of the first two buckets: the median is the first's upper edge.
        assert_eq!((s.wakes, s.p50_late_ns, s.p99_late_ns), (2, 10_000, 20_000));
    }

    /// Where the probe may run (root or CAP_SYS_NICE), it wakes on its period and sees a stall
    /// this test makes itself: a SCHED_FIFO thread at the probe's own priority on its CPU, busy
    /// for 20 ms, which the probe cannot preempt.
    #[test]
    fn the_probe_sees_a_thread_that_holds_its_cpu_where_available() {
        let allowed = CpuSet::of_current_thread()
            .map(|s| s.cpus())
            .unwrap_or_default();
        let Some(cpu) = choose_realtime_cpu(&allowed, None) else {
            println!("SKIP the_probe_sees_a_thread_that_holds_its_cpu_where_available: one CPU");
            return;
        };
        let loop_priority = LoopConfig::default().realtime_priority;
        let p = match Probe::start(cpu, loop_priority) {
            Ok(p) => p,
            Err(why) => {
                println!("SKIP the_probe_sees_a_thread_that_holds_its_cpu_where_available: {why}");
                return;
            }
        };
        std::thread::sleep(Duration::from_millis(50));
        let hog = std::thread::spawn(move || {
            CpuSet::from_cpus(&[cpu])
                .apply_to_current_thread()
                .expect("the probe's CPU");
            set_current_thread_fifo(loop_priority + 1).expect("the probe's priority");
            let from = monotonic_ns();
            while monotonic_ns() - from < 20_000_000 {}
            (from, monotonic_ns())
        });
        let (from, to) = hog.join().expect("hog");
        std::thread::sleep(Duration::from_millis(50));
        let s = p.stats();
        assert!(s.wakes >= 150, "{} wake-ups in 120 ms", s.wakes);
        assert!(
            p.stalled_between(from, to),
            "the 20 ms hold not seen: {s:?}"
        );
        assert!(
            s.longest_ns >= 15_000_000,
            "the longest stall {} ms, held 20 ms",
            s.longest_ns as f64 * 1e-6
        );
    }
}
