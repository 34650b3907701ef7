//! The scene TOML reader (`SceneDesc::parse`, what `SceneDesc::from_file` and `hydrometrad
//! --scene FILE` run), with the anatomy, material and hydraulics tables it hands on.
//!
//! Inputs that name other files (`anatomy_file`, `material_file`) are skipped: the fuzzer must
//! not read the machine's files. Properties: an error starts with the origin and says where (a
//! TOML line or a back-quoted key); an accepted scene passes its own validation again, parses to
//! the same description twice (nothing depends on hash order) and has the scope's port areas in
//! its hydraulics.

use hydrometra_sim::scene::SceneDesc;

const ORIGIN: &str = "fuzz-scene.toml";

/// The scene target.
pub fn check(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(table) = text.parse::<toml::Table>() {
        if table.keys().any(|k| k.ends_with("_file")) {
            return;
        }
    }
    match SceneDesc::parse(text, ORIGIN, None) {
        Err(e) => {
            let msg = e.to_string();
            assert!(msg.starts_with(&format!("{ORIGIN}: ")), "{msg}");
            assert!(
                crate::position::names_a_line(&msg) || msg.contains('`'),
                "error names neither a line nor a key: {msg}"
            );
        }
        Ok(desc) => {
            desc.validate()
                .unwrap_or_else(|e| panic!("accepted scene fails validation: {e}"));
            let again = SceneDesc::parse(text, ORIGIN, None)
                .unwrap_or_else(|e| panic!("second parse failed: {e}"));
            assert_eq!(desc, again, "two parses differ");
            assert_eq!(desc.atlas_key(), again.atlas_key());
            assert_eq!(
                desc.hydraulics.inflow.port_area_mm2,
                desc.scope.inflow_channel_area_mm2
            );
            assert_eq!(
                desc.hydraulics.outflow.port_area_mm2,
                desc.scope.outflow_holes_area_mm2
            );
            let voxel_m = desc.voxel_m();
            assert!((0.2e-3..=5e-3).contains(&voxel_m), "voxel {voxel_m} m");
        }
    }
}
