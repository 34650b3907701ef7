//! The transport's receive path on raw bytes: the frame decoder (`framing.rs`, COBS and the frame
//! checks of `wire.rs`) and the calibration every decoded sample goes through before the
//! simulation sees it.
//!
//! Properties: every byte run between delimiters gets the verdict of an independent reference
//! receiver written from `docs/rig-protocol.md` section 2 (COBS by the text, then
//! `parse_raw_frame`); a run longer than the decoder's buffer is `Oversize`; an accepted frame
//! re-encodes to its input bytes with only the reserved bytes and unused flag bits cleared (so
//! every field is read from its documented offset); chunking never changes the verdicts; the
//! calibrated state of any decoded sample is in range (openings in [0, 1], pump pressure within
//! the calibration's full scale, a valid pose finite with unit quaternion and view direction).

use std::time::Instant;

use hydrometra_drivers::calibration::{Calibration, PA_PER_MMHG};
use hydrometra_drivers::wire::{
    crc32, parse_raw_frame, FrameError, Message, MessageType, CRC_LEN, HEADER_LEN, MAX_ENCODED_LEN,
    MAX_FRAME_LEN,
};

use crate::wire::{decode_chunked, raw_bytes};

/// COBS decoding as `docs/rig-protocol.md` states it: blocks of a code byte (length + 1) and its
/// bytes, a zero implied after each block but a full (0xFF) one and the last. `None` if invalid.
pub fn reference_cobs_decode(run: &[u8]) -> Option<Vec<u8>> {
    let mut out = Vec::with_capacity(run.len());
    let mut i = 0;
    while i < run.len() {
        let code = usize::from(run[i]);
        if code == 0 || i + code > run.len() {
            return None;
        }
        let block = &run[i + 1..i + code];
        if block.contains(&0) {
            return None;
        }
        out.extend_from_slice(block);
        i += code;
        if code != 0xFF && i < run.len() {
            out.push(0);
        }
    }
    Some(out)
}

/// `raw` as the encoder writes the frame decoded from it: reserved bytes and unused flag bits
/// cleared, CRC recomputed.
fn canonical(raw: &[u8]) -> Vec<u8> {
    let mut c = raw.to_vec();
    let payload = HEADER_LEN;
    match MessageType::from_code(raw[1]) {
        Some(MessageType::HostHello) => c[payload + 1..payload + 4].fill(0),
        Some(MessageType::Sample) => {
            c[payload + 14] &= 1;
            c[payload + 15] = 0;
        }
        Some(MessageType::FaultReport) => c[payload + 3] = 0,
        _ => {}
    }
    let body = c.len() - CRC_LEN;
    let crc = crc32(&c[..body]);
    c[body..].copy_from_slice(&crc.to_le_bytes());
    c
}

/// The raw-bytes receive path target.
pub fn check(data: &[u8]) {
    let (chunks, stream) = data.split_at(data.len().min(4));
    let (verdicts, decoder) = decode_chunked(stream, chunks);
    let (whole, _) = decode_chunked(stream, &[]);
    assert_eq!(verdicts, whole, "the chunking changed the verdicts");

    // One verdict per non-empty run ended by a delimiter; the unterminated tail has none.
    let mut runs: Vec<&[u8]> = stream.split(|&b| b == 0).collect();
    runs.pop();
    runs.retain(|r| !r.is_empty());
    assert_eq!(whole.len(), runs.len(), "verdicts for {} runs", runs.len());
    for (run, verdict) in runs.iter().zip(&whole) {
        let expected = if run.len() > MAX_ENCODED_LEN {
            Err(FrameError::Oversize)
        } else {
            match reference_cobs_decode(run) {
                Some(raw) if raw.len() <= MAX_FRAME_LEN => {
                    parse_raw_frame(&raw).map(|f| raw_bytes(&f))
                }
                _ => Err(FrameError::Cobs),
            }
        };
        assert_eq!(verdict, &expected, "run {run:02x?}");
        if let Ok(bytes) = verdict {
            // ok: an accepted run decodes (it matched the reference above).
            let raw = reference_cobs_decode(run).unwrap_or_default();
            assert_eq!(bytes, &canonical(&raw), "fields of {raw:02x?} misread");
        } else if let Err(e) = verdict {
            assert!(!e.to_string().is_empty());
        }
    }
    let stats = decoder.stats();
    assert_eq!(
        stats.frames,
        whole.iter().filter(|v| v.is_ok()).count() as u64
    );

    let calibration = Calibration::default();
    let full_scale_pa = calibration.pump.full_scale_mmhg * PA_PER_MMHG;
    let now = Instant::now();
    let mut previous = None;
    for raw in whole.iter().filter_map(|v| v.as_ref().ok()) {
        let Ok(frame) = parse_raw_frame(raw) else {
            unreachable!("accepted bytes parse")
        };
        let Message::Sample(sample) = frame.message else {
            continue;
        };
        let out = calibration.apply(&sample, frame.sequence, now, previous.as_ref());
        let s = out.state;
        for (what, v) in [
            ("valve_in_opening", s.valve_in_opening),
            ("valve_out_opening", s.valve_out_opening),
        ] {
            assert!((0.0..=1.0).contains(&v), "{what} {v} from {sample:?}");
        }
        assert!(
            (0.0..=full_scale_pa).contains(&s.pump_set_pressure_pa),
            "pump {} Pa from {sample:?}",
            s.pump_set_pressure_pa
        );
        let p = s.scope;
        let finite = p.tip_position_m.iter().all(|c| c.is_finite())
            && p.view_direction.iter().all(|c| c.is_finite())
            && p.orientation.iter().all(|c| c.is_finite());
        assert!(finite, "non-finite pose {p:?} from {sample:?}");
        if p.valid {
            let norm = |v: &[f64]| v.iter().map(|c| c * c).sum::<f64>().sqrt();
            assert!((norm(&p.orientation) - 1.0).abs() < 1e-9, "{p:?}");
            assert!((norm(&p.view_direction) - 1.0).abs() < 1e-9, "{p:?}");
        }
        assert!(out.clamped_values <= 4);
        previous = Some(s);
    }
}
