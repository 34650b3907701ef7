//! systemd notification (READY, WATCHDOG, STOPPING, STATUS); no-ops without NOTIFY_SOCKET.

use std::time::Duration;

/// Talks to systemd when started as a `Type=notify` service.
#[derive(Debug, Clone, Copy)]
pub struct Systemd {
    watchdog_interval: Option<Duration>,
}

impl Systemd {
    /// Reads `NOTIFY_SOCKET` and `WATCHDOG_USEC` from the environment.
    pub fn from_env() -> Self {
        let mut usec = 0u64;
        let enabled = sd_notify::watchdog_enabled(false, &mut usec);
        Self {
            // Ping at half the watchdog timeout, as systemd recommends.
            watchdog_interval: enabled.then(|| Duration::from_micros(usec / 2)),
        }
    }

    /// Interval at which [`Systemd::watchdog`] must be called, if the watchdog is on.
    pub fn watchdog_interval(&self) -> Option<Duration> {
        self.watchdog_interval
    }

    fn send(&self, state: &[sd_notify::NotifyState]) {
        if let Err(e) = sd_notify::notify(false, state) {
            tracing::debug!(error = %e, "sd_notify failed");
        }
    }

    /// Startup finished.
    pub fn ready(&self, status: &str) {
        self.send(&[
            sd_notify::NotifyState::Ready,
            sd_notify::NotifyState::Status(status),
        ]);
    }

    /// The service is alive and making progress.
    pub fn watchdog(&self) {
        self.send(&[sd_notify::NotifyState::Watchdog]);
    }

    /// Free-form status line for `systemctl status`.
    pub fn status(&self, status: &str) {
        self.send(&[sd_notify::NotifyState::Status(status)]);
    }

    /// Shutdown started.
    pub fn stopping(&self) {
        self.send(&[sd_notify::NotifyState::Stopping]);
    }
}
