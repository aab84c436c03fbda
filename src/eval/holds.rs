//! What the agent did once its gripper held the task's object, from the episodes' traces: whether the next
//! command kept the grip and lifted, or let go. It tells a grasp lost after closing on the object from one that
//! never reached it.
use super::EpisodeTrace;
use super::TraceStep;
use serde::{Deserialize, Serialize};

/// Fingers further apart than this after a close have stopped on something (metres; the Panda's open fingers
/// are 0.08 apart, closed on air 0).
const STOPPED_APART: f64 = 0.01;
/// The object counts as between the fingers within the reach radius of the grip site across and sideways ...
const BETWEEN: f64 = 0.03;
/// ... and at most this far beyond it along the fingers (the expert's grips hold it 2-3 cm beyond).
const ALONG: f64 = 0.06;
/// A command that targets the gripper this much higher than it is asks for a lift (metres).
pub const LIFT: f64 = 0.05;
/// The gripper has risen from a hold once it is this much higher (metres).
const RISEN: f64 = 0.04;

/// Steps at which the gripper held the object on the table, and what the next command did.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct HoldSummary {
    /// Episodes with at least one such step.
    pub episodes: usize,
    /// Such steps that had a next step.
    pub steps: usize,
    /// Fraction of them whose next command opened the gripper.
    pub opened: f64,
    /// Fraction of them whose next command targeted a lift.
    pub lifted: f64,
    /// Episodes that held the object but never picked it ...
    pub lost: usize,
    /// ... of which the gripper opened before it rose from the first hold ...
    pub let_go: usize,
    /// ... or rose closed with the object no longer between the fingers.
    pub slipped: usize,
}

/// Whether after `s` the task's object lies between the fingers.
pub(super) fn between(s: &TraceStep) -> bool {
    let [x, y, z] = s.object_in_gripper;
    x.abs() < BETWEEN && y.abs() < BETWEEN && z < ALONG
}

/// Whether after `s` the gripper, commanded closed, holds the task's object that still lies on the table: the
/// fingers stopped apart and the object between them.
fn holding(s: &TraceStep) -> bool {
    s.action[7] > 0.0 && s.fingers[0] - s.fingers[1] > STOPPED_APART && between(s) && !s.picked
}

impl HoldSummary {
    /// Of the traces of one evaluation; none without traces.
    pub fn of(traces: &[EpisodeTrace]) -> Option<HoldSummary> {
        if traces.is_empty() {
            return None;
        }
        let (mut episodes, mut steps, mut opened, mut lifted) = (0, 0, 0, 0);
        let (mut lost, mut let_go, mut slipped) = (0, 0, 0);
        for trace in traces {
            for pair in trace.steps.windows(2) {
                let (now, next) = (&pair[0], &pair[1]);
                if holding(now) {
                    steps += 1;
                    opened += usize::from(next.action[7] <= 0.0);
                    lifted += usize::from(next.action[2] > now.gripper_pos[2] + LIFT);
                }
            }
            let Some(first) = trace.steps.iter().position(holding) else { continue };
            episodes += 1;
            if trace.steps.iter().any(|s| s.picked) {
                continue;
            }
            lost += 1;
            let bottom = trace.steps[first].gripper_pos[2];
            let after = &trace.steps[first..];
            let rise = after.iter().position(|s| s.gripper_pos[2] > bottom + RISEN).unwrap_or(after.len());
            match after[..rise].iter().any(|s| s.action[7] <= 0.0) {
                true => let_go += 1,
                false => slipped += usize::from(after.get(rise).is_some_and(|s| !between(s))),
            }
        }
        let share = |k: usize| if steps == 0 { 0.0 } else { k as f64 / steps as f64 };
        Some(HoldSummary { episodes, steps, opened: share(opened), lifted: share(lifted), lost, let_go, slipped })
    }

    /// Several evaluations' summaries as one (the shares weighted by their holding steps); none of none.
    pub fn pooled(parts: &[HoldSummary]) -> Option<HoldSummary> {
        let first = parts.first()?;
        Some(parts[1..].iter().fold(*first, |a, b| {
            let steps = a.steps + b.steps;
            let share = |x: f64, y: f64| {
                if steps == 0 { 0.0 } else { (x * a.steps as f64 + y * b.steps as f64) / steps as f64 }
            };
            HoldSummary {
                episodes: a.episodes + b.episodes,
                steps,
                opened: share(a.opened, b.opened),
                lifted: share(a.lifted, b.lifted),
                lost: a.lost + b.lost,
                let_go: a.let_go + b.let_go,
                slipped: a.slipped + b.slipped,
            }
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn step(closed: bool, fingers: f64, offset: [f64; 3], target_z: f64, z: f64) -> TraceStep {
        let mut action = [0.0; 8];
        action[2] = target_z;
        action[7] = if closed { 1.0 } else { -1.0 };
        TraceStep {
            step: 1,
            action,
            gripper_pos: [0.5, 0.0, z],
            fingers: [fingers / 2.0, -fingers / 2.0],
            object_in_gripper: offset,
            reached: true,
            picked: false,
            placed: false,
        }
    }

    #[test]
    fn a_hold_is_a_closed_grip_stopped_on_the_object_and_its_next_command_is_counted() {
        let on = [0.005, -0.01, 0.02];
        let trace = |steps| EpisodeTrace { index: 0, steps };
        let traces = [
            // Holds twice: the next command first stays down, then lifts.
            trace(vec![
                step(true, 0.05, on, 0.85, 0.85),
                step(true, 0.05, on, 0.85, 0.85),
                step(true, 0.05, on, 1.0, 0.9),
            ]),
            // Holds, then lets go.
            trace(vec![step(true, 0.05, on, 0.85, 0.85), step(false, 0.07, on, 0.85, 0.85)]),
            // Closed on air beside the object, and open over it: no hold.
            trace(vec![step(true, 0.0, on, 0.85, 0.85), step(true, 0.05, [0.05, 0.0, 0.0], 0.85, 0.85)]),
            trace(vec![step(false, 0.08, on, 0.85, 0.85), step(false, 0.08, on, 0.85, 0.85)]),
        ];
        let s = HoldSummary::of(&traces).unwrap();
        assert_eq!((s.episodes, s.steps), (2, 3));
        assert_eq!((s.opened, s.lifted), (1.0 / 3.0, 1.0 / 3.0));
        // Neither held episode picked: the second let go; the first never rose.
        assert_eq!((s.lost, s.let_go, s.slipped), (2, 1, 0));
        let mut rose = vec![step(true, 0.05, on, 0.85, 0.85), step(true, 0.05, on, 1.0, 0.85)];
        rose.push(step(true, 0.0, [0.0, 0.0, 0.12], 1.0, 0.95));
        let s = HoldSummary::of(&[trace(rose.clone())]).unwrap();
        assert_eq!((s.lost, s.let_go, s.slipped), (1, 0, 1), "rose closed, the object left on the table");
        rose.last_mut().unwrap().picked = true;
        assert_eq!(HoldSummary::of(&[trace(rose)]).unwrap().lost, 0, "a picked episode is not lost");
        assert_eq!(HoldSummary::of(&[]), None);
    }

    #[test]
    fn pooled_summaries_add_their_counts_and_weight_their_shares_by_holding_steps() {
        let a = HoldSummary { episodes: 2, steps: 10, opened: 0.1, lifted: 0.5, lost: 1, let_go: 1, slipped: 0 };
        let b = HoldSummary { episodes: 3, steps: 30, opened: 0.3, lifted: 0.1, lost: 2, let_go: 0, slipped: 2 };
        let p = HoldSummary::pooled(&[a, b]).unwrap();
        assert_eq!((p.episodes, p.steps, p.lost, p.let_go, p.slipped), (5, 40, 3, 1, 2));
        assert!((p.opened - 0.25).abs() < 1e-12 && (p.lifted - 0.2).abs() < 1e-12, "{p:?}");
        assert_eq!(HoldSummary::pooled(&[a]), Some(a));
        assert_eq!(HoldSummary::pooled(&[]), None);
    }
}
