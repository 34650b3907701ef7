//! `hydrometra station bench` runs end to end (one pair of short runs) and reports every figure:
//! it is the lead's measuring tool, its numbers are taken on a quiet machine, not here.

use std::process::{Command, Stdio};

use hydrometra_hil_tests::station::chromium;
use hydrometra_hil_tests::{binary, shared_atlas_cache};
use serde_json::Value;

#[test]
fn the_benchmark_runs_with_and_without_a_station_and_reports_every_figure() {
    let cache = shared_atlas_cache("default");
    let out = Command::new(binary("hydrometra"))
        .args([
            "station",
            "bench",
            "--pairs",
            "1",
            "--seconds",
            "3",
            "--json",
        ])
        .arg("--chromium")
        .arg(chromium())
        .arg("--atlas-cache-dir")
        .arg(&cache)
        .stdin(Stdio::null())
        .output()
        .expect("run the benchmark");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "bench failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let lines: Vec<Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    assert_eq!(lines.len(), 3, "{stdout}");
    let (runs, summary) = lines.split_at(2);
    let with: Vec<&Value> = runs.iter().filter(|r| r["with_station"] == true).collect();
    let without: Vec<&Value> = runs.iter().filter(|r| r["with_station"] == false).collect();
    assert_eq!((with.len(), without.len()), (1, 1), "{stdout}");
    for r in runs {
        // 3 s at 1 kHz, give or take the window's edges.
        let ticks = r["ticks"].as_u64().unwrap();
        assert!((2000..4500).contains(&ticks), "{r}");
        assert!(r["deadline_misses"].as_u64().is_some(), "{r}");
        assert!(r["status_latency_p99_ms"].as_f64().unwrap() > 0.0, "{r}");
        assert!(r["longest_status_gap_ms"].as_f64().unwrap() > 0.0, "{r}");
    }
    let page = &with[0]["page_latency"];
    assert!(
        page["count"].as_u64().unwrap() > 10,
        "the page acknowledged no status: {page}"
    );
    assert!(page["p99_s"].as_f64().unwrap() > 0.0, "{page}");
    assert!(with[0]["station_cpu_percent_of_one_core"].as_f64().unwrap() > 0.0);
    assert!(without[0]["page_latency"].is_null());
    assert_eq!(summary[0]["summary"], true);
    assert!(summary[0]["worst_page_latency_p99_ms"].as_f64().unwrap() > 0.0);
}
