//! The atlas reader (`Atlas::from_bytes`, what `Atlas::read` and the scene's atlas cache run).
//!
//! The first input byte picks how the rest is used: 0 as the file; 1 with the trailing CRC-32
//! recomputed; 2 also with the header's sizes made consistent (the input's metadata, rest
//! positions and level data cut or zero-padded to the counts the header gives, at most 64 vertices
//! and 32 levels), so that mutations reach the checks behind the checksum and the size check.
//!
//! Properties: an error starts with the origin, and a size error states expected and found bytes;
//! an accepted atlas holds what the header says, writes back to an atlas equal to it, and its
//! replay (at any pressure: below, inside and above the levels, NaN, infinite) and subset never
//! panic.

use hydrometra_sim::atlas::format::HEADER_BYTES;
use hydrometra_sim::atlas::{Atlas, AtlasError};

const ORIGIN: &str = "fuzz.hma";

fn u32_at(b: &[u8], off: usize) -> u32 {
    u32::from_le_bytes([b[off], b[off + 1], b[off + 2], b[off + 3]])
}

fn fix_crc(bytes: &mut [u8]) {
    if bytes.len() >= 4 {
        let body = bytes.len() - 4;
        // The atlas format's checksum (docs/atlas-format.md), the crate sim-core uses.
        let crc = crc32fast::hash(&bytes[..body]);
        bytes[body..].copy_from_slice(&crc.to_le_bytes());
    }
}

/// The header's counts made consistent with the data that follows (mode 2).
fn consistent(input: &[u8]) -> Vec<u8> {
    let mut b = input.to_vec();
    b.resize(b.len().max(HEADER_BYTES), 0);
    let n = (u32_at(&b, 16) % 65) as usize;
    let l = (u32_at(&b, 20) % 33) as usize;
    let meta_len = (u32_at(&b, 32) as usize) % 257;
    b[16..20].copy_from_slice(&(n as u32).to_le_bytes());
    b[20..24].copy_from_slice(&(l as u32).to_le_bytes());
    b[32..36].copy_from_slice(&(meta_len as u32).to_le_bytes());
    let total = HEADER_BYTES + meta_len + 24 * n + 16 * l + 24 * n * l + 4;
    b.resize(total, 0);
    b
}

/// The atlas target.
pub fn check(data: &[u8]) {
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    let bytes = match mode % 3 {
        0 => rest.to_vec(),
        1 => {
            let mut b = rest.to_vec();
            fix_crc(&mut b);
            b
        }
        _ => {
            let mut b = consistent(rest);
            fix_crc(&mut b);
            b
        }
    };
    match Atlas::from_bytes(&bytes, ORIGIN) {
        Err(e) => {
            let msg = e.to_string();
            assert!(msg.starts_with(&format!("{ORIGIN}: ")), "{msg}");
            match e {
                AtlasError::Size {
                    expected, found, ..
                } => {
                    assert_eq!(found, bytes.len());
                    assert_ne!(expected, found);
                    assert!(msg.contains("expected") && msg.contains("found"), "{msg}");
                }
                AtlasError::Io { .. } | AtlasError::Argument(_) => {
                    panic!("not a file error: {msg}")
                }
                _ => {}
            }
        }
        Ok(atlas) => check_accepted(&atlas, &bytes),
    }
}

fn check_accepted(atlas: &Atlas, bytes: &[u8]) {
    let n = atlas.vertex_count();
    let l = atlas.level_count();
    assert_eq!(n, u32_at(bytes, 16) as usize);
    assert_eq!(l, u32_at(bytes, 20) as usize);
    assert!(n >= 1 && l >= 2);
    assert!(atlas.pressure_pa.windows(2).all(|w| w[0] < w[1]));
    let back = Atlas::from_bytes(&atlas.to_bytes(), ORIGIN)
        .unwrap_or_else(|e| panic!("the atlas's own bytes are refused: {e}"));
    assert_eq!(&back, atlas, "write and read back changed the atlas");

    let p = &atlas.pressure_pa;
    let mut pos = vec![[0f32; 3]; n];
    let mut dxdp = vec![[0f32; 3]; n];
    for pressure in [
        p[0] - 1.0,
        p[0],
        0.5 * (p[0] + p[1]),
        p[l - 1],
        p[l - 1] * 2.0 + 1.0,
        f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
    ] {
        let _ = atlas.positions_at(pressure, &mut pos);
        let _ = atlas.positions_at_linear(pressure, &mut pos);
        let _ = atlas.replay(pressure, &mut pos, &mut dxdp);
        let v = atlas.cavity_volume_at(pressure);
        let q = atlas.pressure_at_volume(v);
        assert!(
            q.is_nan() || (p[0]..=p[l - 1]).contains(&q),
            "pressure {q} outside the levels"
        );
    }
    let ids: Vec<u32> = (0..n as u32).rev().step_by(2).collect();
    let sub = atlas
        .subset(&ids)
        .unwrap_or_else(|e| panic!("subset of valid ids: {e}"));
    assert_eq!(sub.vertex_count(), ids.len());
    assert!(atlas.subset(&[n as u32]).is_err());
}
