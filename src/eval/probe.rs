//! The open-loop probe: a trained policy's actions on held-out expert windows against the expert's, per action
//! dimension. It separates "the network predicts the wrong action" from "the closed loop goes wrong".
use super::choice::{ChoiceCounts, FirstScene};
use crate::data::loader::{AugmentAt, build_batch};
use crate::data::pairs::{PairDataset, Split, Windows};
use crate::model::mixture::{MixtureParams, mixture_mode, mixture_sample};
use crate::sim::action::{ACTION_DIM, Action};
use crate::train::TrainedPolicy;
use anyhow::{Result, bail};
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
    let mut done = 0;
    for k in 0.. {
        if done >= windows {
            break;
        }
        let n = batch.min(windows - done);
        let host = build_batch(data, split, model, n, seed, k, placement, None, AugmentAt::Host)?;
        let b = host.to_device(model, data.height, data.width, device);
        let steps = b.actions.size()[1];
        let out = tch::no_grad(|| policy.policy.forward_t(&b.context, &b.agent, false));
        let trained = MixtureParams {
            means: out.actions.means.narrow(1, 0, steps),
            log_scales: out.actions.log_scales.narrow(1, 0, steps),
            logits: out.actions.logits.narrow(1, 0, steps),
        };
        let mode = mixture_mode(&trained).to_device(Device::Cpu);
        if placement == Windows::FromStart {
            count_first_targets(data, &host.sources, &mode, &b.actions.to_device(Device::Cpu), &mut first);
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
    })
}

/// Adds each window's first target (position 0 of `mode`, and of the expert's `actions`) to the counts.
fn count_first_targets(
    data: &PairDataset,
    sources: &[[usize; 2]],
    mode: &Tensor,
    actions: &Tensor,
    counts: &mut FirstTargets,
) {
    let plane = |t: &Tensor, i: usize| {
        let row = Vec::<f32>::try_from(t.get(i as i64).get(0).to_kind(Kind::Float)).expect("a float action row");
        let pos = Action::from_normalized(&row).pos();
        [pos[0], pos[1]]
    };
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
