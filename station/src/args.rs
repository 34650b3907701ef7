//! The command line of `hydrometra station`: where it listens, which rigs it shows, at which rates.

use std::net::SocketAddr;
use std::path::PathBuf;

use clap::{Args, Subcommand};

use crate::rates::Rates;

/// Default address: loopback only.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:8737";

/// `hydrometra station`: serve the page, or benchmark it.
#[derive(Args, Debug, Clone)]
#[command(args_conflicts_with_subcommands = true)]
pub struct StationArgs {
    /// `bench`: measure the station (see docs/station.md, "Benchmark").
    #[command(subcommand)]
    pub command: Option<StationCommand>,
    /// Serving the page.
    #[command(flatten)]
    pub serve: ServeArgs,
}

/// Subcommands of `hydrometra station`.
#[derive(Subcommand, Debug, Clone)]
pub enum StationCommand {
    /// Measure rig sample -> page latency, the daemon's figures with and without a station, and
    /// the station's CPU use (starts its own daemons, stations and headless Chromium).
    Bench(crate::bench::BenchArgs),
}

/// How the station serves: where it listens, which rigs it shows, at which rates.
#[derive(Args, Debug, Clone)]
pub struct ServeArgs {
    /// Address to listen on. Any other than loopback needs a token.
    #[arg(long, value_name = "ADDR:PORT", default_value = DEFAULT_LISTEN)]
    pub listen: SocketAddr,
    /// Show the hydrometrad on this machine with this iceoryx2 service prefix (repeat for
    /// several daemons). Default: "hydrometra/v1", unless --zenoh is given.
    #[arg(long, value_name = "PREFIX")]
    pub service_prefix: Vec<String>,
    /// The access token (control always needs it; viewing needs it off loopback). Prefer
    /// --token-file or the HYDROMETRA_STATION_TOKEN variable: a flag is visible to other users.
    #[arg(long, value_name = "TOKEN")]
    pub token: Option<String>,
    /// Read the token from the first line of this file.
    #[arg(long, value_name = "PATH", conflicts_with = "token")]
    pub token_file: Option<PathBuf>,
    /// The recordings directory of the local daemon (default: the directory of the daemon's
    /// open or last recording, asked over its control service).
    #[arg(long, value_name = "DIR")]
    pub recordings_dir: Option<PathBuf>,
    /// Rates and sizes of what the page is sent.
    #[command(flatten)]
    pub rates: Rates,
    /// Rigs over zenoh (the classroom).
    #[command(flatten)]
    pub zenoh: crate::classroom::ZenohArgs,
    /// Seconds of plot history kept per rig (a page opened later starts with it).
    #[arg(long, value_name = "SECS", default_value_t = 600.0)]
    pub history_s: f64,
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(subcommand)]
        command: Top,
    }

    #[derive(clap::Subcommand)]
    enum Top {
        Station(StationArgs),
    }

    fn parse(args: &[&str]) -> StationArgs {
        let Top::Station(s) = Cli::try_parse_from(args).unwrap().command;
        s
    }

    #[test]
    fn the_default_address_is_loopback_only() {
        let s = parse(&["hydrometra", "station"]);
        assert!(s.command.is_none());
        assert_eq!(s.serve.listen, DEFAULT_LISTEN.parse().unwrap());
        assert!(s.serve.listen.ip().is_loopback());
        let b = parse(&["hydrometra", "station", "bench", "--pairs", "2"]);
        assert!(matches!(b.command, Some(StationCommand::Bench(ref a)) if a.pairs == 2));
    }
}
