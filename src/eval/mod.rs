//! Closed-loop evaluation on unseen task instances: per-episode staged success and its aggregates.
pub mod stats;
pub mod strip;
pub mod summary;
pub mod workers;

use crate::data::augment::AugmentDraw;
use crate::data::pairs::context_indices_fixed;
use crate::model::mixture::mixture_sample;
use crate::seeds::derive_seed;
use crate::sim::action::Action;
use crate::sim::env::WorldConfig;
use crate::sim::task::NUM_TASKS;
use crate::train::TrainedPolicy;
use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};
use std::collections::{HashSet, VecDeque};
use std::path::PathBuf;
use tch::{Device, Tensor};
use workers::{Chooser, EpisodeSpec, WorkerPool, WorkerSpec};

/// How to evaluate.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvalConfig {
    /// Episodes, spread evenly over the 16 tasks (episode i runs task i mod 16).
    pub episodes: usize,
    /// Agent actions per episode.
    pub horizon: usize,
    /// Root of the evaluation layouts and the policy's sampling.
    pub seed: u64,
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
}

impl Default for EvalConfig {
    fn default() -> Self {
        EvalConfig {
            episodes: 160,
            horizon: 60,
            seed: 0,
            batch: 32,
            demo_max_actions: 100,
            demo_attempts: 10,
            device: "auto".into(),
            strips: Vec::new(),
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
        if let Some(i) = self.strips.iter().find(|&&i| i >= self.episodes) {
            bail!("eval.strips contains episode {i}, but there are {} episodes", self.episodes);
        }
        crate::train::config::parse_device(&self.device)?;
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
                task: i % NUM_TASKS,
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

/// Runs `config.episodes` rollouts of `policy` in waves of `config.batch`, with `workers` simulation threads.
pub fn evaluate(
    policy: &EvalPolicy,
    world: &WorldConfig,
    config: &EvalConfig,
    exclude: &HashSet<u64>,
    workers: usize,
    output: &EvalOutput,
) -> Result<Vec<EpisodeResult>> {
    config.validate()?;
    let device = crate::train::config::parse_device(&config.device)?;
    if let EvalPolicy::Network(p) = policy
        && p.summary.image != world.image
    {
        bail!(
            "the policy was trained on {}x{} frames, the evaluation world renders {}x{}",
            p.summary.image.height,
            p.summary.image.width,
            world.image.height,
            world.image.width
        );
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
    let specs = config.episode_specs(exclude);
    let mut results = Vec::with_capacity(specs.len());
    for wave in specs.chunks(config.batch) {
        results.extend(run_wave(policy, &pool, wave, world, config, device, output)?);
    }
    Ok(results)
}

fn normalise(rgb: &[u8], world: &WorldConfig) -> Vec<f32> {
    let (h, w) = (world.image.height, world.image.width);
    let mut out = vec![0.0; 3 * h * w];
    AugmentDraw::identity(h, w).apply(rgb, h, w, &mut out);
    out
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
    let (h, w) = (world.image.height as i64, world.image.width as i64);
    // Network inputs: normalised context frames and the window of recent agent frames.
    let (contexts, agent_frames) = match policy {
        EvalPolicy::Network(p) => {
            let model = &p.policy.config().clone();
            let ctx: Vec<Vec<f32>> = started
                .iter()
                .map(|s| {
                    let idx = context_indices_fixed(s.demo_frames.len(), model);
                    idx.iter().flat_map(|&t| normalise(&s.demo_frames[t], world)).collect()
                })
                .collect();
            (ctx, model.agent_frames)
        }
        _ => (Vec::new(), 1),
    };
    let mut windows: Vec<VecDeque<Vec<f32>>> = match policy {
        EvalPolicy::Network(_) => started.iter().map(|s| VecDeque::from([normalise(&s.frame, world)])).collect(),
        _ => vec![VecDeque::new(); n],
    };
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
                let actions = network_actions(p, &active, &contexts, &windows, (h, w), device);
                for (&j, a) in active.iter().zip(actions) {
                    commands[j] = Some(Some(a));
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
            if let EvalPolicy::Network(_) = policy {
                windows[j].push_back(normalise(&s.frame, world));
                if windows[j].len() > agent_frames {
                    windows[j].pop_front();
                }
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

/// One batched forward pass: a sampled action for each active episode.
fn network_actions(
    p: &TrainedPolicy,
    active: &[usize],
    contexts: &[Vec<f32>],
    windows: &[VecDeque<Vec<f32>>],
    (h, w): (i64, i64),
    device: Device,
) -> Vec<Action> {
    let b = active.len() as i64;
    let tc = p.policy.config().context_len() as i64;
    let ta = windows[active[0]].len() as i64;
    let ctx: Vec<f32> = active.iter().flat_map(|&j| contexts[j].iter().copied()).collect();
    let agent: Vec<f32> = active.iter().flat_map(|&j| windows[j].iter().flatten().copied()).collect();
    let ctx = Tensor::from_slice(&ctx).view([b, tc, 3, h, w]).to_device(device);
    let agent = Tensor::from_slice(&agent).view([b, ta, 3, h, w]).to_device(device);
    let sample = tch::no_grad(|| {
        let out = p.policy.forward_t(&ctx, &agent, false);
        let last = |t: &Tensor| t.select(1, ta - 1);
        let params = crate::model::mixture::MixtureParams {
            means: last(&out.actions.means),
            log_scales: last(&out.actions.log_scales),
            logits: last(&out.actions.logits),
        };
        mixture_sample(&params).to_device(Device::Cpu)
    });
    let values: Vec<f32> = Vec::try_from(sample.flatten(0, -1)).expect("float samples");
    values.chunks(crate::sim::action::ACTION_DIM).map(Action::from_normalized).collect()
}
