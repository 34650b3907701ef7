//! systemd notification (READY, WATCHDOG, STOPPING, STATUS); no-ops without NOTIFY_SOCKET.

use std::time::Duration;

/// Talks to systemd when started as a `Type=notify` service.
#[derive(Debug, Clone, Copy)]
pub struct Systemd {
    watchdog_interval: Option<Duration>,
}

impl Systemd {
    /// Reads `WATCHDOG_USEC` (and `WATCHDOG_PID`, which must be this process when set, as in
    /// libsystemd's `sd_watchdog_enabled`) from the environment.
    pub fn from_env() -> Self {
        let usec = std::env::var("WATCHDOG_USEC")
            .ok()
            .and_then(|v| v.parse::<u64>().ok())
            .filter(|&u| u > 0);
        let pid_matches = match std::env::var("WATCHDOG_PID") {
            Ok(pid) => pid.parse::<u32>().ok() == Some(std::process::id()),
            Err(_) => true,
        };
        Self {
            // Ping at half the watchdog timeout, as systemd recommends.
            watchdog_interval: usec
                .filter(|_| pid_matches)
                .map(|u| Duration::from_micros(u / 2)),
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
