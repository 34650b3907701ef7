//! Creating and opening the slice services (cavity topology and positions, flow, particles) with
//! the quality of service of `docs/ipc.md`, in one place for the daemon and for renderers.

use core::fmt::Debug;

use iceoryx2::node::Node;
use iceoryx2::prelude::ZeroCopySend;
use iceoryx2::service::builder::publish_subscribe::{
    PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError,
};
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use iceoryx2::service::Service;

use crate::names::{suffix, ServiceNames};

/// The port factory of slice service `K` on service type `S`.
pub type SliceFactory<S, K> =
    PortFactory<S, [<K as SliceService>::Element], <K as SliceService>::Header>;

/// Quality of service of one slice service.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SliceQos {
    /// Samples kept for late subscribers.
    pub history_size: usize,
    /// Samples buffered per subscriber (safe overflow: the oldest is replaced).
    pub subscriber_max_buffer_size: usize,
    /// Subscribers admitted.
    pub max_subscribers: usize,
}

/// Publishers of every slice service: the daemon alone.
pub const MAX_PUBLISHERS: usize = 1;
/// Nodes that may hold a slice service open at once.
pub const MAX_NODES: usize = 32;

/// A slice service: its name suffix, element and header types, and quality of service.
pub trait SliceService {
    /// The element type of the payload slice.
    type Element: Debug + Copy + ZeroCopySend + 'static;
    /// The user header.
    type Header: Debug + Copy + Default + ZeroCopySend + 'static;
    /// Name suffix under the prefix (one of [`suffix`]).
    const SUFFIX: &'static str;
    /// Quality of service.
    const QOS: SliceQos;
}

/// `<prefix>/cavity/topology`.
pub struct Topology;
impl SliceService for Topology {
    type Element = u32;
    type Header = crate::mesh::MeshTopologyHeader;
    const SUFFIX: &'static str = suffix::MESH_TOPOLOGY;
    const QOS: SliceQos = SliceQos {
        history_size: crate::mesh::qos::HISTORY_SIZE,
        subscriber_max_buffer_size: crate::mesh::qos::SUBSCRIBER_MAX_BUFFER_SIZE,
        max_subscribers: crate::mesh::qos::TOPOLOGY_MAX_SUBSCRIBERS,
    };
}

/// `<prefix>/cavity/positions`.
pub struct Positions;
impl SliceService for Positions {
    type Element = f32;
    type Header = crate::mesh::MeshPositionsHeader;
    const SUFFIX: &'static str = suffix::MESH_POSITIONS;
    const QOS: SliceQos = SliceQos {
        history_size: crate::mesh::qos::HISTORY_SIZE,
        subscriber_max_buffer_size: crate::mesh::qos::SUBSCRIBER_MAX_BUFFER_SIZE,
        max_subscribers: crate::mesh::qos::POSITIONS_MAX_SUBSCRIBERS,
    };
}

/// `<prefix>/flow`.
pub struct Flow;
impl SliceService for Flow {
    type Element = u8;
    type Header = crate::field::FlowFieldHeader;
    const SUFFIX: &'static str = suffix::FLOW_FIELD;
    const QOS: SliceQos = SliceQos {
        history_size: crate::field::qos::HISTORY_SIZE,
        subscriber_max_buffer_size: crate::field::qos::SUBSCRIBER_MAX_BUFFER_SIZE,
        max_subscribers: crate::field::qos::MAX_SUBSCRIBERS,
    };
}

/// `<prefix>/particles`.
pub struct Particles;
impl SliceService for Particles {
    type Element = crate::particles::Particle;
    type Header = crate::particles::ParticlesHeader;
    const SUFFIX: &'static str = suffix::PARTICLES;
    const QOS: SliceQos = SliceQos {
        history_size: crate::particles::qos::HISTORY_SIZE,
        subscriber_max_buffer_size: crate::particles::qos::SUBSCRIBER_MAX_BUFFER_SIZE,
        max_subscribers: crate::particles::qos::MAX_SUBSCRIBERS,
    };
}

/// Why a slice service could not be created or opened.
#[derive(Debug)]
pub enum SliceServiceError {
    /// The prefix and suffix do not form a valid iceoryx2 name.
    Name(String),
    /// iceoryx2 refused to create or open it.
    OpenOrCreate(PublishSubscribeOpenOrCreateError),
    /// iceoryx2 refused to open it.
    Open(PublishSubscribeOpenError),
}

impl core::fmt::Display for SliceServiceError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Name(e) => write!(f, "invalid service name: {e}"),
            Self::OpenOrCreate(e) => write!(f, "cannot create or open the service: {e:?}"),
            Self::Open(e) => write!(f, "cannot open the service: {e:?}"),
        }
    }
}

impl std::error::Error for SliceServiceError {}

/// The service `K` as the daemon creates it (or re-opens it after a restart), with every
/// quality-of-service setting of `docs/ipc.md`.
pub fn create<K: SliceService, S: Service>(
    node: &Node<S>,
    names: &ServiceNames,
) -> Result<SliceFactory<S, K>, SliceServiceError> {
    let name = names
        .service(K::SUFFIX)
        .map_err(|e| SliceServiceError::Name(format!("{}: {e:?}", names.full(K::SUFFIX))))?;
    node.service_builder(&name)
        .publish_subscribe::<[K::Element]>()
        .user_header::<K::Header>()
        .history_size(K::QOS.history_size)
        .subscriber_max_buffer_size(K::QOS.subscriber_max_buffer_size)
        .max_subscribers(K::QOS.max_subscribers)
        .max_publishers(MAX_PUBLISHERS)
        .max_nodes(MAX_NODES)
        .enable_safe_overflow(true)
        .open_or_create()
        .map_err(SliceServiceError::OpenOrCreate)
}

/// The service `K` as a renderer opens it: fails with `DoesNotExist` while the daemon has not
/// created it yet (no scene, or the scene is still preparing).
pub fn open<K: SliceService, S: Service>(
    node: &Node<S>,
    names: &ServiceNames,
) -> Result<SliceFactory<S, K>, SliceServiceError> {
    let name = names
        .service(K::SUFFIX)
        .map_err(|e| SliceServiceError::Name(format!("{}: {e:?}", names.full(K::SUFFIX))))?;
    node.service_builder(&name)
        .publish_subscribe::<[K::Element]>()
        .user_header::<K::Header>()
        .open()
        .map_err(SliceServiceError::Open)
}

/// Samples a publisher pre-allocates for a service with this quality of service (iceoryx2 0.10:
/// each subscriber's buffer and the [`SUBSCRIBER_BORROWED_SAMPLES`] it may borrow, the history
/// and the publisher's [`PUBLISHER_LOANED_SAMPLES`] loans; docs/ipc.md, "Quality of service").
pub fn preallocated_samples(qos: SliceQos) -> usize {
    qos.max_subscribers * (qos.subscriber_max_buffer_size + SUBSCRIBER_BORROWED_SAMPLES)
        + qos.history_size
        + PUBLISHER_LOANED_SAMPLES
}

/// Samples a subscriber may hold borrowed (iceoryx2 0.10's default configuration).
pub const SUBSCRIBER_BORROWED_SAMPLES: usize = 2;
/// Samples the daemon's publishers may hold on loan at once (one being written, one spare).
pub const PUBLISHER_LOANED_SAMPLES: usize = 2;

/// Shared memory (bytes, in `/dev/shm`) the daemon's publisher of `K` needs for payloads of at
/// most `max_len` elements: its pre-allocated samples of header and payload (an estimate: iceoryx2
/// adds a few kB of management data per service).
pub fn shared_memory_bytes<K: SliceService>(max_len: usize) -> usize {
    let sample =
        core::mem::size_of::<K::Header>() + max_len.max(1) * core::mem::size_of::<K::Element>();
    preallocated_samples(K::QOS) * sample.next_multiple_of(8)
}

#[cfg(test)]
mod shm_tests {
    use super::*;

    /// The figure docs/ipc.md states for the default scene's flow service: 19 samples of
    /// 567,840 bytes in a segment of 10,791,922 bytes (measured with `ls -l /dev/shm`).
    #[test]
    fn the_flow_estimate_matches_the_measured_segment_within_a_page_per_sample() {
        assert_eq!(preallocated_samples(Flow::QOS), 19);
        let estimate = shared_memory_bytes::<Flow>(567_840);
        let measured = 10_791_922usize;
        assert!(
            estimate <= measured && measured - estimate < 19 * 4096,
            "{estimate}"
        );
    }
}
