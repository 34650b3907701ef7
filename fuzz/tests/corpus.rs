//! Replays every committed corpus input (`fuzz/corpus/<target>/`) through its target's checks
//! and memory budget, as a plain test: a regression is caught by `cargo test` on any machine,
//! with or without a fuzzer.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use hydrometra_fuzz::alloc::PeakTracking;
use hydrometra_fuzz::{run, target};

#[global_allocator]
static ALLOC: PeakTracking = PeakTracking;

/// One input may take this long (a hang shows as a failure, not a stuck test).
const PER_INPUT: Duration = Duration::from_secs(10);

fn replay(name: &str) {
    assert!(
        hydrometra_fuzz::alloc::installed(),
        "the tracking allocator is not installed"
    );
    let target = target(name).unwrap_or_else(|| panic!("no target {name}"));
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("corpus")
        .join(name);
    let mut inputs: Vec<PathBuf> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.map(|e| e.path()))
        .collect::<Result<_, _>>()
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    inputs.sort();
    assert!(!inputs.is_empty(), "{}: empty corpus", dir.display());
    for path in &inputs {
        let data = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let start = Instant::now();
        let outcome = std::panic::catch_unwind(|| run(target, &data));
        assert!(
            outcome.is_ok(),
            "{}: property failed (message above)",
            path.display()
        );
        let took = start.elapsed();
        assert!(took < PER_INPUT, "{}: took {took:?}", path.display());
    }
    println!("{name}: {} inputs replayed", inputs.len());
}

#[test]
fn wire_frames_corpus_holds() {
    replay("wire_frames");
}

#[test]
fn rig_stream_corpus_holds() {
    replay("rig_stream");
}

#[test]
fn calibration_corpus_holds() {
    replay("calibration");
}

#[test]
fn scenario_corpus_holds() {
    replay("scenario");
}

#[test]
fn scene_corpus_holds() {
    replay("scene");
}

#[test]
fn fluid_case_corpus_holds() {
    replay("fluid_case");
}

#[test]
fn atlas_corpus_holds() {
    replay("atlas");
}

#[test]
fn recording_corpus_holds() {
    replay("recording");
}

#[test]
fn control_corpus_holds() {
    replay("control");
}

#[test]
fn every_target_has_a_replay_test() {
    let source = include_str!("corpus.rs");
    for t in hydrometra_fuzz::TARGETS {
        assert!(
            source.contains(&format!("fn {}_corpus_holds()", t.name)),
            "no replay test for {}",
            t.name
        );
    }
}
