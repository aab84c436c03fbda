//! Training on a small real collection: validation loss falls for every architecture; the model's sizes are
//! checked against the data.
use crate::helpers::{HANG_GUARD, torch_rng, wait_for};
use oneshot_lab::data::collect::collect;
use oneshot_lab::data::collect_config::{CollectConfig, CollectSettings, LayoutSharing};
use oneshot_lab::data::pairs::{FrameForm, PairDataset, Split, Windows};
use oneshot_lab::eval::grip_probe::grip_probe;
use oneshot_lab::eval::probe::{PositionErrors, open_loop};
use oneshot_lab::model::architectures::ARCHITECTURES;
use oneshot_lab::model::config::{Architecture, ModelConfig};
use oneshot_lab::sim::camera::{ImageSize, Visuals};
use oneshot_lab::sim::env::WorldConfig;
use oneshot_lab::sim::robot::Robot;
use oneshot_lab::train::config::{LossWeights, TrainConfig};
use oneshot_lab::train::{TrainRun, curve, load_trained, train};

fn tasks(ids: &[usize]) -> CollectSettings {
    CollectSettings { tasks: ids.to_vec(), ..CollectSettings::default() }
}

#[test]
fn training_on_collected_data_lowers_validation_bc_and_checks_context_length() {
    let _rng = torch_rng();
    let dir = std::env::temp_dir().join(format!("oneshot-test-train-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let world = WorldConfig {
        image: ImageSize { height: 32, width: 40 },
        visuals: Visuals::Collision,
        ..WorldConfig::default()
    };
    for robot in Robot::ALL {
        let config = CollectConfig {
            per_task: 4,
            world: world.clone(),
            settings: CollectSettings { layouts: LayoutSharing::Unique, ..tasks(&[0, 4]) },
            ..CollectConfig::paper(robot)
        };
        collect(&config, &dir.join(robot.name()), 2, false).unwrap();
    }
    let model = ModelConfig { backbone_width: 8, attention_inner: 16, embed_hidden: 32, ..ModelConfig::default() };
    let config = TrainConfig {
        steps: 120,
        batch_size: 6,
        lr: 3e-3,
        device: "cpu".into(),
        val_interval: 40,
        val_batches: 2,
        checkpoint_interval: 60,
        ..TrainConfig::default()
    };
    let out = dir.join("model");
    let run = TrainRun {
        demo_dir: &dir.join("sawyer"),
        agent_dir: &dir.join("panda"),
        per_task: None,
        out: &out,
        progress: false,
    };
    let summary = train(&model, &config, &run).unwrap();
    assert!(summary.final_val_bc < summary.first_val_bc - 0.15, "{} -> {}", summary.first_val_bc, summary.final_val_bc);
    let points = curve::read(&out.join("curve.jsonl"), u64::MAX).unwrap();
    assert_eq!(points.iter().filter(|p| p.split == "val").count(), 4, "steps 0, 40, 80, 120");
    assert!(out.join("checkpoints/step_00000060.safetensors").exists() && out.join("model.safetensors").exists());

    // The open-loop probe of the trained model: its errors per window position average to the overall ones.
    let trained = load_trained(&out, None, tch::Device::Cpu).unwrap();
    let data = PairDataset::open(&dir.join("sawyer"), &dir.join("panda"), config.val_fraction, None).unwrap();
    let report = open_loop(&trained, &data, Split::Train, Windows::FromStart, 5, 2, 0).unwrap();
    assert_eq!((report.windows, report.actions, report.by_position.len()), (5, 30, 6));
    // From each trajectory's start, the expert's own first action heads for the demonstrated object: the
    // object-choice measure reads the expert right before it is used on a policy.
    let choice = report.first_target.expect("windows from the start count first targets");
    assert_eq!((choice.policy.windows, choice.expert.windows, choice.expert.demonstrated), (5, 5, 5));
    assert_eq!(choice.policy.demonstrated + choice.policy.other + choice.policy.still, 5);
    // Each window is run again with its demonstration swapped: for another of the same task, and for one of the
    // next object demonstrated to the same quadrant (for task 0 task 4, for task 4 task 0).
    let swap = report.swap.expect("windows from the start swap their demonstrations");
    assert!(swap.windows > 0 && swap.windows <= 5 && swap.other_object.windows == swap.windows, "{swap:?}");
    assert!(swap.objects_apart > 0.02, "two objects of a layout lie apart: {swap:?}");
    assert!(swap.moved_same_task >= 0.0 && swap.moved_other_object.is_finite(), "{swap:?}");
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(3);
    for _ in 0..5 {
        let sample =
            data.sample(&mut rng, Split::Train, &model, Windows::FromStart, None, FrameForm::Normalised).unwrap();
        let [demo, agent] = sample.source;
        let task = data.trajectory([demo, agent]).1.meta.task;
        assert!(data.demos_for(Split::Train, agent, task).contains(&demo), "a pair's own demonstration is its task's");
        for d in data.demos_for(Split::Train, agent, 4) {
            assert_eq!(data.trajectory([*d, agent]).0.meta.task, 4);
        }
    }
    assert!(
        open_loop(&trained, &data, Split::Train, Windows::Training { start: 0.2 }, 2, 2, 0).unwrap().swap.is_none()
    );
    for d in 0..8 {
        let mean_of =
            |f: fn(&PositionErrors) -> [f64; 8]| report.by_position.iter().map(|p| f(p)[d]).sum::<f64>() / 6.0;
        assert!((mean_of(|p| p.mode) - report.mode[d]).abs() < 1e-6, "dimension {d}");
        assert!((mean_of(|p| p.mean_baseline) - report.mean_baseline[d]).abs() < 1e-6, "dimension {d}");
    }

    // The grip probe reads every step from each expert's close to one past its lift, each with 1 to 5 frames:
    // the lift step is the first whose own action lifts, so the expert lifts there and at no step before it.
    let grip = grip_probe(&trained, &data, Split::Train, 4, 5, 3, 0).unwrap();
    assert_eq!(grip.trajectories, 4, "{grip:?}");
    let lift = grip.by_step.iter().find(|(offset, _)| *offset == 0).expect("a lift row").1;
    assert_eq!((lift.queries, lift.expert_lifts), (4 * 5, 1.0), "{grip:?}");
    for (offset, row) in &grip.by_step {
        assert!(*offset >= -3 && *offset <= 1, "the experts rise 3 steps after closing at the latest: {offset}");
        if *offset < 0 {
            assert_eq!(row.expert_lifts, 0.0, "step {offset}");
        }
        for p in [row.lift_probability, row.mode_lifts, row.open_probability, row.mode_opens] {
            assert!((0.0..=1.0).contains(&p), "step {offset}: {row:?}");
        }
    }
    assert_eq!(grip.lift_by_frames.len(), 5);
    assert!(grip.lift_by_frames.iter().all(|row| row.queries == 4), "each lift seen with 1 to 5 frames");
    assert_eq!(grip.bottom_mode_lifts.iter().sum::<usize>(), 4);
    assert_eq!(grip, grip_probe(&trained, &data, Split::Train, 4, 5, 3, 0).unwrap(), "deterministic by seed");
    let err = grip_probe(&trained, &data, Split::Train, 4, 7, 3, 0).unwrap_err();
    assert!(err.to_string().contains("model.agent_frames"), "{err}");

    // Interrupted after 60 steps and resumed: the same weights as the uninterrupted run, bit for bit.
    let split = dir.join("split");
    let half = TrainConfig { steps: 60, ..config.clone() };
    train(&model, &half, &TrainRun { out: &split, ..run }).unwrap();
    let resumed = train(&model, &config, &TrainRun { out: &split, ..run }).unwrap();
    assert_eq!(resumed.resumed_from, Some(60));
    let a = tch::Tensor::read_safetensors(out.join("model.safetensors")).unwrap();
    let b: std::collections::HashMap<String, tch::Tensor> =
        tch::Tensor::read_safetensors(split.join("model.safetensors")).unwrap().into_iter().collect();
    for (name, t) in &a {
        assert!(t.equal(&b[name]), "{name} differs after resuming");
    }

    // A trunk frozen with `model.freeze_backbone` keeps its pretrained weights (batch-norm statistics may follow
    // the data); the same start without freezing moves them. Freezing needs weights to freeze.
    let trunk_file = dir.join("trunk.safetensors");
    let trunk: Vec<(String, tch::Tensor)> =
        a.iter().filter_map(|(n, t)| n.strip_prefix("backbone.").map(|n| (n.to_string(), t.shallow_clone()))).collect();
    tch::Tensor::write_safetensors(&trunk, &trunk_file).unwrap();
    let pretrained = ModelConfig { pretrained_backbone: Some(trunk_file.to_string_lossy().into()), ..model.clone() };
    let short = TrainConfig { steps: 20, val_interval: 20, checkpoint_interval: 20, ..config.clone() };
    let moved = |freeze_backbone: bool| {
        let name = if freeze_backbone { "frozen" } else { "unfrozen" };
        let m = ModelConfig { freeze_backbone, ..pretrained.clone() };
        train(&m, &short, &TrainRun { out: &dir.join(name), ..run }).unwrap();
        let after: std::collections::HashMap<String, tch::Tensor> =
            tch::Tensor::read_safetensors(dir.join(name).join("model.safetensors")).unwrap().into_iter().collect();
        let weights = trunk.iter().filter(|(n, _)| !n.contains("running_") && !n.contains("num_batches"));
        weights.filter(|(n, t)| !t.equal(&after[&format!("backbone.{n}")])).count()
    };
    assert_eq!(moved(true), 0, "a frozen trunk's weights changed");
    assert!(moved(false) > 0, "fine-tuning left the trunk untouched");
    let no_weights = ModelConfig { freeze_backbone: true, ..model.clone() };
    let err = train(&no_weights, &short, &TrainRun { out: &dir.join("no_weights"), ..run }).unwrap_err();
    assert!(err.to_string().contains("model.freeze_backbone"), "{err}");

    // Every other registered architecture learns from the same data with its own losses.
    for registration in ARCHITECTURES.iter().filter(|r| r.name != model.architecture.0) {
        let other = ModelConfig { architecture: Architecture::named(registration.name), ..model.clone() };
        let weights = if registration.auxiliary_heads {
            config.loss.clone()
        } else {
            LossWeights { inverse: 0.0, point: 0.0, ..config.loss.clone() }
        };
        let short = TrainConfig { steps: 80, val_interval: 80, loss: weights, ..config.clone() };
        let out = dir.join(registration.name);
        let s = train(&other, &short, &TrainRun { out: &out, ..run }).unwrap();
        assert!(
            s.final_val_bc < s.first_val_bc - 0.1,
            "{}: {} -> {}",
            registration.name,
            s.first_val_bc,
            s.final_val_bc
        );
    }

    // A step size that blows the weights up: training stops at the first non-finite loss, naming the step.
    let blown = TrainConfig { steps: 10, val_interval: 10, checkpoint_interval: 10, lr: 1e30, ..config.clone() };
    let err = train(&model, &blown, &TrainRun { out: &dir.join("blown"), ..run }).unwrap_err().to_string();
    assert!(err.contains("training step") && err.contains("the loss is not finite"), "{err}");
    assert!(!dir.join("blown").join("model.safetensors").exists(), "no final weights of a diverged run");

    let too_long = ModelConfig { context_frames: 500, ..model };
    let err = train(&too_long, &config, &TrainRun { out: &dir.join("other"), ..run }).unwrap_err();
    assert!(err.to_string().contains("model.context_frames = 500"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_training_told_to_stop_by_signal_checkpoints_and_the_next_run_resumes_there() {
    let dir = crate::helpers::scratch("train-signal");
    let world = WorldConfig {
        image: ImageSize { height: 32, width: 40 },
        visuals: Visuals::Collision,
        ..WorldConfig::default()
    };
    for robot in Robot::ALL {
        // Each slot a layout of its own, so that validation (held out by layout) has some.
        let settings = CollectSettings { layouts: LayoutSharing::Unique, ..tasks(&[0, 6]) };
        let config = CollectConfig { per_task: 3, world: world.clone(), settings, ..CollectConfig::paper(robot) };
        collect(&config, &dir.join(robot.name()), 2, false).unwrap();
    }
    let config = dir.join("tiny.toml");
    std::fs::write(
        &config,
        "[model]\nbackbone_width = 8\nattention_inner = 16\nembed_hidden = 32\n\
         [train]\nbatch_size = 2\ndevice = \"cpu\"\nval_interval = 1000000\nval_batches = 1\ncheckpoint_interval = 1000000\n",
    )
    .unwrap();
    let out = dir.join("model");
    let train = |steps: &str| {
        let mut cmd = crate::helpers::oneshot();
        cmd.args(["train", "--config", config.to_str().unwrap(), "--steps", steps, "--out", out.to_str().unwrap()]);
        cmd.args(["--demos", dir.join("sawyer").to_str().unwrap(), "--agents", dir.join("panda").to_str().unwrap()]);
        cmd.env("OMP_NUM_THREADS", "1");
        cmd
    };
    // A long training, told to stop once it is under way (its first curve point is written at step 0).
    let child = train("1000000").stderr(std::process::Stdio::piped()).spawn().unwrap();
    wait_for(HANG_GUARD, std::time::Duration::from_millis(200), || {
        out.join("curve.jsonl").exists().then_some(()).ok_or_else(|| "the training wrote no curve".to_string())
    });
    // Between curve points its heartbeat says which step it is at (what `status` reads).
    let heartbeat = out.join(oneshot_lab::train::heartbeat::HEARTBEAT_FILE);
    wait_for(HANG_GUARD, std::time::Duration::from_millis(200), || {
        let beat = oneshot_lab::train::heartbeat::read(&heartbeat).ok_or_else(|| "no heartbeat yet".to_string())?;
        (beat.step >= 1 && beat.at >= beat.first_at).then_some(()).ok_or_else(|| format!("heartbeat {beat:?}"))
    });
    std::thread::sleep(std::time::Duration::from_secs(2));
    unsafe { libc::kill(child.id() as i32, libc::SIGUSR1) };
    let stopped = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&stopped.stderr);
    assert!(!stopped.status.success() && err.contains("stopped by SIGUSR1 at step"), "{err}");
    let (step, _) = oneshot_lab::train::checkpoint::latest(&out.join("checkpoints")).unwrap().expect("a checkpoint");
    assert!(step > 0 && err.contains(&format!("at step {step} ")), "checkpoint at step {step}: {err}");
    assert!(!out.join("model.safetensors").exists(), "a stopped training is not a finished one");

    // The next run resumes from that checkpoint and finishes.
    let resumed = train(&(step + 3).to_string()).output().unwrap();
    assert!(resumed.status.success(), "{}", String::from_utf8_lossy(&resumed.stderr));
    let info: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join(oneshot_lab::train::FINAL_INFO)).unwrap()).unwrap();
    assert_eq!(info["resumed_from"], serde_json::json!(step));
    assert!(!heartbeat.exists(), "a finished training leaves no heartbeat in its folder");
    let _ = std::fs::remove_dir_all(&dir);
}
