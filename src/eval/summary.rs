//! Aggregates of evaluation episodes: success per stage, overall and per task, pooled or as a mean over seeds.
use super::EpisodeResult;
use super::EpisodeTrace;
use super::grasps::GraspSummary;
use super::holds::HoldSummary;
pub use super::stats::StageRates;
use super::stats::{Counts, Rate, wilson};
use crate::sim::task::NUM_TASKS;
use serde::{Deserialize, Serialize};

/// Wilson rates of the stages over `episodes`.
pub fn pooled<'a>(episodes: impl IntoIterator<Item = &'a EpisodeResult>) -> StageRates {
    StageRates::of(&Counts::of(episodes))
}

/// The aggregates of one evaluation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalSummary {
    pub policy: String,
    pub episodes: usize,
    pub overall: StageRates,
    /// In task order; a task without episodes has NaN rates.
    pub per_task: Vec<StageRates>,
    /// Episodes that left the object in another quadrant of the target bin (none in summaries written before
    /// it was recorded).
    #[serde(default)]
    pub wrong_bin: Option<Rate>,
    /// Where the gripper first closed, in episodes that picked and in those that did not (none in summaries
    /// written before it was recorded).
    #[serde(default)]
    pub grasps: Option<GraspSummary>,
    /// What the next command did while the gripper held the object on the table (only where the evaluation kept
    /// traces).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub holds: Option<HoldSummary>,
}

/// Summarises the episodes of one evaluation of `policy`, and their traces where it kept them.
pub fn summarize(policy: &str, results: &[EpisodeResult], traces: &[EpisodeTrace]) -> EvalSummary {
    EvalSummary {
        policy: policy.to_string(),
        episodes: results.len(),
        overall: pooled(results),
        per_task: (0..NUM_TASKS).map(|t| pooled(results.iter().filter(|e| e.task == t))).collect(),
        wrong_bin: Some(wilson(results.iter().filter(|e| e.wrong_bin).count(), results.len())),
        grasps: Some(GraspSummary::of(results)),
        holds: HoldSummary::of(traces),
    }
}

/// Over several training seeds: all episodes pooled, and the mean of the per-seed rates with a t interval.
pub fn across_seeds(per_seed: &[Vec<EpisodeResult>]) -> (StageRates, StageRates) {
    let all = pooled(per_seed.iter().flatten());
    let rates: Vec<StageRates> = per_seed.iter().map(pooled).collect();
    (all, StageRates::mean_over(&rates))
}

/// `value% [low, high]` of a rate.
pub fn percent(r: &Rate) -> String {
    if r.n == 0 {
        return "missing".into();
    }
    format!("{:5.1}% [{:5.1}, {:5.1}]", 100.0 * r.value, 100.0 * r.low, 100.0 * r.high)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn episode(task: usize, stages: [bool; 3]) -> EpisodeResult {
        EpisodeResult {
            index: 0,
            task,
            agent_seed: 0,
            demo_seed: 0,
            reached: stages[0],
            picked: stages[1],
            placed: stages[2],
            wrong_bin: false,
            steps: 1,
            first_reached: None,
            first_picked: None,
            first_placed: None,
            first_close: None,
        }
    }

    #[test]
    fn pooled_and_per_seed_aggregates_count_correctly() {
        let seed_a = vec![episode(0, [true, true, true]), episode(1, [true, false, false])];
        let seed_b = vec![episode(0, [true, true, false]), episode(1, [false, false, false])];
        let s = summarize("x", &seed_a, &[]);
        assert_eq!((s.overall.reached.value, s.overall.placed.value), (1.0, 0.5));
        assert_eq!(s.wrong_bin.unwrap().value, 0.0);
        let wrong = EpisodeResult { wrong_bin: true, ..episode(2, [true, true, false]) };
        assert_eq!(summarize("x", &[wrong, episode(2, [false; 3])], &[]).wrong_bin.unwrap().value, 0.5);
        assert_eq!(s.per_task[1].picked.value, 0.0);
        assert_eq!(s.per_task[5].reached.n, 0);
        let (all, mean) = across_seeds(&[seed_a, seed_b]);
        assert_eq!((all.reached.value, all.picked.value, all.placed.value), (0.75, 0.5, 0.25));
        assert_eq!((mean.placed.value, mean.placed.n), (0.25, 2));
    }
}
