//! Rig scenarios as the offline commands (`hydraulics run`, `scene run`) read them: the rig's part
//! from the emulator, the hydraulic case from the scenario's `[hydraulics]` table.

use hydrometra_drivers::emulator::Scenario;
use hydrometra_sim::hydraulics::CaseScript;

/// A scenario (resolved by [`Scenario::resolve`]: a built-in name, else a file) with the hydraulic
/// case script of its `[hydraulics]` table (empty without one).
pub fn load_scenario(spec: &str) -> anyhow::Result<(Scenario, CaseScript)> {
    let scenario = Scenario::resolve(spec)?;
    let case = CaseScript::from_scenario_table(scenario.hydraulics.as_ref(), &scenario.origin)?;
    Ok((scenario, case))
}
