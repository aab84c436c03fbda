//! Batches for training, built ahead of the training step: samples are decoded and augmented in parallel (rayon)
//! on a producer thread that keeps a bounded queue of ready batches.
use super::augment::Augmentation;
use super::pairs::{PairDataset, Sample, Split, Windows};
use crate::model::config::ModelConfig;
use crate::seeds::derive_seed;
use anyhow::Result;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::thread::JoinHandle;
use tch::{Device, Tensor};

/// A batch of samples as flat host arrays.
pub struct Batch {
    pub size: usize,
    pub context: Vec<f32>,
    pub agent: Vec<f32>,
    pub actions: Vec<f32>,
    pub points: Vec<f32>,
    pub poses: Vec<f32>,
}

/// A batch on a device: `context` `[B, Tc, 3, H, W]`, `agent` `[B, Ta, 3, H, W]`, `actions` `[B, Ta - 1, 8]`,
/// `points` `[B, 2]`, `poses` `[B, 6]`.
pub struct DeviceBatch {
    pub context: Tensor,
    pub agent: Tensor,
    pub actions: Tensor,
    pub points: Tensor,
    pub poses: Tensor,
}

impl Batch {
    /// Stacks samples.
    pub fn from_samples(samples: Vec<Sample>) -> Batch {
        let mut b = Batch {
            size: samples.len(),
            context: vec![],
            agent: vec![],
            actions: vec![],
            points: vec![],
            poses: vec![],
        };
        for s in samples {
            b.context.extend(s.context);
            b.agent.extend(s.agent);
            b.actions.extend(s.actions);
            b.points.extend(s.point);
            b.poses.extend(s.poses);
        }
        b
    }

    /// Copies the batch to `device` with the shapes `model` and frames of `height x width` imply.
    pub fn to_device(&self, model: &ModelConfig, height: usize, width: usize, device: Device) -> DeviceBatch {
        let (b, h, w) = (self.size as i64, height as i64, width as i64);
        let (tc, ta) = (model.context_len() as i64, model.agent_frames as i64);
        let t = |v: &[f32], shape: &[i64]| Tensor::from_slice(v).view(shape).to_device(device);
        DeviceBatch {
            context: t(&self.context, &[b, tc, 3, h, w]),
            agent: t(&self.agent, &[b, ta, 3, h, w]),
            actions: t(&self.actions, &[b, ta - 1, 8]),
            points: t(&self.points, &[b, 2]),
            poses: t(&self.poses, &[b, 6]),
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
) -> Result<Batch> {
    let domain = match split {
        Split::Train => "train-batch",
        Split::Val => "val-batch",
    };
    let samples = (0..batch_size)
        .into_par_iter()
        .map(|i| {
            let mut rng = ChaCha8Rng::seed_from_u64(derive_seed(domain, &[seed, step, i as u64]));
            data.sample(&mut rng, split, model, windows, augment)
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(Batch::from_samples(samples))
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
    /// Augmentation ranges of training samples; none: no augmentation.
    pub augment: Option<Augmentation>,
    /// Ready batches kept queued; 0 builds each batch when it is asked for.
    pub depth: usize,
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
            for step in spec.start.. {
                let batch = build_batch(
                    &data,
                    Split::Train,
                    &spec.model,
                    spec.batch_size,
                    spec.seed,
                    step,
                    Windows::Training,
                    spec.augment.as_ref(),
                );
                if sender.send(batch).is_err() {
                    return;
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
                    Windows::Training,
                    spec.augment.as_ref(),
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
