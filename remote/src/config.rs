//! The daemon's `[remote]` section: whether and how it publishes its services to zenoh.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// How the daemon's zenoh session joins the network.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// A peer: finds the others by multicast scouting on the LAN (or `connect`).
    Peer,
    /// A client of a zenoh router (`connect` names it).
    Client,
}

/// `[remote]`: publish the services to Eclipse Zenoh (docs/station.md). Off by default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RemoteConfig {
    /// Publish at all.
    pub enabled: bool,
    /// This rig's id in the keys (`<key_root>/<rig_id>/status`).
    pub rig_id: String,
    /// First segment of every key.
    pub key_root: String,
    /// `peer` or `client`.
    pub mode: Mode,
    /// Endpoints to connect to (e.g. `tcp/192.168.1.10:7447`, a router or the station).
    pub connect: Vec<String>,
    /// Endpoints to listen on (e.g. `tcp/0.0.0.0:7447`); empty: zenoh's default for the mode.
    pub listen: Vec<String>,
    /// Find peers by UDP multicast on the LAN (peer mode).
    pub multicast_scouting: bool,
    /// Services to publish: `status`, `cavity` (topology and positions), `flow`, `particles`.
    pub services: Vec<String>,
    /// Status copies per second.
    pub status_rate_hz: f64,
    /// Cavity positions and particle copies per second.
    pub scene_rate_hz: f64,
    /// Flow field copies per second (the whole field: the largest payload).
    pub flow_rate_hz: f64,
    /// Answer control requests (`<key_root>/<rig_id>/control`) from the network.
    pub allow_control: bool,
    /// A zenoh configuration file (JSON5) for what this section does not cover: access control
    /// rules, TLS certificates, user/password authentication. Settings of this section win.
    pub zenoh_config: Option<PathBuf>,
}

impl Default for RemoteConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            rig_id: "rig-1".into(),
            key_root: crate::keys::DEFAULT_ROOT.into(),
            mode: Mode::Peer,
            connect: Vec::new(),
            listen: Vec::new(),
            multicast_scouting: true,
            services: ["status", "cavity", "flow", "particles"]
                .map(String::from)
                .to_vec(),
            status_rate_hz: 30.0,
            scene_rate_hz: 10.0,
            flow_rate_hz: 2.0,
            allow_control: false,
            zenoh_config: None,
        }
    }
}

/// The names `services` may hold.
pub const SERVICE_NAMES: [&str; 4] = ["status", "cavity", "flow", "particles"];

/// A key of `[remote]` with a value out of range: `(key, value, expected)`.
pub type Invalid = (String, String, String);

impl RemoteConfig {
    /// Checks every value; the first problem as `(key, value, expected)`.
    pub fn validate(&self) -> Result<(), Invalid> {
        let bad = |key: &str, value: String, expected: &str| {
            Err((format!("remote.{key}"), value, expected.to_string()))
        };
        if let Err(e) = crate::keys::check_rig_id(&self.rig_id) {
            return bad("rig_id", format!("{:?}", self.rig_id), &e.to_string());
        }
        if let Err(e) = crate::keys::check_root(&self.key_root) {
            return bad("key_root", format!("{:?}", self.key_root), &e.to_string());
        }
        for s in &self.services {
            if !SERVICE_NAMES.contains(&s.as_str()) {
                return bad(
                    "services",
                    format!("{s:?}"),
                    "status, cavity, flow or particles",
                );
            }
        }
        for (key, hz) in [
            ("status_rate_hz", self.status_rate_hz),
            ("scene_rate_hz", self.scene_rate_hz),
            ("flow_rate_hz", self.flow_rate_hz),
        ] {
            if !(hz.is_finite() && (0.1..=1000.0).contains(&hz)) {
                return bad(key, hz.to_string(), "0.1 to 1000 per second");
            }
        }
        for (key, list) in [("connect", &self.connect), ("listen", &self.listen)] {
            for e in list.iter() {
                if !e.contains('/') {
                    return bad(
                        key,
                        format!("{e:?}"),
                        "a zenoh endpoint such as \"tcp/192.168.1.10:7447\"",
                    );
                }
            }
        }
        if self.mode == Mode::Client && self.connect.is_empty() && self.enabled {
            return bad(
                "connect",
                "[]".into(),
                "the router's endpoint in client mode",
            );
        }
        Ok(())
    }

    /// Whether service `name` (one of [`SERVICE_NAMES`]) is published.
    pub fn publishes(&self, name: &str) -> bool {
        self.services.iter().any(|s| s == name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_is_off_and_valid() {
        let c = RemoteConfig::default();
        assert!(!c.enabled && !c.allow_control);
        assert_eq!(c.validate(), Ok(()));
    }

    #[test]
    fn bad_values_are_named() {
        let mut c = RemoteConfig {
            rig_id: "a/b".into(),
            ..Default::default()
        };
        assert_eq!(c.validate().unwrap_err().0, "remote.rig_id");
        c.rig_id = "ok".into();
        c.services.push("secrets".into());
        assert_eq!(c.validate().unwrap_err().0, "remote.services");
        c.services.pop();
        c.flow_rate_hz = 0.0;
        assert_eq!(c.validate().unwrap_err().0, "remote.flow_rate_hz");
        c.flow_rate_hz = 1.0;
        c.connect = vec!["192.168.1.1:7447".into()];
        assert_eq!(c.validate().unwrap_err().0, "remote.connect");
        c.connect.clear();
        c.mode = Mode::Client;
        c.enabled = true;
        assert_eq!(c.validate().unwrap_err().0, "remote.connect");
    }

    #[test]
    fn a_toml_section_parses_and_unknown_keys_are_refused() {
        let c: RemoteConfig = toml_like(
            r#"{"enabled": true, "rig_id": "lab-2", "mode": "client", "connect": ["tcp/10.0.0.1:7447"]}"#,
        );
        assert_eq!(c.mode, Mode::Client);
        assert!(serde_json::from_str::<RemoteConfig>(r#"{"rigid": "x"}"#).is_err());
    }

    fn toml_like(json: &str) -> RemoteConfig {
        serde_json::from_str(json).unwrap()
    }
}
