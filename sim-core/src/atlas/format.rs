//! Atlas file format version 1 (little-endian; see docs/atlas-format.md):
//!
//! ```text
//! offset  size        field
//! 0       8           magic "HMATLAS\0"
//! 8       4   u32     format version (1)
//! 12      4   u32     flags (0)
//! 16      4   u32     vertex count V
//! 20      4   u32     level count L
//! 24      8   u64     mesh hash (FNV-1a 64, atlas::mesh_hash)
//! 32      4   u32     metadata length M (bytes of UTF-8 JSON)
//! 36      4   u32     reserved (0)
//! 40      M           metadata JSON object
//! ...     24 V        rest positions, f64 x, y, z per vertex (m)
//! ...     8 L         pressure per level, f64 (Pa), strictly increasing
//! ...     8 L         cavity volume per level, f64 (m^3)
//! ...     12 V L      positions, f32 x, y, z, level-major (m)
//! ...     12 V L      dx/dp, f32 x, y, z, level-major (m/Pa)
//! end-4   4   u32     CRC-32 (IEEE) of every preceding byte
//! ```

use super::{Atlas, AtlasError};
use std::path::Path;

/// File magic.
pub const MAGIC: [u8; 8] = *b"HMATLAS\0";
/// The format version this build writes and reads.
pub const VERSION: u32 = 1;
/// Size of the fixed header in bytes.
pub const HEADER_BYTES: usize = 40;

impl Atlas {
    /// Serializes to the version-1 binary format.
    pub fn to_bytes(&self) -> Vec<u8> {
        let meta = self.metadata.to_string();
        let n = self.vertex_count();
        let l = self.level_count();
        let mut b =
            Vec::with_capacity(HEADER_BYTES + meta.len() + 24 * n + 16 * l + 24 * n * l + 4);
        b.extend_from_slice(&MAGIC);
        b.extend_from_slice(&VERSION.to_le_bytes());
        b.extend_from_slice(&0u32.to_le_bytes());
        b.extend_from_slice(&(n as u32).to_le_bytes());
        b.extend_from_slice(&(l as u32).to_le_bytes());
        b.extend_from_slice(&self.mesh_hash.to_le_bytes());
        b.extend_from_slice(&(meta.len() as u32).to_le_bytes());
        b.extend_from_slice(&0u32.to_le_bytes());
        b.extend_from_slice(meta.as_bytes());
        for p in &self.rest_positions_m {
            for c in p {
                b.extend_from_slice(&c.to_le_bytes());
            }
        }
        for v in self.pressure_pa.iter().chain(&self.cavity_volume_m3) {
            b.extend_from_slice(&v.to_le_bytes());
        }
        for p in self.positions_m.iter().chain(&self.dxdp_m_per_pa) {
            for c in p {
                b.extend_from_slice(&c.to_le_bytes());
            }
        }
        let crc = crc32fast::hash(&b);
        b.extend_from_slice(&crc.to_le_bytes());
        b
    }

    /// Parses and validates the binary format; `origin` names the source in errors.
    pub fn from_bytes(bytes: &[u8], origin: &str) -> Result<Self, AtlasError> {
        let o = || origin.to_string();
        if bytes.len() < HEADER_BYTES + 4 {
            return Err(AtlasError::Size {
                origin: o(),
                what: "header and checksum".into(),
                expected: HEADER_BYTES + 4,
                found: bytes.len(),
            });
        }
        let mut magic = [0u8; 8];
        magic.copy_from_slice(&bytes[0..8]);
        if magic != MAGIC {
            return Err(AtlasError::Magic {
                origin: o(),
                found: magic,
                expected: MAGIC,
            });
        }
        let u32_at = |off: usize| {
            u32::from_le_bytes([bytes[off], bytes[off + 1], bytes[off + 2], bytes[off + 3]])
        };
        let version = u32_at(8);
        if version != VERSION {
            return Err(AtlasError::Version {
                origin: o(),
                found: version,
                supported: VERSION,
            });
        }
        let n = u32_at(16) as usize;
        let l = u32_at(20) as usize;
        let mut hash = [0u8; 8];
        hash.copy_from_slice(&bytes[24..32]);
        let mesh_hash = u64::from_le_bytes(hash);
        let meta_len = u32_at(32) as usize;
        // Sizes in u128 so absurd counts in a corrupt header cannot overflow.
        let expected = HEADER_BYTES as u128
            + meta_len as u128
            + 24 * n as u128
            + 16 * l as u128
            + 24 * n as u128 * l as u128
            + 4;
        if expected != bytes.len() as u128 {
            return Err(AtlasError::Size {
                origin: o(),
                what: format!("file for {n} vertices, {l} levels and {meta_len} metadata bytes"),
                expected: usize::try_from(expected).unwrap_or(usize::MAX),
                found: bytes.len(),
            });
        }
        let body = &bytes[..bytes.len() - 4];
        let stored = u32_at(bytes.len() - 4);
        let computed = crc32fast::hash(body);
        if stored != computed {
            return Err(AtlasError::Checksum {
                origin: o(),
                stored,
                computed,
            });
        }
        if u32_at(12) != 0 {
            return Err(AtlasError::Invalid {
                origin: o(),
                message: format!("flags = {:#x}; version 1 defines none", u32_at(12)),
            });
        }
        let mut off = HEADER_BYTES;
        let meta_text =
            std::str::from_utf8(&bytes[off..off + meta_len]).map_err(|e| AtlasError::Invalid {
                origin: o(),
                message: format!("metadata is not UTF-8: {e}"),
            })?;
        let metadata: serde_json::Value =
            serde_json::from_str(meta_text).map_err(|e| AtlasError::Invalid {
                origin: o(),
                message: format!("metadata is not JSON: {e}"),
            })?;
        if !metadata.is_object() {
            return Err(AtlasError::Invalid {
                origin: o(),
                message: "metadata must be a JSON object".into(),
            });
        }
        off += meta_len;
        let f64_at = |off: usize| {
            let mut a = [0u8; 8];
            a.copy_from_slice(&bytes[off..off + 8]);
            f64::from_le_bytes(a)
        };
        let f32_at = |off: usize| {
            f32::from_le_bytes([bytes[off], bytes[off + 1], bytes[off + 2], bytes[off + 3]])
        };
        let mut rest = Vec::with_capacity(n);
        for i in 0..n {
            let b = off + 24 * i;
            rest.push([f64_at(b), f64_at(b + 8), f64_at(b + 16)]);
        }
        off += 24 * n;
        let pressure_pa: Vec<f64> = (0..l).map(|k| f64_at(off + 8 * k)).collect();
        off += 8 * l;
        let cavity_volume_m3: Vec<f64> = (0..l).map(|k| f64_at(off + 8 * k)).collect();
        off += 8 * l;
        let mut read_vec3 = |count: usize| {
            let v: Vec<[f32; 3]> = (0..count)
                .map(|i| {
                    let b = off + 12 * i;
                    [f32_at(b), f32_at(b + 4), f32_at(b + 8)]
                })
                .collect();
            off += 12 * count;
            v
        };
        let positions_m = read_vec3(n * l);
        let dxdp_m_per_pa = read_vec3(n * l);
        let atlas = Atlas {
            mesh_hash,
            metadata,
            rest_positions_m: rest,
            pressure_pa,
            cavity_volume_m3,
            positions_m,
            dxdp_m_per_pa,
        };
        atlas.validate(origin)?;
        Ok(atlas)
    }

    /// Writes the atlas file.
    pub fn write(&self, path: &Path) -> Result<(), AtlasError> {
        std::fs::write(path, self.to_bytes()).map_err(|source| AtlasError::Io {
            path: path.display().to_string(),
            source,
        })
    }

    /// Reads and validates an atlas file.
    pub fn read(path: &Path) -> Result<Self, AtlasError> {
        let bytes = std::fs::read(path).map_err(|source| AtlasError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_bytes(&bytes, &path.display().to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::super::AtlasLevel;
    use super::*;

    fn sample() -> Atlas {
        let rest: Vec<[f64; 3]> = (0..5)
            .map(|i| [i as f64 * 0.01, 0.02, -0.01 * i as f64])
            .collect();
        let levels: Vec<AtlasLevel> = (0..4)
            .map(|k| {
                let p = 1000.0 * k as f64;
                AtlasLevel {
                    pressure_pa: p,
                    cavity_volume_m3: 1e-6 * (1.0 + 0.1 * k as f64),
                    positions_m: rest
                        .iter()
                        .map(|x| x.map(|c| c * (1.0 + 1e-5 * p)))
                        .collect(),
                    dxdp_m_per_pa: rest.iter().map(|x| x.map(|c| c * 1e-5)).collect(),
                }
            })
            .collect();
        Atlas::new(
            0x1234_5678_9abc_def0,
            serde_json::json!({"material": {"mu_pa": [1.0]}}),
            rest,
            &levels,
        )
        .unwrap()
    }

    #[test]
    fn round_trip_preserves_everything() {
        let a = sample();
        let b = Atlas::from_bytes(&a.to_bytes(), "t").unwrap();
        assert_eq!(a, b);
    }

    #[test]
    fn truncated_files_are_rejected_with_sizes() {
        let bytes = sample().to_bytes();
        for cut in [0, 10, HEADER_BYTES + 3, bytes.len() / 2, bytes.len() - 1] {
            let err = Atlas::from_bytes(&bytes[..cut], "trunc.atlas")
                .unwrap_err()
                .to_string();
            assert!(
                err.contains("trunc.atlas") && err.contains("expected") && err.contains("found"),
                "cut {cut}: {err}"
            );
        }
    }

    #[test]
    fn every_single_bit_flip_is_rejected() {
        let bytes = sample().to_bytes();
        for byte in 0..bytes.len() {
            for bit in [0u8, 3, 7] {
                let mut c = bytes.clone();
                c[byte] ^= 1 << bit;
                assert!(
                    Atlas::from_bytes(&c, "flip").is_err(),
                    "flip of byte {byte} bit {bit} accepted"
                );
            }
        }
        let mut c = bytes.clone();
        let mid = c.len() / 2;
        c[mid] ^= 0x10;
        let err = Atlas::from_bytes(&c, "flip.atlas").unwrap_err().to_string();
        assert!(
            err.contains("CRC-32") && err.contains("flip.atlas"),
            "{err}"
        );
    }

    #[test]
    fn wrong_version_and_magic_are_named() {
        let mut bytes = sample().to_bytes();
        bytes[8..12].copy_from_slice(&2u32.to_le_bytes());
        let err = Atlas::from_bytes(&bytes, "v2.atlas")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("version 2") && err.contains("reads version 1"),
            "{err}"
        );
        let mut bytes = sample().to_bytes();
        bytes[0] = b'X';
        let err = Atlas::from_bytes(&bytes, "m.atlas")
            .unwrap_err()
            .to_string();
        assert!(err.contains("magic"), "{err}");
    }

    #[test]
    fn non_monotone_pressures_are_rejected_even_with_a_valid_checksum() {
        let mut a = sample();
        a.pressure_pa.swap(1, 2);
        let err = Atlas::from_bytes(&a.to_bytes(), "mono.atlas")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("increase strictly") && err.contains("level 2"),
            "{err}"
        );
    }

    #[test]
    fn hermite_replay_is_exact_for_cubic_paths_and_hits_the_levels() {
        // x(p) = x0 (1 + a p + b p^3): Hermite with exact dx/dp reproduces cubics exactly.
        let rest: Vec<[f64; 3]> = vec![[0.01, 0.02, 0.03], [0.04, -0.01, 0.0]];
        let (a, b) = (1e-4, 1e-11);
        let levels: Vec<AtlasLevel> = [0.0, 700.0, 2000.0]
            .iter()
            .map(|&p| AtlasLevel {
                pressure_pa: p,
                cavity_volume_m3: 1.0 + p,
                positions_m: rest
                    .iter()
                    .map(|x| x.map(|c| c * (1.0 + a * p + b * p * p * p)))
                    .collect(),
                dxdp_m_per_pa: rest
                    .iter()
                    .map(|x| x.map(|c| c * (a + 3.0 * b * p * p)))
                    .collect(),
            })
            .collect();
        let atlas = Atlas::new(0, serde_json::json!({}), rest.clone(), &levels).unwrap();
        let mut out = vec![[0.0f32; 3]; 2];
        for p in [0.0, 350.0, 700.0, 1234.5, 2000.0] {
            atlas.positions_at(p, &mut out).unwrap();
            for (o, x) in out.iter().zip(&rest) {
                for c in 0..3 {
                    let exact = x[c] * (1.0 + a * p + b * p * p * p);
                    assert!(
                        (o[c] as f64 - exact).abs() < 1e-8,
                        "p {p}: {} vs {exact}",
                        o[c]
                    );
                }
            }
        }
        // Clamped outside the range; a wrong buffer is an error, not a panic.
        atlas.positions_at(-5.0, &mut out).unwrap();
        assert!((out[0][0] as f64 - 0.01).abs() < 1e-9);
        assert!(atlas.positions_at(0.0, &mut [[0.0; 3]; 3]).is_err());
        assert!((atlas.pressure_at_volume(atlas.cavity_volume_at(900.0)) - 900.0).abs() < 1e-6);
    }
}
