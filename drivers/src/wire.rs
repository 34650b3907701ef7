//! Wire protocol v1: message layouts and their little-endian encoding (no `std`, no allocation).
//!
//! A frame on the wire is `COBS(header | payload | crc32) 0x00`; see `docs/rig-protocol.md` for the
//! byte-level specification that firmware authors implement. [`crate::framing`] splits the byte stream
//! into frames; this module turns one decoded frame into a [`Frame`] and back.

/// Protocol version spoken by this codec (byte 0 of every frame).
pub const PROTOCOL_VERSION: u8 = 1;
/// Header bytes: version (u8), message type (u8), sequence number (u32 LE).
pub const HEADER_LEN: usize = 6;
/// CRC-32 trailer bytes.
pub const CRC_LEN: usize = 4;
/// Largest payload of any v1 message (device hello with a 32-byte serial number).
pub const MAX_PAYLOAD_LEN: usize = 52;
/// Largest unencoded frame: header + payload + CRC.
pub const MAX_FRAME_LEN: usize = HEADER_LEN + MAX_PAYLOAD_LEN + CRC_LEN;
/// Largest frame on the wire: leading 0x00, COBS overhead (1 byte per 254, at least 1), trailing 0x00.
pub const MAX_ENCODED_LEN: usize = 1 + MAX_FRAME_LEN + MAX_FRAME_LEN / 254 + 1 + 1;
/// Longest serial number a device hello can carry, bytes of ASCII.
pub const MAX_SERIAL_LEN: usize = 32;
/// Full scale of the 12-bit raw channels (valve potentiometers, pump setting).
pub const RAW_FULL_SCALE: u16 = 4095;

/// Message type codes (byte 1 of every frame).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum MessageType {
    /// Host -> device: start a session.
    HostHello = 0x01,
    /// Device -> host: answer to a host hello.
    DeviceHello = 0x02,
    /// Device -> host: one sensor sample.
    Sample = 0x10,
    /// Either direction: liveness.
    Heartbeat = 0x20,
    /// Device -> host: a fault the firmware detected.
    FaultReport = 0x30,
}

impl MessageType {
    /// The type for a wire code, if it is one.
    pub fn from_code(code: u8) -> Option<Self> {
        match code {
            0x01 => Some(Self::HostHello),
            0x02 => Some(Self::DeviceHello),
            0x10 => Some(Self::Sample),
            0x20 => Some(Self::Heartbeat),
            0x30 => Some(Self::FaultReport),
            _ => None,
        }
    }

    /// Payload length of this type in v1 (`None` for the variable-length device hello).
    pub fn fixed_payload_len(self) -> Option<usize> {
        match self {
            Self::HostHello => Some(HOST_HELLO_LEN),
            Self::DeviceHello => None,
            Self::Sample => Some(SAMPLE_LEN),
            Self::Heartbeat => Some(HEARTBEAT_LEN),
            Self::FaultReport => Some(FAULT_LEN),
        }
    }
}

const HOST_HELLO_LEN: usize = 8;
const DEVICE_HELLO_FIXED_LEN: usize = 20;
const SAMPLE_LEN: usize = 48;
const HEARTBEAT_LEN: usize = 4;
const FAULT_LEN: usize = 8;

/// Host -> device: opens (or re-opens) a session.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HostHello {
    /// Highest protocol version the host speaks.
    pub protocol_version: u8,
    /// Random value the device echoes in its hello, pairing answer to request.
    pub nonce: u32,
}

/// Device -> host: identity of the rig, sent in answer to a [`HostHello`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DeviceHello {
    /// Protocol version the device speaks.
    pub protocol_version: u8,
    /// Firmware version `(major, minor, patch)`.
    pub firmware_version: (u8, u8, u16),
    /// Capability bits (see [`capabilities`]).
    pub capabilities: u32,
    /// Identifier of the calibration the rig was built/calibrated with.
    pub calibration_id: u32,
    /// Sample rate the device will stream at, Hz.
    pub sample_rate_hz: u16,
    /// The nonce of the host hello being answered.
    pub nonce: u32,
    serial_len: u8,
    serial: [u8; MAX_SERIAL_LEN],
}

/// Capability bits of a [`DeviceHello`].
pub mod capabilities {
    /// Inflow valve potentiometer fitted.
    pub const VALVE_IN: u32 = 1 << 0;
    /// Outflow valve potentiometer fitted.
    pub const VALVE_OUT: u32 = 1 << 1;
    /// Pump setting potentiometer fitted.
    pub const PUMP: u32 = 1 << 2;
    /// Scope tracker fitted.
    pub const TRACKER: u32 = 1 << 3;
    /// Buttons fitted.
    pub const BUTTONS: u32 = 1 << 4;
    /// Everything above.
    pub const ALL: u32 = VALVE_IN | VALVE_OUT | PUMP | TRACKER | BUTTONS;
}

impl DeviceHello {
    /// A device hello; the serial number is truncated to [`MAX_SERIAL_LEN`] bytes.
    pub fn new(
        protocol_version: u8,
        firmware_version: (u8, u8, u16),
        serial_number: &str,
        capabilities: u32,
        calibration_id: u32,
        sample_rate_hz: u16,
        nonce: u32,
    ) -> Self {
        let mut serial = [0u8; MAX_SERIAL_LEN];
        let bytes = serial_number.as_bytes();
        let n = bytes.len().min(MAX_SERIAL_LEN);
        serial[..n].copy_from_slice(&bytes[..n]);
        Self {
            protocol_version,
            firmware_version,
            capabilities,
            calibration_id,
            sample_rate_hz,
            nonce,
            serial_len: n as u8,
            serial,
        }
    }

    /// The serial number bytes (ASCII by specification; not validated here).
    pub fn serial_number_bytes(&self) -> &[u8] {
        &self.serial[..self.serial_len as usize]
    }
}

/// Device -> host: one raw sensor sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorSample {
    /// Device time of the sample, microseconds since boot.
    pub device_time_us: u64,
    /// Inflow valve potentiometer, raw 12-bit counts (0..=4095).
    pub valve_in_raw: u16,
    /// Outflow valve potentiometer, raw 12-bit counts (0..=4095).
    pub valve_out_raw: u16,
    /// Pump set-pressure potentiometer, raw 12-bit counts (0..=4095).
    pub pump_raw: u16,
    /// True when the tracker reports the pose as valid.
    pub pose_valid: bool,
    /// Scope marker position in the tracker frame, millimetres.
    pub position_mm: [f32; 3],
    /// Scope marker orientation in the tracker frame, unit quaternion `[w, x, y, z]`.
    pub orientation_wxyz: [f32; 4],
    /// Button bit field (bit i = button i pressed).
    pub buttons: u32,
}

/// Either direction: liveness, carrying the sender's uptime.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Heartbeat {
    /// Sender's uptime, milliseconds (wraps).
    pub uptime_ms: u32,
}

/// Device -> host: a fault detected by the firmware.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FaultReport {
    /// Fault code (see `docs/rig-protocol.md`).
    pub code: u16,
    /// 0 info, 1 warning, 2 error.
    pub severity: u8,
    /// Code-specific detail.
    pub detail: u32,
}

/// Any v1 message.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Message {
    /// See [`HostHello`].
    HostHello(HostHello),
    /// See [`DeviceHello`].
    DeviceHello(DeviceHello),
    /// See [`SensorSample`].
    Sample(SensorSample),
    /// See [`Heartbeat`].
    Heartbeat(Heartbeat),
    /// See [`FaultReport`].
    FaultReport(FaultReport),
}

impl Message {
    /// The wire type of this message.
    pub fn message_type(&self) -> MessageType {
        match self {
            Message::HostHello(_) => MessageType::HostHello,
            Message::DeviceHello(_) => MessageType::DeviceHello,
            Message::Sample(_) => MessageType::Sample,
            Message::Heartbeat(_) => MessageType::Heartbeat,
            Message::FaultReport(_) => MessageType::FaultReport,
        }
    }
}

/// A decoded v1 frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    /// Sender's sequence number of this frame.
    pub sequence: u32,
    /// The message.
    pub message: Message,
}

/// Why bytes between two delimiters are not a valid frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameError {
    /// The COBS encoding is invalid.
    Cobs,
    /// More bytes than [`MAX_ENCODED_LEN`] without a delimiter.
    Oversize,
    /// Fewer bytes than header plus CRC.
    TooShort {
        /// Decoded length.
        len: usize,
    },
    /// The CRC does not match.
    Crc {
        /// CRC carried by the frame.
        received: u32,
        /// CRC computed over header and payload.
        computed: u32,
    },
    /// A valid frame of a protocol version this codec does not speak.
    UnsupportedVersion {
        /// The frame's version byte.
        version: u8,
        /// The frame's type byte (the header layout is the same in every version).
        type_code: u8,
    },
    /// Unknown message type code.
    UnknownType {
        /// The type byte.
        type_code: u8,
    },
    /// The payload length does not fit the message type.
    BadLength {
        /// The type byte.
        type_code: u8,
        /// Received payload length.
        len: usize,
    },
}

impl core::fmt::Display for FrameError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            FrameError::Cobs => write!(f, "invalid COBS encoding"),
            FrameError::Oversize => {
                write!(f, "no delimiter within {MAX_ENCODED_LEN} bytes")
            }
            FrameError::TooShort { len } => write!(
                f,
                "frame of {len} bytes is shorter than header plus CRC ({})",
                HEADER_LEN + CRC_LEN
            ),
            FrameError::Crc { received, computed } => write!(
                f,
                "CRC mismatch: frame carries {received:#010x}, computed {computed:#010x}"
            ),
            FrameError::UnsupportedVersion { version, .. } => write!(
                f,
                "protocol version {version} (this host speaks {PROTOCOL_VERSION})"
            ),
            FrameError::UnknownType { type_code } => {
                write!(f, "unknown message type {type_code:#04x}")
            }
            FrameError::BadLength { type_code, len } => write!(
                f,
                "payload of {len} bytes does not fit message type {type_code:#04x}"
            ),
        }
    }
}

/// The output buffer is too small for the frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BufferTooSmall;

/// CRC-32 as used by the protocol: CRC-32/ISO-HDLC (the zlib/Ethernet CRC): polynomial 0x04C11DB7,
/// reflected, init 0xFFFFFFFF, final XOR 0xFFFFFFFF. `crc32(b"123456789") == 0xCBF43926`.
pub fn crc32(bytes: &[u8]) -> u32 {
    crc32fast::hash(bytes)
}

struct Writer<'a> {
    buf: &'a mut [u8],
    pos: usize,
}

impl Writer<'_> {
    fn put(&mut self, bytes: &[u8]) -> Result<(), BufferTooSmall> {
        let end = self.pos + bytes.len();
        let dst = self.buf.get_mut(self.pos..end).ok_or(BufferTooSmall)?;
        dst.copy_from_slice(bytes);
        self.pos = end;
        Ok(())
    }
    fn u8(&mut self, v: u8) -> Result<(), BufferTooSmall> {
        self.put(&[v])
    }
    fn u16(&mut self, v: u16) -> Result<(), BufferTooSmall> {
        self.put(&v.to_le_bytes())
    }
    fn u32(&mut self, v: u32) -> Result<(), BufferTooSmall> {
        self.put(&v.to_le_bytes())
    }
    fn u64(&mut self, v: u64) -> Result<(), BufferTooSmall> {
        self.put(&v.to_le_bytes())
    }
    fn f32(&mut self, v: f32) -> Result<(), BufferTooSmall> {
        self.put(&v.to_le_bytes())
    }
}

struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl Reader<'_> {
    // Callers check the payload length first, so reads never run past the end; a short read
    // yields zeros rather than a panic.
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        if let Some(src) = self.buf.get(self.pos..self.pos + N) {
            out.copy_from_slice(src);
        }
        self.pos += N;
        out
    }
    fn u8(&mut self) -> u8 {
        self.take::<1>()[0]
    }
    fn u16(&mut self) -> u16 {
        u16::from_le_bytes(self.take())
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }
    fn f32(&mut self) -> f32 {
        f32::from_le_bytes(self.take())
    }
}

/// Writes the unencoded frame `header | payload | crc32` with an explicit version byte; returns
/// its length. Only the emulator's fault injection uses a version other than [`PROTOCOL_VERSION`].
pub fn write_raw_frame_with_version(
    version: u8,
    sequence: u32,
    message: &Message,
    out: &mut [u8],
) -> Result<usize, BufferTooSmall> {
    let mut w = Writer { buf: out, pos: 0 };
    w.u8(version)?;
    w.u8(message.message_type() as u8)?;
    w.u32(sequence)?;
    match message {
        Message::HostHello(m) => {
            w.u8(m.protocol_version)?;
            w.put(&[0, 0, 0])?;
            w.u32(m.nonce)?;
        }
        Message::DeviceHello(m) => {
            w.u8(m.protocol_version)?;
            w.u8(m.firmware_version.0)?;
            w.u8(m.firmware_version.1)?;
            w.u16(m.firmware_version.2)?;
            w.u32(m.capabilities)?;
            w.u32(m.calibration_id)?;
            w.u16(m.sample_rate_hz)?;
            w.u32(m.nonce)?;
            w.u8(m.serial_len)?;
            w.put(m.serial_number_bytes())?;
        }
        Message::Sample(m) => {
            w.u64(m.device_time_us)?;
            w.u16(m.valve_in_raw)?;
            w.u16(m.valve_out_raw)?;
            w.u16(m.pump_raw)?;
            w.u8(u8::from(m.pose_valid))?;
            w.u8(0)?;
            for p in m.position_mm {
                w.f32(p)?;
            }
            for q in m.orientation_wxyz {
                w.f32(q)?;
            }
            w.u32(m.buttons)?;
        }
        Message::Heartbeat(m) => w.u32(m.uptime_ms)?,
        Message::FaultReport(m) => {
            w.u16(m.code)?;
            w.u8(m.severity)?;
            w.u8(0)?;
            w.u32(m.detail)?;
        }
    }
    let body_len = w.pos;
    let crc = crc32(&w.buf[..body_len]);
    w.u32(crc)?;
    Ok(w.pos)
}

/// Writes the unencoded v1 frame `header | payload | crc32`; returns its length.
pub fn write_raw_frame(
    sequence: u32,
    message: &Message,
    out: &mut [u8],
) -> Result<usize, BufferTooSmall> {
    write_raw_frame_with_version(PROTOCOL_VERSION, sequence, message, out)
}

/// COBS-encodes an unencoded frame into `out` between two 0x00 delimiters; returns the length.
///
/// The leading delimiter costs one byte per frame and guarantees that whatever garbage preceded
/// the frame is terminated, so the frame itself is never lost to a resynchronisation.
pub fn encode_raw_frame(raw: &[u8], out: &mut [u8]) -> Result<usize, BufferTooSmall> {
    *out.first_mut().ok_or(BufferTooSmall)? = 0;
    let n = cobs::try_encode(raw, &mut out[1..]).map_err(|_| BufferTooSmall)?;
    *out.get_mut(n + 1).ok_or(BufferTooSmall)? = 0;
    Ok(n + 2)
}

/// Encodes a v1 frame ready for the wire (COBS plus delimiter); returns the length written.
/// `out` of [`MAX_ENCODED_LEN`] bytes always suffices.
pub fn encode_frame(
    sequence: u32,
    message: &Message,
    out: &mut [u8],
) -> Result<usize, BufferTooSmall> {
    let mut raw = [0u8; MAX_FRAME_LEN];
    let n = write_raw_frame(sequence, message, &mut raw)?;
    encode_raw_frame(&raw[..n], out)
}

/// Parses one unencoded frame (`header | payload | crc32`, COBS already removed).
pub fn parse_raw_frame(raw: &[u8]) -> Result<Frame, FrameError> {
    if raw.len() < HEADER_LEN + CRC_LEN {
        return Err(FrameError::TooShort { len: raw.len() });
    }
    let body_len = raw.len() - CRC_LEN;
    let (body, crc_bytes) = raw.split_at(body_len);
    let received = u32::from_le_bytes([crc_bytes[0], crc_bytes[1], crc_bytes[2], crc_bytes[3]]);
    let computed = crc32(body);
    if received != computed {
        return Err(FrameError::Crc { received, computed });
    }
    let version = body[0];
    let type_code = body[1];
    if version != PROTOCOL_VERSION {
        return Err(FrameError::UnsupportedVersion { version, type_code });
    }
    let sequence = u32::from_le_bytes([body[2], body[3], body[4], body[5]]);
    let payload = &body[HEADER_LEN..];
    let msg_type =
        MessageType::from_code(type_code).ok_or(FrameError::UnknownType { type_code })?;
    let bad_len = FrameError::BadLength {
        type_code,
        len: payload.len(),
    };
    match msg_type.fixed_payload_len() {
        Some(len) if len != payload.len() => return Err(bad_len),
        None if payload.len() < DEVICE_HELLO_FIXED_LEN => return Err(bad_len),
        _ => {}
    }
    let mut r = Reader {
        buf: payload,
        pos: 0,
    };
    let message = match msg_type {
        MessageType::HostHello => {
            let protocol_version = r.u8();
            let _reserved: [u8; 3] = r.take();
            Message::HostHello(HostHello {
                protocol_version,
                nonce: r.u32(),
            })
        }
        MessageType::DeviceHello => {
            let protocol_version = r.u8();
            let firmware_version = (r.u8(), r.u8(), r.u16());
            let capabilities = r.u32();
            let calibration_id = r.u32();
            let sample_rate_hz = r.u16();
            let nonce = r.u32();
            let serial_len = r.u8() as usize;
            if serial_len > MAX_SERIAL_LEN || payload.len() != DEVICE_HELLO_FIXED_LEN + serial_len {
                return Err(bad_len);
            }
            let mut serial = [0u8; MAX_SERIAL_LEN];
            serial[..serial_len].copy_from_slice(&payload[DEVICE_HELLO_FIXED_LEN..]);
            Message::DeviceHello(DeviceHello {
                protocol_version,
                firmware_version,
                capabilities,
                calibration_id,
                sample_rate_hz,
                nonce,
                serial_len: serial_len as u8,
                serial,
            })
        }
        MessageType::Sample => {
            let device_time_us = r.u64();
            let valve_in_raw = r.u16();
            let valve_out_raw = r.u16();
            let pump_raw = r.u16();
            let flags = r.u8();
            let _reserved = r.u8();
            let position_mm = [r.f32(), r.f32(), r.f32()];
            let orientation_wxyz = [r.f32(), r.f32(), r.f32(), r.f32()];
            Message::Sample(SensorSample {
                device_time_us,
                valve_in_raw,
                valve_out_raw,
                pump_raw,
                pose_valid: flags & 1 == 1,
                position_mm,
                orientation_wxyz,
                buttons: r.u32(),
            })
        }
        MessageType::Heartbeat => Message::Heartbeat(Heartbeat { uptime_ms: r.u32() }),
        MessageType::FaultReport => {
            let code = r.u16();
            let severity = r.u8();
            let _reserved = r.u8();
            Message::FaultReport(FaultReport {
                code,
                severity,
                detail: r.u32(),
            })
        }
    };
    Ok(Frame { sequence, message })
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;

    #[test]
    fn crc_matches_the_check_value_of_crc32_iso_hdlc() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn device_hello_with_longest_serial_fits_max_payload() {
        let hello = DeviceHello::new(1, (1, 2, 3), &"X".repeat(40), 0, 0, 250, 7);
        let mut raw = [0u8; MAX_FRAME_LEN];
        let n = write_raw_frame(0, &Message::DeviceHello(hello), &mut raw).unwrap();
        assert_eq!(n, MAX_FRAME_LEN);
        assert_eq!(hello.serial_number_bytes().len(), MAX_SERIAL_LEN);
    }

    #[test]
    fn payload_lengths_match_the_specification() {
        let cases: [(Message, usize); 4] = [
            (
                Message::HostHello(HostHello {
                    protocol_version: 1,
                    nonce: 0,
                }),
                HOST_HELLO_LEN,
            ),
            (
                Message::Sample(SensorSample {
                    device_time_us: 0,
                    valve_in_raw: 0,
                    valve_out_raw: 0,
                    pump_raw: 0,
                    pose_valid: true,
                    position_mm: [0.0; 3],
                    orientation_wxyz: [1.0, 0.0, 0.0, 0.0],
                    buttons: 0,
                }),
                SAMPLE_LEN,
            ),
            (
                Message::Heartbeat(Heartbeat { uptime_ms: 0 }),
                HEARTBEAT_LEN,
            ),
            (
                Message::FaultReport(FaultReport {
                    code: 1,
                    severity: 2,
                    detail: 3,
                }),
                FAULT_LEN,
            ),
        ];
        for (msg, len) in cases {
            let mut raw = [0u8; MAX_FRAME_LEN];
            let n = write_raw_frame(0, &msg, &mut raw).unwrap();
            assert_eq!(n, HEADER_LEN + len + CRC_LEN, "{msg:?}");
        }
    }

    fn hex(s: &str) -> std::vec::Vec<u8> {
        s.split_whitespace()
            .map(|b| u8::from_str_radix(b, 16).unwrap())
            .collect()
    }

    #[test]
    fn worked_examples_in_the_protocol_document_match_the_codec() {
        let doc = include_str!("../../docs/rig-protocol.md");
        let sample = SensorSample {
            device_time_us: 1_234_567,
            valve_in_raw: 2050,
            valve_out_raw: 200,
            pump_raw: 1843,
            pose_valid: true,
            position_mm: [10.0, -2.5, 45.0],
            orientation_wxyz: [1.0, 0.0, 0.0, 0.0],
            buttons: 1,
        };
        let cases: [(u32, Message); 5] = [
            (5, Message::Heartbeat(Heartbeat { uptime_ms: 1000 })),
            (
                0,
                Message::HostHello(HostHello {
                    protocol_version: 1,
                    nonce: 0x1234_5678,
                }),
            ),
            (
                0,
                Message::DeviceHello(DeviceHello::new(
                    1,
                    (1, 2, 3),
                    "RIG-0042",
                    capabilities::ALL,
                    42,
                    250,
                    0x1234_5678,
                )),
            ),
            (7, Message::Sample(sample)),
            (
                9,
                Message::FaultReport(FaultReport {
                    code: 2,
                    severity: 1,
                    detail: 0,
                }),
            ),
        ];
        // The examples are the ```-blocks with "decoded:" and "wire:" lines, in document order.
        let mut blocks = std::vec::Vec::new();
        let mut current: Option<(std::string::String, std::string::String)> = None;
        let mut in_wire = false;
        for line in doc.lines() {
            let t = line.trim();
            if let Some(rest) = t.strip_prefix("decoded:") {
                current = Some((rest.to_string(), std::string::String::new()));
                in_wire = false;
            } else if let Some(rest) = t.strip_prefix("wire:") {
                if let Some(c) = current.as_mut() {
                    c.1 = rest.to_string();
                }
                in_wire = true;
            } else if t == "```" {
                if let Some(c) = current.take() {
                    blocks.push(c);
                }
                in_wire = false;
            } else if let Some(c) = current.as_mut() {
                if in_wire {
                    c.1.push(' ');
                    c.1.push_str(t);
                } else {
                    c.0.push(' ');
                    c.0.push_str(t);
                }
            }
        }
        assert_eq!(
            blocks.len(),
            cases.len(),
            "examples in docs/rig-protocol.md"
        );
        for ((decoded, wire), (seq, msg)) in blocks.iter().zip(cases) {
            let mut raw = [0u8; MAX_FRAME_LEN];
            let n = write_raw_frame(seq, &msg, &mut raw).unwrap();
            assert_eq!(raw[..n], hex(decoded)[..], "{msg:?}");
            let mut enc = [0u8; MAX_ENCODED_LEN];
            let m = encode_frame(seq, &msg, &mut enc).unwrap();
            assert_eq!(enc[..m], hex(wire)[..], "{msg:?}");
            let frame = parse_raw_frame(&hex(decoded)).unwrap();
            assert_eq!(
                frame,
                Frame {
                    sequence: seq,
                    message: msg
                }
            );
        }
        // The heartbeat's CRC as stated in the text.
        assert_eq!(crc32(&hex("01 20 05 00 00 00 e8 03 00 00")), 0xD7D4_5801);
    }
}
