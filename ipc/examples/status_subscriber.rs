//! Minimal Rust renderer-side subscriber: waits for the daemon's "status published" event, then
//! reads the latest status.
//!
//!     cargo run -p hydrometra-ipc --example status_subscriber -- [PREFIX]

use core::time::Duration;

use hydrometra_ipc::{events, status, ServiceNames};
use iceoryx2::prelude::*;

fn main() -> Result<(), Box<dyn core::error::Error>> {
    set_log_level_from_env_or(LogLevel::Error);
    let prefix = std::env::args().nth(1);
    let names = ServiceNames::new(
        prefix
            .as_deref()
            .unwrap_or(hydrometra_ipc::DEFAULT_SERVICE_PREFIX),
    )?;
    let node = NodeBuilder::new().create::<ipc::Service>()?;
    let subscriber = status::open(&node, &names)
        .map_err(|e| {
            format!(
                "cannot open {} ({e:?}): is hydrometrad running?",
                names.full("status")
            )
        })?
        .subscriber_builder()
        .create()?;
    let listener = events::open(&node, &names)?.listener_builder().create()?;
    loop {
        // Block until the daemon publishes (or 1 s passes), then take the newest status.
        let mut shutdown = false;
        listener.timed_wait(
            |event| shutdown |= event.id == events::SHUTDOWN,
            Duration::from_secs(1),
        )?;
        let mut latest = None;
        while let Some(sample) = subscriber.receive()? {
            latest = Some(*sample);
        }
        if let Some(s) = latest {
            println!(
                "#{} t={:.3} s link={} inflow={:.2} outflow={:.2} pump={:.0} Pa alarms={:?}",
                s.sequence,
                s.sim_time_s,
                status::link_state::name(s.link_state),
                s.valve_in_opening,
                s.valve_out_opening,
                s.pump_set_pressure_pa,
                hydrometra_ipc::alarms::names(s.alarm_bits)
            );
        }
        if shutdown {
            println!("daemon stopped");
            return Ok(());
        }
    }
}
