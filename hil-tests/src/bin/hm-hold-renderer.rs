//! A renderer that holds on: subscribes to every scene service of a running daemon (cavity
//! topology and positions, flow, particles) and to status, receives one sample of each and keeps
//! them borrowed, then never reads again. The fault tests kill it with SIGKILL while it holds the
//! samples (`hil-tests/tests/shm_faults.rs`).
//!
//! Usage: `hm-hold-renderer PREFIX [--read]`; prints `holding` once it holds a sample of every
//! service. With `--read` it goes on reading (a healthy renderer) instead of holding.

use std::time::{Duration, Instant};

use hydrometra_ipc::{slice, status, ServiceNames};
use iceoryx2::prelude::*;

fn main() {
    let mut args = std::env::args().skip(1);
    let Some(prefix) = args.next() else {
        eprintln!("usage: hm-hold-renderer PREFIX [--read]");
        std::process::exit(2);
    };
    let read = args.next().as_deref() == Some("--read");
    let names = match ServiceNames::new(&prefix) {
        Ok(n) => n,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(2);
        }
    };
    let node = match NodeBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
    {
        Ok(n) => n,
        Err(e) => {
            eprintln!("node: {e:?}");
            std::process::exit(1);
        }
    };
    let deadline = Instant::now() + Duration::from_secs(30);
    macro_rules! subscribe {
        ($open:expr, $what:literal) => {
            loop {
                match $open.map(|s| s.subscriber_builder().create()) {
                    Ok(Ok(sub)) => break sub,
                    other if Instant::now() > deadline => {
                        eprintln!("cannot subscribe to {}: {other:?}", $what);
                        std::process::exit(1);
                    }
                    _ => std::thread::sleep(Duration::from_millis(20)),
                }
            }
        };
    }
    let status = subscribe!(status::open(&node, &names), "status");
    let topology = subscribe!(slice::open::<slice::Topology, _>(&node, &names), "topology");
    let positions = subscribe!(
        slice::open::<slice::Positions, _>(&node, &names),
        "positions"
    );
    let flow = subscribe!(slice::open::<slice::Flow, _>(&node, &names), "flow");
    let particles = subscribe!(
        slice::open::<slice::Particles, _>(&node, &names),
        "particles"
    );
    macro_rules! one {
        ($sub:expr, $what:literal) => {
            loop {
                match $sub.receive() {
                    Ok(Some(sample)) => break sample,
                    Ok(None) if Instant::now() < deadline => {
                        std::thread::sleep(Duration::from_millis(5))
                    }
                    other => {
                        eprintln!("no sample of {}: {:?}", $what, other.map(|_| ()));
                        std::process::exit(1);
                    }
                }
            }
        };
    }
    let held = (
        one!(status, "status"),
        one!(topology, "topology"),
        one!(positions, "positions"),
        one!(flow, "flow"),
        one!(particles, "particles"),
    );
    println!("holding");
    if read {
        drop(held);
        loop {
            while let Ok(Some(_)) = positions.receive() {}
            while let Ok(Some(_)) = flow.receive() {}
            while let Ok(Some(_)) = particles.receive() {}
            while let Ok(Some(_)) = status.receive() {}
            std::thread::sleep(Duration::from_millis(5));
        }
    }
    loop {
        std::thread::sleep(Duration::from_secs(3600));
    }
}
