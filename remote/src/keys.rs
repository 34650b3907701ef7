//! Key expressions: `<root>/<rig id>/<service>`, the services named as in docs/ipc.md.

/// The default root of every key.
pub const DEFAULT_ROOT: &str = "hydrometra";

/// Services forwarded, by their key suffix.
pub mod service {
    /// `hydrometra.v1.Status`, 752 bytes.
    pub const STATUS: &str = "status";
    /// Mesh topology header + `u32` indices.
    pub const TOPOLOGY: &str = "cavity/topology";
    /// Mesh positions header + `f32` xyz.
    pub const POSITIONS: &str = "cavity/positions";
    /// Flow field header + the flow bytes.
    pub const FLOW: &str = "flow";
    /// Particles header + particles.
    pub const PARTICLES: &str = "particles";
    /// Control: a query carrying a `ControlRequest`, answered with a `ControlResponse`.
    pub const CONTROL: &str = "control";
    /// Every data service.
    pub const DATA: [&str; 5] = [STATUS, TOPOLOGY, POSITIONS, FLOW, PARTICLES];
}

/// Why a rig id or root cannot form key expressions.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "{what} {value:?}: expected 1-64 characters from A-Z a-z 0-9 - _ (no '/', '*', '$', '?', '#')"
)]
pub struct InvalidKey {
    /// `rig id` or `key root`.
    pub what: &'static str,
    /// The value.
    pub value: String,
}

fn plain(what: &'static str, value: &str) -> Result<(), InvalidKey> {
    let ok = !value.is_empty()
        && value.len() <= 64
        && value
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_');
    if ok {
        Ok(())
    } else {
        Err(InvalidKey {
            what,
            value: value.to_string(),
        })
    }
}

/// Checks a rig id.
pub fn check_rig_id(id: &str) -> Result<(), InvalidKey> {
    plain("rig id", id)
}

/// Checks a key root.
pub fn check_root(root: &str) -> Result<(), InvalidKey> {
    plain("key root", root)
}

/// The key of `service` of rig `rig`.
pub fn key(root: &str, rig: &str, service: &str) -> String {
    format!("{root}/{rig}/{service}")
}

/// The key expression matching `service` of every rig.
pub fn every_rig(root: &str, service: &str) -> String {
    format!("{root}/*/{service}")
}

/// The rig id and service of a key under `root`, if it is one of ours.
pub fn parse<'a>(root: &str, key: &'a str) -> Option<(&'a str, &'a str)> {
    let rest = key.strip_prefix(root)?.strip_prefix('/')?;
    let (rig, service) = rest.split_once('/')?;
    (check_rig_id(rig).is_ok() && (service::DATA.contains(&service) || service == service::CONTROL))
        .then_some((rig, service))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_round_trip_and_foreign_keys_are_refused() {
        let k = key(DEFAULT_ROOT, "rig-3", service::POSITIONS);
        assert_eq!(k, "hydrometra/rig-3/cavity/positions");
        assert_eq!(parse(DEFAULT_ROOT, &k), Some(("rig-3", "cavity/positions")));
        assert_eq!(parse(DEFAULT_ROOT, "hydrometra/rig-3/secrets"), None);
        assert_eq!(parse(DEFAULT_ROOT, "other/rig-3/status"), None);
        assert_eq!(parse(DEFAULT_ROOT, "hydrometra/a*b/status"), None);
        assert_eq!(every_rig("hydrometra", "status"), "hydrometra/*/status");
    }

    #[test]
    fn rig_ids_are_plain_names() {
        assert!(check_rig_id("lab-2_rig7").is_ok());
        for bad in ["", "a/b", "*", "a b", "$x", &"x".repeat(65)] {
            let e = check_rig_id(bad).unwrap_err();
            assert!(e.to_string().contains("rig id"), "{e}");
        }
    }
}
