//! `/layout.json`: what the page needs to decode status frames, taken from the renderer contract
//! itself (field offsets by `offset_of!`, names of alarms, states and reasons from
//! `hydrometra-ipc`), so the page holds no second copy of docs/ipc.md.

use core::mem::offset_of;

use hydrometra_ipc::status::{link_down_reason, link_state, scene_state};
use hydrometra_ipc::{alarms, hydraulic_flags, Status};
use serde_json::{json, Map, Value};

/// `(name, offset, type)` of the status fields the page shows; an array field is named once
/// with its element type.
macro_rules! fields {
    ($($name:ident: $ty:literal),* $(,)?) => {
        [$((stringify!($name), offset_of!(Status, $name), $ty)),*]
    };
}

/// The layout description served as `/layout.json`.
pub fn layout() -> Value {
    let status_fields = fields![
        sequence: "u64",
        run_id: "u64",
        sim_time_s: "f64",
        publish_monotonic_ns: "u64",
        link_frames: "u64",
        link_crc_errors: "u64",
        link_malformed: "u64",
        link_sequence_gaps: "u64",
        link_resyncs: "u64",
        link_reconnects: "u64",
        last_sample_age_s: "f64",
        valve_in_opening: "f64",
        valve_out_opening: "f64",
        pump_set_pressure_pa: "f64",
        rig_pump_set_pressure_pa: "f64",
        scope_tip_position_m: "f64x3",
        scope_view_direction: "f64x3",
        scope_orientation_wxyz: "f64x4",
        alarm_bits: "u64",
        tick_rate_hz: "f64",
        ticks: "u64",
        deadline_misses: "u64",
        tick_work_max_s: "f64",
        latency_p50_s: "f64",
        latency_p99_s: "f64",
        latency_max_s: "f64",
        link_state: "u32",
        scope_pose_valid: "u32",
        safe_state: "u32",
        cavity_pressure_pa: "f64",
        cavity_volume_m3: "f64",
        inflow_m3_per_s: "f64",
        outflow_m3_per_s: "f64",
        leak_m3_per_s: "f64",
        absorption_m3_per_s: "f64",
        perforation_m3_per_s: "f64",
        fluid_in_m3: "f64",
        fluid_collected_m3: "f64",
        deficit_m3: "f64",
        deficit_rate_m3_per_s: "f64",
        deficit_limit_m3: "f64",
        procedure_id: "u64",
        procedure_time_s: "f64",
        deficit_warning_stage: "u64",
        hydraulic_flags: "u64",
        link_down_reason: "u32",
        scene_state: "u64",
        scene_frames: "u64",
        scene_step_p99_s: "f64",
        view_clarity: "f64",
        cavity_surface_volume_m3: "f64",
    ];
    let mut fields = Map::new();
    for (name, offset, ty) in status_fields {
        fields.insert(name.into(), json!({ "offset": offset, "type": ty }));
    }
    let bits = |all: &[(u64, &str)]| -> Vec<Value> {
        all.iter()
            .map(|(bit, name)| json!({ "bit": bit.trailing_zeros(), "name": name }))
            .collect()
    };
    json!({
        "frame_version": crate::frame::VERSION,
        "header_bytes": crate::frame::HEADER_LEN,
        "kinds": {
            "status": crate::frame::kind::STATUS,
            "topology": crate::frame::kind::TOPOLOGY,
            "positions": crate::frame::kind::POSITIONS,
            "flow": crate::frame::kind::FLOW,
            "particles": crate::frame::kind::PARTICLES,
            "history": crate::frame::kind::HISTORY,
        },
        "status_bytes": size_of::<Status>(),
        // The scene headers' sizes (the contract appends fields to them): the page finds the
        // payload after them instead of at a number of its own.
        "topology_header_bytes": size_of::<hydrometra_ipc::mesh::MeshTopologyHeader>(),
        "positions_header_bytes": size_of::<hydrometra_ipc::mesh::MeshPositionsHeader>(),
        "particles_header_bytes": size_of::<hydrometra_ipc::particles::ParticlesHeader>(),
        "particle_bytes": size_of::<hydrometra_ipc::particles::Particle>(),
        "status": fields,
        "alarms": bits(&alarms::ALL),
        "hydraulic_flags": bits(&hydraulic_flags::ALL),
        "link_states": (0..=4).map(link_state::name).collect::<Vec<_>>(),
        "scene_states": (0..=4).map(scene_state::name).collect::<Vec<_>>(),
        "link_down_reasons": (0..=9).map(link_down_reason::name).collect::<Vec<_>>(),
        "pa_per_mmhg": hydrometra_units::PA_PER_MMHG,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn offsets_are_those_of_the_contract() {
        let l = layout();
        // Spot checks against the table in docs/ipc.md.
        assert_eq!(l["status"]["cavity_pressure_pa"]["offset"], 352);
        assert_eq!(l["status"]["deficit_m3"]["offset"], 440);
        assert_eq!(l["status"]["procedure_id"]["offset"], 464);
        assert_eq!(l["status_bytes"], 752);
        assert_eq!(l["alarms"][0]["name"], "rig-link-lost");
        assert_eq!(l["link_states"][2], "connected");
    }
}
