//! What became of the episodes that picked the task's object, from their traces: placed, set down in another
//! quadrant, let go with the object still between the fingers yet not placed, lost from the fingers before they
//! opened, or still held when the episode ended. It tells a pick that never held the object from a placing error.
use super::holds::between;
use super::{EpisodeResult, EpisodeTrace};
use std::collections::HashMap;

/// The picked episodes of one or more evaluations, by what followed the pick.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CarrySummary {
    /// Episodes that picked the object ...
    pub picked: usize,
    /// ... and placed it in the demonstrated quadrant;
    pub placed: usize,
    /// ... set it down in another quadrant of the target bin (it rested there at some step);
    pub other_quadrant: usize,
    /// ... opened the gripper with the object between the fingers, and it rested in no quadrant;
    pub let_go: usize,
    /// ... had the object leave the fingers before they opened;
    pub lost: usize,
    /// ... still held it between closed fingers when the episode ended.
    pub held_at_end: usize,
}

impl CarrySummary {
    /// Of one evaluation's episodes and their traces; none without traces or where a picked episode has none.
    pub fn of(results: &[EpisodeResult], traces: &[EpisodeTrace]) -> Option<CarrySummary> {
        if traces.is_empty() {
            return None;
        }
        let by_index: HashMap<usize, &EpisodeTrace> = traces.iter().map(|t| (t.index, t)).collect();
        let mut s = CarrySummary::default();
        for e in results.iter().filter(|e| e.picked) {
            s.picked += 1;
            if e.placed {
                s.placed += 1;
                continue;
            }
            if e.wrong_bin {
                s.other_quadrant += 1;
                continue;
            }
            let steps = &by_index.get(&e.index)?.steps;
            let pick = steps.iter().position(|st| st.picked)?;
            let opens = steps[pick..].iter().position(|st| st.action[7] <= 0.0).map(|k| pick + k);
            // The last command of an episode that ran to its end opens the gripper under the authors' protocol
            // (`eval.binarize_gripper`): an opening there ends the episode, it releases nothing.
            let released = opens.filter(|&o| o + 1 < steps.len());
            let last_closed = &steps[opens.unwrap_or(steps.len()).saturating_sub(1)];
            match (released, between(last_closed)) {
                (Some(_), true) => s.let_go += 1,
                (None, true) => s.held_at_end += 1,
                (_, false) => s.lost += 1,
            }
        }
        Some(s)
    }

    /// Several evaluations' summaries as one; none of none.
    pub fn pooled(parts: &[CarrySummary]) -> Option<CarrySummary> {
        let first = parts.first()?;
        Some(parts[1..].iter().fold(*first, |a, b| CarrySummary {
            picked: a.picked + b.picked,
            placed: a.placed + b.placed,
            other_quadrant: a.other_quadrant + b.other_quadrant,
            let_go: a.let_go + b.let_go,
            lost: a.lost + b.lost,
            held_at_end: a.held_at_end + b.held_at_end,
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::super::TraceStep;
    use super::*;

    const HELD: [f64; 3] = [0.005, -0.01, 0.02];
    const GONE: [f64; 3] = [0.0, -0.4, 0.25];

    fn step(closed: bool, picked: bool, offset: [f64; 3]) -> TraceStep {
        let mut action = [0.0; 8];
        action[7] = if closed { 1.0 } else { -1.0 };
        TraceStep {
            step: 1,
            action,
            gripper_pos: [0.5, 0.0, 1.0],
            fingers: [0.02, -0.02],
            object_in_gripper: offset,
            reached: true,
            picked,
            placed: false,
        }
    }

    fn episode(index: usize, picked: bool, placed: bool, wrong_bin: bool) -> EpisodeResult {
        EpisodeResult {
            index,
            task: 0,
            agent_seed: 0,
            demo_seed: 0,
            reached: true,
            picked,
            placed,
            wrong_bin,
            steps: 3,
            first_reached: Some(1),
            first_picked: picked.then_some(2),
            first_placed: placed.then_some(3),
            first_close: None,
        }
    }

    #[test]
    fn a_picked_episode_is_placed_elsewhere_let_go_lost_or_still_held() {
        let trace = |index, steps| EpisodeTrace { index, steps };
        let let_go = |index| {
            let open = step(false, true, GONE);
            trace(index, vec![step(true, false, HELD), step(true, true, HELD), open.clone(), open])
        };
        let results = [
            episode(0, true, true, true),
            episode(1, true, false, true),
            episode(2, true, false, false),
            episode(3, true, false, false),
            episode(4, true, false, false),
            episode(5, true, false, false),
            episode(6, false, false, false),
            episode(7, true, false, false),
            episode(8, true, false, false),
        ];
        let traces = [
            trace(0, vec![step(true, true, HELD)]),
            trace(1, vec![step(true, true, HELD)]),
            // Opens with the object between the fingers before the last command: let go.
            let_go(2),
            // The object left the fingers while they stayed closed, then they opened: lost.
            trace(3, vec![step(true, true, HELD), step(true, true, GONE), step(false, true, GONE)]),
            // Never opened, the object still between the fingers at the end: held.
            trace(4, vec![step(true, true, HELD), step(true, true, HELD)]),
            // Never opened, the object gone at the end: lost.
            trace(5, vec![step(true, true, HELD), step(true, true, GONE)]),
            // Opened only by the episode's last command, the object held until then: held at the end.
            trace(7, vec![step(true, true, HELD), step(true, true, HELD), step(false, true, GONE)]),
            // Opened at the very step that lifted it: the step before ran closed with the object between.
            trace(8, vec![step(true, false, HELD), step(false, true, HELD), step(false, true, GONE)]),
            trace(6, vec![step(false, false, GONE)]),
        ];
        let s = CarrySummary::of(&results, &traces).unwrap();
        let expected = CarrySummary { picked: 8, placed: 1, other_quadrant: 1, let_go: 2, lost: 2, held_at_end: 2 };
        assert_eq!(s, expected, "placed wins over the latched wrong bin");
        assert_eq!(CarrySummary::of(&results, &[]), None, "no traces kept");
        assert_eq!(CarrySummary::of(&results, &traces[..3]), None, "a picked episode without its trace");
        let pooled = CarrySummary::pooled(&[s, s]).unwrap();
        assert_eq!((pooled.picked, pooled.lost, pooled.held_at_end), (16, 4, 4));
        assert_eq!(CarrySummary::pooled(&[]), None);
    }
}
