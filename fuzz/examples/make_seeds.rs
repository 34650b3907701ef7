//! Writes the seed inputs of every fuzz target from the project's own files and real outputs:
//!
//!     cargo run -p hydrometra-fuzz --example make_seeds -- OUT_DIR ATLAS.hma RECORDING.mcap...
//!
//! The atlas seed is a small real atlas: the vertices of a real one (`target/hil-atlas/*.hma`)
//! thinned with `Atlas::subset`, all levels and metadata kept. The rig byte seeds are the bytes an
//! emulated rig sent, taken from a recording (`hydrometrad --emulated default --record-dir DIR`).
//! `fuzz/run.sh minimize` then keeps only the seeds that add coverage.

use std::path::{Path, PathBuf};

use hydrometra_drivers::calibration::Calibration;
use hydrometra_ipc::control::{command, ControlRequest};
use hydrometra_record::reader::Recording;
use hydrometra_sim::atlas::Atlas;

fn write(out: &Path, target: &str, name: &str, bytes: &[u8]) {
    let dir = out.join(target);
    std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
}

fn copy_all(out: &Path, target: &str, dir: &str, ext: &str) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(dir);
    for entry in std::fs::read_dir(&root).unwrap_or_else(|e| panic!("{}: {e}", root.display())) {
        let path = entry.unwrap_or_else(|e| panic!("{e}")).path();
        if path.extension().is_some_and(|e| e == ext) {
            let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            let name = path.file_name().map(|n| n.to_string_lossy().into_owned());
            write(out, target, &name.unwrap_or_default(), &bytes);
        }
    }
}

/// The ```toml blocks of a document.
fn toml_blocks(doc: &str) -> Vec<String> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(doc);
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut blocks = Vec::new();
    let mut current: Option<String> = None;
    for line in text.lines() {
        match (&mut current, line.trim_start()) {
            (None, "```toml") => current = Some(String::new()),
            (Some(b), "```") => {
                blocks.push(std::mem::take(b));
                current = None;
            }
            (Some(b), _) => {
                b.push_str(line);
                b.push('\n');
            }
            _ => {}
        }
    }
    blocks
}

fn control_bytes(mode: u8, r: &ControlRequest) -> Vec<u8> {
    let mut b = vec![mode];
    for v in [r.schema_version, r.command, r.argument_len, r.reserved0] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b.extend_from_slice(&r.argument[..r.argument_len as usize]);
    b
}

fn main() {
    let args: Vec<PathBuf> = std::env::args_os().skip(1).map(PathBuf::from).collect();
    let [out, atlas, recordings @ ..] = args.as_slice() else {
        panic!("usage: make_seeds OUT_DIR ATLAS.hma RECORDING.mcap...");
    };

    let cal = toml::to_string(&Calibration::default()).unwrap_or_default();
    write(out, "calibration", "default.toml", cal.as_bytes());
    for (i, b) in toml_blocks("docs/calibration.md").iter().enumerate() {
        write(out, "calibration", &format!("doc-{i}.toml"), b.as_bytes());
    }
    copy_all(out, "scenario", "drivers/scenarios", "toml");
    copy_all(out, "scene", "sim-core/src/scene/scenes", "toml");
    for (i, b) in toml_blocks("docs/scene.md").iter().enumerate() {
        write(out, "scene", &format!("doc-{i}.toml"), b.as_bytes());
    }
    copy_all(out, "fluid_case", "docs/fluid-cases", "toml");

    let real = Atlas::read(atlas).unwrap_or_else(|e| panic!("{e}"));
    let ids: Vec<u32> = (0..real.vertex_count() as u32)
        .step_by(997)
        .take(6)
        .collect();
    let small = real.subset(&ids).unwrap_or_else(|e| panic!("{e}"));
    for mode in [0u8, 2] {
        let mut b = vec![mode];
        b.extend_from_slice(&small.to_bytes());
        write(
            out,
            "atlas",
            &format!("subset-{}v-mode{mode}.hma", ids.len()),
            &b,
        );
    }

    for (i, path) in recordings.iter().enumerate() {
        let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        write(out, "recording", &format!("recording-{i}.mcap"), &bytes);
        // Killed mid-write: the file ends inside a chunk.
        write(
            out,
            "recording",
            &format!("recording-{i}-cut.mcap"),
            &bytes[..bytes.len() * 3 / 5],
        );
        let rec = Recording::from_bytes(path, &bytes).unwrap_or_else(|e| panic!("{e}"));
        let rx: Vec<u8> = rec
            .rx
            .iter()
            .flat_map(|r| r.bytes.iter().copied())
            .collect();
        for (k, piece) in rx.chunks(1024).take(3).enumerate() {
            write(out, "rig_stream", &format!("rx-{i}-{k}"), piece);
            write(
                out,
                "wire_frames",
                &format!("rx-{i}-{k}"),
                &piece[..256.min(piece.len())],
            );
        }
    }

    let requests = [
        (command::NEW_PROCEDURE, ""),
        (command::LOAD_SCENE, "default"),
        (command::LOAD_SCENE, " myoma-figo1 "),
        (command::RECORD_START, ""),
        (command::RECORD_STOP, ""),
        (command::RECORD_STATUS, ""),
        (99, ""),
    ];
    for (cmd, arg) in requests {
        let r = ControlRequest::new(cmd, arg).unwrap_or_else(|e| panic!("{e}"));
        write(
            out,
            "control",
            &format!("cmd-{cmd}-{}", arg.trim()),
            &control_bytes(0, &r),
        );
    }
}
