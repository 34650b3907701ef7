//! The classroom over zenoh on loopback: two `hydrometrad` with `[remote]` enabled (rig-a and
//! rig-b, started 3 s apart) connect to one `hydrometra station --zenoh`; the page in a real
//! browser shows both rigs, each card with the numbers of its own daemon (matched by run id and
//! by the status sequence the card shows), and a control request reaches the right rig.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, Instant};

use hydrometra_hil_tests::station::{artifacts, open_page, Station};
use hydrometra_hil_tests::{temp_dir, unique_prefix, Daemon, StatusReader};
use hydrometra_station::browser::Chromium;
use serde_json::Value;

const PA_PER_MMHG: f64 = hydrometra_units::PA_PER_MMHG;

/// A free TCP port on loopback (bound and released; the station binds it right after).
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A daemon configuration publishing status to the station's zenoh endpoint, nothing else on
/// the network (no multicast, listening on loopback only).
fn remote_config(dir: &Path, rig: &str, port: u16, allow_control: bool) -> String {
    let path = dir.join(format!("{rig}.toml"));
    std::fs::write(
        &path,
        format!(
            "[remote]\nenabled = true\nrig_id = \"{rig}\"\nmode = \"peer\"\n\
             connect = [\"tcp/127.0.0.1:{port}\"]\nlisten = [\"tcp/127.0.0.1:0\"]\n\
             multicast_scouting = false\nservices = [\"status\"]\nstatus_rate_hz = 30.0\n\
             allow_control = {allow_control}\n"
        ),
    )
    .unwrap();
    path.display().to_string()
}

/// Every status of a daemon by sequence: (pressure Pa, deficit m³), and its run id.
fn collect(reader: &StatusReader, into: &mut BTreeMap<u64, (f64, f64)>) -> Option<u64> {
    let mut run = None;
    for s in reader.drain() {
        into.insert(s.sequence, (s.cavity_pressure_pa, s.deficit_m3));
        run = Some(s.run_id);
    }
    run
}

#[test]
fn two_rigs_over_zenoh_are_shown_each_with_its_own_numbers() {
    let dir = temp_dir("classroom");
    let port = free_port();
    let station = Station::start(&[
        "--zenoh",
        "--zenoh-no-multicast",
        "--zenoh-listen",
        &format!("tcp/127.0.0.1:{port}"),
    ]);
    let config_a = remote_config(&dir, "rig-a", port, true);
    let config_b = remote_config(&dir, "rig-b", port, false);
    let a = Daemon::start(
        &unique_prefix("rig-a"),
        &[
            "--emulated",
            "default",
            "--no-record",
            "--config",
            &config_a,
        ],
    );
    let reader_a = StatusReader::connect(&a.prefix, Duration::from_secs(30));
    std::thread::sleep(Duration::from_secs(3));
    let b = Daemon::start(
        &unique_prefix("rig-b"),
        &[
            "--emulated",
            "default",
            "--no-record",
            "--config",
            &config_b,
        ],
    );
    let reader_b = StatusReader::connect(&b.prefix, Duration::from_secs(30));
    let (mut seen_a, mut seen_b) = (BTreeMap::new(), BTreeMap::new());
    let (mut run_a, mut run_b) = (None, None);

    let (rt, mut c) = open_page(&station.url, 1400, 900);
    rt.block_on(c.wait_for(
        "document.querySelectorAll('.rig-card').length === 2 && \
         [...document.querySelectorAll('.rig-card .c-pressure')].every(e => e.dataset.seq)",
        Duration::from_secs(60),
    ))
    .unwrap_or_else(|e| panic!("{e}\nrig-a log:\n{}\nrig-b log:\n{}", a.log(), b.log()));

    let mut checked = 0;
    let deadline = Instant::now() + Duration::from_secs(30);
    while checked < 4 {
        assert!(
            Instant::now() < deadline,
            "could not match the cards in 30 s"
        );
        run_a = collect(&reader_a, &mut seen_a).or(run_a);
        run_b = collect(&reader_b, &mut seen_b).or(run_b);
        let cards: Value = rt
            .block_on(c.eval(
                "[...document.querySelectorAll('.rig-card')].map(d => ({
                   id: d.querySelector('.name').textContent,
                   seq: d.querySelector('.c-pressure').dataset.seq,
                   dseq: d.querySelector('.c-deficit').dataset.seq,
                   p: d.querySelector('.c-pressure').textContent,
                   d: d.querySelector('.c-deficit').textContent,
                   run: window.hydrometraStation.rigs[Number(d.dataset.rig)].status.run_id_text }))",
            ))
            .unwrap();
        std::thread::sleep(Duration::from_millis(100));
        run_a = collect(&reader_a, &mut seen_a).or(run_a);
        run_b = collect(&reader_b, &mut seen_b).or(run_b);
        let cards = cards.as_array().expect("cards").clone();
        let ids: Vec<&str> = cards.iter().filter_map(|c| c["id"].as_str()).collect();
        assert!(
            ids.contains(&"rig-a") && ids.contains(&"rig-b"),
            "cards {ids:?}"
        );
        let mut all = true;
        for card in &cards {
            let (seen, run) = match card["id"].as_str() {
                Some("rig-a") => (&seen_a, run_a),
                _ => (&seen_b, run_b),
            };
            let seq: u64 = card["seq"].as_str().unwrap_or("0").parse().unwrap();
            assert_eq!(card["seq"], card["dseq"]);
            assert_eq!(
                card["run"].as_str(),
                run.map(|r| r.to_string()).as_deref(),
                "{} shows another daemon's run",
                card["id"]
            );
            let Some((p_pa, d_m3)) = seen.get(&seq) else {
                all = false; // shown before this subscriber saw it: try again
                continue;
            };
            let p: f64 = card["p"].as_str().unwrap().parse().unwrap();
            let d: f64 = card["d"].as_str().unwrap().parse().unwrap();
            assert!(
                (p - p_pa / PA_PER_MMHG).abs() <= 0.05 + 1e-9,
                "{}: {p} mmHg vs {}",
                card["id"],
                p_pa / PA_PER_MMHG
            );
            assert!(
                (d - d_m3 * 1e6).abs() <= 0.05 + 1e-9,
                "{}: {d} ml vs {}",
                card["id"],
                d_m3 * 1e6
            );
        }
        if all {
            checked += 1;
        }
    }
    assert_ne!(run_a, run_b);

    // Control over zenoh: rig-a allows it, rig-b does not.
    let ask = |c: &mut Chromium, rig: &str| -> Value {
        rt.block_on(c.eval(&format!(
            "(async () => {{
               const i = window.hydrometraStation.rigs.findIndex(r => r && r.info.id === '{rig}');
               const res = await fetch(`/api/rigs/${{i}}/control`, {{ method: 'POST',
                 headers: {{ 'Content-Type': 'application/json',
                            Authorization: 'Bearer {}' }},
                 body: JSON.stringify({{ command: 'record_status' }}) }});
               return {{ status: res.status, body: await res.json() }};
             }})()",
            hydrometra_hil_tests::station::TOKEN
        )))
        .unwrap()
    };
    let answer_a = ask(&mut c, "rig-a");
    assert_eq!(answer_a["status"], 200, "{answer_a}");
    // --no-record: the daemon answers, and says it has no recorder.
    assert_eq!(answer_a["body"]["result"], "unavailable", "{answer_a}");
    let answer_b = ask(&mut c, "rig-b");
    assert_eq!(answer_b["status"], 503, "{answer_b}");
    assert!(
        answer_b["body"]["error"]
            .as_str()
            .is_some_and(|e| e.contains("allow_control")),
        "{answer_b}"
    );
    let shot = artifacts().join("station-classroom.png");
    rt.block_on(c.screenshot(&shot)).expect("screenshot");
    println!("screenshot: {}", shot.display());
}
