//! `docs/ipc.md` is the contract renderer authors read: its layout tables must match the structs
//! byte for byte (offset, size, type and field name, in order, and the total size).

use hydrometra_ipc::field::FlowFieldHeader;
use hydrometra_ipc::mesh::{MeshPositionsHeader, MeshTopologyHeader};
use hydrometra_ipc::particles::{Particle, ParticlesHeader};
use hydrometra_ipc::Status;
use iceoryx2::prelude::ZeroCopySend;
use std::mem::{offset_of, size_of};

/// (field, offset, size, type) of one field.
type Row = (String, usize, usize, String);

fn size_of_return<T, F>(_: impl Fn(&T) -> &F) -> usize {
    size_of::<F>()
}

macro_rules! layout {
    ($t:ty { $($f:ident : $ty:literal),* $(,)? }) => {{
        let rows: Vec<Row> = vec![$(
            (
                stringify!($f).to_string(),
                offset_of!($t, $f),
                size_of_return(|s: &$t| &s.$f),
                $ty.to_string(),
            )
        ),*];
        // Every field listed once, in order, covering the struct without gaps.
        let mut end = 0;
        for (name, offset, size, _) in &rows {
            assert_eq!(*offset, end, "{}: field {name} does not follow the previous one", stringify!($t));
            end = offset + size;
        }
        assert_eq!(end, size_of::<$t>(), "{}: fields do not cover the struct", stringify!($t));
        (unsafe { <$t as ZeroCopySend>::type_name() }.to_string(), size_of::<$t>(), rows)
    }};
}

fn layouts() -> Vec<(String, usize, Vec<Row>)> {
    vec![
        layout!(Status {
            schema_version: "u32",
            size_bytes: "u32",
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
            link_clamped_values: "u64",
            link_device_faults: "u64",
            last_sample_age_s: "f64",
            rig_device_time_us: "u64",
            rig_valve_in_opening: "f64",
            rig_valve_out_opening: "f64",
            rig_pump_set_pressure_pa: "f64",
            valve_in_opening: "f64",
            valve_out_opening: "f64",
            pump_set_pressure_pa: "f64",
            scope_tip_position_m: "f64[3]",
            scope_view_direction: "f64[3]",
            scope_orientation_wxyz: "f64[4]",
            alarm_bits: "u64",
            tick_rate_hz: "f64",
            ticks: "u64",
            deadline_misses: "u64",
            tick_work_max_s: "f64",
            latency_p50_s: "f64",
            latency_p99_s: "f64",
            latency_max_s: "f64",
            latency_samples: "u64",
            statuses_dropped: "u64",
            link_state: "u32",
            rig_sequence: "u32",
            buttons: "u32",
            scope_pose_valid: "u32",
            safe_state: "u32",
            reserved0: "u32",
            cavity_pressure_pa: "f64",
            cavity_volume_m3: "f64",
            inflow_m3_per_s: "f64",
            outflow_m3_per_s: "f64",
            leak_m3_per_s: "f64",
            absorption_m3_per_s: "f64",
            perforation_m3_per_s: "f64",
            inflow_port_velocity_m_per_s: "f64",
            outflow_port_velocity_m_per_s: "f64",
            fluid_in_m3: "f64",
            fluid_collected_m3: "f64",
            deficit_m3: "f64",
            deficit_rate_m3_per_s: "f64",
            deficit_limit_m3: "f64",
            procedure_id: "u64",
            procedure_time_s: "f64",
            deficit_warning_stage: "u64",
            hydraulic_flags: "u64",
            scene_state: "u64",
            scene_frames: "u64",
            scene_stage_runs: "u64[7]",
            scene_stage_skips: "u64[7]",
            scene_stage_p99_s: "f64[7]",
            scene_step_p99_s: "f64",
            view_clarity: "f64",
            cavity_surface_volume_m3: "f64",
        }),
        layout!(MeshTopologyHeader {
            schema_version: "u32",
            vertex_count: "u32",
            triangle_count: "u32",
            reserved0: "u32",
            topology_revision: "u64",
        }),
        layout!(MeshPositionsHeader {
            schema_version: "u32",
            vertex_count: "u32",
            status_sequence: "u64",
            sim_time_s: "f64",
            topology_revision: "u64",
            cavity_pressure_pa: "f64",
        }),
        layout!(FlowFieldHeader {
            schema_version: "u32",
            reserved0: "u32",
            dims: "u32[3]",
            cell_count: "u32",
            origin_m: "f64[3]",
            spacing_m: "f64",
            status_sequence: "u64",
            sim_time_s: "f64",
            labels_offset_bytes: "u64",
            velocities_offset_bytes: "u64",
            total_bytes: "u64",
        }),
        layout!(Particle {
            position_m: "f32[3]",
            velocity_m_per_s: "f32[3]",
            kind: "u32",
            age_s: "f32",
        }),
        layout!(ParticlesHeader {
            schema_version: "u32",
            particle_count: "u32",
            status_sequence: "u64",
            sim_time_s: "f64",
            view_clarity: "f64",
        }),
    ]
}

/// Parses the table that follows `<!-- layout: NAME size=N -->` in docs/ipc.md.
fn doc_layout(doc: &str, type_name: &str) -> (usize, Vec<Row>) {
    let marker = format!("<!-- layout: {type_name} size=");
    let start = doc
        .find(&marker)
        .unwrap_or_else(|| panic!("docs/ipc.md has no layout table for {type_name}"));
    let rest = &doc[start + marker.len()..];
    let size: usize = rest[..rest.find(" -->").unwrap()].parse().unwrap();
    let rows = rest
        .lines()
        .skip(1)
        .skip_while(|l| !l.starts_with('|'))
        .take_while(|l| l.starts_with('|'))
        .skip(2) // header and separator
        .map(|l| {
            let cells: Vec<&str> = l.trim_matches('|').split('|').map(str::trim).collect();
            let name = cells[3].trim_matches('`').to_string();
            (
                name,
                cells[0].parse().unwrap(),
                cells[1].parse().unwrap(),
                cells[2].to_string(),
            )
        })
        .collect();
    (size, rows)
}

#[test]
fn docs_layout_tables_match_the_structs() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/ipc.md");
    let doc = std::fs::read_to_string(path).expect("docs/ipc.md");
    for (type_name, size, rows) in layouts() {
        if std::env::var_os("PRINT_LAYOUT").is_some() {
            // Helps when editing the docs: prints the table skeleton.
            println!("<!-- layout: {type_name} size={size} -->");
            for (n, o, s, t) in &rows {
                println!("| {o} | {s} | {t} | `{n}` |");
            }
            continue;
        }
        let (doc_size, doc_rows) = doc_layout(&doc, &type_name);
        assert_eq!(doc_size, size, "{type_name}: size in docs/ipc.md");
        assert_eq!(doc_rows, rows, "{type_name}: layout table in docs/ipc.md");
    }
}
