//! `/layout.json`: what the page needs to decode status frames, taken from the renderer contract
//! itself (field offsets by `offset_of!`, names of alarms, states and reasons from
//! `hydrometra-ipc`), so the page holds no second copy of docs/ipc.md.

use core::mem::offset_of;

use hydrometra_ipc::status::{link_down_reason, link_state, scene_state};
use hydrometra_ipc::{alarms, hydraulic_flags, Status};
use serde_json::{json, Map, Value};

/// `(name, offset, type)` of the status fields the page shows, the offset and the type taken from
/// the field itself; an array field is named once with its element type and length (`f64x3`).
macro_rules! fields {
    ($($name:ident),* $(,)?) => {
        [$((stringify!($name), offset_of!(Status, $name), wire_type(|s| &s.$name))),*]
    };
}

/// The page's name of a status field's wire type (the decoder's `switch` in `station.js`).
trait WireType {
    const NAME: &'static str;
}

macro_rules! wire_types {
    ($($ty:ty => $name:literal),* $(,)?) => {
        $(impl WireType for $ty {
            const NAME: &'static str = $name;
        })*
    };
}

wire_types! {
    u32 => "u32",
    u64 => "u64",
    f64 => "f64",
    [f64; 3] => "f64x3",
    [f64; 4] => "f64x4",
}

/// The wire type of the field `field` projects a status to.
fn wire_type<T: WireType>(_field: fn(&Status) -> &T) -> &'static str {
    T::NAME
}

/// The layout description served as `/layout.json`.
pub fn layout() -> Value {
    let status_fields = fields![
        sequence,
        run_id,
        sim_time_s,
        publish_monotonic_ns,
        link_frames,
        link_crc_errors,
        link_malformed,
        link_sequence_gaps,
        link_resyncs,
        link_reconnects,
        last_sample_age_s,
        valve_in_opening,
        valve_out_opening,
        pump_set_pressure_pa,
        rig_pump_set_pressure_pa,
        scope_tip_position_m,
        scope_view_direction,
        scope_orientation_wxyz,
        alarm_bits,
        tick_rate_hz,
        ticks,
        deadline_misses,
        tick_work_max_s,
        latency_p50_s,
        latency_p99_s,
        latency_max_s,
        link_state,
        scope_pose_valid,
        safe_state,
        cavity_pressure_pa,
        cavity_volume_m3,
        inflow_m3_per_s,
        outflow_m3_per_s,
        leak_m3_per_s,
        absorption_m3_per_s,
        perforation_m3_per_s,
        fluid_in_m3,
        fluid_collected_m3,
        deficit_m3,
        deficit_rate_m3_per_s,
        deficit_limit_m3,
        procedure_id,
        procedure_time_s,
        deficit_warning_stage,
        hydraulic_flags,
        link_down_reason,
        scene_state,
        scene_frames,
        scene_step_p99_s,
        view_clarity,
        cavity_surface_volume_m3,
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
        assert_eq!(l["status"]["scope_tip_position_m"]["type"], "f64x3");
        assert_eq!(l["status"]["link_state"]["type"], "u32");
    }

    /// Every type the layout names is one the page's decoder reads, and every field lies inside
    /// the status record.
    #[test]
    fn the_page_decodes_every_field_type() {
        let page = include_str!("assets/station.js");
        let l = layout();
        let bytes = l["status_bytes"].as_u64().unwrap();
        for (name, field) in l["status"].as_object().unwrap() {
            let ty = field["type"].as_str().unwrap();
            assert!(page.contains(&format!("case '{ty}':")), "{name}: {ty}");
            let size = match ty {
                "u32" => 4,
                "u64" | "f64" => 8,
                "f64x3" => 24,
                "f64x4" => 32,
                other => panic!("{name}: {other}"),
            };
            assert!(field["offset"].as_u64().unwrap() + size <= bytes, "{name}");
        }
    }
}
