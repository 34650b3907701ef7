//! The hypervisor's steal time, so a real-time check measures the daemon and not the host.
//!
//! On a virtual machine the host can take a virtual CPU away for milliseconds at a time (another
//! guest, the host's own work). The guest's kernel accounts that as *steal* (`/proc/stat`, eighth
//! value of a `cpuN` line, in 1/100 s). What is sampled is the CPU the daemon gives its loop,
//! chosen by the daemon's own rule (`choose_realtime_cpu`) from the CPUs this process may use,
//! which the daemon it starts inherits; with one CPU, the machine's sum. A 1 kHz loop cannot keep
//! its deadlines while its CPU is not running at all, whatever the daemon does; a check of the
//! daemon's timing therefore judges the stretches of a run in which the host took nothing,
//! reports the rest beside it, and fails when too little of the run was left to judge.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use hydrometra_daemon::service::realtime::{choose_realtime_cpu, CpuSet};
use hydrometra_drivers::transport::monotonic_ns;

/// How often `/proc/stat` is read.
const SAMPLE_PERIOD: Duration = Duration::from_millis(50);

/// The kernel accounts a CPU's steal when that CPU takes a tick or leaves idle, so a steal can
/// show up to this long after it happened (and a sample may hold one from just before): a stretch
/// counts as stolen when any steal was seen within this margin of it.
const MARGIN_NS: u64 = 100_000_000;

/// `/proc/stat` counts in USER_HZ ticks.
const STEAL_TICK_S: f64 = 0.01;

/// Samples the machine's steal time on a thread of its own until dropped.
pub struct HostSteal {
    /// (CLOCK_MONOTONIC ns, steal ticks of the loop's CPU so far) per sample.
    samples: Arc<Mutex<Vec<(u64, u64)>>>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

/// The `/proc/stat` line to sample: `cpuN ` for the CPU the daemon's loop gets from the CPUs this
/// process may use (the daemon's own rule, with `loop.realtime_cpu` unset), else the machine's
/// `cpu ` line.
fn stat_line_prefix() -> String {
    let allowed = CpuSet::of_current_thread()
        .map(|s| s.cpus())
        .unwrap_or_default();
    match choose_realtime_cpu(&allowed, None) {
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

impl HostSteal {
    /// Starts sampling now.
    pub fn start() -> Self {
        let samples = Arc::new(Mutex::new(Vec::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (samples, stop) = (samples.clone(), stop.clone());
            let prefix = stat_line_prefix();
            std::thread::spawn(move || {
                while !stop.load(Ordering::Relaxed) {
                    if let Some(ticks) = steal_ticks(&prefix) {
                        let now = monotonic_ns();
                        samples.lock().expect("steal samples").push((now, ticks));
                    }
                    std::thread::sleep(SAMPLE_PERIOD);
                }
            })
        };
        HostSteal {
            samples,
            stop,
            thread: Some(thread),
        }
    }

    /// Whether the host took time from the loop's CPU between the two CLOCK_MONOTONIC instants
    /// (give or take [`MARGIN_NS`]).
    pub fn stolen_between(&self, from_ns: u64, to_ns: u64) -> bool {
        let samples = self.samples.lock().expect("steal samples");
        let (lo, hi) = (from_ns.saturating_sub(MARGIN_NS), to_ns + MARGIN_NS);
        samples
            .windows(2)
            .any(|w| w[1].1 > w[0].1 && w[1].0 >= lo && w[0].0 <= hi)
    }

    /// Seconds the host took from the loop's CPU since the start.
    pub fn stolen_s(&self) -> f64 {
        let samples = self.samples.lock().expect("steal samples");
        match (samples.first(), samples.last()) {
            (Some(a), Some(b)) => (b.1 - a.1) as f64 * STEAL_TICK_S,
            _ => 0.0,
        }
    }
}

impl Drop for HostSteal {
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

    #[test]
    fn a_stretch_is_stolen_only_near_a_rise_in_steal() {
        let s = HostSteal {
            samples: Arc::new(Mutex::new(vec![
                (1_000_000_000, 5),
                (1_050_000_000, 5),
                (1_100_000_000, 7),
                (1_150_000_000, 7),
            ])),
            stop: Arc::new(AtomicBool::new(true)),
            thread: None,
        };
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
            assert!(
                steal_ticks(&stat_line_prefix()).is_some(),
                "{}",
                stat_line_prefix()
            );
        }
        let live = HostSteal::start();
        std::thread::sleep(SAMPLE_PERIOD * 3);
        assert!(live.stolen_s() >= 0.0);
        drop(live);
    }
}
