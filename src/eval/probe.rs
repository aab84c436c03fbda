//! The open-loop probe: a trained policy's actions on held-out expert windows against the expert's, per action
//! dimension. It separates "the network predicts the wrong action" from "the closed loop goes wrong".
use super::choice::{ChoiceCounts, FirstScene};
use crate::data::loader::{AugmentAt, Batch, build_batch};
use crate::data::pairs::{FrameForm, PairDataset, Split, Windows};
use crate::model::mixture::{MixtureParams, mixture_mode, mixture_sample};
use crate::seeds::derive_seed;
use crate::sim::action::{ACTION_DIM, Action};
use crate::sim::task::{NUM_OBJECTS, Task};
use crate::train::TrainedPolicy;
use anyhow::{Result, bail};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use tch::{Device, Kind, Tensor};

/// Mean absolute errors per action dimension, in normalised units ([-1, 1] per dimension).
#[derive(Debug, Clone, PartialEq)]
pub struct ProbeReport {
    /// Windows probed and actions compared (every trained position of each window).
    pub windows: usize,
    pub actions: usize,
    /// The most probable component's mean against the expert's action.
    pub mode: [f64; ACTION_DIM],
    /// One sample of the mixture against the expert's action.
    pub sample: [f64; ACTION_DIM],
    /// The probed actions' own mean at each window position against each action: what ignoring the frames scores.
    pub mean_baseline: [f64; ACTION_DIM],
    /// The mode's and the mean-only errors at each window position (0: the window's first agent frame alone).
    pub by_position: Vec<PositionErrors>,
    /// For a model with `model.pose_head`: the grasp and drop positions' mean absolute errors (metres, x y z
    /// of each) predicted from each window's first agent frame, and what predicting their means scores.
    pub poses_from_first_frame: Option<([f64; 6], [f64; 6])>,
    /// For windows from each trajectory's start: which object the most likely first target heads for, and the
    /// expert's own first action counted the same way (see [`super::choice`]).
    pub first_target: Option<FirstTargets>,
    /// For windows from each trajectory's start: how the first target moves when the demonstration is swapped.
    pub swap: Option<SwapReport>,
}

/// What the first target (window position 0) follows, found by swapping each window's demonstration: for
/// another demonstration of the same task (another layout of the demonstrator's scene, the same object and
/// quadrant) a policy that reads the task should not move; for a demonstration of the next object (in slot order,
/// among those demonstrated) to the same quadrant it should turn to that object in its own scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SwapReport {
    /// Windows swapped both ways.
    pub windows: usize,
    /// Mean distance (m, in the table plane) the first target moves for another demonstration of the same task.
    pub moved_same_task: f64,
    /// Mean distance (m) it moves for a demonstration of the next object to the same quadrant.
    pub moved_other_object: f64,
    /// Mean distance (m) between the two objects in the agent's scene: how far the target should move then.
    pub objects_apart: f64,
    /// The swapped-in object's choice counts ("demonstrated" there is the swapped-in object).
    pub other_object: ChoiceCounts,
}

/// The first targets' choice of object, the policy's and the expert's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FirstTargets {
    pub policy: ChoiceCounts,
    pub expert: ChoiceCounts,
}

/// Errors at one window position, in normalised units.
#[derive(Debug, Clone, PartialEq)]
pub struct PositionErrors {
    pub mode: [f64; ACTION_DIM],
    pub mean_baseline: [f64; ACTION_DIM],
}

fn mae(pred: &Tensor, target: &Tensor) -> [f64; ACTION_DIM] {
    let e = (pred - target).abs().view([-1, ACTION_DIM as i64]).mean_dim([0i64].as_slice(), false, Kind::Double);
    std::array::from_fn(|d| e.double_value(&[d as i64]))
}

/// Probes `windows` windows of `split` placed as `placement` says (no augmentation; batches of `batch`),
/// deterministically from `seed`.
pub fn open_loop(
    policy: &TrainedPolicy,
    data: &PairDataset,
    split: Split,
    placement: Windows,
    windows: usize,
    batch: usize,
    seed: u64,
) -> Result<ProbeReport> {
    if windows == 0 || batch == 0 {
        bail!("the probe needs at least one window and a batch of at least one");
    }
    let model = policy.policy.config();
    data.check_fits(model)?;
    let device = policy.vars.device();
    let (mut preds, mut samples, mut targets) = (Vec::new(), Vec::new(), Vec::new());
    let (mut poses, mut true_poses) = (Vec::new(), Vec::new());
    let mut first = FirstTargets { policy: ChoiceCounts::default(), expert: ChoiceCounts::default() };
    let mut swap = SwapSums::default();
    let mut done = 0;
    for k in 0.. {
        if done >= windows {
            break;
        }
        let n = batch.min(windows - done);
        let host = build_batch(data, split, model, n, seed, k, placement, None, AugmentAt::Host)?;
        let b = host.to_device(model, data.height, data.width, device);
        let steps = b.actions.size()[1];
        let out = tch::no_grad(|| policy.policy.forward_with_states(&b.context, &b.agent, &b.states, false));
        let trained = MixtureParams {
            means: out.actions.means.narrow(1, 0, steps),
            log_scales: out.actions.log_scales.narrow(1, 0, steps),
            logits: out.actions.logits.narrow(1, 0, steps),
        };
        let mode = mixture_mode(&trained).to_device(Device::Cpu);
        if placement == Windows::FromStart {
            count_first_targets(data, &host.sources, &mode, &b.actions.to_device(Device::Cpu), &mut first);
            swap_demonstrations(policy, data, split, &host.sources, &mode, seed, k, &mut swap)?;
        }
        preds.push(mode);
        samples.push(mixture_sample(&trained).to_device(Device::Cpu));
        targets.push(b.actions.to_device(Device::Cpu));
        if let Some(p) = &out.poses {
            poses.push(p.select(1, 0).to_device(Device::Cpu));
            true_poses.push(b.poses.to_device(Device::Cpu));
        }
        done += n;
    }
    let (pred, sample, target) = (Tensor::cat(&preds, 0), Tensor::cat(&samples, 0), Tensor::cat(&targets, 0));
    let mean = target.mean_dim([0i64].as_slice(), true, Kind::Float).expand_as(&target);
    let by_position = (0..target.size()[1])
        .map(|i| PositionErrors {
            mode: mae(&pred.select(1, i), &target.select(1, i)),
            mean_baseline: mae(&mean.select(1, i), &target.select(1, i)),
        })
        .collect();
    let poses_from_first_frame = (!poses.is_empty()).then(|| {
        let (pred, truth) = (Tensor::cat(&poses, 0), Tensor::cat(&true_poses, 0));
        let mean = truth.mean_dim([0i64].as_slice(), true, Kind::Float).expand_as(&truth);
        (pose_mae(&pred, &truth), pose_mae(&mean, &truth))
    });
    Ok(ProbeReport {
        windows: done,
        actions: target.view([-1, ACTION_DIM as i64]).size()[0] as usize,
        mode: mae(&pred, &target),
        sample: mae(&sample, &target),
        mean_baseline: mae(&mean, &target),
        by_position,
        poses_from_first_frame,
        first_target: (placement == Windows::FromStart).then_some(first),
        swap: (placement == Windows::FromStart && swap.windows > 0).then(|| swap.report()),
    })
}

/// Running sums behind a [`SwapReport`].
#[derive(Default)]
struct SwapSums {
    windows: usize,
    same_task: f64,
    other_object: f64,
    apart: f64,
    choices: ChoiceCounts,
}

impl SwapSums {
    fn report(&self) -> SwapReport {
        let n = self.windows as f64;
        SwapReport {
            windows: self.windows,
            moved_same_task: self.same_task / n,
            moved_other_object: self.other_object / n,
            objects_apart: self.apart / n,
            other_object: self.choices,
        }
    }
}

/// Runs the windows of `sources` again with swapped demonstrations (see [`SwapReport`]) and adds how far their
/// first targets moved from `mode`'s. Windows with no other demonstration to swap in are left out.
#[allow(clippy::too_many_arguments)]
fn swap_demonstrations(
    policy: &TrainedPolicy,
    data: &PairDataset,
    split: Split,
    sources: &[[usize; 2]],
    mode: &Tensor,
    seed: u64,
    k: u64,
    sums: &mut SwapSums,
) -> Result<()> {
    let mut swaps = Vec::new();
    for (i, &[demo, agent]) in sources.iter().enumerate() {
        let task = Task::from_id(data.trajectory([demo, agent]).1.meta.task)?;
        let same: Vec<usize> = data.demos_for(split, agent, task.id()).iter().copied().filter(|&d| d != demo).collect();
        // The next object (in slot order) with demonstrations of this quadrant.
        let next = (1..NUM_OBJECTS)
            .map(|o| Task { object: (task.object + o) % NUM_OBJECTS, target: task.target })
            .find(|t| !data.demos_for(split, agent, t.id()).is_empty());
        let (Some(&same_task), Some(next)) = (same.get(i % same.len().max(1)), next) else {
            continue;
        };
        let other = data.demos_for(split, agent, next.id());
        let other_object = other[i % other.len()];
        swaps.push(Swap { window: i, agent, same_task, other_object, object: task.object, next: next.object });
    }
    if swaps.is_empty() {
        return Ok(());
    }
    let model = policy.policy.config();
    let first_targets = |demo_of: fn(&Swap) -> usize| -> Result<Tensor> {
        let samples = swaps
            .iter()
            .map(|w| {
                let mut rng = ChaCha8Rng::seed_from_u64(derive_seed("probe-swap", &[seed, k, w.window as u64]));
                data.sample_pair(
                    &mut rng,
                    [demo_of(w), w.agent],
                    model,
                    Windows::FromStart,
                    None,
                    FrameForm::Normalised,
                )
            })
            .collect::<Result<Vec<_>>>()?;
        let b = Batch::from_samples(samples, model, data.height, data.width, Device::Cpu);
        let b = b.to_device(model, data.height, data.width, policy.vars.device());
        let out = tch::no_grad(|| policy.policy.forward_with_states(&b.context, &b.agent, &b.states, false));
        let first = MixtureParams {
            means: out.actions.means.narrow(1, 0, 1),
            log_scales: out.actions.log_scales.narrow(1, 0, 1),
            logits: out.actions.logits.narrow(1, 0, 1),
        };
        Ok(mixture_mode(&first).to_device(Device::Cpu))
    };
    let (same, other) = (first_targets(|w| w.same_task)?, first_targets(|w| w.other_object)?);
    for (j, w) in swaps.iter().enumerate() {
        let own = plane(mode, w.window);
        let (demo, agent) = data.trajectory([w.other_object, w.agent]);
        let scene = FirstScene::with_object(demo, agent, w.next);
        sums.windows += 1;
        sums.same_task += distance(own, plane(&same, j));
        sums.other_object += distance(own, plane(&other, j));
        sums.apart += distance(scene.objects[w.object], scene.objects[w.next]);
        sums.choices.add(&scene, plane(&other, j));
    }
    Ok(())
}

/// One window's swapped demonstrations: another of its own task, and one of the next object to the same quadrant.
struct Swap {
    window: usize,
    agent: usize,
    same_task: usize,
    other_object: usize,
    object: usize,
    next: usize,
}

/// The first action's target (x, y) of row `i` of `actions` (`[B, T, ACTION_DIM]`, normalised).
fn plane(actions: &Tensor, i: usize) -> [f64; 2] {
    let row = Vec::<f32>::try_from(actions.get(i as i64).get(0).to_kind(Kind::Float)).expect("a float action row");
    let pos = Action::from_normalized(&row).pos();
    [pos[0], pos[1]]
}

fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// Adds each window's first target (position 0 of `mode`, and of the expert's `actions`) to the counts.
fn count_first_targets(
    data: &PairDataset,
    sources: &[[usize; 2]],
    mode: &Tensor,
    actions: &Tensor,
    counts: &mut FirstTargets,
) {
    for (i, &source) in sources.iter().enumerate() {
        let (demo, agent) = data.trajectory(source);
        let scene = FirstScene::of(demo, agent);
        counts.policy.add(&scene, plane(mode, i));
        counts.expert.add(&scene, plane(actions, i));
    }
}

fn pose_mae(pred: &Tensor, target: &Tensor) -> [f64; 6] {
    let e = (pred - target).abs().mean_dim([0i64].as_slice(), false, Kind::Double);
    std::array::from_fn(|d| e.double_value(&[d as i64]))
}
