//! A non-blocking tap: a bounded, lock-free channel a time-critical thread offers values to
//! without ever waiting. When the consumer falls behind, values are dropped and counted.
//!
//! Used by the rig I/O thread to hand every received chunk to a recorder, and by the daemon's
//! publisher to hand statuses to it. The buffer is allocated once, when the tap is made; `offer`
//! moves the value into a preallocated slot (std's bounded channel, a lock-free array queue).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::Arc;

/// The sending end; cheap to clone.
#[derive(Debug)]
pub struct Tap<T> {
    tx: SyncSender<T>,
    dropped: Arc<AtomicU64>,
}

impl<T> Clone for Tap<T> {
    fn clone(&self) -> Self {
        Self {
            tx: self.tx.clone(),
            dropped: Arc::clone(&self.dropped),
        }
    }
}

/// The receiving end.
#[derive(Debug)]
pub struct TapReceiver<T> {
    /// Values in the order they were offered.
    pub rx: Receiver<T>,
    dropped: Arc<AtomicU64>,
}

/// A tap holding up to `capacity` values (at least 1).
pub fn tap<T>(capacity: usize) -> (Tap<T>, TapReceiver<T>) {
    let (tx, rx) = sync_channel(capacity.max(1));
    let dropped = Arc::new(AtomicU64::new(0));
    (
        Tap {
            tx,
            dropped: Arc::clone(&dropped),
        },
        TapReceiver { rx, dropped },
    )
}

impl<T> Tap<T> {
    /// Offers a value; never blocks. Returns false when it was dropped: the channel was full
    /// (counted) or the receiver is gone (not counted: nobody records).
    pub fn offer(&self, value: T) -> bool {
        match self.tx.try_send(value) {
            Ok(()) => true,
            Err(TrySendError::Full(_)) => {
                self.dropped.fetch_add(1, Ordering::Relaxed);
                false
            }
            Err(TrySendError::Disconnected(_)) => false,
        }
    }
}

impl<T> TapReceiver<T> {
    /// Values dropped so far because the channel was full.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_tap_drops_and_counts_without_blocking() {
        let (tx, rx) = tap::<u32>(3);
        let accepted: Vec<bool> = (0..5).map(|i| tx.offer(i)).collect();
        assert_eq!(accepted, [true, true, true, false, false]);
        assert_eq!(rx.dropped(), 2);
        let got: Vec<u32> = rx.rx.try_iter().collect();
        assert_eq!(got, [0, 1, 2]);
        assert!(tx.offer(9));
        drop(rx);
        assert!(!tx.offer(10));
    }
}
