//! The station's side of the classroom: subscriptions to every rig's services under a key root
//! (or only the named rigs), decoded into the renderer contract's types; and control requests as
//! zenoh queries.

use std::sync::Arc;
use std::time::Duration;

use hydrometra_ipc::control::{ControlRequest, ControlResponse};
use hydrometra_ipc::field::FlowFieldHeader;
use hydrometra_ipc::mesh::{MeshPositionsHeader, MeshTopologyHeader};
use hydrometra_ipc::particles::{Particle, ParticlesHeader};
use hydrometra_ipc::Status;
use zenoh::Wait;

use crate::keys::{self, service};
use crate::wire::{bytes_of, decode_slice, read_exact};

/// One decoded sample of a rig.
#[derive(Debug, Clone)]
pub enum Update {
    /// A status.
    Status(Box<Status>),
    /// The cavity topology.
    Topology(MeshTopologyHeader, Vec<u32>),
    /// Cavity positions.
    Positions(MeshPositionsHeader, Vec<f32>),
    /// A flow field (the flow service's bytes).
    Flow(FlowFieldHeader, Vec<u8>),
    /// Particles.
    Particles(ParticlesHeader, Vec<Particle>),
}

/// Decodes the payload of `service`; `None` if it does not have the contract's layout.
pub fn decode(svc: &str, bytes: &[u8]) -> Option<Update> {
    Some(match svc {
        service::STATUS => Update::Status(Box::new(read_exact::<Status>(bytes)?)),
        service::TOPOLOGY => {
            let (h, e) = decode_slice(bytes)?;
            Update::Topology(h, e)
        }
        service::POSITIONS => {
            let (h, e) = decode_slice(bytes)?;
            Update::Positions(h, e)
        }
        service::FLOW => {
            let (h, e) = decode_slice(bytes)?;
            Update::Flow(h, e)
        }
        service::PARTICLES => {
            let (h, e) = decode_slice(bytes)?;
            Update::Particles(h, e)
        }
        _ => return None,
    })
}

/// What the callback is given: the rig id and the update, or `Err` with the service whose
/// payload did not decode.
pub type OnUpdate = Arc<dyn Fn(&str, Result<Update, &str>) + Send + Sync>;

/// Subscribes to every data service of every rig under `root` (of the rigs in `only`, if not
/// empty); `on` runs on zenoh's threads and must be quick. Keep the subscribers alive.
pub fn subscribe(
    zenoh: &zenoh::Session,
    root: &str,
    only: &[String],
    on: OnUpdate,
) -> Result<Vec<zenoh::pubsub::Subscriber<()>>, String> {
    let mut subs = Vec::new();
    for svc in service::DATA {
        let key = keys::every_rig(root, svc);
        let (on, root, only) = (on.clone(), root.to_string(), only.to_vec());
        let sub = zenoh
            .declare_subscriber(key.clone())
            .callback(move |sample| {
                let Some((rig, svc)) = keys::parse(&root, sample.key_expr().as_str()) else {
                    return;
                };
                if !only.is_empty() && !only.iter().any(|r| r == rig) {
                    return;
                }
                let bytes = sample.payload().to_bytes();
                match decode(svc, &bytes) {
                    Some(u) => on(rig, Ok(u)),
                    None => on(rig, Err(svc)),
                }
            })
            .wait()
            .map_err(|e| format!("cannot subscribe to {key}: {e}"))?;
        subs.push(sub);
    }
    Ok(subs)
}

/// Sends one control request to rig `rig` and waits up to `timeout` for its answer (blocking).
pub fn control(
    zenoh: &zenoh::Session,
    root: &str,
    rig: &str,
    request: &ControlRequest,
    timeout: Duration,
) -> Result<ControlResponse, String> {
    let key = keys::key(root, rig, service::CONTROL);
    let replies = zenoh
        .get(key.clone())
        .payload(bytes_of(request).to_vec())
        .timeout(timeout)
        .wait()
        .map_err(|e| format!("{key}: {e}"))?;
    let reply = replies.recv().map_err(|_| {
        format!(
            "{key}: no answer within {:.0} s: the rig does not allow control over zenoh \
             ([remote] allow_control), or it is unreachable",
            timeout.as_secs_f64()
        )
    })?;
    match reply.result() {
        Ok(sample) => read_exact::<ControlResponse>(&sample.payload().to_bytes())
            .ok_or_else(|| format!("{key}: the answer is no ControlResponse")),
        Err(e) => Err(format!("{key}: {:?}", e.payload().to_bytes())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::encode_slice;

    #[test]
    fn payloads_decode_by_service_and_bad_ones_are_refused() {
        let s = Status {
            sequence: 3,
            ..Status::default()
        };
        match decode(service::STATUS, bytes_of(&s)) {
            Some(Update::Status(b)) => assert_eq!(b.sequence, 3),
            other => panic!("{other:?}"),
        }
        assert!(decode(service::STATUS, &[0u8; 10]).is_none());
        let h = MeshTopologyHeader {
            triangle_count: 1,
            ..Default::default()
        };
        match decode(service::TOPOLOGY, &encode_slice(&h, &[0u32, 1, 2])) {
            Some(Update::Topology(h, t)) => assert_eq!((h.triangle_count, t.len()), (1, 3)),
            other => panic!("{other:?}"),
        }
        assert!(decode(service::TOPOLOGY, &[1u8; 25]).is_none());
        assert!(decode("unknown", &[]).is_none());
    }
}
