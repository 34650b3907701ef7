//! Stream framing: splits a byte stream at 0x00 delimiters, undoes COBS and parses frames.
//!
//! The decoder owns a fixed buffer (no allocation, no `std`), accepts bytes in chunks of any size,
//! and gets back in step at the next delimiter after garbage, a lost byte or an overlong run.

use crate::wire::{parse_raw_frame, Frame, FrameError, MAX_ENCODED_LEN, MAX_FRAME_LEN};

/// What the decoder has seen since it was created.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DecoderStats {
    /// Valid frames returned.
    pub frames: u64,
    /// Frames rejected for a CRC mismatch.
    pub crc_errors: u64,
    /// Byte runs rejected for any other reason (COBS, length, type, version, oversize).
    pub malformed: u64,
    /// Times a valid frame followed one or more rejected byte runs (recoveries).
    pub resyncs: u64,
}

/// Incremental frame decoder.
#[derive(Debug, Clone)]
pub struct FrameDecoder {
    buf: [u8; MAX_ENCODED_LEN],
    len: usize,
    overflowed: bool,
    out_of_step: bool,
    stats: DecoderStats,
}

impl Default for FrameDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameDecoder {
    /// A decoder waiting for the first byte.
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_ENCODED_LEN],
            len: 0,
            overflowed: false,
            out_of_step: false,
            stats: DecoderStats {
                frames: 0,
                crc_errors: 0,
                malformed: 0,
                resyncs: 0,
            },
        }
    }

    /// Counters since creation.
    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Drops any partial frame (e.g. after reopening the port); counters are kept.
    pub fn reset(&mut self) {
        self.len = 0;
        self.overflowed = false;
    }

    /// Feeds one byte; returns a result when the byte completes a non-empty frame.
    pub fn push(&mut self, byte: u8) -> Option<Result<Frame, FrameError>> {
        if byte != 0 {
            if self.len < self.buf.len() {
                self.buf[self.len] = byte;
                self.len += 1;
            } else {
                self.overflowed = true;
            }
            return None;
        }
        // Delimiter: an empty frame (repeated 0x00) is padding, not an error.
        if self.len == 0 && !self.overflowed {
            return None;
        }
        let result = if self.overflowed {
            Err(FrameError::Oversize)
        } else {
            let mut raw = [0u8; MAX_FRAME_LEN];
            match cobs::decode(&self.buf[..self.len], &mut raw) {
                Ok(n) => parse_raw_frame(&raw[..n]),
                Err(_) => Err(FrameError::Cobs),
            }
        };
        self.reset();
        match &result {
            Ok(_) => {
                self.stats.frames += 1;
                if self.out_of_step {
                    self.stats.resyncs += 1;
                    self.out_of_step = false;
                }
            }
            Err(e) => {
                self.out_of_step = true;
                match e {
                    FrameError::Crc { .. } => self.stats.crc_errors += 1,
                    _ => self.stats.malformed += 1,
                }
            }
        }
        Some(result)
    }

    /// Feeds a chunk, calling `on_frame` for every completed frame or rejected byte run.
    pub fn push_slice(
        &mut self,
        bytes: &[u8],
        mut on_frame: impl FnMut(Result<Frame, FrameError>),
    ) {
        for &b in bytes {
            if let Some(r) = self.push(b) {
                on_frame(r);
            }
        }
    }
}
