//! The binary WebSocket frames the station sends to the page: the one copy of their layout
//! (specified for other clients in docs/station.md, "Frames").
//!
//! Every frame starts with a 16-byte header (little-endian): `kind` u8, `version` u8, `rig` u16
//! (index into the hello message's rig list), `reserved` u32 (0), `origin_ns` u64 (status frames:
//! host `CLOCK_MONOTONIC` of the rig sample the status reflects, which the page echoes back in its
//! acknowledgement; 0 otherwise). The body follows; payloads of the renderer contract keep their
//! docs/ipc.md layouts byte for byte.

use bytes::{BufMut, Bytes, BytesMut};
use hydrometra_ipc::mesh::{MeshPositionsHeader, MeshTopologyHeader};
use hydrometra_ipc::particles::{Particle, ParticlesHeader};
use hydrometra_ipc::Status;
use hydrometra_remote::wire::{bytes_of, slice_bytes};

/// Version of the frame layout, in every header.
pub const VERSION: u8 = 1;
/// Bytes of the common header.
pub const HEADER_LEN: usize = 16;

/// Frame kinds (header byte 0).
pub mod kind {
    /// Body: one `hydrometra.v1.Status` (752 bytes, docs/ipc.md).
    pub const STATUS: u8 = 1;
    /// Body: `MeshTopologyHeader` (24 bytes) then `3 × triangle_count` u32.
    pub const TOPOLOGY: u8 = 2;
    /// Body: `MeshPositionsHeader` (40 bytes) then `3 × vertex_count` f32.
    pub const POSITIONS: u8 = 3;
    /// Body: a [`super::FlowArrowsHeader`] (32 bytes) then `arrow_count` arrows of 6 f32.
    pub const FLOW: u8 = 4;
    /// Body: `ParticlesHeader` (its `size_of`, `/layout.json`'s `particles_header_bytes`) then
    /// `particle_count` particles of 32 bytes.
    pub const PARTICLES: u8 = 5;
    /// Body: `count` u32, `record_bytes` u32 (40), then `count` [`super::HistoryRecord`]s.
    pub const HISTORY: u8 = 6;
    /// Every kind, in the order a client is sent them (topology before positions).
    pub const ALL: [u8; 6] = [HISTORY, TOPOLOGY, POSITIONS, FLOW, PARTICLES, STATUS];
}

fn header(kind: u8, rig: u16, origin_ns: u64, body_len: usize) -> BytesMut {
    let mut b = BytesMut::with_capacity(HEADER_LEN + body_len);
    b.put_u8(kind);
    b.put_u8(VERSION);
    b.put_u16_le(rig);
    b.put_u32_le(0);
    b.put_u64_le(origin_ns);
    b
}

/// Host monotonic time of the rig sample a status reflects (its publication minus the sample's
/// age); 0 before the first sample.
pub fn rig_sample_ns(s: &Status) -> u64 {
    if !s.last_sample_age_s.is_finite() || s.last_sample_age_s < 0.0 {
        return 0;
    }
    s.publish_monotonic_ns
        .saturating_sub((s.last_sample_age_s * 1e9) as u64)
}

/// A status frame.
pub fn status(rig: u16, s: &Status) -> Bytes {
    let body = bytes_of(s);
    let mut b = header(kind::STATUS, rig, rig_sample_ns(s), body.len());
    b.put_slice(body);
    b.freeze()
}

/// A cavity topology frame.
pub fn topology(rig: u16, h: &MeshTopologyHeader, indices: &[u32]) -> Bytes {
    let (hb, body) = (bytes_of(h), slice_bytes(indices));
    let mut b = header(kind::TOPOLOGY, rig, 0, hb.len() + body.len());
    b.put_slice(hb);
    b.put_slice(body);
    b.freeze()
}

/// A cavity positions frame.
pub fn positions(rig: u16, h: &MeshPositionsHeader, xyz: &[f32]) -> Bytes {
    let (hb, body) = (bytes_of(h), slice_bytes(xyz));
    let mut b = header(kind::POSITIONS, rig, 0, hb.len() + body.len());
    b.put_slice(hb);
    b.put_slice(body);
    b.freeze()
}

/// A particles frame with at most `max` particles (an evenly spaced subset of more); the header's
/// `particle_count` says how many follow.
pub fn particles(rig: u16, h: &ParticlesHeader, all: &[Particle], max: usize) -> Bytes {
    let stride = all.len().div_ceil(max.max(1)).max(1);
    let kept = all.len().div_ceil(stride);
    let mut hdr = *h;
    hdr.particle_count = kept as u32;
    let hb = bytes_of(&hdr);
    let mut b = header(
        kind::PARTICLES,
        rig,
        0,
        hb.len() + kept * size_of::<Particle>(),
    );
    b.put_slice(hb);
    for p in all.iter().step_by(stride) {
        b.put_slice(bytes_of(p));
    }
    b.freeze()
}

/// Header of a flow frame: the flow field averaged over cubic blocks of cells (one arrow per
/// block holding fluid), so the page draws a few thousand arrows whatever the grid.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FlowArrowsHeader {
    /// Arrows that follow.
    pub arrow_count: u32,
    /// Edge of an averaging block, m.
    pub block_m: f32,
    /// `status_sequence` of the flow field (docs/ipc.md).
    pub status_sequence: u64,
    /// Scene time of the flow field, s.
    pub sim_time_s: f64,
    /// Largest arrow speed, m/s.
    pub max_speed_m_per_s: f32,
    /// Fluid cells averaged.
    pub fluid_cells: u32,
}

/// Bytes of [`FlowArrowsHeader`] in a frame.
pub const FLOW_HEADER_LEN: usize = 32;
/// Bytes of one arrow: position x, y, z (m) and mean velocity x, y, z (m/s), f32 each.
pub const ARROW_LEN: usize = 24;

/// A flow frame from arrows of `[position; 3], [velocity; 3]`.
pub fn flow(rig: u16, h: &FlowArrowsHeader, arrows: &[[f32; 6]]) -> Bytes {
    let mut b = header(
        kind::FLOW,
        rig,
        0,
        FLOW_HEADER_LEN + arrows.len() * ARROW_LEN,
    );
    b.put_u32_le(arrows.len() as u32);
    b.put_f32_le(h.block_m);
    b.put_u64_le(h.status_sequence);
    b.put_f64_le(h.sim_time_s);
    b.put_f32_le(h.max_speed_m_per_s);
    b.put_u32_le(h.fluid_cells);
    for a in arrows {
        for v in a {
            b.put_f32_le(*v);
        }
    }
    b.freeze()
}

/// One point of the plots' history: what the page plots, taken from a status.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct HistoryRecord {
    /// Status `sim_time_s`, s.
    pub sim_time_s: f64,
    /// Cavity pressure, Pa.
    pub cavity_pressure_pa: f32,
    /// Pump set pressure the simulation uses, Pa.
    pub pump_set_pressure_pa: f32,
    /// Inflow, m³/s.
    pub inflow_m3_per_s: f32,
    /// Outflow, m³/s.
    pub outflow_m3_per_s: f32,
    /// Losses: leak + absorption + perforation, m³/s.
    pub losses_m3_per_s: f32,
    /// Fluid deficit, m³.
    pub deficit_m3: f32,
    /// Deficit limit, m³.
    pub deficit_limit_m3: f32,
    /// Low 32 alarm bits, or-ed over the statuses the record stands for.
    pub alarm_bits: u32,
}

/// Bytes of one [`HistoryRecord`].
pub const HISTORY_RECORD_LEN: usize = 40;

impl HistoryRecord {
    /// The record of one status (alarm bits of that status alone).
    pub fn of(s: &Status) -> Self {
        Self {
            sim_time_s: s.sim_time_s,
            cavity_pressure_pa: s.cavity_pressure_pa as f32,
            pump_set_pressure_pa: s.pump_set_pressure_pa as f32,
            inflow_m3_per_s: s.inflow_m3_per_s as f32,
            outflow_m3_per_s: s.outflow_m3_per_s as f32,
            losses_m3_per_s: (s.leak_m3_per_s + s.absorption_m3_per_s + s.perforation_m3_per_s)
                as f32,
            deficit_m3: s.deficit_m3 as f32,
            deficit_limit_m3: s.deficit_limit_m3 as f32,
            alarm_bits: s.alarm_bits as u32,
        }
    }
}

/// A history frame.
pub fn history(rig: u16, records: impl ExactSizeIterator<Item = HistoryRecord>) -> Bytes {
    let n = records.len();
    let mut b = header(kind::HISTORY, rig, 0, 8 + n * HISTORY_RECORD_LEN);
    b.put_u32_le(n as u32);
    b.put_u32_le(HISTORY_RECORD_LEN as u32);
    for r in records {
        b.put_f64_le(r.sim_time_s);
        for v in [
            r.cavity_pressure_pa,
            r.pump_set_pressure_pa,
            r.inflow_m3_per_s,
            r.outflow_m3_per_s,
            r.losses_m3_per_s,
            r.deficit_m3,
            r.deficit_limit_m3,
        ] {
            b.put_f32_le(v);
        }
        b.put_u32_le(r.alarm_bits);
    }
    b.freeze()
}

#[cfg(test)]
mod tests {
    use super::*;
    use hydrometra_remote::wire::{read_exact, read_slice};

    #[test]
    fn a_status_frame_is_the_header_then_the_ipc_record_byte_for_byte() {
        let mut s = Status {
            sequence: 7,
            publish_monotonic_ns: 5_000_000_000,
            last_sample_age_s: 0.002,
            cavity_pressure_pa: 4321.5,
            ..Status::default()
        };
        s.deficit_m3 = 1.5e-4;
        let f = status(3, &s);
        assert_eq!(f.len(), HEADER_LEN + size_of::<Status>());
        assert_eq!((f[0], f[1]), (kind::STATUS, VERSION));
        assert_eq!(u16::from_le_bytes([f[2], f[3]]), 3);
        let origin = u64::from_le_bytes(f[8..16].try_into().unwrap());
        assert_eq!(origin, 4_998_000_000);
        let back: Status = read_exact(&f[HEADER_LEN..]).unwrap();
        assert_eq!(back.sequence, 7);
        assert_eq!(back.cavity_pressure_pa, 4321.5);
        assert_eq!(back.deficit_m3, 1.5e-4);
        assert!(read_exact::<Status>(&f[HEADER_LEN + 1..]).is_none());
    }

    #[test]
    fn particles_are_thinned_evenly_to_the_cap_and_the_header_counts_them() {
        let all: Vec<Particle> = (0..10)
            .map(|i| Particle {
                age_s: i as f32,
                ..Particle::default()
            })
            .collect();
        let h = ParticlesHeader {
            particle_count: 10,
            ..Default::default()
        };
        let f = particles(0, &h, &all, 4);
        let hb = size_of::<ParticlesHeader>();
        let back: ParticlesHeader = read_exact(&f[HEADER_LEN..HEADER_LEN + hb]).unwrap();
        assert_eq!(back.particle_count, 4); // stride 3: 0, 3, 6, 9
        let kept: Vec<Particle> = read_slice(&f[HEADER_LEN + hb..]).unwrap();
        let ages: Vec<f32> = kept.iter().map(|p| p.age_s).collect();
        assert_eq!(ages, vec![0.0, 3.0, 6.0, 9.0]);
        assert_eq!(particles(0, &h, &all, 100).len(), HEADER_LEN + hb + 10 * 32);
    }

    #[test]
    fn history_and_flow_frames_have_the_documented_sizes() {
        let r = HistoryRecord::of(&Status::default());
        assert_eq!(history(0, [r, r].into_iter()).len(), HEADER_LEN + 8 + 80);
        let h = FlowArrowsHeader::default();
        assert_eq!(
            flow(1, &h, &[[0.0; 6]; 3]).len(),
            HEADER_LEN + FLOW_HEADER_LEN + 3 * ARROW_LEN
        );
    }
}
