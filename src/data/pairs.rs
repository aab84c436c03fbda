//! Training pairs: a demonstrator video and an agent trajectory of the same task, in the same split (and in the
//! multi-object world, of the same environment: a task names an object slot, which only an environment fills).
//! A sample is the video's context frames, a window of agent frames, its actions and the point target.
use super::augment::{AugmentDraw, Augmentation};
use super::collect_config::CollectConfig;
use super::manifest::{Manifest, ManifestEntry};
use super::trajectory::Trajectory;
use crate::model::config::{ContextMode, ModelConfig};
use crate::sim::action::Action;
use crate::sim::env::WorldConfig;
use crate::sim::robot::Robot;
use crate::sim::task::NUM_TASKS;
use anyhow::{Context, Result, bail};
use rand::Rng;
use rayon::prelude::*;
use std::path::Path;

/// Probability that a training window is forced to the start of its trajectory, and (separately) to its end: the
/// authors' 0.2 each (`train.window_start` changes the first).
pub const AUTHORS_WINDOW_END: f64 = 0.2;

/// Training or validation trajectories.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Split {
    Train,
    Val,
}

/// Demonstrator and agent trajectories, split by layout and grouped by what a pair must share ([`pair_group`]).
pub struct PairDataset {
    demos: Vec<Trajectory>,
    agents: Vec<Trajectory>,
    /// Decoded RGB frames `[demos, agents][trajectory][step]` of the trajectories the frame budget holds
    /// ([`super::frame_cache`]); the others decode their JPEG on every use.
    decoded: [Vec<Option<Vec<Vec<u8>>>>; 2],
    /// `[split][group]` -> indices into `demos` / `agents`.
    demo_index: [Vec<Vec<usize>>; 2],
    agent_index: [Vec<Vec<usize>>; 2],
    /// The world both collections were recorded in, and the JPEG quality of their frames.
    pub world: WorldConfig,
    pub jpeg_quality: u8,
    pub height: usize,
    pub width: usize,
}

/// Loads the trajectories of a collection folder (checking digests) in parallel: every one, or the first
/// `per_task` slots of each task (the manifest then reads as a collection of that size).
fn load_collection(dir: &Path, robot: Robot, per_task: Option<usize>) -> Result<(Manifest, Vec<Trajectory>)> {
    let mut manifest = Manifest::load(dir)?;
    if manifest.config.robot != robot {
        bail!("{} holds {} trajectories, expected {robot}", dir.display(), manifest.config.robot);
    }
    if let Some(n) = per_task {
        if n > manifest.config.per_task {
            bail!(
                "{} holds {} trajectories per task, fewer than the {n} asked for",
                dir.display(),
                manifest.config.per_task
            );
        }
        manifest.trajectories.retain(|e| e.index < n);
        // The environment pool stays the whole collection's, whose size the default derives from `per_task` (in
        // the multi-object world the first `n` slots are whole environments' and the pool shrinks with them).
        if !manifest.config.library() {
            manifest.config.settings.layout_pool = manifest.config.pool_size();
        }
        manifest.config.per_task = n;
    }
    let trajs = manifest
        .trajectories
        .par_iter()
        .map(|e| {
            let bytes = e.read_verified(dir)?;
            Trajectory::from_bytes(&bytes).with_context(|| format!("parsing {}", dir.join(&e.file).display()))
        })
        .collect::<Result<Vec<_>>>()?;
    Ok((manifest, trajs))
}

/// Split of a trajectory, by layout: where layouts are shared, the environments in the last `val_fraction` of the
/// pool (at least one) validate, so no validation layout is trained on under another task; where each slot has
/// its own layout, the last `val_fraction` of each task's `per_task` slots (at least one).
pub fn split_of(entry: &ManifestEntry, config: &CollectConfig, val_fraction: f64) -> Split {
    let last = |n: usize| ((n as f64 * val_fraction).round() as usize).max(1);
    let (position, count) = match (entry.environment, config.pool_size()) {
        (Some(env), Some(pool)) => (env as usize, pool),
        _ => (entry.index, config.per_task),
    };
    if position + last(count) >= count { Split::Val } else { Split::Train }
}

/// What a demonstration and an agent trajectory paired for training share: their task, and in the multi-object
/// world their environment too (as `environment * 16 + task`).
pub fn pair_group(entry: &ManifestEntry, config: &CollectConfig) -> usize {
    match entry.environment {
        Some(env) if config.library() => env as usize * NUM_TASKS + entry.task,
        _ => entry.task,
    }
}

impl PairDataset {
    /// Opens a demonstrator collection and an agent collection, all of each or the first `per_task` slots of each
    /// task; `val_fraction` of each task's slots validate.
    pub fn open(demo_dir: &Path, agent_dir: &Path, val_fraction: f64, per_task: Option<usize>) -> Result<PairDataset> {
        let (dm, demos) = load_collection(demo_dir, Robot::Sawyer, per_task)?;
        let (am, agents) = load_collection(agent_dir, Robot::Panda, per_task)?;
        let (di, ai) = (dm.config.world.image, am.config.world.image);
        if di != ai {
            bail!("frame sizes differ: demonstrator {}x{}, agent {}x{}", di.height, di.width, ai.height, ai.width);
        }
        if dm.config.world != am.config.world {
            bail!(
                "{} and {} were collected in different worlds ({:?} vs {:?})",
                demo_dir.display(),
                agent_dir.display(),
                dm.config.world,
                am.config.world
            );
        }
        if dm.config.settings.jpeg_quality != am.config.settings.jpeg_quality {
            bail!(
                "{} and {} store frames at different JPEG qualities ({} vs {})",
                demo_dir.display(),
                agent_dir.display(),
                dm.config.settings.jpeg_quality,
                am.config.settings.jpeg_quality
            );
        }
        for (m, who) in [(&dm, "demonstrator"), (&am, "agent")] {
            if m.config.per_task < 2 {
                bail!("the {who} collection has {} trajectory per task; a train/val split needs 2", m.config.per_task);
            }
        }
        let (ds, a_s) = (&dm.config.settings, &am.config.settings);
        if dm.config.library() && (ds.seed, ds.environment_instances) != (a_s.seed, a_s.environment_instances) {
            bail!(
                "{} and {} group their slots into different environments (collect.seed {} vs {}, \
                 collect.environment_instances {} vs {}): their tasks name different objects",
                demo_dir.display(),
                agent_dir.display(),
                ds.seed,
                a_s.seed,
                ds.environment_instances,
                a_s.environment_instances
            );
        }
        let index = |m: &Manifest| -> [Vec<Vec<usize>>; 2] {
            let groups = m.trajectories.iter().map(|e| pair_group(e, &m.config) + 1).max().unwrap_or(0);
            let mut idx = [vec![Vec::new(); groups.max(NUM_TASKS)], vec![Vec::new(); groups.max(NUM_TASKS)]];
            for (k, e) in m.trajectories.iter().enumerate() {
                let s = split_of(e, &m.config, val_fraction) as usize;
                idx[s][pair_group(e, &m.config)].push(k);
            }
            idx
        };
        let (demo_index, agent_index) = (index(&dm), index(&am));
        for (split, name) in [(Split::Train, "training"), (Split::Val, "validation")] {
            if agent_index[split as usize].iter().all(Vec::is_empty) {
                bail!(
                    "{}: no {name} trajectory (train.val_fraction = {val_fraction}, layout pool {:?}): a split \
                     by layout needs a larger collection or collect.layout_pool",
                    agent_dir.display(),
                    am.config.pool_size()
                );
            }
        }
        for s in 0..2 {
            let groups = demo_index[s].len().max(agent_index[s].len());
            for g in 0..groups {
                let has = |index: &[Vec<usize>]| index.get(g).is_some_and(|list| !list.is_empty());
                if has(&demo_index[s]) != has(&agent_index[s]) {
                    let t = g % NUM_TASKS;
                    match dm.config.library() {
                        true => bail!(
                            "task {t} of environment {} has trajectories for only one of the two robots",
                            g / NUM_TASKS
                        ),
                        false => bail!("task {t} has trajectories for only one of the two robots"),
                    }
                }
            }
        }
        let mut data = PairDataset {
            decoded: [vec![None; demos.len()], vec![None; agents.len()]],
            demos,
            agents,
            demo_index,
            agent_index,
            world: dm.config.world.clone(),
            jpeg_quality: dm.config.settings.jpeg_quality,
            height: di.height,
            width: di.width,
        };
        data.hold_decoded(super::frame_cache::budget()?)?;
        Ok(data)
    }

    /// The demonstration and the agent trajectory a sample was drawn from ([`Sample::source`]).
    pub fn trajectory(&self, source: [usize; 2]) -> (&Trajectory, &Trajectory) {
        (&self.demos[source[0]], &self.agents[source[1]])
    }

    /// Agent trajectory `k` of the collection.
    pub fn agent(&self, k: usize) -> &Trajectory {
        &self.agents[k]
    }

    /// Holds decoded the frames of as many whole trajectories as fit in `budget` bytes, the agent's first (a
    /// sample shows more agent frames than demonstrator frames), and drops the rest: those decode their JPEG on
    /// every use. A budget of 0 decodes every frame on use.
    pub fn hold_decoded(&mut self, budget: usize) -> Result<()> {
        let frame_bytes = 3 * self.height * self.width;
        let mut left = budget;
        let mut chosen: [Vec<bool>; 2] = [vec![false; self.demos.len()], vec![false; self.agents.len()]];
        for robot in [1, 0] {
            for (k, t) in [&self.demos, &self.agents][robot].iter().enumerate() {
                let bytes = t.len() * frame_bytes;
                if bytes <= left {
                    left -= bytes;
                    chosen[robot][k] = true;
                }
            }
        }
        for robot in [0, 1] {
            let trajs = [&self.demos, &self.agents][robot];
            self.decoded[robot] = trajs
                .par_iter()
                .zip(&chosen[robot])
                .map(|(t, &keep)| keep.then(|| (0..t.len()).map(|k| t.frame_rgb(k)).collect()).transpose())
                .collect::<Result<_>>()?;
        }
        Ok(())
    }

    /// Frames held decoded, and frames in all.
    pub fn frames_held(&self) -> (usize, usize) {
        let held = self.decoded.iter().flatten().flatten().map(Vec::len).sum();
        (held, self.demos.iter().chain(&self.agents).map(Trajectory::len).sum())
    }

    /// RGB frame `t` of trajectory `k` of the demonstrator (`robot` 0) or agent (1) collection.
    fn rgb(&self, robot: usize, k: usize, t: usize) -> Result<std::borrow::Cow<'_, [u8]>> {
        Ok(match &self.decoded[robot][k] {
            Some(frames) => std::borrow::Cow::Borrowed(&frames[t]),
            None => std::borrow::Cow::Owned([&self.demos, &self.agents][robot][k].frame_rgb(t)?),
        })
    }

    /// The agent trajectories of `split`, in collection order.
    pub fn agents_of(&self, split: Split) -> Vec<usize> {
        let mut all: Vec<usize> = self.agent_index[split as usize].iter().flatten().copied().collect();
        all.sort_unstable();
        all
    }

    /// Number of (demonstrator video, agent trajectory) pairs in `split`.
    pub fn pairs(&self, split: Split) -> usize {
        let s = split as usize;
        self.demo_index[s].iter().zip(&self.agent_index[s]).map(|(d, a)| d.len() * a.len()).sum()
    }

    /// The shortest trajectory of either robot.
    pub fn shortest(&self) -> usize {
        self.demos.iter().chain(&self.agents).map(Trajectory::len).min().unwrap_or(0)
    }

    /// Checks that the model's context and window fit every trajectory.
    pub fn check_fits(&self, model: &ModelConfig) -> Result<()> {
        let shortest = self.shortest();
        if model.context_len() > shortest {
            bail!(
                "model.context_frames = {} exceeds the shortest demonstrator video ({shortest} frames)",
                model.context_len()
            );
        }
        if model.agent_frames > shortest {
            bail!(
                "model.agent_frames = {} exceeds the shortest agent trajectory ({shortest} frames)",
                model.agent_frames
            );
        }
        Ok(())
    }

    /// Draws one sample of `split`: a uniformly random agent trajectory and demonstrator video of its task, its
    /// agent window placed as `windows` says, augmented within `augment` if given.
    pub fn sample<R: Rng>(
        &self,
        rng: &mut R,
        split: Split,
        model: &ModelConfig,
        windows: Windows,
        augment: Option<&Augmentation>,
        form: FrameForm,
    ) -> Result<Sample> {
        let s = split as usize;
        let groups: Vec<usize> =
            (0..self.agent_index[s].len()).filter(|&g| !self.agent_index[s][g].is_empty()).collect();
        if groups.is_empty() {
            bail!("the {split:?} split is empty");
        }
        // Uniform over agent trajectories: weight groups by their count.
        let total: usize = groups.iter().map(|&g| self.agent_index[s][g].len()).sum();
        let mut pick = rng.random_range(0..total);
        let group = *groups
            .iter()
            .find(|&&g| {
                let n = self.agent_index[s][g].len();
                if pick < n {
                    true
                } else {
                    pick -= n;
                    false
                }
            })
            .expect("pick is below the total");
        let agent_k = self.agent_index[s][group][pick];
        let demo_list = &self.demo_index[s][group];
        let demo_k = demo_list[rng.random_range(0..demo_list.len())];
        self.sample_pair(rng, [demo_k, agent_k], model, windows, augment, form)
    }

    /// The demonstrations of `split` that show task `task` in agent trajectory `agent`'s pair group (its own
    /// task, or another one for a counterfactual; in the multi-object world, within its environment).
    pub fn demos_for(&self, split: Split, agent: usize, task: usize) -> &[usize] {
        let s = split as usize;
        let Some(group) = self.agent_index[s].iter().position(|g| g.contains(&agent)) else {
            return &[];
        };
        let other = group - group % NUM_TASKS + task;
        self.demo_index[s].get(other).map_or(&[], Vec::as_slice)
    }

    /// A sample of demonstration `source[0]` and agent trajectory `source[1]` (indices as in
    /// [`Sample::source`]): its context frames, window and augmentation drawn from `rng` as [`Self::sample`]
    /// draws them.
    pub fn sample_pair<R: Rng>(
        &self,
        rng: &mut R,
        source: [usize; 2],
        model: &ModelConfig,
        windows: Windows,
        augment: Option<&Augmentation>,
        form: FrameForm,
    ) -> Result<Sample> {
        let [demo_k, agent_k] = source;
        let (demo, agent) = (&self.demos[demo_k], &self.agents[agent_k]);
        // The task the demonstration shows (a counterfactual pair's differs from the agent's).
        let task = demo.meta.task;
        let (h, w) = (self.height, self.width);
        let frame_len = 3 * h * w;
        let context_idx = context_indices(rng, demo.len(), model);
        let draw = |rng: &mut R| match augment {
            Some(a) => AugmentDraw::sample(rng, a, h, w),
            None => AugmentDraw::identity(h, w),
        };
        // Context frames share one draw; each agent frame has its own (the authors').
        let demo_draw = draw(rng);
        let context: Vec<(usize, usize, AugmentDraw)> = context_idx.iter().map(|&t| (0, t, demo_draw)).collect();
        let start = match windows {
            Windows::Training { start } => window_start(rng, agent.len(), model.agent_frames, start),
            Windows::FromStart => 0,
            Windows::At(start) => {
                if start + model.agent_frames > agent.len() {
                    bail!(
                        "a window of {} frames at frame {start} does not fit agent trajectory {agent_k} ({} frames)",
                        model.agent_frames,
                        agent.len()
                    );
                }
                start
            }
        };
        let agent_frames: Vec<(usize, usize, AugmentDraw)> =
            (0..model.agent_frames).map(|k| (1, start + k, draw(rng))).collect();
        let trajectory = [demo_k, agent_k];
        let frames = |list: &[(usize, usize, AugmentDraw)]| -> Result<FrameData> {
            Ok(match form {
                FrameForm::Normalised => {
                    let mut out = vec![0.0f32; list.len() * frame_len];
                    for (k, (robot, t, d)) in list.iter().enumerate() {
                        let rgb = self.rgb(*robot, trajectory[*robot], *t)?;
                        d.apply(&rgb, h, w, &mut out[k * frame_len..(k + 1) * frame_len]);
                    }
                    FrameData::Normalised(out)
                }
                FrameForm::Raw => {
                    let mut bytes = Vec::with_capacity(list.len() * frame_len);
                    for (robot, t, _) in list {
                        bytes.extend_from_slice(&self.rgb(*robot, trajectory[*robot], *t)?);
                    }
                    FrameData::Raw { bytes, draws: list.iter().map(|(_, _, d)| *d).collect() }
                }
            })
        };
        let (context, frames) = (frames(&context)?, frames(&agent_frames)?);
        let actions = (start..start + model.agent_frames - 1)
            .flat_map(|t| Action(agent.actions[t].map(f64::from)).normalized())
            .collect();
        let states = (start..start + model.agent_frames).flat_map(|t| agent.robot_state(t)).collect();
        let [col, row] = agent.eef_pixel[start + model.agent_frames - 1];
        let point = [2.0 * col / w as f32 - 1.0, 2.0 * row / h as f32 - 1.0];
        Ok(Sample {
            task,
            source: trajectory,
            start,
            context,
            agent: frames,
            actions,
            states,
            point,
            poses: agent.grasp_and_drop(),
        })
    }
}

/// Where a sample's agent window lies in its trajectory.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Windows {
    /// As training draws it: at the trajectory's start with probability `start`, at its end with probability
    /// 0.2, otherwise anywhere (the authors' `start` is 0.2).
    Training { start: f64 },
    /// At the trajectory's start: the approach to the object, where the action depends most on where it lies.
    FromStart,
    /// Starting at this frame (the probes'); a window that does not fit the trajectory is an error.
    At(usize),
}

/// How a sample carries its frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameForm {
    /// Augmented and normalised on the host.
    Normalised,
    /// Raw bytes with each frame's augmentation draw, for the training device to apply
    /// ([`super::device_augment`]).
    Raw,
}

/// A sample's frames of one kind (context or agent), in the form asked for.
pub enum FrameData {
    /// Planar normalised `[T, 3, H, W]`, flattened.
    Normalised(Vec<f32>),
    /// Interleaved RGB `[T, H, W, 3]`, flattened, and each frame's draw.
    Raw { bytes: Vec<u8>, draws: Vec<AugmentDraw> },
}

/// One training sample.
pub struct Sample {
    /// The task the demonstration shows.
    pub task: usize,
    /// The demonstration and the agent trajectory it was drawn from (see [`PairDataset::trajectory`]).
    pub source: [usize; 2],
    /// The agent window's first frame in its trajectory.
    pub start: usize,
    /// The demonstrator's `Tc` frames.
    pub context: FrameData,
    /// The agent's `Ta` frames.
    pub agent: FrameData,
    /// `[Ta - 1, 8]` normalised actions, flattened.
    pub actions: Vec<f32>,
    /// `[Ta, STATE_DIM]` the robot's own state at each agent frame ([`crate::sim::env::robot_state`]), flattened.
    pub states: Vec<f32>,
    /// End-effector pixel at the window's last frame, on the [-1, 1] grid (x = column, y = row).
    pub point: [f32; 2],
    /// The agent trajectory's grasp and drop positions (see [`Trajectory::grasp_and_drop`]).
    pub poses: [f32; 6],
}

/// Demonstrator frames to show for a video of `len` frames (training and evaluation alike, as the authors'
/// `select_random_frames`): in `spread` mode one frame drawn uniformly from each equal segment, first and last
/// forced; `first_last` the two ends; `final` the last frame repeated `context_frames` times.
pub fn context_indices<R: Rng>(rng: &mut R, len: usize, model: &ModelConfig) -> Vec<usize> {
    let n = model.context_frames;
    match model.context {
        ContextMode::Final => vec![len - 1; n],
        ContextMode::FirstLast => vec![0, len - 1],
        ContextMode::Spread => (0..n)
            .map(|i| match i {
                0 => 0,
                _ if i == n - 1 => len - 1,
                _ => rng.random_range(i * len / n..((i + 1) * len / n).max(i * len / n + 1)),
            })
            .collect(),
    }
}

/// First frame of an agent window of `frames` in a trajectory of `len`, forced to the start with probability
/// `start`.
fn window_start<R: Rng>(rng: &mut R, len: usize, frames: usize, start: f64) -> usize {
    let last = len - frames;
    let u: f64 = rng.random();
    if u < start {
        0
    } else if u < start + AUTHORS_WINDOW_END {
        last
    } else {
        rng.random_range(0..=last)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn training_windows_start_at_the_first_frame_as_often_as_asked() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (len, frames, n) = (60, 7, 20_000);
        for start in [0.0, AUTHORS_WINDOW_END, 0.8] {
            let draws: Vec<usize> = (0..n).map(|_| window_start(&mut rng, len, frames, start)).collect();
            let share = |at: usize| draws.iter().filter(|&&s| s == at).count() as f64 / n as f64;
            // Forced starts plus the uniform draws that land on 0 (1 in 54 of the rest).
            let uniform = (1.0 - start - AUTHORS_WINDOW_END) / (len - frames + 1) as f64;
            assert!((share(0) - start - uniform).abs() < 0.015, "start {start}: {}", share(0));
            assert!((share(len - frames) - AUTHORS_WINDOW_END - uniform).abs() < 0.015, "start {start}");
            assert!(draws.iter().all(|&s| s <= len - frames));
        }
    }

    #[test]
    fn spread_context_forces_ends_and_covers_each_segment() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let model = ModelConfig::default();
        for _ in 0..100 {
            let idx = context_indices(&mut rng, 50, &model);
            assert_eq!((idx[0], idx[3]), (0, 49));
            assert!((12..25).contains(&idx[1]) && (25..37).contains(&idx[2]), "{idx:?}");
        }
        let final_only = ModelConfig { context: ContextMode::Final, ..ModelConfig::default() };
        assert_eq!(context_indices(&mut rng, 50, &final_only), vec![49; 4], "the last frame, repeated");
    }

    #[test]
    fn validation_takes_the_last_tenth_of_slots_or_of_the_layout_pool() {
        use crate::data::collect_config::LayoutSharing;
        let mut config = CollectConfig::paper(Robot::Panda);
        config.per_task = 20;
        config.settings.layouts = LayoutSharing::Unique;
        let entry = |index: usize, environment: Option<u64>| ManifestEntry {
            objects: None,
            file: String::new(),
            task: 3,
            index,
            instance_seed: 0,
            environment,
            attempts: 1,
            steps: 0,
            bytes: 0,
            blake3: String::new(),
        };
        let val: Vec<usize> = (0..20).filter(|&i| split_of(&entry(i, None), &config, 0.1) == Split::Val).collect();
        assert_eq!(val, vec![18, 19]);
        config.per_task = 2;
        assert_eq!(split_of(&entry(1, None), &config, 0.1), Split::Val);
        assert_eq!(split_of(&entry(0, None), &config, 0.1), Split::Train);
        // Shared layouts: 20 per task of 16 tasks draw from a pool of 160 environments; the last 16 validate,
        // whatever the slot.
        config.per_task = 20;
        config.settings.layouts = LayoutSharing::Shared;
        assert_eq!(config.pool_size(), Some(160));
        assert_eq!(split_of(&entry(0, Some(144)), &config, 0.1), Split::Val);
        assert_eq!(split_of(&entry(19, Some(143)), &config, 0.1), Split::Train);
    }
}
