//! How fast the training data path builds batches (sampling, JPEG decoding where frames are not held decoded,
//! augmentation, normalisation) and copies them to the training device: the supply to set beside a training
//! step's demand, batch size x steps per second.
use crate::data::augment::Augmentation;
use crate::data::loader::{AugmentAt, Batch, build_batches};
use crate::data::pairs::{PairDataset, Split};
use crate::model::config::ModelConfig;
use anyhow::{Result, bail};
use std::time::Instant;
use tch::Device;

/// Measured batch building and copying.
#[derive(Debug, Clone, PartialEq)]
pub struct LoaderRate {
    pub batch_size: usize,
    /// Batches timed (after one untimed warm-up group), a whole number of groups.
    pub batches: usize,
    /// Threads that built the batches.
    pub threads: usize,
    /// Batches built at once, in parallel (a training's `train.prefetch`).
    pub at_once: usize,
    /// Seconds spent building the timed batches on the host.
    pub build_seconds: f64,
    /// Seconds spent copying them to the device (and augmenting them there, when that is where it happens).
    pub copy_seconds: f64,
}

impl LoaderRate {
    /// Samples built per second.
    pub fn samples_per_second(&self) -> f64 {
        (self.batch_size * self.batches) as f64 / self.build_seconds
    }

    /// Samples built and copied to the device per second, one after the other on the calling thread.
    pub fn delivered_per_second(&self) -> f64 {
        (self.batch_size * self.batches) as f64 / (self.build_seconds + self.copy_seconds)
    }
}

/// Builds `batches` training batches of `batch_size` from `data` (rounded up to whole groups of `at_once` built in
/// parallel, as a training's prefetch builds them) on a pool of `threads` threads (augmented with `augment`'s
/// ranges, if given, on the host or the device as its `AugmentAt` says) and copies each to `device`, timing the
/// two apart.
pub fn measure(
    data: &PairDataset,
    model: &ModelConfig,
    (batch_size, batches): (usize, usize),
    (threads, at_once): (usize, usize),
    (augment, at): (Option<&Augmentation>, AugmentAt),
    device: Device,
) -> Result<LoaderRate> {
    if batch_size == 0 || batches == 0 || threads == 0 || at_once == 0 {
        bail!(
            "the loader benchmark needs a batch size, a number of batches, of threads and of batches at once of at \
             least 1"
        );
    }
    data.check_fits(model)?;
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build()?;
    let authors_windows = super::config::TrainConfig::default().windows();
    let (mut build_seconds, mut copy_seconds, mut timed) = (0.0, 0.0, 0);
    for group in 0..=batches.div_ceil(at_once) as u64 {
        let first = group * at_once as u64;
        let steps = first..first + at_once as u64;
        let start = Instant::now();
        let built: Vec<Batch> = pool
            .install(|| build_batches(data, Split::Train, model, batch_size, 0, steps, authors_windows, augment, at))
            .into_iter()
            .collect::<Result<_>>()?;
        let built_at = Instant::now();
        for batch in &built {
            let on_device = batch.to_device(model, data.height, data.width, device);
            if let Device::Cuda(i) = device {
                tch::Cuda::synchronize(i as i64);
            }
            drop(on_device);
        }
        if group > 0 {
            build_seconds += (built_at - start).as_secs_f64();
            copy_seconds += built_at.elapsed().as_secs_f64();
            timed += built.len();
        }
    }
    Ok(LoaderRate { batch_size, batches: timed, threads, at_once, build_seconds, copy_seconds })
}
