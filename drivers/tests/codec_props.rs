//! Property tests of the wire codec: round trips under arbitrary chunking, resynchronisation after
//! arbitrary garbage, detection of every single-bit flip.

use hydrometra_drivers::framing::FrameDecoder;
use hydrometra_drivers::wire::{
    encode_frame, DeviceHello, FaultReport, Frame, FrameError, Heartbeat, HostHello, Message,
    SensorSample, MAX_ENCODED_LEN,
};
use proptest::prelude::*;

fn any_f32() -> impl Strategy<Value = f32> {
    // Every bit pattern, NaNs included: the codec must carry them untouched (calibration rejects).
    any::<u32>().prop_map(f32::from_bits)
}

fn any_message() -> impl Strategy<Value = Message> {
    prop_oneof![
        (any::<u8>(), any::<u32>()).prop_map(|(protocol_version, nonce)| {
            Message::HostHello(HostHello {
                protocol_version,
                nonce,
            })
        }),
        (
            any::<u8>(),
            any::<(u8, u8, u16)>(),
            "[ -~]{0,40}",
            any::<u32>(),
            any::<u32>(),
            any::<u16>(),
            any::<u32>()
        )
            .prop_map(|(v, fw, serial, caps, cal, rate, nonce)| {
                Message::DeviceHello(DeviceHello::new(v, fw, &serial, caps, cal, rate, nonce))
            }),
        (
            any::<u64>(),
            any::<[u16; 3]>(),
            any::<bool>(),
            prop::array::uniform3(any_f32()),
            prop::array::uniform4(any_f32()),
            any::<u32>()
        )
            .prop_map(|(t, raw, valid, p, q, buttons)| {
                Message::Sample(SensorSample {
                    device_time_us: t,
                    valve_in_raw: raw[0],
                    valve_out_raw: raw[1],
                    pump_raw: raw[2],
                    pose_valid: valid,
                    position_mm: p,
                    orientation_wxyz: q,
                    buttons,
                })
            }),
        any::<u32>().prop_map(|uptime_ms| Message::Heartbeat(Heartbeat { uptime_ms })),
        (any::<u16>(), any::<u8>(), any::<u32>()).prop_map(|(code, severity, detail)| {
            Message::FaultReport(FaultReport {
                code,
                severity,
                detail,
            })
        }),
    ]
}

fn encode(seq: u32, m: &Message) -> Vec<u8> {
    let mut buf = [0u8; MAX_ENCODED_LEN];
    let n = encode_frame(seq, m, &mut buf).unwrap();
    buf[..n].to_vec()
}

/// Frames compare by their encoding, so NaN payloads compare bit for bit.
fn same(a: &Frame, seq: u32, m: &Message) -> bool {
    a.sequence == seq && encode(a.sequence, &a.message) == encode(seq, m)
}

fn decode_all(dec: &mut FrameDecoder, bytes: &[u8]) -> Vec<Result<Frame, FrameError>> {
    let mut out = Vec::new();
    dec.push_slice(bytes, |r| out.push(r));
    out
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn round_trip_under_arbitrary_chunking(
        msgs in prop::collection::vec((any::<u32>(), any_message()), 1..20),
        cuts in prop::collection::vec(1usize..80, 0..200),
    ) {
        let stream: Vec<u8> = msgs.iter().flat_map(|(s, m)| encode(*s, m)).collect();
        let mut dec = FrameDecoder::new();
        let mut got = Vec::new();
        let mut pos = 0;
        let mut cut = cuts.iter().cycle();
        while pos < stream.len() {
            let n = if cuts.is_empty() { stream.len() } else { *cut.next().unwrap() };
            let end = (pos + n).min(stream.len());
            got.extend(decode_all(&mut dec, &stream[pos..end]));
            pos = end;
        }
        prop_assert_eq!(got.len(), msgs.len());
        for (r, (s, m)) in got.iter().zip(&msgs) {
            let f = r.as_ref().map_err(|e| TestCaseError::fail(format!("{e}")))?;
            prop_assert!(same(f, *s, m), "{:?} != {:?}", f, m);
        }
        prop_assert_eq!(dec.stats().crc_errors + dec.stats().malformed, 0);
    }

    #[test]
    fn garbage_never_panics_and_the_next_valid_frame_is_decoded(
        garbage in prop::collection::vec(any::<u8>(), 0..600),
        seq in any::<u32>(),
        m in any_message(),
    ) {
        let mut dec = FrameDecoder::new();
        let mut results = decode_all(&mut dec, &garbage);
        results.extend(decode_all(&mut dec, &encode(seq, &m)));
        let last = results.pop().expect("the valid frame yields a result");
        let f = last.map_err(|e| TestCaseError::fail(format!("{e}")))?;
        prop_assert!(same(&f, seq, &m));
        // Whatever the garbage produced was rejected, and the valid frame counts as a resync.
        let rejected = results.iter().filter(|r| r.is_err()).count() as u64;
        prop_assert_eq!(dec.stats().crc_errors + dec.stats().malformed, rejected);
        prop_assert_eq!(dec.stats().resyncs, u64::from(rejected > 0));
        // A garbage-produced valid frame would need a 2^-32 CRC coincidence.
        prop_assert!(results.iter().all(|r| r.is_err()));
    }

    #[test]
    fn garbage_between_frames_loses_no_frame(
        frames in prop::collection::vec(
            (any::<u32>(), any_message(), prop::collection::vec(any::<u8>(), 0..100)),
            1..12,
        ),
    ) {
        // Garbage before each frame; the frame's leading delimiter ends the garbage.
        let mut stream = Vec::new();
        for (s, m, g) in &frames {
            stream.extend_from_slice(g);
            stream.extend(encode(*s, m));
        }
        let mut dec = FrameDecoder::new();
        let got: Vec<Frame> = decode_all(&mut dec, &stream).into_iter().filter_map(Result::ok).collect();
        prop_assert_eq!(got.len(), frames.len());
        for (f, (s, m, _)) in got.iter().zip(&frames) {
            prop_assert!(same(f, *s, m));
        }
    }

    #[test]
    fn every_single_bit_flip_is_detected(seq in any::<u32>(), m in any_message()) {
        let good = encode(seq, &m);
        let next = encode(seq.wrapping_add(1), &Message::Heartbeat(Heartbeat { uptime_ms: 7 }));
        for bit in 0..good.len() * 8 {
            let mut bad = good.clone();
            bad[bit / 8] ^= 1 << (bit % 8);
            let mut dec = FrameDecoder::new();
            let mut results = decode_all(&mut dec, &bad);
            results.extend(decode_all(&mut dec, &next));
            let valid: Vec<&Frame> = results.iter().filter_map(|r| r.as_ref().ok()).collect();
            // Only the following, untouched frame may come out; the flipped one never does.
            prop_assert_eq!(valid.len(), 1, "bit {} of {:02x?}", bit, good);
            prop_assert_eq!(valid[0].sequence, seq.wrapping_add(1));
        }
    }
}

#[test]
fn oversized_run_is_rejected_and_the_decoder_recovers() {
    let mut dec = FrameDecoder::new();
    let results = decode_all(&mut dec, &[0x55; 10_000]);
    assert!(results.is_empty());
    let m = Message::Heartbeat(Heartbeat { uptime_ms: 1 });
    let results = decode_all(&mut dec, &encode(3, &m));
    assert_eq!(results.len(), 2);
    assert_eq!(results[0], Err(FrameError::Oversize));
    assert!(same(results[1].as_ref().unwrap(), 3, &m));
    assert_eq!(dec.stats().resyncs, 1);
}
