//! Service names: every service lives under one configurable prefix.

use iceoryx2::prelude::ServiceName;
use iceoryx2::service::service_name::ServiceNameError;

/// The prefix used when none is configured. The schema major version is part of it, so a daemon
/// speaking v2 never collides with v1 renderers.
pub const DEFAULT_SERVICE_PREFIX: &str = "hydrometra/v1";

/// Error for a prefix that cannot form valid iceoryx2 service names.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InvalidPrefix {
    /// The rejected prefix.
    pub prefix: String,
    /// Why it was rejected.
    pub reason: String,
}

impl core::fmt::Display for InvalidPrefix {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "invalid service prefix {:?}: {} (expected a non-empty '/'-separated name such as \"{}\")",
            self.prefix, self.reason, DEFAULT_SERVICE_PREFIX
        )
    }
}

impl std::error::Error for InvalidPrefix {}

/// The names of all hydrometra services under one prefix.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServiceNames {
    prefix: String,
    status: ServiceName,
    events: ServiceName,
}

impl Default for ServiceNames {
    fn default() -> Self {
        Self::new(DEFAULT_SERVICE_PREFIX).unwrap_or_else(|e| unreachable!("{e}"))
        // ok: constant, tested
    }
}

/// Longest prefix accepted: leaves room for the longest suffix within iceoryx2's 255-byte limit.
pub const MAX_PREFIX_LEN: usize = 200;

impl ServiceNames {
    /// Names under `prefix` (e.g. `hydrometra/v1` or `lab-3/hydrometra/v1`). A trailing `/` is
    /// ignored.
    pub fn new(prefix: &str) -> Result<Self, InvalidPrefix> {
        let trimmed = prefix.trim_end_matches('/');
        let fail = |reason: &str| InvalidPrefix {
            prefix: prefix.to_string(),
            reason: reason.to_string(),
        };
        if trimmed.is_empty() {
            return Err(fail("it is empty"));
        }
        if trimmed.len() > MAX_PREFIX_LEN {
            return Err(fail(&format!("it is longer than {MAX_PREFIX_LEN} bytes")));
        }
        if trimmed.split('/').any(str::is_empty) {
            return Err(fail(
                "it contains an empty path segment ('//' or a leading '/')",
            ));
        }
        if trimmed.chars().any(|c| c.is_control() || c.is_whitespace()) {
            return Err(fail("it contains whitespace or control characters"));
        }
        let make = |suffix: &str| {
            ServiceName::new(&format!("{trimmed}/{suffix}"))
                .map_err(|e| fail(&format!("iceoryx2 rejects it: {e:?}")))
        };
        for suffix in suffix::ALL {
            make(suffix)?;
        }
        Ok(Self {
            prefix: trimmed.to_string(),
            status: make(suffix::STATUS)?,
            events: make(suffix::EVENTS)?,
        })
    }

    /// The iceoryx2 name of the status service.
    pub fn status(&self) -> &ServiceName {
        &self.status
    }

    /// The iceoryx2 name of the event service.
    pub fn events(&self) -> &ServiceName {
        &self.events
    }

    /// The prefix, without a trailing `/`.
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// Full name string of a service suffix (one of [`suffix`]).
    pub fn full(&self, suffix: &str) -> String {
        format!("{}/{}", self.prefix, suffix)
    }

    /// The iceoryx2 service name for a suffix (one of [`suffix`]).
    pub fn service(&self, suffix: &str) -> Result<ServiceName, ServiceNameError> {
        ServiceName::new(&self.full(suffix))
    }
}

/// Service name suffixes, appended to the prefix with a `/`.
pub mod suffix {
    /// Status record, publish-subscribe, [`crate::Status`].
    pub const STATUS: &str = "status";
    /// Wake-up events for renderers, event service, ids in [`crate::events`].
    pub const EVENTS: &str = "events";
    /// Cavity surface topology (triangles), publish-subscribe, slice of `u32`.
    pub const MESH_TOPOLOGY: &str = "cavity/topology";
    /// Cavity surface vertex positions per frame, publish-subscribe, slice of `f32`.
    pub const MESH_POSITIONS: &str = "cavity/positions";
    /// Flow field on the voxel grid, publish-subscribe, slice of `u8` with sections.
    pub const FLOW_FIELD: &str = "flow";
    /// Particles (blood, bubbles, fragments), publish-subscribe, slice of [`crate::particles::Particle`].
    pub const PARTICLES: &str = "particles";
    /// The control service, request-response, [`crate::control`].
    pub const CONTROL: &str = "control";
    /// Every suffix.
    pub const ALL: [&str; 7] = [
        STATUS,
        EVENTS,
        MESH_TOPOLOGY,
        MESH_POSITIONS,
        FLOW_FIELD,
        PARTICLES,
        CONTROL,
    ];
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_names_are_under_hydrometra_v1() {
        let n = ServiceNames::default();
        assert_eq!(n.full(suffix::STATUS), "hydrometra/v1/status");
        assert_eq!(n.full(suffix::EVENTS), "hydrometra/v1/events");
        assert_eq!(
            n.full(suffix::MESH_POSITIONS),
            "hydrometra/v1/cavity/positions"
        );
    }

    #[test]
    fn trailing_slash_is_ignored_and_bad_prefixes_are_named() {
        assert_eq!(ServiceNames::new("lab/x/").unwrap().prefix(), "lab/x");
        for bad in ["", "/", "a//b", "/abs", "has space", "tab\tx"] {
            let err = ServiceNames::new(bad).unwrap_err();
            assert_eq!(err.prefix, bad);
            assert!(err.to_string().contains("expected"), "{err}");
        }
        assert!(ServiceNames::new(&"x".repeat(MAX_PREFIX_LEN + 1)).is_err());
    }
}
