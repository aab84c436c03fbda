//! Benchmarks that print figures: training step rate and memory beside the trunk alone, the data path's samples
//! per second, evaluation rollouts per second, and the orchestrator's overhead on a large cached grid.
use super::config::chosen_config;
use super::default_workers;
use super::options::ResolutionArgs;
use anyhow::{Context, Result, bail};
use oneshot_lab::config::Experiment;
use oneshot_lab::data::augment::Augmentation;
use oneshot_lab::data::loader::AugmentAt;
use oneshot_lab::data::pairs::PairDataset;
use oneshot_lab::device::{autotune_convolutions, parse_device};
use oneshot_lab::eval::rollout::rollouts;
use oneshot_lab::eval::run::SUMMARY_FILE;
use oneshot_lab::eval::{Actor, EvalConfig, EvalOutput};
use oneshot_lab::model::architectures::ARCHITECTURES;
use oneshot_lab::model::batch::DeviceBatch;
use oneshot_lab::model::config::{Architecture, ModelConfig};
use oneshot_lab::model::resnet::ResNet18;
use oneshot_lab::pipeline::executor::artifact_dir;
use oneshot_lab::pipeline::integrity::seal;
use oneshot_lab::pipeline::load_plan;
use oneshot_lab::pipeline::stages::{Kind as StageKind, StageOutputs};
use oneshot_lab::pipeline::store::{Claim, Store};
use oneshot_lab::sim::camera::ImageSize;
use oneshot_lab::sim::env::{STATE_DIM, WorldConfig};
use oneshot_lab::sim::task::NUM_TASKS;
use oneshot_lab::train::adam::Adam;
use oneshot_lab::train::config::{MemoryFormat, Precision, TrainConfig, check_heads, check_precision};
use oneshot_lab::train::throughput;
use oneshot_lab::train::{FINAL_INFO, FINAL_WEIGHTS, TrainSummary, build_policy, checkpoint, load_trained};
use std::collections::HashSet;
use std::path::PathBuf;
use std::time::Instant;
use tch::nn::ModuleT;
use tch::{Device, Kind, Tensor, nn};

/// Arguments of the `bench train` command.
#[derive(clap::Args)]
pub struct BenchTrainArgs {
    /// Model, frame size and batch to time (not with `--experiment`).
    #[arg(long, value_enum, default_value_t = BenchSize::Small, conflicts_with = "experiment")]
    pub config: BenchSize,
    /// Times this experiment file's configuration instead (its base, or `--cell`): its model, frame size, batch,
    /// training settings and device, with fresh weights on random frames. The data path is not timed (`bench
    /// loader` times it), on-device augmentation included.
    #[arg(long)]
    pub experiment: Option<PathBuf>,
    /// The cell of `--experiment` to time (e.g. `n1600-full-s0`).
    #[arg(long, requires = "experiment")]
    pub cell: Option<String>,
    #[command(flatten)]
    pub file_resolution: ResolutionArgs,
    /// Training steps timed (after the warm-up steps).
    #[arg(long, default_value_t = 5)]
    pub steps: usize,
    /// Untimed steps first (libtorch's first steps on a CPU run slower).
    #[arg(long, default_value_t = 3)]
    pub warmup: usize,
    /// Override the configuration's batch size.
    #[arg(long)]
    pub batch: Option<usize>,
    /// `auto` (CUDA when present), `cpu`, `cuda` or `cuda:N` (default: the experiment's `train.device`, else `auto`).
    #[arg(long)]
    pub device: Option<String>,
    /// Architectures to time, comma separated, or `all` (default: the experiment's, else the transformer).
    #[arg(long)]
    pub architectures: Option<String>,
    /// Number type of the forward pass, as `train.precision` (default: the experiment's, else fp32).
    #[arg(long, value_enum)]
    pub precision: Option<PrecisionArg>,
    /// Layout of the trunk's images, as `train.memory_format` (default: the experiment's, else contiguous).
    #[arg(long, value_enum)]
    pub memory_format: Option<MemoryFormatArg>,
}

/// A benchmark configuration: model, frame size and batch.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum BenchSize {
    /// The paper's network at 240x320, batch 30.
    Paper,
    /// The smoke experiment's network at 64x80, batch 8.
    Small,
}

/// The number type of the forward pass (`train.precision`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum PrecisionArg {
    /// Everything in fp32 (the authors').
    #[value(name = "fp32")]
    Fp32,
    /// bf16 autocast: matrix products and convolutions in bf16, weights, gradients and the optimiser in fp32.
    #[value(name = "bf16")]
    Bf16,
}

/// Layout of image tensors in the trunk (`train.memory_format`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum MemoryFormatArg {
    /// Channels before rows and columns (NCHW), PyTorch's default.
    Contiguous,
    /// Channels last (NHWC strides).
    #[value(name = "channels_last")]
    ChannelsLast,
}

/// Arguments of the `bench eval` command.
#[derive(clap::Args)]
pub struct BenchEvalArgs {
    /// Episodes per policy.
    #[arg(long, default_value_t = 16)]
    pub episodes: usize,
    /// Actions per episode.
    #[arg(long, default_value_t = 40)]
    pub horizon: usize,
    /// Simulation threads (default: CPU cores).
    #[arg(long, value_parser = super::options::at_least_one)]
    pub workers: Option<usize>,
}

/// Arguments of the `bench plan` command.
#[derive(clap::Args)]
pub struct BenchPlanArgs {
    /// Cells in the grid (stages are about twice as many).
    #[arg(long, default_value_t = 200)]
    pub cells: usize,
}

/// Arguments of the `bench loader` command.
#[derive(clap::Args)]
pub struct BenchLoaderArgs {
    /// Demonstrator collection folder.
    #[arg(long)]
    pub demos: PathBuf,
    /// Agent collection folder.
    #[arg(long)]
    pub agents: PathBuf,
    /// Samples per batch.
    #[arg(long, default_value_t = 30)]
    pub batch: usize,
    /// Batches timed (after one warm-up group), rounded up to whole groups of `--at-once`.
    #[arg(long, default_value_t = 20)]
    pub batches: usize,
    /// Threads building the batches (default: CPU cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Batches built at once, in parallel, as a training with `train.prefetch` at this value builds them.
    #[arg(long, default_value_t = 1)]
    pub at_once: usize,
    /// Build batches without augmentation.
    #[arg(long)]
    pub no_augment: bool,
    /// Decode each frame's JPEG when it is used, as a dataset too large to hold decoded does.
    #[arg(long)]
    pub decode_on_use: bool,
    /// Where batches are copied: `auto`, `cpu`, `cuda` or `cuda:N`.
    #[arg(long, default_value = "auto")]
    pub device: String,
    /// Where frames are augmented, as `train.augment_on`.
    #[arg(long, value_enum, default_value_t = AugmentOnArg::Host)]
    pub augment_on: AugmentOnArg,
}

/// Where training frames are augmented (`train.augment_on`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum AugmentOnArg {
    /// By the threads building the batch, on the host.
    Host,
    /// On the device, after the copy.
    Device,
}

/// `bench train`: a configuration's training step rate beside its trunk alone.
pub fn train(a: BenchTrainArgs) -> Result<()> {
    let resolution = a.file_resolution.resolution();
    let mut c = match &a.experiment {
        Some(file) => {
            let experiment = Experiment::load(file, &resolution)?;
            let (what, config) = chosen_config(&experiment, file, a.cell.as_deref())?;
            let whose = if a.cell.is_some() { "the cell's" } else { "the experiment's" };
            BenchConfig {
                name: format!("{}, {what}", file.display()),
                model: config.model.clone(),
                image: config.world.image,
                batch: config.train.batch_size,
                train: config.train.clone(),
                projected: (usize::try_from(config.train.steps)?, whose),
            }
        }
        None if resolution.profile.is_some() || !resolution.overrides.is_empty() => {
            bail!("--profile and --set resolve an experiment file: give it with --experiment")
        }
        None => bench_config(a.config),
    };
    c.batch = a.batch.unwrap_or(c.batch);
    let architectures: Vec<String> = match a.architectures.as_deref() {
        None => vec![c.model.architecture.0.clone()],
        Some("all") => ARCHITECTURES.iter().map(|r| r.name.to_string()).collect(),
        Some(list) => list.split(',').map(|n| n.trim().to_string()).collect(),
    };
    if let Some(unknown) = architectures.iter().find(|n| Architecture::named(n).registration().is_none()) {
        let names: Vec<&str> = ARCHITECTURES.iter().map(|r| r.name).collect();
        bail!("--architectures names `{unknown}`, which is not registered (all, {})", names.join(", "));
    }
    match a.precision {
        Some(PrecisionArg::Fp32) => c.train.precision = Precision::Fp32,
        Some(PrecisionArg::Bf16) => c.train.precision = Precision::Bf16,
        None => {}
    }
    match a.memory_format {
        Some(MemoryFormatArg::Contiguous) => c.train.memory_format = MemoryFormat::Contiguous,
        Some(MemoryFormatArg::ChannelsLast) => c.train.memory_format = MemoryFormat::ChannelsLast,
        None => {}
    }
    if let Some(device) = a.device {
        c.train.device = device;
    }
    let timing = Timing { warmup: a.warmup, steps: a.steps.max(1) };
    bench_train(&c, timing, &architectures)
}

/// `bench eval`: rollouts per second of a small network and of the random policy.
pub fn eval(a: BenchEvalArgs) -> Result<()> {
    bench_eval(a.episodes.max(1), a.horizon.max(1), a.workers.unwrap_or_else(default_workers))
}

/// `bench plan`: the orchestrator's overhead on a large cached grid.
pub fn plan(a: BenchPlanArgs) -> Result<()> {
    bench_plan(a.cells.max(1))
}

/// `bench loader`: training samples/s the data path builds from two collections and copies to the device.
pub fn loader(a: BenchLoaderArgs) -> Result<()> {
    let device = parse_device(&a.device)?;
    let threads = a.threads.unwrap_or_else(default_workers);
    let opened = Instant::now();
    let mut data = PairDataset::open(&a.demos, &a.agents, TrainConfig::default().val_fraction, None)?;
    let open_seconds = opened.elapsed().as_secs_f64();
    if a.decode_on_use {
        data.hold_decoded(0)?;
    }
    let (held, frames_in_all) = data.frames_held();
    let model = ModelConfig::default();
    let augmentation = Augmentation::default();
    let augment = (!a.no_augment).then_some(&augmentation);
    let (at, place) = match a.augment_on {
        AugmentOnArg::Host => (AugmentAt::Host, "host"),
        AugmentOnArg::Device => (AugmentAt::Device(device), "device"),
    };
    let rate = throughput::measure(&data, &model, (a.batch, a.batches), (threads, a.at_once), (augment, at), device)?;
    let frames = a.batch * (model.context_len() + model.agent_frames);
    println!(
        "loader benchmark: {}x{} frames, {} ({} s to open), batch {} ({} frames), augmentation {} on the {}, {} \
         threads, {} batch(es) built at once",
        data.height,
        data.width,
        format_args!("{held} of {frames_in_all} held decoded, the rest JPEG-decoded on use"),
        format_args!("{open_seconds:.1}"),
        a.batch,
        frames,
        if augment.is_some() { "on" } else { "off" },
        place,
        rate.threads,
        rate.at_once
    );
    let per_batch = |s: f64| s / rate.batches as f64;
    println!(
        "  build {:.4} s/batch = {:.1} samples/s; copy to {:?}{} {:.4} s/batch; built and copied {:.1} samples/s",
        per_batch(rate.build_seconds),
        rate.samples_per_second(),
        device,
        if at == AugmentAt::Host { "" } else { " and augment there" },
        per_batch(rate.copy_seconds),
        rate.delivered_per_second()
    );
    Ok(())
}

/// What a training benchmark times: model, frame size, batch and the training's settings (loss weights, number
/// formats, device).
struct BenchConfig {
    name: String,
    model: ModelConfig,
    image: ImageSize,
    batch: usize,
    train: TrainConfig,
    /// Training steps whose hours the table projects, and whose they are: the paper's, or the experiment's.
    projected: (usize, &'static str),
}

/// How many steps a benchmark runs untimed, then timed.
#[derive(Clone, Copy)]
struct Timing {
    warmup: usize,
    steps: usize,
}

/// The configuration `--config` names.
fn bench_config(size: BenchSize) -> BenchConfig {
    match size {
        BenchSize::Paper => BenchConfig {
            name: "paper".into(),
            model: ModelConfig::default(),
            image: ImageSize { height: 240, width: 320 },
            batch: 30,
            train: TrainConfig::default(),
            projected: (PAPER_STEPS, "the paper's"),
        },
        BenchSize::Small => BenchConfig {
            name: "small".into(),
            model: ModelConfig { backbone_width: 16, attention_inner: 32, embed_hidden: 64, ..ModelConfig::default() },
            image: ImageSize { height: 64, width: 80 },
            batch: 8,
            train: TrainConfig::default(),
            projected: (PAPER_STEPS, "the paper's"),
        },
    }
}

/// Peak resident memory of this process (kB), from /proc.
fn peak_rss_kb() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

fn synthetic_batch(c: &BenchConfig, device: Device) -> DeviceBatch {
    let (b, h, w) = (c.batch as i64, c.image.height as i64, c.image.width as i64);
    let (tc, ta) = (c.model.context_len() as i64, c.model.agent_frames as i64);
    let opts = (Kind::Float, device);
    DeviceBatch {
        context: Tensor::randn([b, tc, 3, h, w], opts),
        agent: Tensor::randn([b, ta, 3, h, w], opts),
        actions: Tensor::rand([b, ta - 1, 8], opts) * 2.0 - 1.0,
        points: Tensor::rand([b, 2], opts) * 2.0 - 1.0,
        poses: Tensor::rand([b, 6], opts),
        pose_weights: Tensor::ones([b, ta], opts),
        tasks: Tensor::randint(NUM_TASKS as i64, [b], (Kind::Int64, device)),
        states: Tensor::rand([b, ta, STATE_DIM as i64], opts),
    }
}

fn sync(device: Device) {
    if let Device::Cuda(i) = device {
        tch::Cuda::synchronize(i as i64);
    }
}

/// Seconds per call of `step` over `timing.steps` calls, after `timing.warmup` untimed calls, the device
/// synchronised around them.
fn seconds_per_step(timing: Timing, device: Device, mut step: impl FnMut()) -> f64 {
    for _ in 0..timing.warmup {
        step();
    }
    sync(device);
    let start = Instant::now();
    for _ in 0..timing.steps {
        step();
    }
    sync(device);
    start.elapsed().as_secs_f64() / timing.steps as f64
}

/// Resets the peak resident memory that [`peak_rss_kb`] reads (Linux `clear_refs`); false where it cannot.
fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// Times `steps` full training steps of each architecture, then the ResNet-18 trunk's forward + backward on the
/// same frames.
fn bench_train(c: &BenchConfig, timing: Timing, architectures: &[String]) -> Result<()> {
    let (precision, memory_format) = (c.train.precision, c.train.memory_format);
    let device = parse_device(&c.train.device)?;
    autotune_convolutions(device);
    tch::manual_seed(0);
    let batch = synthetic_batch(c, device);
    let frames = c.batch * (c.model.context_len() + c.model.agent_frames);
    println!(
        "training benchmark `{}`: {}x{} frames, batch {} ({} frames per step), backbone width {}, device {:?}, {:?}, \
         {:?}",
        c.name,
        c.image.height,
        c.image.width,
        c.batch,
        frames,
        c.model.backbone_width,
        device,
        precision,
        memory_format
    );
    println!(
        "  {:<18} {:>12} {:>10} {:>9} {:>10} {:>12} {:>12}",
        "architecture",
        "parameters",
        "s/step",
        "steps/s",
        "samples/s",
        "peak memory",
        format!("{} steps", c.projected.0)
    );
    let weights = &c.train.loss;
    let mut parts = Vec::new();
    for name in architectures {
        let model = ModelConfig { architecture: Architecture::named(name), ..c.model.clone() };
        // What a training would refuse for this architecture (its heads, its number type) is skipped, not timed.
        let fits = model
            .validate()
            .and_then(|()| check_heads(&model, &c.train))
            .and_then(|()| check_precision(&model, &c.train));
        if let Err(e) = fits {
            println!("  {name:<18} skipped: {e}");
            continue;
        }
        let (vs, mut policy) = build_policy(&model, device)?;
        policy.set_channels_last(memory_format == MemoryFormat::ChannelsLast);
        let parameters: i64 = vs.trainable_variables().iter().map(|t| t.numel() as i64).sum();
        let mut opt = Adam::new(&vs, 5e-4);
        let fresh_peak = reset_peak_rss();
        let forward = || {
            let _precision = precision.scope(device);
            weights.total(&policy.losses(&batch, true))
        };
        let s = seconds_per_step(timing, device, || opt.backward_step(&forward()));
        // The same step in parts: what a fused optimiser step or a captured graph could at most save.
        let forward_s = seconds_per_step(timing, device, || drop(forward()));
        let backward_s = seconds_per_step(timing, device, || forward().backward()) - forward_s;
        parts.push((name.clone(), forward_s, backward_s, s - forward_s - backward_s));
        let memory = match (device, peak_rss_kb()) {
            (Device::Cpu, Some(kb)) if fresh_peak => format!("{:.2} GiB", kb as f64 / (1024.0 * 1024.0)),
            (Device::Cpu, Some(kb)) => format!("<= {:.2} GiB", kb as f64 / (1024.0 * 1024.0)),
            // libtorch's caching allocator keeps what it took, so what the process holds is its peak so far.
            (Device::Cuda(_), _) => match gpu_memory_held_mib() {
                Some(mib) => format!("<= {:.2} GiB", mib as f64 / 1024.0),
                None => "n/a".to_string(),
            },
            _ => "n/a".to_string(),
        };
        println!(
            "  {name:<18} {parameters:>12} {s:>10.3} {:>9.2} {:>10.1} {memory:>12} {:>12.2}",
            1.0 / s,
            c.batch as f64 / s,
            c.projected.0 as f64 * s / 3600.0
        );
    }

    println!("  step parts (the same step timed again without the optimiser, then without the backward pass):");
    for (name, forward, backward, optimiser) in parts {
        let total = forward + backward + optimiser;
        println!(
            "  {name:<18} forward {forward:.3} s ({:.0}%), backward {backward:.3} s ({:.0}%), Adam {optimiser:.3} s ({:.0}%)",
            100.0 * forward / total,
            100.0 * backward / total,
            100.0 * optimiser / total
        );
    }

    let trunk_vs = nn::VarStore::new(device);
    let mut trunk = ResNet18::new(&trunk_vs.root(), c.model.backbone_width, c.model.backbone_stages);
    trunk.set_channels_last(memory_format == MemoryFormat::ChannelsLast);
    let images = Tensor::cat(&[&batch.context, &batch.agent], 1).flatten(0, 1);
    let trunk_step = || {
        let loss = {
            let _precision = precision.scope(device);
            trunk.forward_t(&images, true).mean(Kind::Float)
        };
        loss.backward();
        for v in trunk_vs.trainable_variables() {
            let mut g = v.grad();
            if g.defined() {
                let _ = g.zero_();
            }
        }
    };
    let trunk_s = seconds_per_step(timing, device, trunk_step);
    println!("  {:<18} {:>12} {trunk_s:>10.3} {:>9.2}", "ResNet-18 trunk", "", 1.0 / trunk_s);
    if device.is_cuda() {
        println!("  peak memory: GPU memory this process holds (nvidia-smi), the most any step so far needed");
    }
    let (projected, whose) = c.projected;
    println!("  {projected} steps: hours for {whose} {projected} training steps at this rate");
    Ok(())
}

/// Training steps of the paper's runs (the authors' `experiments/base.yaml`).
const PAPER_STEPS: usize = 60_000;

/// GPU memory (MiB) this process holds, as `nvidia-smi` reports it; none without nvidia-smi.
fn gpu_memory_held_mib() -> Option<u64> {
    let out = std::process::Command::new("nvidia-smi")
        .args(["--query-compute-apps=pid,used_memory", "--format=csv,noheader,nounits"])
        .output()
        .ok()?;
    let me = std::process::id().to_string();
    String::from_utf8_lossy(&out.stdout).lines().find_map(|l| {
        let (pid, mib) = l.split_once(',')?;
        (pid.trim() == me).then(|| mib.trim().parse().ok()).flatten()
    })
}

/// Times evaluation of the `small` network (fresh weights: its speed does not depend on them), and of the random
/// policy through the same path, with `workers` simulation threads.
fn bench_eval(episodes: usize, horizon: usize, workers: usize) -> Result<()> {
    let c = bench_config(BenchSize::Small);
    let dir = std::env::temp_dir().join(format!("oneshot-bench-eval-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    tch::manual_seed(0);
    let (vs, _) = build_policy(&c.model, Device::Cpu)?;
    checkpoint::save(&vs, &dir.join(FINAL_WEIGHTS))?;
    let world = WorldConfig { image: c.image, ..WorldConfig::default() };
    let summary = TrainSummary::untrained(c.model.clone(), world.clone(), 90);
    std::fs::write(dir.join(FINAL_INFO), serde_json::to_string(&summary)?)?;
    let trained = load_trained(&dir, None, Device::Cpu)?;
    std::fs::remove_dir_all(&dir)?;

    let config = EvalConfig { episodes, horizon, batch: episodes, device: "cpu".into(), ..EvalConfig::default() };
    println!(
        "evaluation benchmark: {episodes} episodes x {horizon} steps, {}x{} frames, {workers} simulation threads, CPU",
        c.image.height, c.image.width
    );
    let specs = config.episode_specs(world.objects, &HashSet::new());
    for (name, policy) in [("small network", Actor::Network(&trained)), ("random policy", Actor::Random)] {
        let start = Instant::now();
        let (results, _) =
            rollouts(&policy, &world, &config, &specs, workers, &EvalOutput { strips_dir: None, videos_dir: None })?;
        let s = start.elapsed().as_secs_f64();
        let steps: usize = results.iter().map(|r| r.steps).sum();
        println!(
            "  {name:<14}: {:>6.2} rollouts/s  {:>7.1} agent steps/s  ({s:.1} s, demonstrations included)",
            episodes as f64 / s,
            steps as f64 / s
        );
    }
    if let Some(kb) = peak_rss_kb() {
        println!("  peak memory (process): {:.2} GiB", kb as f64 / (1024.0 * 1024.0));
    }
    Ok(())
}

/// Builds a grid of at least `cells` cells, marks every stage cached in a scratch store, then times the `plan`
/// and `run` commands of this binary on it.
fn bench_plan(cells: usize) -> Result<()> {
    let dir = std::env::temp_dir().join(format!("oneshot-bench-plan-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let variants = 10usize;
    let seeds = cells.div_ceil(2 * variants);
    let mut text =
        String::from("name = \"bench_plan\"\n[grid]\nsizes = [480, 1600]\nreferences = [\"expert\", \"random\"]\n");
    text += &format!("seeds = [{}]\n", (0..seeds).map(|s| s.to_string()).collect::<Vec<_>>().join(", "));
    let names: Vec<String> = (0..variants).map(|v| format!("\"v{v}\"")).collect();
    text += &format!("variants = [{}]\n", names.join(", "));
    for v in 0..variants {
        text += &format!("[variants.v{v}]\ntrain.lr = {}\n", 1e-4 * (v + 1) as f64);
    }
    let file = dir.join("bench_plan.toml");
    std::fs::write(&file, text)?;
    let store_dir = dir.join("runs");
    let (_, plan) = load_plan(&file, &Default::default())?;
    let mut store = Store::open(&store_dir)?;
    store.register(&plan.order.iter().map(|k| &plan.stages[k]).collect::<Vec<_>>())?;
    // Benchmark set-up only: every stage is recorded finished, with no results, in a sealed artifact folder that
    // is empty but for an evaluation's summary without episodes (the report reads it).
    for k in &plan.order {
        let artifact = artifact_dir(&store_dir, plan.stages[k].kind(), k);
        std::fs::create_dir_all(&artifact)?;
        if plan.stages[k].kind() == StageKind::Eval {
            std::fs::write(artifact.join(SUMMARY_FILE), "{}")?;
        }
        seal(&artifact)?;
        let Claim::Acquired(attempt) = store.claim(k, false)? else { bail!("a fresh store has stage {k} claimed") };
        store.complete(k, attempt, &artifact, &StageOutputs::default())?;
    }
    println!("orchestrator benchmark: {} cells, {} stages, all cached", plan.cells.len(), plan.stages.len());
    let exe = std::env::current_exe()?;
    for cmd in ["plan", "run"] {
        let start = Instant::now();
        let out = std::process::Command::new(&exe)
            .args([cmd, &file.to_string_lossy(), "--store", &store_dir.to_string_lossy()])
            .output()?;
        let s = start.elapsed().as_secs_f64();
        if !out.status.success() {
            bail!("`{cmd}` failed: {}", String::from_utf8_lossy(&out.stderr));
        }
        if cmd == "run" && !String::from_utf8_lossy(&out.stdout).contains(": 0 stages run,") {
            bail!("`run` found stages to run on a grid that is all cached: {}", String::from_utf8_lossy(&out.stdout));
        }
        let what = if cmd == "run" { "whole command, report included" } else { "whole command" };
        println!("  {cmd:<4}: {s:.3} s ({what})");
    }
    std::fs::remove_dir_all(&dir)?;
    Ok(())
}
