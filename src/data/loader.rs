//! Batches for training, built ahead of the training step: samples are decoded and augmented in parallel (rayon)
//! on a producer thread that keeps a bounded queue of ready batches.
use super::augment::{AugmentDraw, Augmentation, DRAW_LEN};
use super::device_augment::{augment_frames, bytes_to_device};
use super::pairs::{FrameData, FrameForm, PairDataset, Sample, Split, Windows};
use crate::model::batch::DeviceBatch;
use crate::model::config::ModelConfig;
use crate::seeds::derive_seed;
use crate::sim::env::STATE_DIM;
use anyhow::Result;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::thread::JoinHandle;
use tch::{Device, Tensor};

/// A batch of samples on the host.
pub struct Batch {
    pub size: usize,
    pub frames: BatchFrames,
    pub actions: Vec<f32>,
    /// The robot's own state at each agent frame `[B, Ta, STATE_DIM]`.
    pub states: Vec<f32>,
    pub points: Vec<f32>,
    pub poses: Vec<f32>,
    /// The weight of each agent frame `[B, Ta]` in the pose loss (all 1 unless [`Batch::pose_at_start_only`]).
    pub pose_weights: Vec<f32>,
    /// Each agent window's first frame in its trajectory.
    pub starts: Vec<usize>,
    /// The task each sample demonstrates.
    pub tasks: Vec<i64>,
    /// Each sample's demonstration and agent trajectory ([`Sample::source`]).
    pub sources: Vec<[usize; 2]>,
}

/// A batch's frames, in the form its samples were drawn in.
pub enum BatchFrames {
    /// Augmented and normalised planar frames `[B, T, 3, H, W]`, flattened.
    Normalised { context: Vec<f32>, agent: Vec<f32> },
    /// RGB bytes `[B, T, H, W, 3]` (pinned when bound for a GPU) and each frame's draw `[B * (Tc + Ta),
    /// DRAW_LEN]`, context frames of a sample first, for the device to augment.
    Raw { context: Tensor, agent: Tensor, draws: Tensor, jitter: bool },
}

/// Where a batch's frames are augmented and normalised.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AugmentAt {
    /// On the host, by the threads that build the batch.
    Host,
    /// On the training device; raw frames bound for `Device` are pinned when it is a GPU.
    Device(Device),
}

impl Batch {
    /// Quantises the actions to multiples of `1 / resolution`, truncating towards zero (`train.action_resolution`;
    /// 0 leaves them exact).
    pub fn quantise_actions(mut self, resolution: u32) -> Batch {
        if resolution > 0 {
            let r = resolution as f32;
            self.actions.iter_mut().for_each(|a| *a = (*a * r).trunc() / r);
        }
        self
    }

    /// Scores the pose loss at a trajectory's first frame only (`train.pose_frames = "first"`): every other
    /// agent frame gets weight 0.
    pub fn pose_at_start_only(mut self, on: bool) -> Batch {
        if on {
            let ta = self.pose_weights.len() / self.size.max(1);
            for (b, start) in self.starts.iter().enumerate() {
                for k in 0..ta {
                    self.pose_weights[b * ta + k] = if start + k == 0 { 1.0 } else { 0.0 };
                }
            }
        }
        self
    }

    /// Stacks samples (all drawn in one [`FrameForm`]); raw frames become host tensors, pinned for `pin_for` when
    /// it is a GPU.
    pub fn from_samples(
        samples: Vec<Sample>,
        model: &ModelConfig,
        height: usize,
        width: usize,
        pin_for: Device,
    ) -> Batch {
        let size = samples.len();
        let (mut actions, mut states, mut points, mut poses) = (vec![], vec![], vec![], vec![]);
        let sources = samples.iter().map(|s| s.source).collect();
        let starts = samples.iter().map(|s| s.start).collect();
        let pose_weights = vec![1.0; size * model.agent_frames];
        let tasks = samples.iter().map(|s| s.task as i64).collect();
        let (mut context, mut agent, mut bytes, mut agent_bytes, mut draws) = (vec![], vec![], vec![], vec![], vec![]);
        let mut jitter = false;
        for s in samples {
            actions.extend(s.actions);
            states.extend(s.states);
            points.extend(s.point);
            poses.extend(s.poses);
            for (frames, floats, raw) in
                [(s.context, &mut context, &mut bytes), (s.agent, &mut agent, &mut agent_bytes)]
            {
                match frames {
                    FrameData::Normalised(v) => floats.extend(v),
                    FrameData::Raw { bytes, draws: d } => {
                        raw.extend(bytes);
                        jitter |= d.iter().any(AugmentDraw::jitters);
                        draws.extend(d.iter().flat_map(AugmentDraw::row));
                    }
                }
            }
        }
        let frames = if draws.is_empty() {
            BatchFrames::Normalised { context, agent }
        } else {
            let (b, h, w) = (size as i64, height as i64, width as i64);
            let (tc, ta) = (model.context_len() as i64, model.agent_frames as i64);
            let host = |v: &[u8], t: i64| {
                let x = Tensor::from_slice(v).view([b, t, h, w, 3]);
                // `_pin_memory` is what `pin_memory` calls, without its warning (printed per batch) that
                // naming the device is deprecated: libtorch's C API always names one.
                if pin_for.is_cuda() { x.internal_pin_memory(pin_for) } else { x }
            };
            // Per sample, context draws then agent draws: reorder into all context frames, then all agent frames.
            let rows = Tensor::from_slice(&draws).view([b, tc + ta, DRAW_LEN as i64]);
            let draws = Tensor::cat(
                &[rows.narrow(1, 0, tc).reshape([b * tc, -1]), rows.narrow(1, tc, ta).reshape([b * ta, -1])],
                0,
            );
            BatchFrames::Raw { context: host(&bytes, tc), agent: host(&agent_bytes, ta), draws, jitter }
        };
        Batch { size, frames, actions, states, points, poses, pose_weights, starts, tasks, sources }
    }

    /// Copies the batch to `device` (augmenting raw frames there) with the shapes `model` and frames of
    /// `height x width` imply.
    pub fn to_device(&self, model: &ModelConfig, height: usize, width: usize, device: Device) -> DeviceBatch {
        let (b, h, w) = (self.size as i64, height as i64, width as i64);
        let (tc, ta) = (model.context_len() as i64, model.agent_frames as i64);
        let t = |v: &[f32], shape: &[i64]| Tensor::from_slice(v).view(shape).to_device(device);
        let (context, agent) = match &self.frames {
            BatchFrames::Normalised { context, agent } => (t(context, &[b, tc, 3, h, w]), t(agent, &[b, ta, 3, h, w])),
            BatchFrames::Raw { context, agent, draws, jitter } => {
                let augment = |frames: &Tensor, draws: Tensor, len: i64| {
                    let on_device = bytes_to_device(frames, device).view([b * len, h, w, 3]);
                    augment_frames(&on_device, &draws, *jitter).view([b, len, 3, h, w])
                };
                (augment(context, draws.narrow(0, 0, b * tc), tc), augment(agent, draws.narrow(0, b * tc, b * ta), ta))
            }
        };
        DeviceBatch {
            context,
            agent,
            actions: t(&self.actions, &[b, ta - 1, 8]),
            states: t(&self.states, &[b, ta, STATE_DIM as i64]),
            points: t(&self.points, &[b, 2]),
            poses: t(&self.poses, &[b, 6]),
            pose_weights: t(&self.pose_weights, &[b, ta]),
            tasks: Tensor::from_slice(&self.tasks).to_device(device),
        }
    }
}

/// Builds batch `step` of `split` deterministically from `seed` (each sample has its own derived generator), its
/// windows placed as `windows` says.
#[allow(clippy::too_many_arguments)]
pub fn build_batch(
    data: &PairDataset,
    split: Split,
    model: &ModelConfig,
    batch_size: usize,
    seed: u64,
    step: u64,
    windows: Windows,
    augment: Option<&Augmentation>,
    at: AugmentAt,
) -> Result<Batch> {
    let domain = match split {
        Split::Train => "train-batch",
        Split::Val => "val-batch",
    };
    let (form, pin_for) = match at {
        AugmentAt::Host => (FrameForm::Normalised, Device::Cpu),
        AugmentAt::Device(d) => (FrameForm::Raw, d),
    };
    let samples = (0..batch_size)
        .into_par_iter()
        .map(|i| {
            let mut rng = ChaCha8Rng::seed_from_u64(derive_seed(domain, &[seed, step, i as u64]));
            data.sample(&mut rng, split, model, windows, augment, form)
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(Batch::from_samples(samples, model, data.height, data.width, pin_for))
}

/// Builds the batches of `steps` at once, in parallel (each as [`build_batch`] builds it), in step order: what a
/// single batch leaves serial (stacking its samples, pinning them) then runs beside the other batches' work.
#[allow(clippy::too_many_arguments)]
pub fn build_batches(
    data: &PairDataset,
    split: Split,
    model: &ModelConfig,
    batch_size: usize,
    seed: u64,
    steps: std::ops::Range<u64>,
    windows: Windows,
    augment: Option<&Augmentation>,
    at: AugmentAt,
) -> Vec<Result<Batch>> {
    steps
        .into_par_iter()
        .map(|step| build_batch(data, split, model, batch_size, seed, step, windows, augment, at))
        .collect()
}

/// Training batches for steps `start..`: produced ahead on a background thread (`depth` > 0), or built when asked
/// for (`depth` = 0), which on a machine with few cores avoids batch building and the network step competing for
/// the same cores.
pub struct Prefetcher {
    source: Source,
}

enum Source {
    Inline { data: Arc<PairDataset>, spec: Box<PrefetchSpec>, next: u64 },
    Thread { receiver: Receiver<Result<Batch>>, handle: Option<JoinHandle<()>> },
}

/// What the producer thread needs.
pub struct PrefetchSpec {
    pub model: ModelConfig,
    pub batch_size: usize,
    pub seed: u64,
    pub start: u64,
    /// Where windows are drawn in their trajectories.
    pub windows: Windows,
    /// Augmentation ranges of training samples; none: no augmentation.
    pub augment: Option<Augmentation>,
    /// Ready batches kept queued, built `depth` at a time in parallel; 0 builds each batch when it is asked for.
    pub depth: usize,
    /// Where the frames are augmented.
    pub augment_at: AugmentAt,
}

impl Prefetcher {
    /// Starts producing.
    pub fn start(data: Arc<PairDataset>, spec: PrefetchSpec) -> Prefetcher {
        if spec.depth == 0 {
            let next = spec.start;
            return Prefetcher { source: Source::Inline { data, spec: Box::new(spec), next } };
        }
        let (sender, receiver): (SyncSender<Result<Batch>>, _) = sync_channel(spec.depth);
        let handle = std::thread::spawn(move || {
            let group = spec.depth as u64;
            for first in (spec.start..).step_by(spec.depth) {
                let batches = build_batches(
                    &data,
                    Split::Train,
                    &spec.model,
                    spec.batch_size,
                    spec.seed,
                    first..first + group,
                    spec.windows,
                    spec.augment.as_ref(),
                    spec.augment_at,
                );
                for batch in batches {
                    if sender.send(batch).is_err() {
                        return;
                    }
                }
            }
        });
        Prefetcher { source: Source::Thread { receiver, handle: Some(handle) } }
    }

    /// The next batch.
    pub fn next_batch(&mut self) -> Result<Batch> {
        match &mut self.source {
            Source::Inline { data, spec, next } => {
                *next += 1;
                build_batch(
                    data,
                    Split::Train,
                    &spec.model,
                    spec.batch_size,
                    spec.seed,
                    *next - 1,
                    spec.windows,
                    spec.augment.as_ref(),
                    spec.augment_at,
                )
            }
            Source::Thread { receiver, .. } => {
                receiver.recv().map_err(|_| anyhow::anyhow!("batch producer stopped"))?
            }
        }
    }
}

impl Drop for Prefetcher {
    fn drop(&mut self) {
        if let Source::Thread { receiver, handle } = &mut self.source {
            // Unblock the producer by draining once, then let it see the closed channel.
            while receiver.try_recv().is_ok() {}
            if let Some(h) = handle.take() {
                drop(std::mem::replace(receiver, sync_channel(1).1));
                let _ = h.join();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn actions_are_quantised_towards_zero_as_the_authors_record_them() {
        let batch = |actions: Vec<f32>| Batch {
            size: 1,
            frames: BatchFrames::Normalised { context: vec![], agent: vec![] },
            actions,
            states: vec![],
            points: vec![],
            poses: vec![],
            pose_weights: vec![],
            starts: vec![],
            tasks: vec![],
            sources: vec![],
        };
        let exact = vec![0.999, -0.999, 0.5, 0.0039, -0.0039, 1.0];
        let q = batch(exact.clone()).quantise_actions(128).actions;
        assert_eq!(q, [127.0 / 128.0, -127.0 / 128.0, 0.5, 0.0, 0.0, 1.0]);
        assert_eq!(batch(exact.clone()).quantise_actions(0).actions, exact);
    }

    #[test]
    fn the_pose_loss_can_be_kept_to_each_trajectorys_first_frame() {
        // Two samples of three agent frames: one window starts the trajectory, the other at its frame 3.
        let batch = || Batch {
            size: 2,
            frames: BatchFrames::Normalised { context: vec![], agent: vec![] },
            actions: vec![],
            states: vec![],
            points: vec![],
            poses: vec![],
            pose_weights: vec![1.0; 6],
            starts: vec![0, 3],
            tasks: vec![],
            sources: vec![],
        };
        assert_eq!(batch().pose_at_start_only(true).pose_weights, [1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        assert_eq!(batch().pose_at_start_only(false).pose_weights, [1.0; 6]);
    }
}
