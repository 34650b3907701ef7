//! The properties hydrometra's fuzz targets check, one module per decoder or reader, shared by
//! the libFuzzer binaries (`fuzz/targets`, built by `fuzz/run.sh`) and by the plain tests that
//! replay the committed corpus (`tests/corpus.rs`), so a regression shows in `cargo test` even
//! where no fuzzer is installed.
//!
//! Every check panics when a property fails; [`run`] adds the memory budget: the bytes a reader
//! holds at once must stay within its target's budget for the input's length.

pub mod alloc;
pub mod atlas;
pub mod calibration;
pub mod control;
pub mod fluid_case;
pub mod position;
pub mod recording;
pub mod scenario;
pub mod scene;
pub mod stream;
pub mod wire;

/// One fuzz target.
#[derive(Debug)]
pub struct Target {
    /// Its name: the binary, the corpus folder `fuzz/corpus/<name>`.
    pub name: &'static str,
    /// What it feeds.
    pub reads: &'static str,
    /// Longer inputs are ignored (libFuzzer's `-max_len`).
    pub max_len: usize,
    /// Bytes the reader may hold at once: `fixed + per_input_byte * len`.
    pub memory_fixed: usize,
    /// See `memory_fixed`.
    pub memory_per_input_byte: usize,
    /// The properties; panics when one fails.
    pub check: fn(&[u8]),
}

const MIB: usize = 1 << 20;

/// Every target, in the order `fuzz/run.sh all` runs them.
pub const TARGETS: &[Target] = &[
    Target {
        name: "wire_frames",
        reads: "rig wire codec and COBS framing, structure-aware (drivers wire.rs, framing.rs)",
        max_len: 4096,
        memory_fixed: MIB,
        memory_per_input_byte: 64,
        check: wire::check,
    },
    Target {
        name: "rig_stream",
        reads: "the transport's frame decoder on raw bytes, then calibration of every sample",
        max_len: 4096,
        memory_fixed: MIB,
        memory_per_input_byte: 64,
        check: stream::check,
    },
    Target {
        name: "calibration",
        reads: "calibration TOML (drivers calibration.rs)",
        max_len: 64 * 1024,
        memory_fixed: 8 * MIB,
        memory_per_input_byte: 512,
        check: calibration::check,
    },
    Target {
        name: "scenario",
        reads: "emulator scenario TOML (drivers emulator/scenario.rs, faults.rs)",
        max_len: 64 * 1024,
        memory_fixed: 8 * MIB,
        memory_per_input_byte: 512,
        check: scenario::check,
    },
    Target {
        name: "scene",
        reads: "scene TOML (sim-core SceneDesc::parse)",
        max_len: 64 * 1024,
        memory_fixed: 8 * MIB,
        memory_per_input_byte: 512,
        check: scene::check,
    },
    Target {
        name: "fluid_case",
        reads: "fluid case TOML (sim-core fluid::case::Case::parse)",
        max_len: 64 * 1024,
        memory_fixed: 8 * MIB,
        memory_per_input_byte: 512,
        check: fluid_case::check,
    },
    Target {
        name: "atlas",
        reads: "binary atlas .hma (sim-core atlas/format.rs Atlas::from_bytes)",
        max_len: 256 * 1024,
        memory_fixed: 8 * MIB,
        memory_per_input_byte: 32,
        check: atlas::check,
    },
    Target {
        name: "recording",
        reads: "MCAP recording (daemon record/reader.rs Recording::from_bytes)",
        max_len: 256 * 1024,
        memory_fixed: 16 * MIB,
        memory_per_input_byte: 300,
        check: recording::check,
    },
    Target {
        name: "control",
        reads: "control requests (daemon service/control.rs Request::decode) and responses",
        max_len: 1024,
        memory_fixed: MIB,
        memory_per_input_byte: 64,
        check: control::check,
    },
];

/// The target called `name`.
pub fn target(name: &str) -> Option<&'static Target> {
    TARGETS.iter().find(|t| t.name == name)
}

/// Checks one input: the target's properties, then its memory budget.
pub fn run(target: &Target, data: &[u8]) {
    if data.len() > target.max_len {
        return;
    }
    let ((), peak) = alloc::peak_during(|| (target.check)(data));
    let budget = target.memory_fixed + target.memory_per_input_byte * data.len();
    assert!(
        peak <= budget,
        "{}: held {peak} bytes at once for a {}-byte input (budget {budget})",
        target.name,
        data.len()
    );
}
