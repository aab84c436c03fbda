//! How an evaluation runs: episodes, horizon, the agent's window, and how the network's action is used.
use super::history::HistoryMode;
use super::workers::EpisodeSpec;
use crate::model::config::ModelConfig;
use crate::seeds::derive_seed;
use crate::sim::env::{GripperYaw, ObjectSet, WorldConfig};
use crate::sim::object::Split;
use crate::sim::task::{NUM_TASKS, Task};
use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};
use std::collections::HashSet;

/// Which action the network's distribution yields at each step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum ActionChoice {
    /// A sample (the authors').
    #[default]
    Sample,
    /// The mean of the most probable mixture component: no sampling noise, which matters while the learned
    /// scales are still wide (short training runs).
    Mode,
    /// The mean of a sampled mixture component: the sample's choice between components (to lift or to stay)
    /// without the logistic spread within one (a diagnosis, not the authors').
    Component,
}

/// Who moves the agent during an evaluation of a network.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum Control {
    /// The network's actions, step by step.
    #[default]
    Policy,
    /// The scripted grasp-and-place, fed the grasp and drop positions the network predicts from the
    /// demonstration and the agent's first frame (the paper's DAML-Auxiliary; needs an architecture with a pose
    /// head).
    ScriptedPoses,
}

/// How to evaluate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct EvalConfig {
    /// Episodes, spread evenly over the tasks (episode i runs task `tasks[i mod len]`).
    pub episodes: usize,
    /// Agent actions per episode.
    pub horizon: usize,
    /// Root of the evaluation layouts and the policy's sampling.
    pub seed: u64,
    /// Task ids evaluated; in an experiment file they default to `collect.tasks`.
    pub tasks: Vec<usize>,
    /// Episodes run in lockstep (the network's batch).
    pub batch: usize,
    /// Action budget of the demonstrator's expert.
    pub demo_max_actions: usize,
    /// Demonstrator layouts tried before a demonstration counts as impossible.
    pub demo_attempts: usize,
    /// `auto`, `cpu`, `cuda` or `cuda:N` for the network.
    pub device: String,
    /// Episode indices to draw as PNG strips (context frames beside the agent's frames).
    pub strips: Vec<usize>,
    /// Episode indices to record as animated GIFs (the demonstration beside the rollout, with its stages); the
    /// report links them.
    pub videos: Vec<usize>,
    /// Width of the videos' frames: each episode recorded is replayed in a scene that renders this wide (the
    /// height in the policy frame's proportions), so a video shows what the policy saw at a size a person can
    /// see; frames at least this wide already are kept as they are.
    pub video_width: usize,
    /// How the agent's recent frames are kept (the authors clear them once `history_frames` are held).
    pub history: HistoryMode,
    /// Most agent frames the network sees; at most `model.agent_frames - 1`, the window positions that
    /// behaviour cloning trains.
    pub history_frames: usize,
    /// Sampled actions (the authors'), the most likely, or a sampled component's mean.
    pub action: ActionChoice,
    /// Replace the network's rotation by the agent expert's fixed orientation (the authors' test script does;
    /// needs `world.agent_yaw = "fixed"`).
    pub fixed_rotation: bool,
    /// Gripper +1 (close) where the network's command is positive, else -1, and open on the last step (the
    /// authors').
    pub binarize_gripper: bool,
    /// Training steps whose checkpoints are evaluated beside the final weights (success against training steps;
    /// each a multiple of `train.checkpoint_interval`). Read by experiment files.
    pub checkpoints: Vec<u64>,
    /// Who moves the agent: the network's actions, or the scripted expert executing its predicted positions.
    pub control: Control,
    /// Write every episode's steps (the command, the gripper, its fingers and the object in its frame) to
    /// `traces.jsonl` beside the episodes.
    pub traces: bool,
}

impl Default for EvalConfig {
    fn default() -> Self {
        EvalConfig {
            episodes: 160,
            horizon: 60,
            seed: 0,
            tasks: (0..NUM_TASKS).collect(),
            batch: 32,
            demo_max_actions: 100,
            demo_attempts: 10,
            device: "auto".into(),
            strips: Vec::new(),
            videos: Vec::new(),
            video_width: 320,
            history: HistoryMode::Reset,
            history_frames: 5,
            action: ActionChoice::Sample,
            fixed_rotation: true,
            binarize_gripper: true,
            checkpoints: Vec::new(),
            control: Control::Policy,
            traces: false,
        }
    }
}

/// The most episodes (or steps of one) an evaluation may ask for: far above the paper's 160 episodes of 60 steps.
const MAX_EPISODES: usize = 1_000_000;

impl EvalConfig {
    /// Checks ranges; errors name the key.
    pub fn validate(&self) -> Result<()> {
        if self.episodes == 0 || self.horizon == 0 || self.batch == 0 {
            bail!("eval.episodes, eval.horizon and eval.batch must be at least 1");
        }
        if self.episodes > MAX_EPISODES || self.horizon > MAX_EPISODES {
            bail!(
                "eval.episodes = {} and eval.horizon = {} must be at most {MAX_EPISODES}",
                self.episodes,
                self.horizon
            );
        }
        if self.demo_max_actions == 0 || self.demo_attempts == 0 {
            bail!("eval.demo_max_actions and eval.demo_attempts must be at least 1");
        }
        if self.history_frames == 0 {
            bail!("eval.history_frames must be at least 1");
        }
        if self.tasks.is_empty() {
            bail!("eval.tasks is empty");
        }
        for &t in &self.tasks {
            Task::from_id(t).with_context(|| format!("eval.tasks contains {t}"))?;
        }
        if let Some(i) = self.strips.iter().find(|&&i| i >= self.episodes) {
            bail!("eval.strips contains episode {i}, but there are {} episodes", self.episodes);
        }
        if let Some(i) = self.videos.iter().find(|&&i| i >= self.episodes) {
            bail!("eval.videos contains episode {i}, but there are {} episodes", self.episodes);
        }
        if !(16..=1024).contains(&self.video_width) {
            bail!("eval.video_width = {} out of range 16..=1024", self.video_width);
        }
        crate::device::check_device_name(&self.device)?;
        Ok(())
    }

    /// Checks the settings that depend on the evaluated network and its world; errors name the keys.
    pub fn check_policy(&self, model: &ModelConfig, world: &WorldConfig) -> Result<()> {
        if self.history_frames + 1 > model.agent_frames {
            bail!(
                "eval.history_frames = {} exceeds model.agent_frames - 1 = {}: behaviour cloning never trains the \
                 action at a later window position",
                self.history_frames,
                model.agent_frames - 1
            );
        }
        if self.control == Control::ScriptedPoses && !model.architecture.registration().is_some_and(|r| r.pose_head) {
            bail!(
                "eval.control = \"scripted_poses\" needs an architecture with a pose head (daml); model.architecture \
                 = {:?} has none",
                model.architecture.0
            );
        }
        if self.fixed_rotation && world.agent_yaw != GripperYaw::Fixed {
            bail!(
                "eval.fixed_rotation = true needs world.agent_yaw = \"fixed\" (the agent's expert turns its gripper)"
            );
        }
        Ok(())
    }

    /// The episodes: tasks in rotation, layouts from the `eval` seed domain, none in `exclude` (training seeds).
    /// In the multi-object world each rotation through the tasks is one environment of the held-out objects,
    /// drawn by its own seed, for the demonstrator and the agent alike.
    pub fn episode_specs(&self, objects: ObjectSet, exclude: &HashSet<u64>) -> Vec<EpisodeSpec> {
        let fresh = |domain: &str, i: usize| {
            (0u64..)
                .map(|attempt| derive_seed(domain, &[self.seed, i as u64, attempt]))
                .find(|s| !exclude.contains(s))
                .expect("some seed is not excluded")
        };
        (0..self.episodes)
            .map(|i| EpisodeSpec {
                index: i,
                task: self.tasks[i % self.tasks.len()],
                agent_seed: fresh("eval-agent", i),
                demo_seed: fresh("eval-demo", i),
                objects: objects.environment(
                    Split::HeldOut,
                    derive_seed("eval-environment", &[self.seed, (i / self.tasks.len()) as u64]),
                ),
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn evaluation_layouts_avoid_every_shared_training_layout() {
        use crate::data::collect_config::CollectConfig;
        use crate::sim::robot::Robot;
        let mut seeds = HashSet::new();
        for robot in [Robot::Sawyer, Robot::Panda] {
            let c = CollectConfig::paper(robot);
            seeds.extend(
                (0..16).flat_map(|t| (0..c.per_task).map(move |i| (t, i))).map(|(t, i)| c.instance_seed(t, i, 0)),
            );
        }
        let eval = EvalConfig { episodes: 160, ..EvalConfig::default() };
        let specs = eval.episode_specs(ObjectSet::Base, &seeds);
        assert!(specs.iter().all(|e| !seeds.contains(&e.agent_seed) && !seeds.contains(&e.demo_seed)));
    }

    #[test]
    fn multi_object_evaluation_runs_each_round_of_tasks_in_an_environment_of_the_held_out_objects() {
        let eval = EvalConfig { episodes: 48, ..EvalConfig::default() };
        let specs = eval.episode_specs(ObjectSet::Library, &HashSet::new());
        let held: HashSet<_> = crate::sim::object::split_objects(Split::HeldOut).into_iter().collect();
        for round in specs.chunks(eval.tasks.len()) {
            assert!(round.iter().all(|s| s.objects == round[0].objects), "one environment per round of tasks");
            assert_eq!(round[0].objects.iter().copied().collect::<HashSet<_>>(), held);
        }
        assert!(specs[0].objects != specs[16].objects || specs[16].objects != specs[32].objects);
        let base = eval.episode_specs(ObjectSet::Base, &HashSet::new());
        assert!(base.iter().all(|s| s.objects == crate::sim::object::Object::ALL));
        assert_eq!(base[5].agent_seed, specs[5].agent_seed, "the same layout seeds");
    }

    #[test]
    fn the_window_may_not_reach_untrained_positions() {
        let model = ModelConfig::default();
        let world = WorldConfig::default();
        assert!(EvalConfig::default().check_policy(&model, &world).is_ok());
        let six = EvalConfig { history_frames: 6, ..EvalConfig::default() };
        assert!(six.check_policy(&model, &world).is_ok(), "positions 0..5 are trained with 7-frame windows");
        let seven = EvalConfig { history_frames: 7, ..EvalConfig::default() };
        let err = seven.check_policy(&model, &world).unwrap_err().to_string();
        assert!(err.contains("eval.history_frames = 7") && err.contains("agent_frames"), "{err}");
        let turning = WorldConfig { agent_yaw: GripperYaw::ObjectYaw, ..WorldConfig::default() };
        let err = EvalConfig::default().check_policy(&model, &turning).unwrap_err().to_string();
        assert!(err.contains("eval.fixed_rotation"), "{err}");
    }

    #[test]
    fn scripted_control_needs_a_pose_head() {
        let scripted = EvalConfig { control: Control::ScriptedPoses, ..EvalConfig::default() };
        let world = WorldConfig::default();
        let err = scripted.check_policy(&ModelConfig::default(), &world).unwrap_err().to_string();
        assert!(err.contains("eval.control = \"scripted_poses\"") && err.contains("transformer"), "{err}");
        let daml =
            ModelConfig { architecture: crate::model::config::Architecture::named("daml"), ..Default::default() };
        assert!(scripted.check_policy(&daml, &world).is_ok());
    }
}
