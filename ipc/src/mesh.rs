//! Cavity surface services (specified, published once the deformation stage lands).
//!
//! Topology is published on change (history 1, so a late renderer gets it); positions every
//! frame. A renderer matches positions to topology by `topology_revision`.

use iceoryx2::prelude::ZeroCopySend;

/// User header of `<prefix>/cavity/topology`; payload: `[u32]` vertex indices, three per
/// triangle, counter-clockwise seen from inside the cavity (normals point into the fluid).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("hydrometra.v1.MeshTopologyHeader")]
pub struct MeshTopologyHeader {
    /// [`crate::SCHEMA_VERSION`].
    pub schema_version: u32,
    /// Number of vertices the indices refer to.
    pub vertex_count: u32,
    /// Number of triangles; the payload holds `3 * triangle_count` `u32`.
    pub triangle_count: u32,
    /// Reserved, 0.
    pub reserved0: u32,
    /// Incremented whenever the topology changes (new case, remeshing).
    pub topology_revision: u64,
}

/// User header of `<prefix>/cavity/positions`; payload: `[f32]`, `3 * vertex_count` values,
/// x, y, z per vertex in the organ frame, m.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("hydrometra.v1.MeshPositionsHeader")]
pub struct MeshPositionsHeader {
    /// [`crate::SCHEMA_VERSION`].
    pub schema_version: u32,
    /// Number of vertices; the payload holds `3 * vertex_count` `f32`.
    pub vertex_count: u32,
    /// Sequence of the [`crate::Status`] published in the same frame.
    pub status_sequence: u64,
    /// Simulated time of the frame, s.
    pub sim_time_s: f64,
    /// The topology these positions belong to.
    pub topology_revision: u64,
    /// Cavity pressure the positions were replayed at, Pa.
    pub cavity_pressure_pa: f64,
    /// The scene frame this sample belongs to: +1 per frame stepped, the same in the positions,
    /// flow and particles of one frame, never published twice.
    pub scene_frame: u64,
    /// How long after it was due the frame started, s (0 on time; a frame period or more: the
    /// scene was behind, see `Status::scene_frames_late`).
    pub frame_late_s: f64,
}

/// Quality of service of the cavity services (see `docs/ipc.md`): history 1 (a late renderer gets
/// the current topology), safe overflow, one publisher.
pub mod qos {
    /// History of both services.
    pub const HISTORY_SIZE: usize = 1;
    /// Subscriber buffer of both services.
    pub const SUBSCRIBER_MAX_BUFFER_SIZE: usize = 2;
    /// Subscribers of `cavity/topology`.
    pub const TOPOLOGY_MAX_SUBSCRIBERS: usize = 16;
    /// Subscribers of `cavity/positions`.
    pub const POSITIONS_MAX_SUBSCRIBERS: usize = 8;
}
