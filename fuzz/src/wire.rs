//! The rig wire codec, structure-aware: frames built from the fuzzer's bytes (every message type,
//! any field value, NaN floats included) are encoded, buried in garbage, cut into chunks of any
//! size and decoded again.
//!
//! Properties: `parse(write(frame)) == frame` bit for bit; the encoding stays within
//! `MAX_ENCODED_LEN` and holds 0x00 only as its two delimiters; the stream decoder gets every frame
//! back, in order, whatever garbage precedes it (the leading delimiter ends it); how the stream is
//! chunked never changes what is decoded; the counters add up.

use arbitrary::{Result, Unstructured};
use hydrometra_drivers::framing::FrameDecoder;
use hydrometra_drivers::wire::{
    encode_frame, parse_raw_frame, write_raw_frame, DeviceHello, FaultReport, Frame, FrameError,
    Heartbeat, HostHello, Message, SensorSample, MAX_ENCODED_LEN, MAX_FRAME_LEN,
};

/// Frames per input at most (keeps an execution short).
const MAX_FRAMES: usize = 16;
/// Garbage before a frame, bytes at most (more than one oversize run).
const MAX_GARBAGE: usize = 160;

/// The raw (unencoded) bytes of a frame: equal bytes mean equal frames, NaN payloads included.
pub fn raw_bytes(frame: &Frame) -> Vec<u8> {
    let mut raw = [0u8; MAX_FRAME_LEN];
    // ok: MAX_FRAME_LEN holds the largest frame (the codec's own constant).
    let n = write_raw_frame(frame.sequence, &frame.message, &mut raw)
        .unwrap_or_else(|_| panic!("a {MAX_FRAME_LEN}-byte buffer must hold any frame"));
    raw[..n].to_vec()
}

/// A decoder result in a comparable form: the frame's raw bytes or the error.
pub fn comparable(
    r: &std::result::Result<Frame, FrameError>,
) -> std::result::Result<Vec<u8>, FrameError> {
    r.as_ref().map(raw_bytes).map_err(|e| *e)
}

fn message(u: &mut Unstructured) -> Result<Message> {
    let f32_any = |u: &mut Unstructured| -> Result<f32> { Ok(f32::from_bits(u.arbitrary()?)) };
    Ok(match u.int_in_range(0u8..=4)? {
        0 => Message::HostHello(HostHello {
            protocol_version: u.arbitrary()?,
            nonce: u.arbitrary()?,
        }),
        1 => {
            let serial: String = u.arbitrary()?;
            Message::DeviceHello(DeviceHello::new(
                u.arbitrary()?,
                (u.arbitrary()?, u.arbitrary()?, u.arbitrary()?),
                &serial,
                u.arbitrary()?,
                u.arbitrary()?,
                u.arbitrary()?,
                u.arbitrary()?,
            ))
        }
        2 => Message::Sample(SensorSample {
            device_time_us: u.arbitrary()?,
            valve_in_raw: u.arbitrary()?,
            valve_out_raw: u.arbitrary()?,
            pump_raw: u.arbitrary()?,
            pose_valid: u.arbitrary()?,
            position_mm: [f32_any(u)?, f32_any(u)?, f32_any(u)?],
            orientation_wxyz: [f32_any(u)?, f32_any(u)?, f32_any(u)?, f32_any(u)?],
            buttons: u.arbitrary()?,
        }),
        3 => Message::Heartbeat(Heartbeat {
            uptime_ms: u.arbitrary()?,
        }),
        _ => Message::FaultReport(FaultReport {
            code: u.arbitrary()?,
            severity: u.arbitrary()?,
            detail: u.arbitrary()?,
        }),
    })
}

/// Decodes `stream` fed in the given chunk sizes (cycled; 0 means 1).
pub fn decode_chunked(
    stream: &[u8],
    chunks: &[u8],
) -> (Vec<std::result::Result<Vec<u8>, FrameError>>, FrameDecoder) {
    let mut decoder = FrameDecoder::new();
    let mut out = Vec::new();
    let mut rest = stream;
    let mut sizes = chunks.iter().cycle();
    while !rest.is_empty() {
        let n = sizes
            .next()
            .map_or(rest.len(), |&s| usize::from(s.max(1)))
            .min(rest.len());
        let (chunk, tail) = rest.split_at(n);
        decoder.push_slice(chunk, |r| out.push(comparable(&r)));
        rest = tail;
    }
    (out, decoder)
}

/// The structure-aware wire target.
pub fn check(data: &[u8]) {
    let mut u = Unstructured::new(data);
    let _ = check_frames(&mut u);
}

fn check_frames(u: &mut Unstructured) -> Result<()> {
    let mut stream = Vec::new();
    let mut sent = Vec::new();
    let count = u.int_in_range(0..=MAX_FRAMES)?;
    for _ in 0..count {
        let frame = Frame {
            sequence: u.arbitrary()?,
            message: message(u)?,
        };
        let raw = raw_bytes(&frame);
        let parsed = parse_raw_frame(&raw)
            .unwrap_or_else(|e| panic!("{frame:?} written as {raw:02x?} does not parse: {e}"));
        assert_eq!(
            raw_bytes(&parsed),
            raw,
            "decode(encode(x)) != x for {frame:?}"
        );
        let mut enc = [0u8; MAX_ENCODED_LEN];
        let n = encode_frame(frame.sequence, &frame.message, &mut enc)
            .unwrap_or_else(|_| panic!("MAX_ENCODED_LEN does not hold {frame:?}"));
        let enc = &enc[..n];
        assert!(
            enc.len() >= 2 && enc[0] == 0 && enc[n - 1] == 0 && !enc[1..n - 1].contains(&0),
            "encoding of {frame:?} is not 0x00 COBS 0x00: {enc:02x?}"
        );
        let garbage_len = u.int_in_range(0..=MAX_GARBAGE)?;
        stream.extend_from_slice(u.bytes(garbage_len)?);
        stream.extend_from_slice(enc);
        sent.push(raw);
    }
    let chunks: Vec<u8> = u.arbitrary()?;

    let (chunked, decoder) = decode_chunked(&stream, &chunks);
    let (whole, _) = decode_chunked(&stream, &[]);
    let (bytewise, _) = decode_chunked(&stream, &[1]);
    assert_eq!(chunked, whole, "the chunking changed what was decoded");
    assert_eq!(
        bytewise, whole,
        "byte-by-byte decoding differs from whole-slice decoding"
    );

    // Every frame sent comes back, in order (garbage may decode to extra frames of its own).
    let mut received = whole.iter().filter_map(|r| r.as_ref().ok());
    for (i, raw) in sent.iter().enumerate() {
        assert!(
            received.any(|r| r == raw),
            "frame {i} of {} ({raw:02x?}) lost in the stream",
            sent.len()
        );
    }
    let stats = decoder.stats();
    let ok = whole.iter().filter(|r| r.is_ok()).count() as u64;
    let crc = whole
        .iter()
        .filter(|r| matches!(r, Err(FrameError::Crc { .. })))
        .count() as u64;
    assert_eq!(stats.frames, ok, "frames counter");
    assert_eq!(stats.crc_errors, crc, "crc_errors counter");
    assert_eq!(
        stats.malformed,
        whole.len() as u64 - ok - crc,
        "malformed counter"
    );
    assert!(stats.resyncs <= stats.frames, "more resyncs than frames");
    Ok(())
}
