//! Case files (placeholder, replaced below).
