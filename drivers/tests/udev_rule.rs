//! The udev rule matches the rig's USB ids on the tty subsystem and sets the symlink, group, mode
//! and the ModemManager ignore flag; other serial adapters are left alone.

use std::collections::HashMap;
use std::path::PathBuf;

use hydrometra_drivers::transport::{RIG_DEVICE_PATH, RIG_USB_PID, RIG_USB_VID};

#[derive(Debug, PartialEq)]
struct Clause {
    key: String,
    op: String,
    value: String,
}

fn rule_file() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../udev/70-hydrometra-rig.rules")
}

/// Splits one rule line into `KEY op "value"` clauses (udev syntax, no escapes needed here).
fn parse_rule(line: &str) -> Vec<Clause> {
    let mut clauses = Vec::new();
    let mut rest = line.trim();
    while !rest.is_empty() {
        let op_at = rest
            .find(['=', '!', '+', ':'])
            .unwrap_or_else(|| panic!("no operator in {rest:?}"));
        let key = rest[..op_at].trim().to_string();
        let after = &rest[op_at..];
        let op_len = if after.starts_with("==")
            || after.starts_with("!=")
            || after.starts_with("+=")
            || after.starts_with(":=")
        {
            2
        } else {
            1
        };
        let op = after[..op_len].to_string();
        let after = after[op_len..].trim_start();
        assert!(
            after.starts_with('"'),
            "value of {key} must be quoted: {after:?}"
        );
        let end = after[1..].find('"').expect("closing quote") + 1;
        let value = after[1..end].to_string();
        clauses.push(Clause { key, op, value });
        rest = after[end + 1..].trim_start();
        rest = rest.strip_prefix(',').unwrap_or(rest).trim_start();
    }
    clauses
}

fn rules() -> Vec<Vec<Clause>> {
    let text = std::fs::read_to_string(rule_file()).unwrap();
    text.lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
        .map(parse_rule)
        .collect()
}

/// Evaluates the match clauses of a rule against a device's properties (`ATTRS{..}` searched in
/// the device and its parents, flattened here into one map).
fn matches(rule: &[Clause], device: &HashMap<&str, &str>) -> bool {
    rule.iter()
        .filter(|c| c.op == "==" || c.op == "!=")
        .all(|c| {
            let actual = device.get(c.key.as_str()).copied();
            let equal = actual == Some(c.value.as_str());
            if c.op == "==" {
                equal
            } else {
                !equal
            }
        })
}

fn assignments(rule: &[Clause]) -> HashMap<String, (String, String)> {
    rule.iter()
        .filter(|c| c.op != "==" && c.op != "!=")
        .map(|c| (c.key.clone(), (c.op.clone(), c.value.clone())))
        .collect()
}

#[test]
fn rule_matches_the_rig_and_sets_symlink_group_mode_and_modemmanager_ignore() {
    let rules = rules();
    assert_eq!(rules.len(), 1, "one rule line");
    let rule = &rules[0];
    let vid = format!("{RIG_USB_VID:04x}");
    let pid = format!("{RIG_USB_PID:04x}");
    let rig: HashMap<&str, &str> = [
        ("ACTION", "add"),
        ("SUBSYSTEM", "tty"),
        ("ATTRS{idVendor}", vid.as_str()),
        ("ATTRS{idProduct}", pid.as_str()),
    ]
    .into();
    assert!(matches(rule, &rig));
    let set = assignments(rule);
    let link = RIG_DEVICE_PATH.strip_prefix("/dev/").unwrap();
    assert_eq!(set["SYMLINK"], ("+=".into(), link.into()));
    assert_eq!(set["GROUP"], ("=".into(), "dialout".into()));
    assert_eq!(set["MODE"], ("=".into(), "0660".into()));
    assert_eq!(set["ENV{ID_MM_DEVICE_IGNORE}"], ("=".into(), "1".into()));

    // Other devices are not touched: another adapter, the rig's USB node itself, removal.
    let mut ftdi = rig.clone();
    ftdi.insert("ATTRS{idVendor}", "0403");
    ftdi.insert("ATTRS{idProduct}", "6001");
    assert!(!matches(rule, &ftdi));
    let mut same_vendor = rig.clone();
    same_vendor.insert("ATTRS{idProduct}", "0002");
    assert!(!matches(rule, &same_vendor));
    let mut usb_node = rig.clone();
    usb_node.insert("SUBSYSTEM", "usb");
    assert!(!matches(rule, &usb_node));
    let mut removal = rig.clone();
    removal.insert("ACTION", "remove");
    assert!(!matches(rule, &removal));
}

#[test]
fn rule_passes_udevadm_verify_where_available() {
    // Only where systemd's udevadm has `verify` (systemd >= 254); the parse test above always runs.
    let has_verify = std::process::Command::new("udevadm")
        .args(["verify", "--help"])
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false);
    if !has_verify {
        eprintln!(
            "SKIP rule_passes_udevadm_verify_where_available: udevadm verify not available \
             (systemd >= 254)"
        );
        return;
    }
    let out = std::process::Command::new("udevadm")
        .arg("verify")
        .arg(rule_file())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "udevadm verify: {}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}
