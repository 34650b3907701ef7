//! `hydrometra station` refuses to listen off loopback without a token, and refuses weak tokens,
//! naming the flags; on loopback it generates a token and prints the page's address.

use std::process::{Command, Stdio};

use hydrometra_hil_tests::binary;

fn station(args: &[&str]) -> std::process::Output {
    Command::new(binary("hydrometra"))
        .arg("station")
        .args(args)
        .env_remove("HYDROMETRA_STATION_TOKEN")
        .stdin(Stdio::null())
        .output()
        .expect("run hydrometra station")
}

#[test]
fn off_loopback_without_a_token_is_refused_naming_the_flags() {
    // Refused before binding: nothing listens on these addresses.
    for addr in ["0.0.0.0:0", "[::]:0", "192.0.2.1:8737"] {
        let out = station(&[
            "--listen",
            addr,
            "--service-prefix",
            "hydrometra-cli-test/v1",
        ]);
        assert!(!out.status.success(), "{addr}: started without a token");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("needs a token") && err.contains("--token"),
            "{addr}: {err}"
        );
        assert!(out.stdout.is_empty(), "{addr}: printed a URL");
    }
}

#[test]
fn weak_tokens_are_refused() {
    let out = station(&["--listen", "0.0.0.0:0", "--token", "secret"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("at least 16"), "{err}");
}

#[test]
fn on_loopback_a_token_is_generated_and_printed_in_the_url() {
    let mut child = Command::new(binary("hydrometra"))
        .args(["station", "--listen", "127.0.0.1:0", "--service-prefix"])
        .arg("hydrometra-cli-test-loopback/v1")
        .env_remove("HYDROMETRA_STATION_TOKEN")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let url = hydrometra_station::bench::read_url(&mut child);
    let _ = child.kill();
    let _ = child.wait();
    let url = url.unwrap();
    let (addr, token) = url
        .strip_prefix("http://127.0.0.1:")
        .and_then(|r| r.split_once("/#token="))
        .unwrap_or_else(|| panic!("{url}"));
    assert!(addr.parse::<u16>().is_ok_and(|p| p > 0), "{url}");
    assert_eq!(token.len(), 32, "{url}");
    assert!(token.bytes().all(|b| b.is_ascii_hexdigit()), "{url}");
}
