//! The control request handler's checks (`Request::decode`, run on every request to
//! `<prefix>/control` before any handler), on whole 272-byte `ControlRequest`s from the fuzzer,
//! and the response text it answers with.
//!
//! Input: byte 0 picks whether the schema version is forced to the spoken one (so mutations reach
//! the command and argument checks); the rest fills the request's fields, zero-padded.
//! Properties: an accepted request is one the client API can build and decodes to itself again
//! (its argument non-empty, trimmed, at most `ARGUMENT_CAPACITY` bytes); a refused one gets a
//! `bad_request` message that names the field at fault; a response carries the longest prefix
//! of its text that fits, cut on a character boundary.

use hydrometra_daemon::service::control::Request;
use hydrometra_ipc::control::{command, ControlRequest, ControlResponse, ARGUMENT_CAPACITY};
use hydrometra_ipc::SCHEMA_VERSION;

fn u32_at(b: &[u8], off: usize) -> u32 {
    u32::from_le_bytes([b[off], b[off + 1], b[off + 2], b[off + 3]])
}

/// The control request target.
pub fn check(data: &[u8]) {
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    let mut b = [0u8; 16 + ARGUMENT_CAPACITY];
    let n = rest.len().min(b.len());
    b[..n].copy_from_slice(&rest[..n]);
    let mut argument = [0u8; ARGUMENT_CAPACITY];
    argument.copy_from_slice(&b[16..]);
    let request = ControlRequest {
        schema_version: if mode & 1 == 1 {
            SCHEMA_VERSION
        } else {
            u32_at(&b, 0)
        },
        command: u32_at(&b, 4) % if mode & 2 == 2 { 8 } else { u32::MAX },
        argument_len: u32_at(&b, 8),
        reserved0: u32_at(&b, 12),
        argument,
    };
    match Request::decode(&request) {
        Ok(decoded) => {
            let (cmd, arg) = match &decoded {
                Request::NewProcedure => (command::NEW_PROCEDURE, ""),
                Request::LoadScene(scene) => {
                    assert!(!scene.is_empty() && scene.trim() == scene, "{scene:?}");
                    (command::LOAD_SCENE, scene.as_str())
                }
                Request::RecordStart => (command::RECORD_START, ""),
                Request::RecordStop => (command::RECORD_STOP, ""),
                Request::RecordStatus => (command::RECORD_STATUS, ""),
            };
            assert_eq!(request.schema_version, SCHEMA_VERSION);
            assert_eq!(request.command, cmd);
            let rebuilt = ControlRequest::new(cmd, arg)
                .unwrap_or_else(|e| panic!("accepted {decoded:?} cannot be sent: {e}"));
            assert_eq!(Request::decode(&rebuilt).as_ref(), Ok(&decoded));
        }
        Err(message) => {
            let names_field = [
                "schema_version",
                "argument_len",
                "takes no argument",
                "unknown command",
                "load_scene needs",
            ]
            .iter()
            .any(|f| message.contains(f));
            assert!(names_field, "bad_request message names no field: {message}");
            check_response(request.command, &message);
        }
    }
    if let Ok(text) = std::str::from_utf8(rest) {
        check_response(request.command, text);
    }
}

fn check_response(cmd: u32, text: &str) {
    let r = ControlResponse::new(cmd, 1, text);
    let got = r.message();
    assert!(
        text.starts_with(&got),
        "{got:?} is not a prefix of {text:?}"
    );
    assert!(got.len() <= hydrometra_ipc::control::TEXT_CAPACITY);
    let longest = (0..=text.len().min(hydrometra_ipc::control::TEXT_CAPACITY))
        .rev()
        .find(|&i| text.is_char_boundary(i))
        .unwrap_or(0);
    assert_eq!(got.len(), longest, "response text cut short: {got:?}");
}
