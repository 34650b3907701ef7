//! A zenoh session from the `[remote]` settings (or the station's `--zenoh-*` flags).

use std::path::PathBuf;

use zenoh::Wait;

use crate::config::Mode;

/// How a session joins the network.
#[derive(Debug, Clone, PartialEq)]
pub struct SessionSettings {
    /// Peer or client.
    pub mode: Mode,
    /// Endpoints to connect to.
    pub connect: Vec<String>,
    /// Endpoints to listen on (empty: zenoh's default for the mode).
    pub listen: Vec<String>,
    /// UDP multicast scouting on the LAN.
    pub multicast_scouting: bool,
    /// A zenoh configuration file (JSON5) underneath these settings.
    pub config_file: Option<PathBuf>,
}

/// Why a session could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// The zenoh configuration file or a setting was refused.
    #[error("zenoh configuration {what}: {message}")]
    Config {
        /// Which file or setting.
        what: String,
        /// zenoh's message.
        message: String,
    },
    /// zenoh could not open the session (an endpoint it cannot listen on or reach, ...).
    #[error("cannot open a zenoh session: {0}")]
    Open(String),
}

/// The zenoh configuration these settings make.
pub fn config(s: &SessionSettings) -> Result<zenoh::Config, SessionError> {
    let mut c = match &s.config_file {
        Some(path) => zenoh::Config::from_file(path).map_err(|e| SessionError::Config {
            what: path.display().to_string(),
            message: e.to_string(),
        })?,
        None => zenoh::Config::default(),
    };
    let mode = match s.mode {
        Mode::Peer => "\"peer\"",
        Mode::Client => "\"client\"",
    };
    let json = |v: &Vec<String>| serde_json::Value::from(v.clone()).to_string();
    let mut set = |key: &str, value: String| {
        c.insert_json5(key, &value)
            .map_err(|e| SessionError::Config {
                what: format!("{key} = {value}"),
                message: e.to_string(),
            })
    };
    set("mode", mode.to_string())?;
    if !s.connect.is_empty() {
        set("connect/endpoints", json(&s.connect))?;
    }
    if !s.listen.is_empty() {
        set("listen/endpoints", json(&s.listen))?;
    }
    set(
        "scouting/multicast/enabled",
        s.multicast_scouting.to_string(),
    )?;
    Ok(c)
}

/// Opens a session (blocking the calling thread until zenoh is up).
pub fn open(s: &SessionSettings) -> Result<zenoh::Session, SessionError> {
    zenoh::open(config(s)?)
        .wait()
        .map_err(|e| SessionError::Open(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn settings_become_zenoh_configuration_and_a_bad_file_is_named() {
        let s = SessionSettings {
            mode: Mode::Client,
            connect: vec!["tcp/127.0.0.1:7447".into()],
            listen: vec![],
            multicast_scouting: false,
            config_file: None,
        };
        let c = config(&s).unwrap();
        let text = format!("{c}");
        assert!(text.contains("client"), "{text}");
        assert!(text.contains("tcp/127.0.0.1:7447"), "{text}");
        let bad = SessionSettings {
            config_file: Some("/nonexistent/zenoh.json5".into()),
            ..s
        };
        let e = config(&bad).unwrap_err().to_string();
        assert!(e.contains("/nonexistent/zenoh.json5"), "{e}");
    }
}
