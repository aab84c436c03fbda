//! Where the agent's gripper first closed in each episode, summarised: what a failed grasp missed by, beside
//! what a successful one looked like.
use super::EpisodeResult;
use super::stats::{Rate, wilson};
use serde::{Deserialize, Serialize};

/// Where the agent's gripper first closed: how often it closed at all, and the task's object in the gripper's
/// frame then, split by whether the episode picked the object.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GraspSummary {
    /// Episodes whose gripper closed at some step.
    pub closed: Rate,
    /// None where no such episode closed.
    pub picked: Option<CloseOffsets>,
    pub not_picked: Option<CloseOffsets>,
}

/// Medians over closes of the object's offset in the gripper's frame, metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CloseOffsets {
    pub closes: usize,
    /// |x|: across the fingers.
    pub across: f64,
    /// |y|: sideways, along the fingers' faces.
    pub sideways: f64,
    /// z: along the fingers, signed.
    pub along: f64,
}

impl GraspSummary {
    /// Of `episodes`.
    pub fn of(episodes: &[EpisodeResult]) -> GraspSummary {
        GraspSummary::of_closes(episodes.iter().map(|e| (e.picked, e.first_close.map(|c| c.object_in_gripper))))
    }

    /// Of episodes given as (picked, the object in the gripper's frame at the first close, if it closed).
    pub fn of_closes(episodes: impl IntoIterator<Item = (bool, Option<[f64; 3]>)>) -> GraspSummary {
        let episodes: Vec<(bool, Option<[f64; 3]>)> = episodes.into_iter().collect();
        let offsets = |picked: bool| {
            let closes: Vec<[f64; 3]> =
                episodes.iter().filter(|(p, _)| *p == picked).filter_map(|(_, close)| *close).collect();
            (!closes.is_empty()).then(|| CloseOffsets {
                closes: closes.len(),
                across: median(closes.iter().map(|o| o[0].abs())),
                sideways: median(closes.iter().map(|o| o[1].abs())),
                along: median(closes.iter().map(|o| o[2])),
            })
        };
        GraspSummary {
            closed: wilson(episodes.iter().filter(|(_, close)| close.is_some()).count(), episodes.len()),
            picked: offsets(true),
            not_picked: offsets(false),
        }
    }
}

/// The median of a non-empty set (the mean of the middle two for an even count).
fn median(values: impl Iterator<Item = f64>) -> f64 {
    let mut v: Vec<f64> = values.collect();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 { v[n / 2] } else { (v[n / 2 - 1] + v[n / 2]) / 2.0 }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::GripperClose;

    fn episode(picked: bool, close: Option<[f64; 3]>) -> EpisodeResult {
        EpisodeResult {
            index: 0,
            task: 0,
            agent_seed: 0,
            demo_seed: 0,
            reached: true,
            picked,
            placed: false,
            wrong_bin: false,
            steps: 1,
            first_reached: None,
            first_picked: None,
            first_placed: None,
            first_close: close.map(|object_in_gripper| GripperClose { step: 3, object_in_gripper }),
        }
    }

    #[test]
    fn closes_are_counted_and_their_offsets_split_by_whether_the_object_was_picked() {
        let episodes = [
            episode(true, Some([0.001, -0.002, 0.01])),
            episode(false, Some([-0.03, 0.01, 0.05])),
            episode(false, Some([0.01, -0.03, 0.07])),
            episode(false, Some([0.02, 0.0, -0.01])),
            episode(false, None),
        ];
        let g = GraspSummary::of(&episodes);
        assert_eq!((g.closed.value, g.closed.n), (0.8, 5));
        assert_eq!(g.picked, Some(CloseOffsets { closes: 1, across: 0.001, sideways: 0.002, along: 0.01 }));
        let missed = g.not_picked.unwrap();
        assert_eq!(missed.closes, 3);
        assert_eq!((missed.across, missed.sideways, missed.along), (0.02, 0.01, 0.05), "medians of |x|, |y| and z");
        assert_eq!(median([1.0, 4.0, 2.0, 3.0].into_iter()), 2.5);
        let never = GraspSummary::of(&[episode(false, None)]);
        assert_eq!((never.closed.value, never.picked, never.not_picked), (0.0, None, None));
    }
}
