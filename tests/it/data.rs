//! The dataset format and collection: round trips, determinism across worker counts, atomic output.
use crate::helpers::scratch;
use oneshot_lab::data::collect::collect;
use oneshot_lab::data::collect_config::{CollectConfig, CollectSettings, LayoutSharing};
use oneshot_lab::data::manifest::Manifest;
use oneshot_lab::data::trajectory::Trajectory;
use oneshot_lab::fsio::staging_sibling;
use oneshot_lab::sim::camera::{ImageSize, Visuals};
use oneshot_lab::sim::env::WorldConfig;
use oneshot_lab::sim::robot::Robot;

fn tiny(robot: Robot, tasks: Vec<usize>, per_task: usize) -> CollectConfig {
    let world = WorldConfig {
        image: ImageSize { height: 32, width: 40 },
        visuals: Visuals::Collision,
        ..WorldConfig::default()
    };
    CollectConfig {
        per_task,
        world,
        settings: CollectSettings { tasks, ..Default::default() },
        ..CollectConfig::paper(robot)
    }
}

#[test]
fn collection_is_byte_identical_for_any_worker_count_and_round_trips() {
    let dir = scratch("data-determinism");
    let config = tiny(Robot::Sawyer, vec![3, 14], 2);
    let one = collect(&config, &dir.join("one"), 1, false).unwrap();
    let two = collect(&config, &dir.join("two"), 3, false).unwrap();
    assert_eq!(one, two);
    for e in &one.trajectories {
        let a = std::fs::read(dir.join("one").join(&e.file)).unwrap();
        let b = std::fs::read(dir.join("two").join(&e.file)).unwrap();
        assert_eq!(a, b, "{}", e.file);
    }
    Manifest::load(&dir.join("one")).unwrap().verify(&dir.join("one")).unwrap();

    let e = &one.trajectories[0];
    let traj = Trajectory::load(&dir.join("one").join(&e.file)).unwrap();
    assert_eq!(traj.len(), e.steps);
    assert_eq!(traj.actions.len(), e.steps - 1);
    assert_eq!((traj.meta.task, traj.meta.instance_seed), (3, e.instance_seed));
    assert!(traj.meta.stages.placed && traj.stages.last().unwrap()[2] == 1);
    assert_eq!(traj.frame_rgb(0).unwrap().len(), 32 * 40 * 3);
    assert_eq!(Trajectory::from_bytes(&traj.to_bytes().unwrap()).unwrap(), traj);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn demonstrator_and_agent_collections_use_different_layouts() {
    let sawyer = tiny(Robot::Sawyer, vec![0], 1);
    let panda = tiny(Robot::Panda, vec![0], 1);
    assert_ne!(sawyer.instance_seed(0, 0, 0), panda.instance_seed(0, 0, 0));
}

#[test]
fn existing_output_is_refused_and_stale_staging_is_replaced() {
    let dir = scratch("data-atomic");
    let out = dir.join("set");
    std::fs::create_dir_all(&out).unwrap();
    let err = collect(&tiny(Robot::Panda, vec![0], 1), &out, 1, false).unwrap_err();
    assert!(err.to_string().contains("already exists"), "{err}");
    std::fs::remove_dir_all(&out).unwrap();

    // An interrupted run leaves only the hidden staging folder, which is not a collection.
    let staging = staging_sibling(&out).unwrap();
    std::fs::create_dir_all(staging.join("trajectories")).unwrap();
    assert!(Manifest::load(&out).is_err() && Manifest::load(&staging).is_err());
    collect(&tiny(Robot::Panda, vec![0], 1), &out, 1, false).unwrap();
    assert!(!staging.exists());
    assert_eq!(Manifest::load(&out).unwrap().trajectories.len(), 1);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_corrupted_file_fails_verification() {
    let dir = scratch("data-verify");
    let out = dir.join("set");
    let manifest = collect(&tiny(Robot::Panda, vec![9], 1), &out, 1, false).unwrap();
    let path = out.join(&manifest.trajectories[0].file);
    let mut bytes = std::fs::read(&path).unwrap();
    let n = bytes.len();
    bytes[n - 10] ^= 0xff;
    std::fs::write(&path, bytes).unwrap();
    let err = manifest.verify(&out).unwrap_err();
    assert!(err.to_string().contains("task09_0000"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn out_of_range_task_is_an_error_naming_it() {
    let err = tiny(Robot::Panda, vec![0, 16], 1).validate().unwrap_err();
    assert!(format!("{err:#}").contains("16"), "{err:#}");
}

#[test]
fn a_smaller_dataset_size_is_the_first_slots_of_each_task_of_the_larger_collection() {
    use oneshot_lab::config::{Experiment, Resolution};
    use oneshot_lab::data::pairs::{PairDataset, Split};
    use oneshot_lab::pipeline::stages::{Job, collection_totals, plan};
    let dir = scratch("data-nested");
    let file = dir.join("sizes.toml");
    let text = "[world]\nimage = { height = 32, width = 40 }\nvisuals = \"collision\"\n[collect]\ntasks = [0, 6]\n[grid]\nsizes = [4, 6]\n";
    std::fs::write(&file, text).unwrap();

    // A size spreads over the collected tasks: 4 and 6 trajectories of 2 tasks are 2 and 3 slots per task.
    // One collection per robot, of 3 slots per task; the smaller cell's training names the 2 slots it uses.
    let experiment = Experiment::load(&file, &Resolution::default()).unwrap();
    let nested = plan(&experiment);
    assert_eq!(collection_totals(&nested), (2, 2 * 3 * 2), "one collection per robot, 3 slots of 2 tasks each");
    let train_of = |cell: &str| {
        let c = nested.cells.iter().find(|c| c.name.starts_with(cell)).unwrap();
        &nested.stages[c.train.as_ref().unwrap()]
    };
    let (small, large) = (train_of("n4-"), train_of("n6-"));
    assert_eq!(small.inputs["per_task"], 2);
    assert!(large.inputs.get("per_task").is_none(), "the largest size uses the whole collection");
    assert_eq!(small.upstream, large.upstream, "both train on the same collections");
    assert!(matches!(&small.job, Job::Train(t) if t.per_task == Some(2)));
    let separate =
        Experiment { grid: oneshot_lab::config::Grid { nested: false, ..experiment.grid.clone() }, ..experiment };
    assert_eq!(collection_totals(&plan(&separate)), (4, 2 * (2 + 3) * 2), "grid.nested = false collects each size");

    // With a layout of its own per slot, the first two slots of the larger collection are, file for file, a
    // separate collection of two slots (shared layouts draw from a pool sized by the collection, as the
    // authors' separate collections of each size did).
    let unique = |robot, per_task| {
        let mut c = tiny(robot, vec![0, 6], per_task);
        c.settings.layouts = LayoutSharing::Unique;
        c
    };
    for robot in [Robot::Sawyer, Robot::Panda] {
        let big = collect(&unique(robot, 3), &dir.join(format!("big-{robot}")), 2, false).unwrap();
        let small = collect(&unique(robot, 2), &dir.join(format!("small-{robot}")), 2, false).unwrap();
        assert_eq!(big.trajectories.len(), 6);
        for e in &small.trajectories {
            let a = std::fs::read(dir.join(format!("small-{robot}")).join(&e.file)).unwrap();
            let b = std::fs::read(dir.join(format!("big-{robot}")).join(&e.file)).unwrap();
            assert_eq!(a, b, "{}", e.file);
        }
    }
    let subset = PairDataset::open(&dir.join("big-sawyer"), &dir.join("big-panda"), 0.1, Some(2)).unwrap();
    let own = PairDataset::open(&dir.join("small-sawyer"), &dir.join("small-panda"), 0.1, None).unwrap();
    for split in [Split::Train, Split::Val] {
        assert_eq!(subset.pairs(split), own.pairs(split), "{split:?}");
    }
    assert_eq!(subset.pairs(Split::Train), 2, "slot 0 of each task trains, slot 1 validates");
    let err = PairDataset::open(&dir.join("big-sawyer"), &dir.join("big-panda"), 0.1, Some(4)).err().unwrap();
    assert!(err.to_string().contains("fewer than the 4 asked for"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_loader_benchmark_times_the_training_path_and_decoding_on_use_builds_the_same_batches() {
    use oneshot_lab::data::augment::Augmentation;
    use oneshot_lab::data::loader::{AugmentAt, build_batch, build_batches};
    use oneshot_lab::data::pairs::{PairDataset, Split, Windows};
    use oneshot_lab::model::config::ModelConfig;
    use oneshot_lab::train::config::TrainConfig;
    use oneshot_lab::train::throughput::measure;
    use tch::Device;
    let dir = scratch("data-loader");
    for robot in [Robot::Sawyer, Robot::Panda] {
        collect(&tiny(robot, vec![0, 6], 2), &dir.join(robot.to_string()), 2, false).unwrap();
    }
    let open = || PairDataset::open(&dir.join("sawyer"), &dir.join("panda"), 0.1, None).unwrap();
    let (held, mut on_use, mut part) = (open(), open(), open());
    on_use.hold_decoded(0).unwrap();
    let (all, frames) = held.frames_held();
    assert!(all == frames && frames > 0 && on_use.frames_held() == (0, frames));
    // A budget of a third of the frames holds whole trajectories up to it, the agent's first.
    let frame_bytes = 3 * held.height * held.width;
    part.hold_decoded(frames / 3 * frame_bytes).unwrap();
    let (some, _) = part.frames_held();
    assert!(some > 0 && some <= frames / 3, "{some} of {frames} held");
    let (model, aug) = (ModelConfig::default(), Augmentation::default());
    let batch = |data: &PairDataset, at: AugmentAt| {
        let b =
            build_batch(data, Split::Train, &model, 4, 7, 3, TrainConfig::default().windows(), Some(&aug), at).unwrap();
        b.to_device(&model, data.height, data.width, Device::Cpu)
    };
    let (a, b) = (batch(&held, AugmentAt::Host), batch(&on_use, AugmentAt::Host));
    assert!(a.context.equal(&b.context) && a.agent.equal(&b.agent) && a.actions.equal(&b.actions));
    let c = batch(&part, AugmentAt::Host);
    assert!(a.context.equal(&c.context) && a.agent.equal(&c.agent));

    // Augmenting on the training device (here the CPU's tensor kernels) makes the same batch.
    let d = batch(&held, AugmentAt::Device(Device::Cpu));
    for (host, device) in [(&a.context, &d.context), (&a.agent, &d.agent)] {
        assert_eq!(host.size(), device.size());
        let worst = (host - device).abs().max().double_value(&[]);
        assert!(worst < 1e-3, "host and device augmentation differ by {worst}");
    }
    assert!(a.actions.equal(&d.actions) && a.points.equal(&d.points));

    // Windows from the start (the probe's approach windows) begin with a trajectory's first action.
    let agents = dir.join("panda");
    let firsts: Vec<Vec<f32>> = Manifest::load(&agents)
        .unwrap()
        .trajectories
        .iter()
        .map(|e| Trajectory::load(&agents.join(&e.file)).unwrap())
        .map(|t| oneshot_lab::sim::action::Action(t.actions[0].map(f64::from)).normalized().to_vec())
        .collect();
    let start = build_batch(&held, Split::Train, &model, 4, 7, 3, Windows::FromStart, None, AugmentAt::Host).unwrap();
    let per_sample = start.actions.len() / 4;
    for s in start.actions.chunks(per_sample) {
        assert!(firsts.iter().any(|f| f[..] == s[..8]), "a window from the start begins with a first action");
    }

    // Batches built several at once, as a prefetching training builds them, are the batches built one by one.
    let windows = TrainConfig::default().windows();
    let at_once = build_batches(&held, Split::Train, &model, 4, 7, 2..5, windows, Some(&aug), AugmentAt::Host);
    for (step, batch) in (2..5).zip(at_once) {
        let one = build_batch(&held, Split::Train, &model, 4, 7, step, windows, Some(&aug), AugmentAt::Host).unwrap();
        let (a, b) = (batch.unwrap().to_device(&model, held.height, held.width, Device::Cpu), one);
        let b = b.to_device(&model, held.height, held.width, Device::Cpu);
        assert!(a.context.equal(&b.context) && a.agent.equal(&b.agent) && a.actions.equal(&b.actions), "step {step}");
    }

    // A prefetching training's batches (built two at a time on a background thread) are the inline ones.
    use oneshot_lab::data::loader::{PrefetchSpec, Prefetcher};
    let spec = |depth| PrefetchSpec {
        model: model.clone(),
        batch_size: 4,
        seed: 7,
        start: 1,
        windows,
        augment: Some(aug.clone()),
        depth,
        augment_at: AugmentAt::Host,
    };
    let data = std::sync::Arc::new(open());
    let (mut ahead, mut inline) = (Prefetcher::start(data.clone(), spec(2)), Prefetcher::start(data, spec(0)));
    for _ in 0..5 {
        let (a, b) = (ahead.next_batch().unwrap(), inline.next_batch().unwrap());
        let (a, b) = (
            a.to_device(&model, held.height, held.width, Device::Cpu),
            b.to_device(&model, held.height, held.width, Device::Cpu),
        );
        assert!(a.context.equal(&b.context) && a.agent.equal(&b.agent) && a.actions.equal(&b.actions));
    }

    for (threads, at_once, at) in [
        (1, 1, AugmentAt::Host),
        (2, 1, AugmentAt::Host),
        (2, 1, AugmentAt::Device(Device::Cpu)),
        (2, 2, AugmentAt::Host),
    ] {
        let rate = measure(&on_use, &model, (4, 3), (threads, at_once), (Some(&aug), at), Device::Cpu).unwrap();
        // Three batches in groups of two time two groups.
        let timed = 3usize.div_ceil(at_once) * at_once;
        assert_eq!((rate.batch_size, rate.batches, rate.threads, rate.at_once), (4, timed, threads, at_once));
        assert!(rate.build_seconds > 0.0 && rate.copy_seconds > 0.0, "{rate:?}");
        assert!(rate.samples_per_second() > rate.delivered_per_second(), "{rate:?}");
    }
    let err = measure(&held, &model, (4, 0), (1, 1), (None, AugmentAt::Host), Device::Cpu).unwrap_err();
    assert!(err.to_string().contains("number of batches"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn multi_object_collections_lay_out_training_objects_and_pair_within_an_environment() {
    use oneshot_lab::data::pairs::{FrameForm, PairDataset, Split, Windows};
    use oneshot_lab::model::config::ModelConfig;
    use oneshot_lab::sim::env::ObjectSet;
    use oneshot_lab::sim::task::{Instance, Task};
    use rand::SeedableRng;
    let dir = scratch("data-library");
    // Six slots of three tasks: three environments of two instances, the last of which validates.
    let library = |robot| {
        let mut c = tiny(robot, vec![1, 6, 11], 6);
        c.world.objects = ObjectSet::Library;
        c.world.close_on_arrival = true;
        c
    };
    let mut environment_of = std::collections::HashMap::new();
    for robot in [Robot::Sawyer, Robot::Panda] {
        let config = library(robot);
        let folder = dir.join(robot.to_string());
        let manifest = collect(&config, &folder, 2, false).unwrap();
        for e in &manifest.trajectories {
            let env = e.environment.unwrap();
            assert_eq!(env, e.index as u64 / 2);
            let objects = config.objects(Some(env));
            assert!(objects.iter().all(|o| !o.held_out()), "{objects:?}");
            let names: Vec<String> = objects.iter().map(|o| o.name().to_string()).collect();
            assert_eq!(e.objects.as_ref(), Some(&names), "the manifest names the environment's objects");
            // The stored first frame lays out the environment's objects: their footprints decide where each lies.
            let traj = Trajectory::load(&folder.join(&e.file)).unwrap();
            let laid = Instance::sample_with(Task::from_id(e.task).unwrap(), e.instance_seed, objects);
            for (pose, want) in traj.object_poses[0].iter().zip(&laid.objects) {
                let off = (pose[0] as f64 - want.pos[0]).hypot(pose[1] as f64 - want.pos[1]);
                assert!(off < 0.02, "{}: an object lies {off:.3} m from its layout", e.file);
            }
            environment_of.insert((robot, e.instance_seed), env);
        }
    }
    let data = PairDataset::open(&dir.join("sawyer"), &dir.join("panda"), 0.1, None).unwrap();
    // Within an environment: two environments of 2 x 2 pairs per task train (pairing across them would give 4 x 4).
    assert_eq!(data.pairs(Split::Train), 3 * 2 * 2 * 2);
    assert_eq!(data.pairs(Split::Val), 3 * 2 * 2);
    let model = ModelConfig::default();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
    for split in [Split::Train, Split::Val] {
        for _ in 0..20 {
            let s = data.sample(&mut rng, split, &model, Windows::FromStart, None, FrameForm::Raw).unwrap();
            let (demo, agent) = data.trajectory(s.source);
            let env = |robot, t: &Trajectory| environment_of[&(robot, t.meta.instance_seed)];
            assert_eq!(env(Robot::Sawyer, demo), env(Robot::Panda, agent));
            assert_eq!((demo.meta.task, agent.meta.task), (s.task, s.task));
            assert_eq!(env(Robot::Panda, agent) == 2, split == Split::Val);
            // Each agent frame comes with the robot's state when it was seen: the fingers open at the start.
            let states: Vec<f32> = (0..model.agent_frames).flat_map(|t| agent.robot_state(s.start + t)).collect();
            assert_eq!(s.states, states);
            assert!((agent.robot_state(0)[7] - 1.0).abs() < 0.05, "open fingers read as 1: {:?}", agent.robot_state(0));
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
