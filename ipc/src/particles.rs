//! Particle service: the scene's blood, bubble and fragment particles, every scene frame.

use iceoryx2::prelude::ZeroCopySend;

/// Particle kinds.
pub mod kind {
    /// Blood.
    pub const BLOOD: u32 = 0;
    /// Air bubble.
    pub const BUBBLE: u32 = 1;
    /// Tissue fragment.
    pub const FRAGMENT: u32 = 2;
}

/// One particle, 32 bytes.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("hydrometra.v1.Particle")]
pub struct Particle {
    /// Position in the organ frame, m.
    pub position_m: [f32; 3],
    /// Velocity, m/s.
    pub velocity_m_per_s: [f32; 3],
    /// One of [`kind`].
    pub kind: u32,
    /// Time since emission, s.
    pub age_s: f32,
}

/// User header of `<prefix>/particles`; payload: `[Particle]` of `particle_count` elements.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[type_name("hydrometra.v1.ParticlesHeader")]
pub struct ParticlesHeader {
    /// [`crate::SCHEMA_VERSION`].
    pub schema_version: u32,
    /// Number of particles in the payload.
    pub particle_count: u32,
    /// Sequence of the [`crate::Status`] published in the same frame.
    pub status_sequence: u64,
    /// Simulated time of the frame, s.
    pub sim_time_s: f64,
    /// View clarity in [0, 1] (1 clear) from the particle density in front of the scope.
    pub view_clarity: f64,
    /// The scene frame this sample belongs to: +1 per frame stepped, the same in the positions,
    /// flow and particles of one frame, never published twice.
    pub scene_frame: u64,
    /// How long after it was due the frame started, s (0 on time; a frame period or more: the
    /// scene was behind, see `Status::scene_frames_late`).
    pub frame_late_s: f64,
}

/// Quality of service of the particle service (see `docs/ipc.md`).
pub mod qos {
    /// History.
    pub const HISTORY_SIZE: usize = 1;
    /// Subscriber buffer.
    pub const SUBSCRIBER_MAX_BUFFER_SIZE: usize = 2;
    /// Subscribers.
    pub const MAX_SUBSCRIBERS: usize = 8;
}
