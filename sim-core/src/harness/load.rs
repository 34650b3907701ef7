//! Background load for benchmarks: busy threads at the default priority that compete with the
//! solver for the cores, as a renderer or another process on the rig's machine would. A
//! fork-join measured "under load" runs beside them (`--load-threads` of `hydrometra fluid bench`
//! and `hydrometra scene bench`).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::{self, JoinHandle};

/// `n` threads spinning on integer work until dropped.
pub struct BusyThreads {
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<u64>>,
}

impl BusyThreads {
    /// Starts `n` busy threads (none for 0).
    pub fn start(n: usize) -> std::io::Result<BusyThreads> {
        let stop = Arc::new(AtomicBool::new(false));
        let mut threads = Vec::with_capacity(n);
        for i in 0..n {
            let flag = Arc::clone(&stop);
            let spawned = thread::Builder::new()
                .name(format!("bench-load-{i}"))
                .spawn(move || {
                    // A multiply-xorshift chain the optimiser cannot drop (its result is returned).
                    let mut x = 0x9e37_79b9_7f4a_7c15u64 ^ i as u64;
                    while !flag.load(Ordering::Relaxed) {
                        for _ in 0..4096 {
                            x ^= x << 13;
                            x ^= x >> 7;
                            x = x.wrapping_mul(0x2545_f491_4f6c_dd1d);
                        }
                    }
                    x
                });
            match spawned {
                Ok(t) => threads.push(t),
                Err(e) => {
                    // Stop the ones already running before reporting.
                    drop(BusyThreads { stop, threads });
                    return Err(e);
                }
            }
        }
        Ok(BusyThreads { stop, threads })
    }

    /// How many threads are spinning.
    pub fn count(&self) -> usize {
        self.threads.len()
    }
}

impl Drop for BusyThreads {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The threads burn CPU while alive and are gone when dropped.
    #[test]
    fn busy_threads_burn_cpu_until_dropped() {
        let cpu = || crate::fork_join::cpu_time_ns(crate::fork_join::CpuClock::Process);
        let Some(before) = cpu() else {
            eprintln!("SKIP busy_threads_burn_cpu_until_dropped: no process CPU clock");
            return;
        };
        let load = BusyThreads::start(1).expect("a load thread");
        assert_eq!(load.count(), 1);
        let t = std::time::Instant::now();
        thread::sleep(std::time::Duration::from_millis(200));
        drop(load);
        let wall = t.elapsed().as_nanos() as u64;
        let used = cpu().unwrap_or(before) - before;
        // One spinning thread on a shared machine: at least a tenth of the wall time.
        assert!(used > wall / 10, "{used} ns of CPU in {wall} ns");
    }
}
