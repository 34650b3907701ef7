//! What the TOML targets check of an error message: that it says where.

/// Whether an error message gives a TOML position (`line N`).
pub fn names_a_line(message: &str) -> bool {
    message
        .split("line ")
        .skip(1)
        .any(|rest| rest.starts_with(|c: char| c.is_ascii_digit()))
}
