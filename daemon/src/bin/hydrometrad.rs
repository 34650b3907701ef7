//! `hydrometrad`: the real-time hydrometra simulation service.

fn main() -> anyhow::Result<()> {
    anyhow::bail!("hydrometrad is not built yet: see the open daemon issue")
}
