//! The station's access token: given (`--token`, `--token-file`, `HYDROMETRA_STATION_TOKEN`) or,
//! on a loopback listener, generated at start. Control actions always need it; data needs it when
//! the station listens on another address than loopback.

use std::path::Path;

/// Environment variable holding the token.
pub const TOKEN_ENV: &str = "HYDROMETRA_STATION_TOKEN";
/// Shortest token accepted (a guessable token is no protection).
pub const MIN_TOKEN_LEN: usize = 16;

/// Why no usable token was found.
#[derive(Debug, thiserror::Error)]
pub enum TokenError {
    /// The token file could not be read.
    #[error("--token-file {path}: {source}")]
    File {
        /// The file.
        path: String,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The token is too short or has characters a URL fragment or header would mangle.
    #[error(
        "{origin}: a token of {len} characters; expected at least {MIN_TOKEN_LEN} characters \
         from A-Z a-z 0-9 - _ . ~"
    )]
    Weak {
        /// Where it came from.
        origin: String,
        /// Its length.
        len: usize,
    },
    /// Off loopback without a token.
    #[error(
        "--listen {0}: listening on an address other than loopback needs a token (--token, \
         --token-file or {TOKEN_ENV}); see docs/station.md, \"Security\""
    )]
    Missing(String),
}

/// The access token.
#[derive(Clone)]
pub struct Token(String);

impl core::fmt::Debug for Token {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("Token(..)")
    }
}

impl Token {
    /// The token's text (for the URL printed at start).
    pub fn reveal(&self) -> &str {
        &self.0
    }

    /// Whether `presented` is the token, compared in time independent of where they differ.
    pub fn matches(&self, presented: &str) -> bool {
        let (a, b) = (self.0.as_bytes(), presented.as_bytes());
        let mut diff = (a.len() != b.len()) as u8;
        for (i, x) in a.iter().enumerate() {
            diff |= x ^ b.get(i).copied().unwrap_or(0);
        }
        diff == 0
    }
}

fn check(origin: &str, text: &str) -> Result<Token, TokenError> {
    let text = text.trim();
    let plain = text
        .bytes()
        .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'-' | b'_' | b'.' | b'~'));
    if text.len() < MIN_TOKEN_LEN || !plain {
        return Err(TokenError::Weak {
            origin: origin.to_string(),
            len: text.len(),
        });
    }
    Ok(Token(text.to_string()))
}

/// A random token of 32 hex digits from the kernel's generator.
pub fn generate() -> Result<Token, std::io::Error> {
    use std::io::Read;
    let mut bytes = [0u8; 16];
    std::fs::File::open("/dev/urandom")?.read_exact(&mut bytes)?;
    Ok(Token(bytes.iter().map(|b| format!("{b:02x}")).collect()))
}

/// The token from the flag, else the file, else the environment; `None` if none is given.
pub fn configured(
    flag: Option<&str>,
    file: Option<&Path>,
    env: Option<String>,
) -> Result<Option<Token>, TokenError> {
    if let Some(t) = flag {
        return check("--token", t).map(Some);
    }
    if let Some(path) = file {
        let text = std::fs::read_to_string(path).map_err(|source| TokenError::File {
            path: path.display().to_string(),
            source,
        })?;
        let first = text.lines().next().unwrap_or("");
        return check(&format!("--token-file {}", path.display()), first).map(Some);
    }
    match env {
        Some(t) => check(TOKEN_ENV, &t).map(Some),
        None => Ok(None),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_match_exactly() {
        let t = check("t", "abcdefghijklmnop").unwrap();
        assert!(t.matches("abcdefghijklmnop"));
        for other in [
            "abcdefghijklmnoq",
            "abcdefghijklmno",
            "abcdefghijklmnopq",
            "",
        ] {
            assert!(!t.matches(other), "{other}");
        }
    }

    #[test]
    fn weak_tokens_are_refused_naming_their_origin() {
        let e = check("--token", "short").unwrap_err().to_string();
        assert!(e.contains("--token") && e.contains("16"), "{e}");
        assert!(check("x", "has spaces in the token").is_err());
        assert!(configured(None, None, Some("abc".into())).is_err());
        assert!(configured(None, None, None).unwrap().is_none());
    }

    #[test]
    fn generated_tokens_are_long_and_differ() {
        let (a, b) = (generate().unwrap(), generate().unwrap());
        assert_eq!(a.reveal().len(), 32);
        assert!(!a.matches(b.reveal()));
        assert!(check("generated", a.reveal()).is_ok());
    }

    #[test]
    fn a_token_file_gives_its_first_line() {
        let p = std::env::temp_dir().join(format!("station-token-{}", std::process::id()));
        std::fs::write(&p, "0123456789abcdef-xyz\nignored\n").unwrap();
        let t = configured(None, Some(&p), None).unwrap().unwrap();
        assert!(t.matches("0123456789abcdef-xyz"));
        std::fs::remove_file(&p).unwrap();
        assert!(matches!(
            configured(None, Some(&p), None),
            Err(TokenError::File { .. })
        ));
    }
}
