//! Flow field service: the fluid's cell labels and cell-centred velocities, every fluid step.

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

/// User header of `<prefix>/flow`; payload: `[u8]` of `total_bytes` with two sections:
/// labels (`cell_count` `u8`, x fastest, then y, then z) at `labels_offset_bytes`, and
/// cell-centred velocities (`3 * cell_count` little-endian `f32`, m/s, same order) at
/// `velocities_offset_bytes` (a multiple of 4).
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
