//! The scene thread's pace: when a frame is due, whether it has anything new to show, and how far
//! the scene degrades when its frames do not fit their period (docs/daemon.md, "Overload").
//!
//! The 1 kHz loop never waits for the scene; an overloaded scene would only fall behind, showing
//! the trainee an ever older cavity. So the scene gives up quality in steps, each kept for at
//! least [`HOLD`] before the next is tried, and takes it back one step at a time once frames
//! fit again with room to spare for [`RECOVER_AFTER`]:
//!
//! | level | the scene ... |
//! |---|---|
//! | 0 | runs at full quality |
//! | 1 | steps the fluid once per frame (no CFL substeps) |
//! | 2 | and halves the particle budget (no new particles above it) |
//! | 3 | and runs at half its frame rate |

use std::time::{Duration, Instant};

use hydrometra_sim::scene::SceneQuality;

/// The deepest degradation level.
pub const MAX_LEVEL: u32 = 3;
/// A frame whose work (step and publication) takes more than this share of its period counts as
/// overrun.
pub const OVERRUN_SHARE: f64 = 0.9;
/// Frames fit "with room to spare" below this share of the period the better level would have.
pub const SPARE_SHARE: f64 = 0.4;
/// Shortest time between two changes of level.
pub const HOLD: Duration = Duration::from_secs(1);
/// Time without overrun, with room to spare, before one level of quality comes back.
pub const RECOVER_AFTER: Duration = Duration::from_secs(5);
/// Weight of the newest frame in the smoothed frame work.
const SMOOTHING: f64 = 0.2;

/// What the scene thread does with a frame slot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Slot {
    /// Step and publish a frame.
    Step,
    /// Nothing new arrived from the loop since the last frame (it advanced no time): the frame is
    /// skipped, never published twice.
    NoNewInput,
}

/// The scene's frame clock and its degradation level.
#[derive(Debug)]
pub struct Pacer {
    nominal_period: Duration,
    next_due: Instant,
    level: u32,
    last_change: Instant,
    fitting_since: Option<Instant>,
    smoothed_work_s: f64,
    /// The loop's offer count the last stepped frame read (offers count from 1).
    last_offers: u64,
    /// Frames that started one period or more after they were due, since the scene started.
    pub frames_late: u64,
    /// Frame slots not stepped: no new input, or passed while a late frame ran.
    pub frames_skipped: u64,
    /// Frames stepped.
    pub frames: u64,
}

impl Pacer {
    /// A pacer for frames every `nominal_period`, the first due now.
    pub fn new(nominal_period: Duration, now: Instant) -> Self {
        Self {
            nominal_period,
            next_due: now,
            level: 0,
            last_change: now,
            fitting_since: None,
            smoothed_work_s: 0.0,
            last_offers: 0,
            frames_late: 0,
            frames_skipped: 0,
            frames: 0,
        }
    }

    /// The degradation level in use (0 full quality .. [`MAX_LEVEL`]).
    pub fn level(&self) -> u32 {
        self.level
    }

    /// The period of the current level.
    pub fn period(&self) -> Duration {
        period_at(self.nominal_period, self.level)
    }

    /// When the next frame is due.
    pub fn next_due(&self) -> Instant {
        self.next_due
    }

    /// Called when the frame due at [`Pacer::next_due`] starts at `now` with the loop's offer
    /// count `offers` (0 before the loop's first offer): how late it is (0 on time), and whether it is stepped. Slots that passed
    /// while the previous frame overran are skipped (counted), not run in a burst.
    pub fn begin(&mut self, now: Instant, offers: u64) -> (Duration, Slot) {
        let period = self.period();
        let late = now.saturating_duration_since(self.next_due);
        let missed = (late.as_nanos() / period.as_nanos().max(1)) as u64;
        if missed > 0 {
            self.frames_late += 1;
            self.frames_skipped += missed;
        }
        self.next_due += period * (1 + missed as u32);
        if offers == self.last_offers {
            self.frames_skipped += 1;
            return (late, Slot::NoNewInput);
        }
        self.last_offers = offers;
        self.frames += 1;
        (late, Slot::Step)
    }

    /// Called after a stepped frame whose work (step and publication) took `work`, at `now`;
    /// returns the new level when it changed.
    pub fn end(&mut self, work: Duration, now: Instant) -> Option<u32> {
        let work_s = work.as_secs_f64();
        self.smoothed_work_s = if self.frames <= 1 {
            work_s
        } else {
            SMOOTHING * work_s + (1.0 - SMOOTHING) * self.smoothed_work_s
        };
        let period_s = self.period().as_secs_f64();
        let overrun = self.smoothed_work_s > OVERRUN_SHARE * period_s;
        let held = now.saturating_duration_since(self.last_change) >= HOLD;
        if overrun {
            self.fitting_since = None;
            if held && self.level < MAX_LEVEL {
                return Some(self.change(self.level + 1, now));
            }
            return None;
        }
        let better = period_at(self.nominal_period, self.level.saturating_sub(1)).as_secs_f64();
        if self.level == 0 || self.smoothed_work_s >= SPARE_SHARE * better {
            self.fitting_since = None;
            return None;
        }
        let since = *self.fitting_since.get_or_insert(now);
        if held && now.saturating_duration_since(since) >= RECOVER_AFTER {
            return Some(self.change(self.level - 1, now));
        }
        None
    }

    fn change(&mut self, level: u32, now: Instant) -> u32 {
        // The frame clock restarts from now at the new period.
        self.level = level;
        self.last_change = now;
        self.fitting_since = None;
        self.next_due = now + self.period();
        level
    }
}

/// The frame period at `level`: the nominal one, doubled at level 3.
pub fn period_at(nominal: Duration, level: u32) -> Duration {
    if level >= 3 {
        nominal * 2
    } else {
        nominal
    }
}

/// The scene's quality at `level`: one fluid substep from level 1, half the particle budget
/// from level 2 (the frame period doubles at level 3: [`period_at`]).
pub fn quality_at(level: u32) -> SceneQuality {
    SceneQuality {
        max_fluid_substeps: (level >= 1).then_some(1),
        particle_budget_share: if level >= 2 { 0.5 } else { 1.0 },
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PERIOD: Duration = Duration::from_millis(16);

    #[test]
    fn a_frame_without_new_input_is_skipped_never_stepped_twice() {
        let t0 = Instant::now();
        let mut p = Pacer::new(PERIOD, t0);
        assert_eq!(p.begin(t0, 5).1, Slot::Step);
        assert_eq!(p.begin(t0 + PERIOD, 5).1, Slot::NoNewInput);
        assert_eq!(p.begin(t0 + 2 * PERIOD, 6).1, Slot::Step);
        assert_eq!((p.frames, p.frames_skipped, p.frames_late), (2, 1, 0));
    }

    #[test]
    fn slots_passed_during_a_long_frame_are_skipped_and_the_frame_counts_late() {
        let t0 = Instant::now();
        let mut p = Pacer::new(PERIOD, t0);
        p.begin(t0, 1);
        // Due at t0 + 16 ms, starts 2.5 periods later: two slots passed.
        let (late, slot) = p.begin(t0 + PERIOD + PERIOD * 5 / 2, 2);
        assert_eq!(slot, Slot::Step);
        assert_eq!(late, PERIOD * 5 / 2);
        assert_eq!((p.frames_late, p.frames_skipped), (1, 2));
        assert_eq!(p.next_due(), t0 + PERIOD * 4);
    }

    /// Under sustained overload the level deepens one step per `HOLD`, to the deepest; once
    /// frames fit with room to spare it comes back one step per `RECOVER_AFTER`.
    #[test]
    fn overload_degrades_in_steps_and_quality_comes_back_in_steps() {
        let t0 = Instant::now();
        let mut p = Pacer::new(PERIOD, t0);
        let mut now = t0;
        let mut levels = vec![];
        for n in 0..400u64 {
            p.begin(now, n);
            if let Some(l) = p.end(PERIOD, now) {
                levels.push((l, now - t0));
            }
            now += PERIOD;
        }
        assert_eq!(
            levels.iter().map(|l| l.0).collect::<Vec<_>>(),
            vec![1, 2, 3]
        );
        for w in levels.windows(2) {
            assert!(w[1].1 - w[0].1 >= HOLD);
        }
        assert_eq!(p.period(), PERIOD * 2);
        // Now each frame takes a tenth of the nominal period.
        let mut back = vec![];
        let from = now;
        for n in 400..2000u64 {
            p.begin(now, n);
            if let Some(l) = p.end(PERIOD / 10, now) {
                back.push((l, now - from));
            }
            now += p.period();
        }
        assert_eq!(back.iter().map(|l| l.0).collect::<Vec<_>>(), vec![2, 1, 0]);
        assert!(back[0].1 >= RECOVER_AFTER);
        for w in back.windows(2) {
            assert!(w[1].1 - w[0].1 >= RECOVER_AFTER);
        }
    }

    #[test]
    fn frames_that_fit_but_without_room_to_spare_hold_the_level() {
        let t0 = Instant::now();
        let mut p = Pacer::new(PERIOD, t0);
        let mut now = t0;
        // Overload to level 1.
        for n in 0..80u64 {
            p.begin(now, n);
            p.end(PERIOD, now);
            now += PERIOD;
            if p.level() == 1 {
                break;
            }
        }
        assert_eq!(p.level(), 1);
        // 60 % of the period: no overrun, no room to spare: level 1 for good.
        for n in 100..1000u64 {
            p.begin(now, n);
            assert_eq!(p.end(PERIOD * 6 / 10, now), None);
            now += PERIOD;
        }
        assert_eq!(p.level(), 1);
    }

    #[test]
    fn the_levels_map_to_documented_settings() {
        assert_eq!(quality_at(0), SceneQuality::default());
        assert_eq!(quality_at(1).max_fluid_substeps, Some(1));
        assert_eq!(quality_at(1).particle_budget_share, 1.0);
        assert_eq!(quality_at(2).particle_budget_share, 0.5);
        assert_eq!(quality_at(3), quality_at(2));
        assert_eq!(period_at(PERIOD, 2), PERIOD);
        assert_eq!(period_at(PERIOD, 3), PERIOD * 2);
    }
}
