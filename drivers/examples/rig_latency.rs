//! Latency from the emulated firmware taking a sample to a consumer thread holding the calibrated
//! state (encode, pseudo-terminal, I/O thread decode + calibration, condvar wake-up).
//!
//! Run: `cargo run --release -p hydrometra-drivers --example rig_latency -- [SECONDS]`

use std::time::Duration;

use hydrometra_drivers::calibration::Calibration;
use hydrometra_drivers::emulator::{EmulatedRig, EmulatorOptions, Scenario};
use hydrometra_drivers::transport::{DeviceTarget, LinkConfig, RigLink};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let seconds: f64 = match std::env::args().nth(1) {
        Some(s) => s
            .parse()
            .map_err(|_| format!("SECONDS {s:?}: expected a number"))?,
        None => 10.0,
    };
    let scenario = Scenario::builtin("default").ok_or("no default scenario")?;
    let rig = EmulatedRig::start(scenario, EmulatorOptions::default())?;
    let link = RigLink::spawn(LinkConfig::new(
        DeviceTarget::Path(rig.device_path().to_path_buf()),
        Calibration::default(),
    ))?;
    let origin = rig.device_time_origin();
    let mut decode_us = Vec::new();
    let mut wake_us = Vec::new();
    let mut last = link
        .wait_for_sample(None, Duration::from_secs(5))
        .ok_or("no sample within 5 s")?;
    let end = std::time::Instant::now() + Duration::from_secs_f64(seconds);
    while std::time::Instant::now() < end {
        let Some(s) = link.wait_for_sample(Some(last.received_at), Duration::from_secs(1)) else {
            return Err("sample stream stopped".into());
        };
        let woke = std::time::Instant::now();
        let taken = origin + Duration::from_micros(s.device_time_us);
        decode_us.push(s.received_at.saturating_duration_since(taken).as_secs_f64() * 1e6);
        wake_us.push(woke.saturating_duration_since(taken).as_secs_f64() * 1e6);
        last = s;
    }
    let snap = link.snapshot();
    link.shutdown();
    rig.stop();
    for (name, v) in [
        ("sample -> decoded", &mut decode_us),
        ("sample -> consumer", &mut wake_us),
    ] {
        v.sort_by(f64::total_cmp);
        let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
        println!(
            "{name:20} n={} p50={:.0} us p99={:.0} us p99.9={:.0} us max={:.0} us",
            v.len(),
            q(0.5),
            q(0.99),
            q(0.999),
            v[v.len() - 1]
        );
    }
    println!(
        "frames={} crc_errors={} sequence_gaps={}",
        snap.counters.frames, snap.counters.crc_errors, snap.counters.sequence_gaps
    );
    Ok(())
}
