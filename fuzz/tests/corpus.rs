//! Replays every committed corpus input (`fuzz/corpus/<target>/`) through its target's checks
//! and memory budget, as a plain test: a regression is caught by `cargo test` on any machine,
//! with or without a fuzzer. Then the CI's fuzzing smoke: seeded random mutations of the corpus
//! (bit flips, random bytes, inserted, deleted and repeated runs, splices of two inputs) through
//! the same checks for a few seconds per target. It needs no instrumented build (that one costs
//! 8-22 minutes from a clean clone); the coverage-guided runs are `fuzz/run.sh` (fuzz/README.md).

use std::path::PathBuf;
use std::time::{Duration, Instant};

use hydrometra_fuzz::alloc::PeakTracking;
use hydrometra_fuzz::{run, target};

#[global_allocator]
static ALLOC: PeakTracking = PeakTracking;

/// One input may take this long (a hang shows as a failure, not a stuck test).
const PER_INPUT: Duration = Duration::from_secs(10);

/// The mutation smoke's time per target (`FUZZ_SMOKE_SECONDS` overrides it).
const SMOKE: Duration = Duration::from_secs(3);

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
    let corpus: Vec<Vec<u8>> = inputs
        .iter()
        .map(|p| std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())))
        .collect();
    smoke(target, &corpus);
}

/// Mutates corpus inputs at random (seeded by the target's name, so a failure repeats) and runs
/// each mutant through the target's checks until the smoke's time is up.
fn smoke(target: &hydrometra_fuzz::Target, corpus: &[Vec<u8>]) {
    let seconds = std::env::var("FUZZ_SMOKE_SECONDS")
        .ok()
        .and_then(|s| s.parse::<f64>().ok())
        .map_or(SMOKE, Duration::from_secs_f64);
    let seed = target.name.bytes().fold(0xcbf2_9ce4_8422_2325_u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    });
    let mut rng = fastrand::Rng::with_seed(seed);
    let start = Instant::now();
    let mut runs = 0u64;
    while start.elapsed() < seconds {
        let mut data = corpus[rng.usize(..corpus.len())].clone();
        for _ in 0..rng.usize(1..=4) {
            mutate(&mut rng, &mut data, corpus);
        }
        let outcome = std::panic::catch_unwind(|| run(target, &data));
        assert!(
            outcome.is_ok(),
            "{}: mutant {runs} (seed {seed:#x}) failed a property (message above); its bytes: {data:?}",
            target.name
        );
        runs += 1;
    }
    println!("{}: {runs} mutants in {:?}", target.name, start.elapsed());
    assert!(runs > 0, "{}: no mutant ran", target.name);
}

/// One random edit of `data`; `corpus` gives the other half of a splice.
fn mutate(rng: &mut fastrand::Rng, data: &mut Vec<u8>, corpus: &[Vec<u8>]) {
    let len = data.len();
    match rng.u8(..6) {
        0 if len > 0 => {
            let i = rng.usize(..len);
            data[i] ^= 1 << rng.u8(..8);
        }
        1 if len > 0 => {
            let i = rng.usize(..len);
            data[i] = rng.u8(..);
        }
        2 => {
            let at = rng.usize(..=len);
            let n = rng.usize(1..=16);
            let bytes: Vec<u8> = (0..n).map(|_| rng.u8(..)).collect();
            data.splice(at..at, bytes);
        }
        3 if len > 0 => {
            let at = rng.usize(..len);
            let end = (at + rng.usize(1..=64)).min(len);
            data.drain(at..end);
        }
        4 if len > 0 => {
            let at = rng.usize(..len);
            let end = (at + rng.usize(1..=64)).min(len);
            let run = data[at..end].to_vec();
            data.splice(end..end, run);
        }
        _ => {
            let other = &corpus[rng.usize(..corpus.len())];
            let keep = rng.usize(..=len);
            let from = rng.usize(..=other.len());
            data.truncate(keep);
            data.extend_from_slice(&other[from..]);
        }
    }
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
