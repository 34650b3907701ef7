//! Helpers for the station's end-to-end tests: a `hydrometra station` child process and Debian's
//! Chromium.

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};

use crate::{binary, workspace_root};

/// The token the tests' stations use.
pub const TOKEN: &str = "browser-test-token-0123456789";

/// Where screenshots go (kept after the test): `target/station-artifacts/`.
pub fn artifacts() -> PathBuf {
    workspace_root().join("target/station-artifacts")
}

/// Debian's Chromium; panics naming the install step when it is missing.
pub fn chromium() -> PathBuf {
    let p = PathBuf::from(hydrometra_station::browser::DEFAULT_CHROMIUM);
    assert!(
        p.is_file(),
        "{} missing: run .ci/setup (it installs Debian's chromium)",
        p.display()
    );
    p
}

/// A `hydrometra station --listen 127.0.0.1:0 --token TOKEN ARGS...` child; killed on drop.
pub struct Station {
    child: Child,
    /// The page's address with the token.
    pub url: String,
}

impl Station {
    /// Starts it and waits for the line with its address.
    pub fn start(args: &[&str]) -> Station {
        let mut child = Command::new(binary("hydrometra"))
            .arg("station")
            .args(["--listen", "127.0.0.1:0", "--token", TOKEN])
            .args(args)
            .env("RUST_LOG", "info")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("spawn hydrometra station");
        let url = hydrometra_station::bench::read_url(&mut child).expect("station URL");
        assert!(url.ends_with(&format!("#token={TOKEN}")), "{url}");
        Station { child, url }
    }
}

/// A headless Chromium of `width` × `height` pixels showing `url`, and the runtime that drives it.
pub fn open_page(
    url: &str,
    width: u32,
    height: u32,
) -> (
    tokio::runtime::Runtime,
    hydrometra_station::browser::Chromium,
) {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("a tokio runtime");
    let mut c = rt
        .block_on(hydrometra_station::browser::Chromium::launch(
            &chromium(),
            width,
            height,
        ))
        .expect("chromium");
    rt.block_on(c.open(url)).expect("open the page");
    (rt, c)
}

impl Drop for Station {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
