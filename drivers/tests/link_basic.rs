//! The plain (no-fault) path: emulated rig -> pseudo-terminal -> transport -> calibrated state.

use std::time::Duration;

use hydrometra_drivers::calibration::{Calibration, PA_PER_MMHG};
use hydrometra_drivers::emulator::{EmulatedRig, EmulatorOptions, Scenario};
use hydrometra_drivers::state::LinkState;
use hydrometra_drivers::transport::{DeviceTarget, LinkConfig, RigLink};

#[test]
fn link_handshakes_and_delivers_the_scenario_state() {
    let scenario = Scenario::builtin("default").unwrap();
    let rig = EmulatedRig::start(scenario.clone(), EmulatorOptions::default()).unwrap();
    let link = RigLink::spawn(LinkConfig::new(
        DeviceTarget::Path(rig.device_path().to_path_buf()),
        Calibration::default(),
    ))
    .unwrap();
    let first = link
        .wait_for_sample(None, Duration::from_secs(5))
        .expect("a sample within 5 s");
    let mut last = first;
    for _ in 0..50 {
        last = link
            .wait_for_sample(Some(last.received_at), Duration::from_secs(1))
            .expect("samples keep coming");
    }
    let snap = link.snapshot();
    assert_eq!(snap.link_state, LinkState::Connected);
    let dev = snap.device.expect("device info after handshake");
    assert_eq!(dev.serial_number, "EMU-0001");
    assert_eq!(dev.protocol_version, 1);
    assert_eq!(dev.sample_rate_hz, 250);
    assert_eq!(snap.counters.crc_errors, 0);
    assert_eq!(snap.counters.sequence_gaps, 0);
    assert_eq!(snap.counters.reconnects, 0);
    assert!(snap.counters.frames >= 51);
    // The sample matches the scenario at the device time within the 12-bit quantisation.
    let expect = scenario.sample_at(last.device_time_us as f64 * 1e-6);
    assert!((last.valve_in_opening - expect.valve_in).abs() <= 1.0 / 3700.0);
    assert!((last.valve_out_opening - expect.valve_out).abs() <= 1.0 / 3700.0);
    let pump_step_pa = 200.0 * PA_PER_MMHG / 4095.0;
    assert!((last.pump_set_pressure_pa - expect.pump_mmhg * PA_PER_MMHG).abs() <= pump_step_pa);
    for i in 0..3 {
        assert!((last.scope.tip_position_m[i] - expect.tip_mm[i] * 1e-3).abs() < 1e-6);
        assert!((last.scope.view_direction[i] - expect.view_dir[i]).abs() < 1e-5);
    }
    // ~250 Hz: 50 consecutive samples arrive at 4 ms spacing of device time.
    let dt_us = last.device_time_us - first.device_time_us;
    assert!(
        (150_000..=400_000).contains(&dt_us),
        "{dt_us} us for 50 samples"
    );
    link.shutdown();
    rig.stop();
}

#[test]
fn scheduled_faults_from_the_plan_fire_and_are_counted() {
    use hydrometra_drivers::emulator::{Fault, FaultEvent, FaultPlan};
    let scenario = Scenario::builtin("default").unwrap();
    let options = EmulatorOptions {
        faults: FaultPlan {
            chunk_max_bytes: 4,
            events: vec![
                FaultEvent {
                    at_s: 0.4,
                    fault: Fault::DropFrames { count: 3 },
                },
                FaultEvent {
                    at_s: 0.3,
                    fault: Fault::FaultReport {
                        code: 2,
                        severity: 1,
                        detail: 5,
                    },
                },
            ],
        },
        ..EmulatorOptions::default()
    };
    let rig = EmulatedRig::start(scenario, options).unwrap();
    let link = RigLink::spawn(LinkConfig::new(
        DeviceTarget::Path(rig.device_path().to_path_buf()),
        Calibration::default(),
    ))
    .unwrap();
    let deadline = std::time::Instant::now() + Duration::from_secs(5);
    loop {
        let s = link.snapshot();
        if s.counters.sequence_gaps == 3 && s.counters.device_faults == 1 && s.counters.frames > 200
        {
            assert_eq!(s.counters.crc_errors + s.counters.malformed, 0, "{s:?}");
            assert_eq!(s.link_state, LinkState::Connected);
            break;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "{s:?} {:?}",
            rig.stats()
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(rig.stats().frames_dropped, 3);
    assert_eq!(rig.stats().fault_reports, 1);
}

#[test]
fn missing_usb_device_is_retried_quietly_and_reported() {
    let link = RigLink::spawn(LinkConfig::new(
        DeviceTarget::Usb {
            vid: 0x1209,
            pid: 0x0001,
            serial_number: Some("NOT-PLUGGED".into()),
        },
        Calibration::default(),
    ))
    .unwrap();
    std::thread::sleep(Duration::from_millis(400));
    let s = link.snapshot();
    assert_eq!(s.link_state, LinkState::Disconnected);
    assert!(s.latest.is_none());
    let err = s.last_error.expect("the open failure is reported");
    assert!(
        err.contains("1209:0001") && err.contains("NOT-PLUGGED"),
        "{err}"
    );
    // Backoff 50 + 100 + 200 ms: three or four sysfs scans, not a loop.
    assert!(link.io_thread_cpu_time() < Duration::from_millis(100));
    link.shutdown();
}
