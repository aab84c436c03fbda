//! `eval` and `probe`: a policy in closed loop, and a trained one open loop on held-out expert windows.
use super::args::{EvalArgs, LocaliseArgs, ProbeArgs, parse_named};
use super::default_workers;
use anyhow::{Result, bail};
use oneshot_lab::data::augment::Augmentation;
use oneshot_lab::data::pairs::{PairDataset, Split, Windows};
use oneshot_lab::device::parse_device;
use oneshot_lab::eval::layouts::{Layouts, training_seeds};
use oneshot_lab::eval::localise::{LocaliseConfig, LocaliseTarget};
use oneshot_lab::eval::probe::{open_loop, print_probe};
use oneshot_lab::eval::run::run_eval;
use oneshot_lab::eval::summary::print_summary;
use oneshot_lab::eval::{EvalConfig, Policy, PolicyFiles, Weights};
use oneshot_lab::train::load_trained;

/// Evaluates `expert`, `random` or a training folder and prints success per task and stage.
pub fn eval(a: EvalArgs) -> Result<()> {
    let mut config = EvalConfig::default();
    config.episodes = a.episodes.unwrap_or(config.episodes);
    config.horizon = a.horizon.unwrap_or(config.horizon);
    config.seed = a.seed.unwrap_or(config.seed);
    config.batch = a.batch.unwrap_or(config.batch);
    config.device = a.device.unwrap_or(config.device);
    config.tasks = a.tasks.unwrap_or(config.tasks);
    config.strips = a.strips;
    config.videos = a.videos;
    if let Some(control) = &a.control {
        config.control =
            parse_named(control).map_err(|e| anyhow::anyhow!("--control {e} (policy or scripted_poses)"))?;
    }
    if let Some(history) = &a.history {
        config.history = parse_named(history).map_err(|e| anyhow::anyhow!("--history {e} (reset or sliding)"))?;
    }
    if let Some(action) = &a.action {
        config.action = parse_named(action).map_err(|e| anyhow::anyhow!("--action {e} (sample or mode)"))?;
    }
    let layouts = match a.training_layouts.as_deref() {
        Some([demos, agents]) => Layouts::Training { demos: demos.clone(), agents: agents.clone() },
        Some(other) => bail!("--training-layouts takes DEMOS,AGENTS: two folders, not {}", other.len()),
        None => Layouts::Fresh(training_seeds(&a.exclude_from)?),
    };
    let policy: PolicyFiles = Policy::parse(&a.policy, |dir| Weights { at: dir.into(), step: a.checkpoint });
    let world = match (&policy, a.frames.given()) {
        (_, false) => None,
        (Policy::Network(_), true) => {
            bail!("a trained policy is evaluated in the world it was trained in: drop --height, --width and --visuals")
        }
        (_, true) => Some(a.frames.world()),
    };
    let workers = a.workers.unwrap_or_else(default_workers);
    let (_, summary) = run_eval(&policy, world.as_ref(), &config, &layouts, workers, a.out.as_deref())?;
    print_summary(&summary);
    Ok(())
}

/// Prints the open-loop errors of a trained policy per action dimension.
pub fn probe(a: ProbeArgs) -> Result<()> {
    let trained = load_trained(&a.policy, a.checkpoint, parse_device(&a.device)?)?;
    let data = PairDataset::open(&a.demos, &a.agents, trained.summary.train.val_fraction, None)?;
    let split = if a.train_split { Split::Train } else { Split::Val };
    let placement = if a.from_start { Windows::FromStart } else { trained.summary.train.windows() };
    print_probe(&open_loop(&trained, &data, split, placement, a.windows, 16, a.seed)?);
    Ok(())
}

/// `localise`: the localisation check's errors over training, in centimetres.
pub fn localise(a: LocaliseArgs) -> Result<()> {
    let config = LocaliseConfig {
        backbone_width: a.backbone_width,
        backbone_stages: a.backbone_stages,
        steps: a.steps,
        batch: a.batch,
        lr: a.lr,
        per_task: None,
        hold_out_every: 5,
        report_every: a.report_every,
        seed: a.seed,
        target: a.target,
        trunk_out: a.save_trunk.clone(),
        augmentation: match a.augment.as_str() {
            "authors" => Some(Augmentation::default()),
            "colour" => Some(Augmentation { crop: [0.0; 2], shift: [0.0; 2], ..Augmentation::default() }),
            _ => None,
        },
    };
    let r = oneshot_lab::eval::localise::localise(&a.agents, &config, parse_device(&a.device)?)?;
    let cm = |e: [f64; 2]| format!("{:5.2} / {:5.2}", 100.0 * e[0], 100.0 * e[1]);
    let (what, baseline) = match a.target {
        LocaliseTarget::Grasp => ("the task's grasp position", "per-task mean position"),
        LocaliseTarget::Objects => ("the four objects' positions", "mean position of each object"),
    };
    println!(
        "{what} from the first frame ({}x{}; {} training, {} held-out layouts), mean absolute error x / y (cm)",
        r.height, r.width, r.train_frames, r.held_out_frames
    );
    println!("{baseline}, held out: {}", cm(r.mean_baseline));
    println!("{:>6}  {:>13}  {:>13}", "step", "training", "held out");
    for e in &r.curve {
        println!("{:>6}  {:>13}  {:>13}", e.step, cm(e.train), cm(e.held_out));
    }
    Ok(())
}
