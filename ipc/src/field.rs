//! Flow field service: the fluid's cell labels, cell-centred velocities and fluid volume
//! fractions, every fluid step.

use iceoryx2::prelude::ZeroCopySend;

/// Cell labels in the flow field's label section.
pub mod label {
    /// Solid (tissue or outside the cavity).
    pub const SOLID: u8 = 0;
    /// Fluid.
    pub const FLUID: u8 = 1;
    /// Inflow cell at the scope tip (prescribed velocity).
    pub const INFLOW: u8 = 2;
    /// Outflow cell (drained through the outflow valve).
    pub const OUTFLOW: u8 = 3;
    /// Occupied by the scope.
    pub const SCOPE: u8 = 4;
    /// The cavity wall, a moving solid: its velocity is the wall's.
    pub const WALL: u8 = 5;
    /// The open external os: fluid leaks out (or in) freely at pressure 0.
    pub const OPEN: u8 = 6;
}

/// User header of `<prefix>/flow`; payload: `[u8]` of `total_bytes` with three sections:
/// labels (`cell_count` `u8`, x fastest, then y, then z) at `labels_offset_bytes`,
/// cell-centred velocities (`3 * cell_count` little-endian `f32`, m/s, same order) at
/// `velocities_offset_bytes` (a multiple of 4), and fluid volume fractions (`cell_count` `u8`,
/// [`fraction_from_u8`], same order) at `fractions_offset_bytes` (0: no such section).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("hydrometra.v1.FlowFieldHeader")]
pub struct FlowFieldHeader {
    /// [`crate::SCHEMA_VERSION`].
    pub schema_version: u32,
    /// Reserved, 0.
    pub reserved0: u32,
    /// Cells along x, y, z.
    pub dims: [u32; 3],
    /// Number of cells, `dims[0] * dims[1] * dims[2]`.
    pub cell_count: u32,
    /// Centre of cell (0, 0, 0) in the organ frame, m.
    pub origin_m: [f64; 3],
    /// Cell edge length (cubic cells), m.
    pub spacing_m: f64,
    /// Sequence of the [`crate::Status`] published in the same frame.
    pub status_sequence: u64,
    /// Simulated time of the frame, s.
    pub sim_time_s: f64,
    /// Byte offset of the label section in the payload.
    pub labels_offset_bytes: u64,
    /// Byte offset of the velocity section in the payload.
    pub velocities_offset_bytes: u64,
    /// Payload length, bytes.
    pub total_bytes: u64,
    /// The scene frame this sample belongs to: +1 per frame stepped, the same in the positions,
    /// flow and particles of one frame, never published twice.
    pub scene_frame: u64,
    /// How long after it was due the frame started, s (0 on time; a frame period or more: the
    /// scene was behind, see `Status::scene_frames_late`).
    pub frame_late_s: f64,
    /// Byte offset of the fluid volume fraction section in the payload; 0 when the payload has
    /// none (the labels are at 0, so a present section is never there). Appended to v1.
    pub fractions_offset_bytes: u64,
}

impl FlowFieldHeader {
    /// The fluid volume fraction section of `payload` (`cell_count` bytes, [`fraction_from_u8`]),
    /// or `None` when the payload has none (`fractions_offset_bytes` 0) or is too short for it.
    pub fn fractions<'a>(&self, payload: &'a [u8]) -> Option<&'a [u8]> {
        let at = usize::try_from(self.fractions_offset_bytes).ok()?;
        let end = at.checked_add(self.cell_count as usize)?;
        if at == 0 || end as u64 > self.total_bytes {
            return None;
        }
        payload.get(at..end)
    }
}

/// Byte layout of a flow payload of `cell_count` cells as the daemon writes it: labels at 0,
/// velocities at the next multiple of 4, fractions right after the velocities.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FlowLayout {
    /// Cells.
    pub cell_count: usize,
    /// Offset of the labels, bytes.
    pub labels_offset_bytes: usize,
    /// Offset of the velocities, bytes (a multiple of 4).
    pub velocities_offset_bytes: usize,
    /// Offset of the fluid volume fractions, bytes.
    pub fractions_offset_bytes: usize,
    /// Payload length, bytes.
    pub total_bytes: usize,
}

impl FlowLayout {
    /// The layout of `cell_count` cells.
    pub fn new(cell_count: usize) -> Self {
        let velocities = cell_count.div_ceil(4) * 4;
        let fractions = velocities + 12 * cell_count;
        Self {
            cell_count,
            labels_offset_bytes: 0,
            velocities_offset_bytes: velocities,
            fractions_offset_bytes: fractions,
            total_bytes: fractions + cell_count,
        }
    }

    /// Sets the header's cell count, section offsets and payload length to this layout's.
    pub fn write_offsets(&self, header: &mut FlowFieldHeader) {
        header.cell_count = self.cell_count as u32;
        header.labels_offset_bytes = self.labels_offset_bytes as u64;
        header.velocities_offset_bytes = self.velocities_offset_bytes as u64;
        header.fractions_offset_bytes = self.fractions_offset_bytes as u64;
        header.total_bytes = self.total_bytes as u64;
    }

    /// Writes the whole payload into `out` (resized to [`FlowLayout::total_bytes`]; no allocation
    /// once its capacity holds that), from each cell's label, velocity (m/s) and fluid volume
    /// fraction (already quantised, [`fraction_to_u8`]). Bytes between the labels and the
    /// velocities are 0. Section by section: a publisher copies the result into its loaned sample
    /// in one `memcpy` (byte by byte through one function, a 0.6 mm field of 312,620 cells cost
    /// the scene thread milliseconds a frame).
    pub fn fill(
        &self,
        out: &mut Vec<u8>,
        label: impl Fn(usize) -> u8,
        velocity_m_per_s: impl Fn(usize) -> [f32; 3],
        fraction: impl Fn(usize) -> u8,
    ) {
        out.resize(self.total_bytes, 0);
        let (labels, rest) = out.split_at_mut(self.velocities_offset_bytes);
        for (c, byte) in labels.iter_mut().enumerate() {
            *byte = if c < self.cell_count { label(c) } else { 0 };
        }
        let (velocities, fractions) = rest.split_at_mut(12 * self.cell_count);
        for (c, chunk) in velocities.chunks_exact_mut(12).enumerate() {
            let v = velocity_m_per_s(c);
            for (component, bytes) in v.iter().zip(chunk.chunks_exact_mut(4)) {
                bytes.copy_from_slice(&component.to_ne_bytes());
            }
        }
        for (c, byte) in fractions.iter_mut().enumerate() {
            *byte = fraction(c);
        }
    }
}

/// Quantises a fluid volume fraction for the payload: `round(255 f)`, `f` clamped to [0, 1]
/// first (NaN reads 0). 255 steps put an iso-surface within h/510 of where the exact fractions
/// put it and cost one byte a cell (an `f32` would cost four for precision no renderer draws).
#[inline]
pub fn fraction_to_u8(fraction: f64) -> u8 {
    if fraction.is_nan() {
        return 0;
    }
    (fraction.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// The fluid volume fraction a payload byte stands for: `byte / 255`.
#[inline]
pub fn fraction_from_u8(byte: u8) -> f64 {
    byte as f64 / 255.0
}

/// Quality of service of the flow service (see `docs/ipc.md`).
pub mod qos {
    /// History.
    pub const HISTORY_SIZE: usize = 1;
    /// Subscriber buffer.
    pub const SUBSCRIBER_MAX_BUFFER_SIZE: usize = 2;
    /// Subscribers (the field is large: each adds buffer samples to the pre-allocation).
    pub const MAX_SUBSCRIBERS: usize = 4;
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sections_follow_each_other_aligned_and_fill_the_payload() {
        for cells in [1usize, 3, 4, 5, 57_001] {
            let l = FlowLayout::new(cells);
            assert_eq!(l.labels_offset_bytes, 0);
            assert_eq!(l.velocities_offset_bytes % 4, 0);
            assert!(l.velocities_offset_bytes >= cells && l.velocities_offset_bytes < cells + 4);
            assert_eq!(
                l.fractions_offset_bytes,
                l.velocities_offset_bytes + 12 * cells
            );
            assert_eq!(l.total_bytes, l.fractions_offset_bytes + cells);
        }
    }

    #[test]
    fn every_byte_comes_from_its_cell() {
        let l = FlowLayout::new(5);
        // A buffer that held a larger payload before: shrunk to this one, every byte rewritten.
        let mut bytes = vec![0xAA; 2 * l.total_bytes];
        l.fill(
            &mut bytes,
            |c| 10 + c as u8,
            |c| [c as f32, -(c as f32), 0.5],
            |c| 200 + c as u8,
        );
        assert_eq!(bytes.len(), l.total_bytes);
        assert_eq!(&bytes[..5], &[10, 11, 12, 13, 14]);
        assert_eq!(&bytes[5..8], &[0, 0, 0]);
        let f = |at: usize| f32::from_ne_bytes(bytes[at..at + 4].try_into().unwrap());
        let v = l.velocities_offset_bytes;
        assert_eq!([f(v + 36), f(v + 40), f(v + 44)], [3.0, -3.0, 0.5]);
        assert_eq!(
            &bytes[l.fractions_offset_bytes..],
            &[200, 201, 202, 203, 204]
        );
    }

    #[test]
    fn a_reader_finds_the_fractions_only_where_the_header_says_they_are() {
        let l = FlowLayout::new(5);
        let payload: Vec<u8> = (0..l.total_bytes).map(|n| n as u8).collect();
        let mut h = FlowFieldHeader {
            cell_count: 5,
            total_bytes: l.total_bytes as u64,
            fractions_offset_bytes: l.fractions_offset_bytes as u64,
            ..FlowFieldHeader::default()
        };
        let at = l.fractions_offset_bytes;
        assert_eq!(h.fractions(&payload), Some(&payload[at..at + 5]));
        h.fractions_offset_bytes = 0;
        assert_eq!(h.fractions(&payload), None, "0: no section");
        h.fractions_offset_bytes = at as u64 + 1;
        assert_eq!(h.fractions(&payload), None, "past total_bytes");
        h.fractions_offset_bytes = at as u64;
        assert_eq!(h.fractions(&payload[..at + 4]), None, "a short payload");
    }

    #[test]
    fn fractions_quantise_to_the_nearest_of_255_steps_within_zero_and_one() {
        assert_eq!(fraction_to_u8(0.0), 0);
        assert_eq!(fraction_to_u8(1.0), 255);
        assert_eq!(fraction_to_u8(1.7), 255); // a merge target's stabilised fraction
        assert_eq!(fraction_to_u8(-1e-9), 0);
        assert_eq!(fraction_to_u8(f64::NAN), 0);
        assert_eq!(fraction_to_u8(0.5), 128);
        for i in 0..=1000 {
            let f = i as f64 / 1000.0;
            let back = fraction_from_u8(fraction_to_u8(f));
            assert!((back - f).abs() <= 0.5 / 255.0 + 1e-12, "{f} -> {back}");
        }
    }
}
