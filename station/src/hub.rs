//! The hub between the rig sources and the browsers: for every rig the newest frame of each kind
//! (a slot per kind, overwritten: newest wins), the plots' history, and counters. Sources never
//! wait for a browser; every browser's task takes what is newest when it is ready for more.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

use bytes::Bytes;
use hydrometra_ipc::Status;
use serde::Serialize;
use tokio::sync::watch;

use crate::frame::{self, kind, HistoryRecord};

/// Kinds kept in a rig's slots, in the order a browser is sent them (topology before positions).
pub const SLOT_KINDS: [u8; 5] = [
    kind::TOPOLOGY,
    kind::POSITIONS,
    kind::FLOW,
    kind::PARTICLES,
    kind::STATUS,
];

/// Spacing of the history's records in status time, s (10 per second).
pub const HISTORY_INTERVAL_S: f64 = 0.1;

fn slot_index(k: u8) -> usize {
    SLOT_KINDS.iter().position(|s| *s == k).unwrap_or(0)
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panicking holder cannot leave these plain values inconsistent: keep going.
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// What the page is told about a rig.
#[derive(Debug, Clone, Serialize)]
pub struct RigInfo {
    /// Index in frames and URLs.
    pub index: u16,
    /// Rig id (zenoh) or the service prefix (iceoryx2).
    pub id: String,
    /// Where its data comes from, for a human.
    pub source: String,
    /// Whether the station can send it control requests.
    pub control: bool,
    /// Whether the station can list its recordings.
    pub recordings: bool,
}

#[derive(Default)]
struct Slot {
    /// Updates so far (0: never).
    updates: u64,
    frame: Option<Bytes>,
}

/// Counters of one rig (docs/station.md, `/api/stats`).
#[derive(Debug, Default, Serialize)]
pub struct RigCounters {
    /// Statuses received from the rig's source.
    pub statuses_received: AtomicU64,
    /// Frames encoded, per kind in [`SLOT_KINDS`] order.
    pub frames_encoded: [AtomicU64; 5],
    /// Scene samples not encoded because no browser was connected.
    pub skipped_no_browser: AtomicU64,
    /// Payloads the source could not decode (wrong size, sections outside the payload).
    pub decode_errors: AtomicU64,
    /// Times the source (re)opened the rig's services.
    pub reconnects: AtomicU64,
}

#[derive(Default)]
struct History {
    run_id: u64,
    records: VecDeque<HistoryRecord>,
    pending_alarms: u32,
    capacity: usize,
}

/// One rig: its newest frames, its history and its counters.
pub struct Rig {
    /// What the page is told about it.
    pub info: RigInfo,
    /// Counters.
    pub counters: RigCounters,
    slots: Mutex<[Slot; 5]>,
    history: Mutex<History>,
    latest: Mutex<Option<Status>>,
    changed: Arc<watch::Sender<u64>>,
    browsers: Arc<AtomicUsize>,
}

impl Rig {
    /// Whether a browser is connected (scene frames are encoded only then).
    pub fn wanted(&self) -> bool {
        self.browsers.load(Ordering::Relaxed) > 0
    }

    /// Stores the newest frame of kind `k` and wakes the browsers.
    pub fn put(&self, k: u8, frame: Bytes) {
        let i = slot_index(k);
        {
            let mut slots = lock(&self.slots);
            slots[i].updates += 1;
            slots[i].frame = Some(frame);
        }
        self.counters.frames_encoded[i].fetch_add(1, Ordering::Relaxed);
        self.changed.send_modify(|g| *g = g.wrapping_add(1));
    }

    /// Records a received status: the latest (for the API), the history, and a status frame when
    /// `send` and a browser is connected.
    pub fn status(&self, s: &Status, send: bool) {
        self.counters
            .statuses_received
            .fetch_add(1, Ordering::Relaxed);
        *lock(&self.latest) = Some(*s);
        {
            let mut h = lock(&self.history);
            if h.run_id != s.run_id {
                // Another daemon run: its clock restarted.
                h.records.clear();
                h.run_id = s.run_id;
            }
            h.pending_alarms |= s.alarm_bits as u32;
            let due = h
                .records
                .back()
                .is_none_or(|r| s.sim_time_s - r.sim_time_s >= HISTORY_INTERVAL_S);
            if due {
                let mut r = HistoryRecord::of(s);
                r.alarm_bits = std::mem::take(&mut h.pending_alarms);
                if h.records.len() >= h.capacity {
                    h.records.pop_front();
                }
                h.records.push_back(r);
            }
        }
        if send && self.wanted() {
            self.put(kind::STATUS, frame::status(self.info.index, s));
        }
    }

    /// The newest status received, if any.
    pub fn latest(&self) -> Option<Status> {
        *lock(&self.latest)
    }

    /// The history as one frame.
    pub fn history_frame(&self) -> Bytes {
        let h = lock(&self.history);
        frame::history(self.info.index, h.records.iter().copied())
    }

    /// Frames newer than `seen` (updates per slot), in [`SLOT_KINDS`] order; `seen` is advanced.
    /// Returns also how many updates were overwritten before this browser took them.
    pub fn newer(&self, seen: &mut [u64; 5]) -> (Vec<Bytes>, u64) {
        let slots = lock(&self.slots);
        let mut out = Vec::new();
        let mut superseded = 0;
        for (i, slot) in slots.iter().enumerate() {
            if slot.updates > seen[i] {
                if let Some(f) = &slot.frame {
                    superseded += slot.updates - seen[i] - 1;
                    out.push(f.clone());
                }
                seen[i] = slot.updates;
            }
        }
        (out, superseded)
    }
}

/// Station-wide counters.
#[derive(Debug, Default, Serialize)]
pub struct StationCounters {
    /// Browsers connected now.
    pub browsers: AtomicUsize,
    /// Browsers connected since start.
    pub browsers_total: AtomicU64,
    /// Frames sent to browsers.
    pub frames_sent: AtomicU64,
    /// Frames overwritten by a newer one before a browser took them (slow browsers).
    pub frames_superseded: AtomicU64,
    /// Browsers disconnected because one send took longer than the send timeout.
    pub browsers_dropped_slow: AtomicU64,
    /// Client messages refused (malformed, oversized, binary, unauthorised).
    pub client_errors: AtomicU64,
}

/// Every rig, the browsers' wake-up and the station's counters.
pub struct Hub {
    rigs: Mutex<Vec<Arc<Rig>>>,
    changed: Arc<watch::Sender<u64>>,
    /// Station-wide counters.
    pub counters: StationCounters,
    browsers: Arc<AtomicUsize>,
    history_capacity: usize,
    latency: Mutex<hdrhistogram::Histogram<u64>>,
}

impl Hub {
    /// An empty hub keeping `history_s` seconds of plot history per rig.
    pub fn new(history_s: f64) -> Arc<Self> {
        let (tx, _) = watch::channel(0u64);
        Arc::new(Self {
            rigs: Mutex::new(Vec::new()),
            changed: Arc::new(tx),
            counters: StationCounters::default(),
            browsers: Arc::new(AtomicUsize::new(0)),
            history_capacity: (history_s / HISTORY_INTERVAL_S).ceil().max(1.0) as usize,
            // 1 µs to 60 s, 3 significant digits: valid bounds, cannot fail.
            latency: Mutex::new(
                hdrhistogram::Histogram::new_with_bounds(1, 60_000_000, 3)
                    .unwrap_or_else(|_| unreachable!("constant histogram bounds")), // ok: constant
            ),
        })
    }

    /// Adds a rig (its index is its position) and tells the browsers.
    pub fn add_rig(&self, id: String, source: String, control: bool, recordings: bool) -> Arc<Rig> {
        let mut rigs = lock(&self.rigs);
        let rig = Arc::new(Rig {
            info: RigInfo {
                index: rigs.len() as u16,
                id,
                source,
                control,
                recordings,
            },
            counters: RigCounters::default(),
            slots: Mutex::new(Default::default()),
            history: Mutex::new(History {
                capacity: self.history_capacity,
                ..Default::default()
            }),
            latest: Mutex::new(None),
            changed: self.changed.clone(),
            browsers: self.browsers.clone(),
        });
        rigs.push(rig.clone());
        drop(rigs);
        self.changed.send_modify(|g| *g = g.wrapping_add(1));
        rig
    }

    /// The rigs so far.
    pub fn rigs(&self) -> Vec<Arc<Rig>> {
        lock(&self.rigs).clone()
    }

    /// The rig with this index.
    pub fn rig(&self, index: usize) -> Option<Arc<Rig>> {
        lock(&self.rigs).get(index).cloned()
    }

    /// The rig with this id.
    pub fn rig_by_id(&self, id: &str) -> Option<Arc<Rig>> {
        lock(&self.rigs).iter().find(|r| r.info.id == id).cloned()
    }

    /// A receiver woken on every new frame or rig.
    pub fn subscribe(&self) -> watch::Receiver<u64> {
        self.changed.subscribe()
    }

    /// Registers a browser for as long as the guard lives.
    pub fn browser(self: &Arc<Self>) -> BrowserGuard {
        self.browsers.fetch_add(1, Ordering::Relaxed);
        self.counters.browsers.fetch_add(1, Ordering::Relaxed);
        self.counters.browsers_total.fetch_add(1, Ordering::Relaxed);
        BrowserGuard { hub: self.clone() }
    }

    /// Records one rig-sample-to-page latency reported by a browser.
    pub fn record_latency(&self, latency_ns: u64) {
        let us = (latency_ns / 1000).clamp(1, 60_000_000);
        let _ = lock(&self.latency).record(us);
    }

    /// p50, p99, max (s) and count of the latencies browsers reported.
    pub fn latency(&self) -> (f64, f64, f64, u64) {
        let h = lock(&self.latency);
        let s = |us: u64| us as f64 * 1e-6;
        (
            s(h.value_at_quantile(0.5)),
            s(h.value_at_quantile(0.99)),
            s(h.max()),
            h.len(),
        )
    }

    /// Forgets the latencies so far (the benchmark's warm-up).
    pub fn reset_latency(&self) {
        lock(&self.latency).reset();
    }
}

/// A connected browser; unregisters on drop.
pub struct BrowserGuard {
    hub: Arc<Hub>,
}

impl Drop for BrowserGuard {
    fn drop(&mut self) {
        self.hub.browsers.fetch_sub(1, Ordering::Relaxed);
        self.hub.counters.browsers.fetch_sub(1, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn status_at(t: f64, run: u64, alarms: u64) -> Status {
        Status {
            sim_time_s: t,
            run_id: run,
            alarm_bits: alarms,
            ..Status::default()
        }
    }

    #[test]
    fn a_slow_browser_gets_the_newest_frame_and_counts_what_it_missed() {
        let hub = Hub::new(10.0);
        let rig = hub.add_rig("a".into(), "test".into(), false, false);
        let _b = hub.browser();
        let mut seen = [0u64; 5];
        for i in 0..5u8 {
            rig.put(kind::POSITIONS, Bytes::from(vec![i]));
        }
        rig.put(kind::TOPOLOGY, Bytes::from_static(b"t"));
        let (frames, superseded) = rig.newer(&mut seen);
        // Topology first, then the newest positions only.
        assert_eq!(
            frames,
            vec![Bytes::from_static(b"t"), Bytes::from(vec![4u8])]
        );
        assert_eq!(superseded, 4);
        assert!(rig.newer(&mut seen).0.is_empty());
    }

    #[test]
    fn history_keeps_ten_records_a_second_ors_alarms_and_restarts_with_the_run() {
        let hub = Hub::new(1.0); // 10 records
        let rig = hub.add_rig("a".into(), "test".into(), false, false);
        for i in 0..200 {
            // 1 kHz statuses over 0.2 s, one alarm bit raised at 50 ms only.
            let alarms = if i == 50 { 1 << 13 } else { 0 };
            rig.status(&status_at(i as f64 * 1e-3, 1, alarms), false);
        }
        let h = lock(&rig.history);
        let t: Vec<f64> = h.records.iter().map(|r| r.sim_time_s).collect();
        assert_eq!(t.len(), 2);
        assert!((t[1] - 0.1).abs() < 1e-9, "{t:?}");
        assert_eq!(h.records[1].alarm_bits, 1 << 13);
        drop(h);
        for i in 0..30 {
            rig.status(&status_at(i as f64 * 0.1, 1, 0), false);
        }
        assert_eq!(lock(&rig.history).records.len(), 10);
        rig.status(&status_at(0.0, 2, 0), false);
        assert_eq!(lock(&rig.history).records.len(), 1);
    }

    #[test]
    fn status_frames_are_encoded_only_while_a_browser_is_connected() {
        let hub = Hub::new(1.0);
        let rig = hub.add_rig("a".into(), "test".into(), false, false);
        rig.status(&status_at(0.0, 1, 0), true);
        assert!(rig.newer(&mut [0; 5]).0.is_empty());
        let b = hub.browser();
        rig.status(&status_at(0.1, 1, 0), true);
        assert_eq!(rig.newer(&mut [0; 5]).0.len(), 1);
        drop(b);
        assert!(!rig.wanted());
    }
}
