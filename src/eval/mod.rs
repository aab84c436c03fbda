//! Closed-loop evaluation on unseen task instances: per-episode staged success and its aggregates.
//!
//! The protocol follows the authors' `test_transformers.py`: episode i runs task i mod 16 (of the evaluated
//! tasks) on a fresh layout, with a fresh demonstration by the Sawyer's expert on another layout; the network sees
//! context frames drawn like in training and its own recent frames (see [`history`]), and its action at the
//! window's last position is sampled; the rotation is replaced by the agent's fixed orientation and the gripper
//! binarised.
pub mod history;
pub mod probe;
pub mod stats;
pub mod strip;
pub mod summary;
pub mod workers;

use crate::data::augment::AugmentDraw;
use crate::data::manifest::Manifest;
use crate::data::pairs::context_indices;
use crate::data::trajectory::jpeg_round_trip;
use crate::model::config::ModelConfig;
use crate::model::mixture::{MixtureParams, mixture_mode, mixture_sample};
use crate::seeds::derive_seed;
use crate::sim::action::{ACTION_DIM, Action};
use crate::sim::env::{GripperYaw, WorldConfig};
use crate::sim::task::{NUM_TASKS, Task};
use crate::train::TrainedPolicy;
use anyhow::{Context, Result, bail};
use history::{AgentHistory, HistoryMode};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::collections::HashSet;
use std::path::PathBuf;
use tch::{Device, Tensor};
use workers::{Chooser, EpisodeSpec, WorkerPool, WorkerSpec};

/// Which action the network's distribution yields at each step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum ActionChoice {
    /// A sample (the authors').
    #[default]
    Sample,
    /// The mean of the most probable mixture component: no sampling noise, which matters while the learned
    /// scales are still wide (short training runs).
    Mode,
}

/// How to evaluate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
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
    /// How the agent's recent frames are kept (the authors clear them once `history_frames` are held).
    pub history: HistoryMode,
    /// Most agent frames the network sees; at most `model.agent_frames - 1`, the window positions that
    /// behaviour cloning trains.
    pub history_frames: usize,
    /// Sampled or most likely actions.
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
            history: HistoryMode::Reset,
            history_frames: 5,
            action: ActionChoice::Sample,
            fixed_rotation: true,
            binarize_gripper: true,
            checkpoints: Vec::new(),
        }
    }
}

impl EvalConfig {
    /// Checks ranges; errors name the key.
    pub fn validate(&self) -> Result<()> {
        if self.episodes == 0 || self.horizon == 0 || self.batch == 0 {
            bail!("eval.episodes, eval.horizon and eval.batch must be at least 1");
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
        crate::train::config::parse_device(&self.device)?;
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
        if self.fixed_rotation && world.agent_yaw != GripperYaw::Fixed {
            bail!(
                "eval.fixed_rotation = true needs world.agent_yaw = \"fixed\" (the agent's expert turns its gripper)"
            );
        }
        Ok(())
    }

    /// The episodes: tasks in rotation, layouts from the `eval` seed domain, none in `exclude` (training seeds).
    pub fn episode_specs(&self, exclude: &HashSet<u64>) -> Vec<EpisodeSpec> {
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
            })
            .collect()
    }
}

/// The policy being evaluated.
pub enum EvalPolicy<'a> {
    Network(&'a TrainedPolicy),
    Expert,
    Random,
}

impl EvalPolicy<'_> {
    /// A short name for reports.
    pub fn name(&self) -> &'static str {
        match self {
            EvalPolicy::Network(_) => "network",
            EvalPolicy::Expert => "expert",
            EvalPolicy::Random => "random",
        }
    }
}

/// One episode's outcome.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeResult {
    pub index: usize,
    pub task: usize,
    pub agent_seed: u64,
    pub demo_seed: u64,
    pub reached: bool,
    pub picked: bool,
    pub placed: bool,
    /// Actions taken (the episode stops once placed).
    pub steps: usize,
    /// First step after which each stage held.
    pub first_reached: Option<usize>,
    pub first_picked: Option<usize>,
    pub first_placed: Option<usize>,
}

/// Where strips go, if any are asked for.
pub struct EvalOutput {
    pub strips_dir: Option<PathBuf>,
}

/// Runs `config.episodes` rollouts of `policy` on fresh layouts (none in `exclude`), in waves of `config.batch`,
/// with `workers` simulation threads.
pub fn evaluate(
    policy: &EvalPolicy,
    world: &WorldConfig,
    config: &EvalConfig,
    exclude: &HashSet<u64>,
    workers: usize,
    output: &EvalOutput,
) -> Result<Vec<EpisodeResult>> {
    config.validate()?;
    evaluate_episodes(policy, world, config, &config.episode_specs(exclude), workers, output)
}

/// Episodes on the layouts of a demonstrator and an agent collection: each agent trajectory's own layout,
/// demonstrated on the layout of the demonstrator trajectory of the same task and slot (the training pairs an
/// overfitted policy reproduces).
pub fn training_layouts(demos: &Manifest, agents: &Manifest) -> Vec<EpisodeSpec> {
    agents
        .trajectories
        .iter()
        .filter_map(|a| {
            let d = demos.trajectories.iter().find(|d| d.task == a.task && d.index == a.index)?;
            Some((a.task, a.instance_seed, d.instance_seed))
        })
        .enumerate()
        .map(|(index, (task, agent_seed, demo_seed))| EpisodeSpec { index, task, agent_seed, demo_seed })
        .collect()
}

/// Runs the episodes `specs` of `policy` in waves of `config.batch`, with `workers` simulation threads.
pub fn evaluate_episodes(
    policy: &EvalPolicy,
    world: &WorldConfig,
    config: &EvalConfig,
    specs: &[EpisodeSpec],
    workers: usize,
    output: &EvalOutput,
) -> Result<Vec<EpisodeResult>> {
    config.validate()?;
    let device = crate::train::config::parse_device(&config.device)?;
    if let EvalPolicy::Network(p) = policy {
        let differences = world_differences(&p.summary.world, world);
        if !differences.is_empty() {
            bail!("the policy was trained in another world than the evaluation's: {}", differences.join("; "));
        }
        config.check_policy(p.policy.config(), world)?;
    }
    tch::manual_seed(derive_seed("eval-sampling", &[config.seed]) as i64);
    let chooser = match policy {
        EvalPolicy::Network(_) => Chooser::Central,
        EvalPolicy::Expert => Chooser::Expert,
        EvalPolicy::Random => Chooser::Random,
    };
    let spec = WorkerSpec {
        world: world.clone(),
        chooser,
        demo_max_actions: config.demo_max_actions,
        demo_attempts: config.demo_attempts,
        seed: config.seed,
    };
    let pool = WorkerPool::new(workers.clamp(1, config.batch), &spec)?;
    let mut results = Vec::with_capacity(specs.len());
    for wave in specs.chunks(config.batch) {
        results.extend(run_wave(policy, &pool, wave, world, config, device, output)?);
    }
    Ok(results)
}

/// `world.key: trained vs evaluated` for every setting in which `trained` and `evaluated` differ.
pub fn world_differences(trained: &WorldConfig, evaluated: &WorldConfig) -> Vec<String> {
    let (a, b) = (serde_json::to_value(trained), serde_json::to_value(evaluated));
    let (Ok(serde_json::Value::Object(a)), Ok(serde_json::Value::Object(b))) = (a, b) else {
        return vec!["the worlds do not serialise".into()];
    };
    a.iter()
        .filter(|(k, v)| b.get(*k) != Some(v))
        .map(|(k, v)| format!("world.{k}: trained {v}, evaluated {}", b.get(k).cloned().unwrap_or_default()))
        .collect()
}

/// A frame as the network sees it during evaluation: through the JPEG encoding of the training data, then
/// normalised, exactly as training reads a stored frame.
pub fn network_frame(rgb: &[u8], world: &WorldConfig, jpeg_quality: u8) -> Result<Vec<f32>> {
    let (h, w) = (world.image.height, world.image.width);
    let decoded = jpeg_round_trip(rgb, h, w, jpeg_quality)?;
    let mut out = vec![0.0; 3 * h * w];
    AugmentDraw::identity(h, w).apply(&decoded, h, w, &mut out);
    Ok(out)
}

/// Turns the network's normalised action into the command sent at `step`: the rotation replaced by the agent's
/// fixed orientation and the gripper binarised, where the configuration says so.
fn command(normalised: &[f32], step: usize, config: &EvalConfig, rest: (f64, [f64; 3])) -> Action {
    let mut a = Action::from_normalized(normalised);
    if config.fixed_rotation {
        let (angle, axis) = rest;
        a.0[3..7].copy_from_slice(&[angle, axis[0], axis[1], axis[2]]);
    }
    if config.binarize_gripper {
        a.0[ACTION_DIM - 1] = if a.0[ACTION_DIM - 1] > 0.0 && step + 1 < config.horizon { 1.0 } else { -1.0 };
    }
    a
}

/// What the network needs of one episode: its context frames and the window of its own recent frames.
struct NetworkInputs {
    context: Vec<f32>,
    history: AgentHistory<Vec<f32>>,
}

/// Runs one lockstep wave of episodes.
fn run_wave(
    policy: &EvalPolicy,
    pool: &WorkerPool,
    wave: &[EpisodeSpec],
    world: &WorldConfig,
    config: &EvalConfig,
    device: Device,
    output: &EvalOutput,
) -> Result<Vec<EpisodeResult>> {
    let started = pool.start(wave)?;
    let n = wave.len();
    let mut inputs: Vec<NetworkInputs> = Vec::new();
    if let EvalPolicy::Network(p) = policy {
        let q = p.summary.jpeg_quality;
        for (e, s) in wave.iter().zip(&started) {
            let mut rng = ChaCha8Rng::seed_from_u64(derive_seed("eval-context", &[config.seed, e.index as u64]));
            let mut context = Vec::new();
            for t in context_indices(&mut rng, s.demo_frames.len(), p.policy.config()) {
                context.extend(network_frame(&s.demo_frames[t], world, q)?);
            }
            let mut history = AgentHistory::new(config.history, config.history_frames);
            history.push(network_frame(&s.frame, world, q)?);
            inputs.push(NetworkInputs { context, history });
        }
    }
    let strip_wanted: Vec<bool> = wave.iter().map(|e| config.strips.contains(&e.index)).collect();
    let mut strip_frames: Vec<Vec<Vec<u8>>> = started
        .iter()
        .zip(&strip_wanted)
        .map(|(s, &want)| if want { vec![s.frame.clone()] } else { Vec::new() })
        .collect();
    let mut results: Vec<EpisodeResult> = wave
        .iter()
        .zip(&started)
        .map(|(e, s)| EpisodeResult {
            index: e.index,
            task: e.task,
            agent_seed: e.agent_seed,
            demo_seed: s.demo_seed,
            reached: false,
            picked: false,
            placed: false,
            steps: 0,
            first_reached: None,
            first_picked: None,
            first_placed: None,
        })
        .collect();

    for t in 0..config.horizon {
        let active: Vec<usize> = (0..n).filter(|&j| !results[j].placed).collect();
        if active.is_empty() {
            break;
        }
        let mut commands: Vec<Option<Option<Action>>> = vec![None; n];
        match policy {
            EvalPolicy::Network(p) => {
                let sampled = network_actions(p, &active, &inputs, world, config.action, device)?;
                for (&j, a) in active.iter().zip(sampled.chunks(ACTION_DIM)) {
                    commands[j] = Some(Some(command(a, t, config, started[j].rest_orientation)));
                }
            }
            _ => active.iter().for_each(|&j| commands[j] = Some(None)),
        }
        let stepped = pool.step(&commands)?;
        for &j in &active {
            let s = &stepped[j];
            let r = &mut results[j];
            r.steps = t + 1;
            let hit = |flag: bool, first: &mut Option<usize>| {
                if flag && first.is_none() {
                    *first = Some(t + 1);
                }
            };
            hit(s.stages.reached, &mut r.first_reached);
            hit(s.stages.picked, &mut r.first_picked);
            hit(s.stages.placed, &mut r.first_placed);
            (r.reached, r.picked, r.placed) = (s.stages.reached, s.stages.picked, s.stages.placed);
            if let EvalPolicy::Network(p) = policy {
                inputs[j].history.push(network_frame(&s.frame, world, p.summary.jpeg_quality)?);
            }
            if strip_wanted[j] {
                strip_frames[j].push(s.frame.clone());
            }
        }
    }
    if let Some(dir) = &output.strips_dir {
        for j in (0..n).filter(|&j| strip_wanted[j]) {
            let path = dir.join(format!("episode_{:04}_task{:02}.png", wave[j].index, wave[j].task));
            strip::write_strip(&path, &started[j].demo_frames, &strip_frames[j], world.image, &results[j])
                .with_context(|| format!("writing strip {}", path.display()))?;
        }
    }
    Ok(results)
}

/// One batched forward pass: a normalised action (8 values) for each active episode, read at the last position of
/// its window.
fn network_actions(
    p: &TrainedPolicy,
    active: &[usize],
    inputs: &[NetworkInputs],
    world: &WorldConfig,
    choice: ActionChoice,
    device: Device,
) -> Result<Vec<f32>> {
    let (h, w) = (world.image.height as i64, world.image.width as i64);
    let b = active.len() as i64;
    let tc = p.policy.config().context_len() as i64;
    let ta = inputs[active[0]].history.len() as i64;
    let ctx: Vec<f32> = active.iter().flat_map(|&j| inputs[j].context.iter().copied()).collect();
    let agent: Vec<f32> = active.iter().flat_map(|&j| inputs[j].history.frames().flatten().copied()).collect();
    let ctx = Tensor::from_slice(&ctx).view([b, tc, 3, h, w]).to_device(device);
    let agent = Tensor::from_slice(&agent).view([b, ta, 3, h, w]).to_device(device);
    let sample = tch::no_grad(|| {
        let out = p.policy.forward_t(&ctx, &agent, false);
        let last = |t: &Tensor| t.select(1, ta - 1);
        let params = MixtureParams {
            means: last(&out.actions.means),
            log_scales: last(&out.actions.log_scales),
            logits: last(&out.actions.logits),
        };
        match choice {
            ActionChoice::Sample => mixture_sample(&params),
            ActionChoice::Mode => mixture_mode(&params),
        }
        .to_device(Device::Cpu)
    });
    Ok(Vec::try_from(sample.flatten(0, -1))?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn commands_take_the_fixed_rotation_and_a_binary_gripper_opened_at_the_end() {
        let config = EvalConfig { horizon: 10, ..EvalConfig::default() };
        let rest = (1.0, [0.0, 1.0, 0.0]);
        let wild = [0.1f32, -0.2, 0.3, -0.9, 0.7, -0.6, 0.5, 0.2];
        let a = command(&wild, 3, &config, rest);
        assert_eq!(&a.0[3..7], &[1.0, 0.0, 1.0, 0.0]);
        assert_eq!(a.gripper(), 1.0, "a positive command closes");
        assert_eq!(command(&wild, 9, &config, rest).gripper(), -1.0, "the last step opens");
        let open = [0.0f32, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -0.01];
        assert_eq!(command(&open, 0, &config, rest).gripper(), -1.0);
        let raw = EvalConfig { fixed_rotation: false, binarize_gripper: false, ..config };
        let b = command(&wild, 9, &raw, rest);
        assert_eq!(b, Action::from_normalized(&wild), "both switches off: the network's action as it is");
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
    fn world_differences_name_each_setting() {
        let a = WorldConfig::default();
        let b = WorldConfig { policy_hz: 20.0, agent_yaw: GripperYaw::ObjectYaw, ..a.clone() };
        let d = world_differences(&a, &b);
        assert_eq!(d.len(), 2, "{d:?}");
        assert!(d.iter().any(|s| s.starts_with("world.policy_hz: trained 10.0, evaluated 20.0")), "{d:?}");
        assert!(world_differences(&a, &a).is_empty());
    }
}
