//! Host-side cost per rig sample: decoding a frame from the byte stream, calibrating it, and
//! encoding (the firmware side). Run: `cargo bench -p hydrometra-drivers --bench codec`.

use std::hint::black_box;
use std::time::Instant;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use hydrometra_drivers::calibration::Calibration;
use hydrometra_drivers::framing::FrameDecoder;
use hydrometra_drivers::wire::{encode_frame, Message, SensorSample, MAX_ENCODED_LEN};

fn sample() -> SensorSample {
    SensorSample {
        device_time_us: 1_234_567,
        valve_in_raw: 2050,
        valve_out_raw: 900,
        pump_raw: 1843,
        pose_valid: true,
        position_mm: [10.0, -2.5, 45.0],
        orientation_wxyz: [0.9238795, 0.0, 0.3826834, 0.0],
        buttons: 1,
    }
}

fn bench(c: &mut Criterion) {
    let msg = Message::Sample(sample());
    let mut wire = [0u8; MAX_ENCODED_LEN];
    let n = encode_frame(7, &msg, &mut wire).unwrap();
    let mut g = c.benchmark_group("rig_codec");
    g.throughput(Throughput::Elements(1));
    g.bench_function("encode_sample_frame", |b| {
        let mut out = [0u8; MAX_ENCODED_LEN];
        b.iter(|| encode_frame(black_box(7), black_box(&msg), &mut out).unwrap())
    });
    g.bench_function("decode_sample_frame", |b| {
        let mut dec = FrameDecoder::new();
        b.iter(|| {
            let mut got = None;
            dec.push_slice(black_box(&wire[..n]), |r| got = Some(r));
            got
        })
    });
    let cal = Calibration::from_toml_str(
        "[tracker]\nrotation_wxyz = [0.9238795325112867, 0.0, 0.3826834323650898, 0.0]\n\
         translation_mm = [-120.0, 40.0, 300.0]\ntip_offset_mm = [0.0, 0.0, 180.0]\n",
        "bench",
    )
    .unwrap();
    let s = sample();
    let now = Instant::now();
    g.bench_function("calibrate_sample", |b| {
        b.iter(|| cal.apply(black_box(&s), 7, now, None))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
