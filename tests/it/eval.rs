//! Closed-loop evaluation: reference policies, reproducibility, unseen layouts.
use crate::helpers::{scratch, torch_rng};
use oneshot_lab::eval::EvalConfig;
use oneshot_lab::eval::layouts::Layouts;
use oneshot_lab::eval::run::run_eval;
use oneshot_lab::eval::{ActionChoice, Actor, Weights};
use oneshot_lab::model::config::ModelConfig;
use oneshot_lab::sim::camera::{ImageSize, Visuals};
use oneshot_lab::sim::env::{ObjectSet, STATE_VERSION, WorldConfig};
use oneshot_lab::sim::object::Object;
use oneshot_lab::train::{FINAL_INFO, FINAL_WEIGHTS, TrainSummary, build_policy, checkpoint, load_trained};
use std::collections::HashSet;

/// 32x40 frames of collision geometry: collected about four times faster than with the visual meshes on Mesa.
fn world() -> WorldConfig {
    WorldConfig { image: ImageSize { height: 32, width: 40 }, visuals: Visuals::Collision, ..WorldConfig::default() }
}

fn config(episodes: usize, horizon: usize) -> EvalConfig {
    EvalConfig { episodes, horizon, batch: 8, device: "cpu".into(), ..EvalConfig::default() }
}

#[test]
fn the_expert_places_and_the_random_policy_does_not() {
    let _rng = torch_rng();
    let none = HashSet::new();
    let (_, expert) =
        run_eval(&Actor::Expert, Some(&world()), &config(16, 80), &Layouts::Fresh(none.clone()), 2, None).unwrap();
    let placed = expert.overall.placed;
    assert!(placed.value >= 15.0 / 16.0, "expert placed {placed:?}");
    // The expert closes on its object: every episode records the first close, the picked ones with the object
    // between the fingers (within the reach radius across and sideways).
    let grasps = expert.grasps.as_ref().unwrap();
    assert_eq!(grasps.closed.value, 1.0, "{grasps:?}");
    let picked = grasps.picked.unwrap();
    assert!(picked.closes >= 15 && picked.across < 0.03 && picked.sideways < 0.03, "{picked:?}");
    assert!(placed.low < placed.value && placed.high >= placed.value);
    let (episodes, random) =
        run_eval(&Actor::Random, Some(&world()), &config(16, 30), &Layouts::Fresh(none.clone()), 2, None).unwrap();
    assert_eq!(random.overall.placed.value, 0.0);
    let random_closes = episodes.iter().filter(|e| e.first_close.is_some()).count();
    assert_eq!(random.grasps.unwrap().closed.value, random_closes as f64 / 16.0);
    assert!(episodes.iter().all(|e| e.steps == 30));
    let tasks: HashSet<usize> = episodes.iter().map(|e| e.task).collect();
    assert_eq!(tasks.len(), 16, "episodes cover every task");
}

#[test]
fn in_the_multi_object_world_the_expert_places_the_held_out_objects_in_their_own_quadrants() {
    let _rng = torch_rng();
    let library = WorldConfig { objects: ObjectSet::Library, close_on_arrival: true, ..world() };
    let layouts = Layouts::Fresh(HashSet::new());
    let (episodes, summary) = run_eval(&Actor::Expert, Some(&library), &config(16, 80), &layouts, 2, None).unwrap();
    assert!(summary.overall.placed.value >= 14.0 / 16.0, "expert placed {:?}", summary.overall.placed);
    assert!(episodes.iter().all(|e| !(e.placed && e.wrong_bin)), "a placed object is in its own quadrant");
}

#[test]
fn the_same_checkpoint_seed_and_count_give_the_same_episodes_and_another_state_encoding_is_refused() {
    let _rng = torch_rng();
    let dir = scratch("eval-repeat");
    let model = ModelConfig { backbone_width: 8, attention_inner: 16, embed_hidden: 32, ..ModelConfig::default() };
    tch::manual_seed(5);
    let (vs, _) = build_policy(&model, tch::Device::Cpu).unwrap();
    checkpoint::save(&vs, &dir.join(FINAL_WEIGHTS)).unwrap();
    let summary = TrainSummary::untrained(model.clone(), world(), 90);
    std::fs::write(dir.join(FINAL_INFO), serde_json::to_string(&summary).unwrap()).unwrap();
    let policy = Actor::Network(Weights { at: dir.clone(), step: None });
    let none = HashSet::new();
    let (a, _) = run_eval(&policy, Some(&world()), &config(4, 8), &Layouts::Fresh(none.clone()), 2, None).unwrap();
    let (b, _) = run_eval(&policy, Some(&world()), &config(4, 8), &Layouts::Fresh(none.clone()), 1, None).unwrap();
    assert_eq!(a, b);
    assert!(a.iter().all(|e| e.steps == 8 || e.placed));
    // The most likely action and a sampled component's mean go through the same rollout, as reproducibly.
    for action in [ActionChoice::Mode, ActionChoice::Component] {
        let chosen = EvalConfig { action, ..config(4, 8) };
        let (x, _) = run_eval(&policy, Some(&world()), &chosen, &Layouts::Fresh(none.clone()), 2, None).unwrap();
        let (y, _) = run_eval(&policy, Some(&world()), &chosen, &Layouts::Fresh(none.clone()), 1, None).unwrap();
        assert_eq!(x, y, "{action:?}");
    }
    // A network that reads the robot's state runs on the state observed with each frame, as reproducibly.
    let stated = scratch("eval-repeat-state");
    let model = ModelConfig { concat_state: true, ..model };
    let (vs, _) = build_policy(&model, tch::Device::Cpu).unwrap();
    checkpoint::save(&vs, &stated.join(FINAL_WEIGHTS)).unwrap();
    let summary = TrainSummary::untrained(model, world(), 90);
    std::fs::write(stated.join(FINAL_INFO), serde_json::to_string(&summary).unwrap()).unwrap();
    let policy = Actor::Network(Weights { at: stated.clone(), step: None });
    let (c, _) = run_eval(&policy, Some(&world()), &config(4, 8), &Layouts::Fresh(none.clone()), 2, None).unwrap();
    let (d, _) = run_eval(&policy, Some(&world()), &config(4, 8), &Layouts::Fresh(none.clone()), 1, None).unwrap();
    assert_eq!(c, d);
    assert!(c.iter().all(|e| e.steps == 8 || e.placed));
    // One trained on another encoding of the state is refused, naming its file.
    let mut summary: TrainSummary = serde_json::from_slice(&std::fs::read(stated.join(FINAL_INFO)).unwrap()).unwrap();
    summary.state_version = Some(STATE_VERSION + 1);
    std::fs::write(stated.join(FINAL_INFO), serde_json::to_string(&summary).unwrap()).unwrap();
    let err = load_trained(&stated, None, tch::Device::Cpu).err().expect("another encoding is refused").to_string();
    assert!(err.contains(FINAL_INFO) && err.contains(&format!("version {}", STATE_VERSION + 1)), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
    std::fs::remove_dir_all(&stated).unwrap();
}

#[test]
fn evaluation_layouts_avoid_training_seeds() {
    let _rng = torch_rng();
    let c = config(32, 10);
    let first = c.episode_specs(ObjectSet::Base, &HashSet::new());
    let taken: HashSet<u64> = first.iter().take(5).map(|e| e.agent_seed).chain([first[7].demo_seed]).collect();
    let second = c.episode_specs(ObjectSet::Base, &taken);
    assert!(second.iter().all(|e| !taken.contains(&e.agent_seed) && !taken.contains(&e.demo_seed)));
    assert_eq!(first[10], second[10], "episodes without a clash keep their layouts");
}

#[test]
fn daml_auxiliary_hands_the_agent_to_the_scripted_expert_and_needs_a_pose_head() {
    let _rng = torch_rng();
    use oneshot_lab::eval::config::Control;
    use oneshot_lab::model::config::Architecture;
    let save = |name: &str, model: ModelConfig| {
        let dir = scratch(name);
        tch::manual_seed(6);
        let (vs, _) = build_policy(&model, tch::Device::Cpu).unwrap();
        checkpoint::save(&vs, &dir.join(FINAL_WEIGHTS)).unwrap();
        let summary = TrainSummary::untrained(model, world(), 90);
        std::fs::write(dir.join(FINAL_INFO), serde_json::to_string(&summary).unwrap()).unwrap();
        Actor::Network(Weights { at: dir, step: None })
    };
    let none = HashSet::new();
    let daml = ModelConfig { architecture: Architecture::named("daml"), backbone_width: 8, ..ModelConfig::default() };
    let policy = save("daml", daml);
    let own = EvalConfig { strips: vec![0], ..config(2, 12) };
    let scripted = EvalConfig { control: Control::ScriptedPoses, ..own.clone() };
    let out = scratch("eval-outputs");
    let (a, _) =
        run_eval(&policy, Some(&world()), &scripted, &Layouts::Fresh(none.clone()), 1, Some(&out.join("a"))).unwrap();
    run_eval(&policy, Some(&world()), &own, &Layouts::Fresh(none.clone()), 1, Some(&out.join("b"))).unwrap();
    assert!(a.iter().all(|e| e.steps == 12 || e.placed));
    let strip = |run: &str| {
        let dir = out.join(run).join("strips");
        let file = std::fs::read_dir(&dir).unwrap().next().expect("one strip").unwrap().path();
        std::fs::read(file).unwrap()
    };
    assert_ne!(strip("a"), strip("b"), "the scripted expert, not the network's actions, moves the agent");

    let transformer = save("transformer", ModelConfig { backbone_width: 8, ..ModelConfig::default() });
    let err = run_eval(&transformer, Some(&world()), &scripted, &Layouts::Fresh(none), 1, None).unwrap_err();
    assert!(format!("{err:#}").contains("eval.control = \"scripted_poses\""), "{err:#}");
}

#[test]
fn the_localisation_check_fits_grasp_and_object_positions_of_its_training_frames() {
    use oneshot_lab::data::collect::collect;
    use oneshot_lab::data::collect_config::{CollectConfig, CollectSettings, LayoutSharing};
    use oneshot_lab::data::manifest::Manifest;
    use oneshot_lab::sim::robot::Robot;
    use oneshot_lab::train::pretrain::{LocaliseConfig, LocaliseTarget, localise};
    let _guard = torch_rng();
    let dir = scratch("eval-localise");
    // Each slot a layout of its own, so that every fifth trajectory is held out.
    let settings = CollectSettings { tasks: vec![1], layouts: LayoutSharing::Unique, ..CollectSettings::default() };
    let collection = CollectConfig { per_task: 20, world: world(), settings, ..CollectConfig::paper(Robot::Panda) };
    collect(&collection, &dir.join("panda"), 2, false).unwrap();
    let config = LocaliseConfig {
        backbone_width: 8,
        backbone_stages: 2,
        steps: 150,
        batch: 16,
        lr: 1e-3,
        per_task: None,
        hold_out_every: 5,
        report_every: 50,
        seed: 0,
        target: LocaliseTarget::Grasp,
        trunk_out: None,
        augmentation: None,
        object_attention: false,
        init_trunk: None,
        attention_shape: oneshot_lab::train::pretrain::ATTENTION_SHAPE,
        attention_out: None,
        curve_out: None,
    };
    let trunk_file = dir.join("trunks").join("trunk.safetensors");
    let mut last_train = vec![];
    let jitter = oneshot_lab::data::augment::Augmentation::default();
    for (target, augmentation, object_attention) in [
        (LocaliseTarget::Grasp, None, false),
        (LocaliseTarget::Objects, None, false),
        (LocaliseTarget::Objects, Some(jitter), false),
        (LocaliseTarget::Grasp, None, true),
    ] {
        let trunk_out = (target == LocaliseTarget::Objects && augmentation.is_none()).then(|| trunk_file.clone());
        // The object attention's run keeps its curve as it goes: what it returns, point for point.
        let curve_out = object_attention.then(|| dir.join("attention_curve.jsonl"));
        let run = LocaliseConfig { target, trunk_out, augmentation, object_attention, curve_out, ..config.clone() };
        let r = localise(&dir.join("panda"), &run, tch::Device::Cpu).unwrap();
        if let Some(path) = &run.curve_out {
            assert_eq!(oneshot_lab::train::pretrain::read_curve(path).unwrap(), r.curve);
        }
        last_train.push(r.curve[3].train);
        assert_eq!((r.train_frames, r.held_out_frames, r.height, r.width), (16, 4, 32, 40));
        assert_eq!(r.curve.iter().map(|e| e.step).collect::<Vec<_>>(), [0, 50, 100, 150]);
        let (first, last) = (r.curve[0].train, r.curve[3].train);
        // Augmented frames are harder to fit in 150 steps: they need only to have started.
        let goal = if run.augmentation.is_some() { 0.9 } else { 0.5 };
        assert!(
            last[0] + last[1] < goal * (first[0] + first[1]),
            "{target:?}: error did not fall: {first:?} -> {last:?}"
        );
        // Objects lie anywhere in the 40 x 50 cm source bin: the mean misses by centimetres, not metres.
        assert!(r.mean_baseline.iter().all(|&e| e > 0.01 && e < 0.2), "{target:?}: {:?}", r.mean_baseline);
    }
    // The first 10 slots of the task only: 8 training and 2 held-out layouts.
    let subset = LocaliseConfig { per_task: Some(10), steps: 1, report_every: 1, ..config.clone() };
    let r = localise(&dir.join("panda"), &subset, tch::Device::Cpu).unwrap();
    assert_eq!((r.train_frames, r.held_out_frames), (8, 2));
    // A run started from the saved trunk begins elsewhere than one from scratch (same seed, same head); a missing
    // trunk file is an error naming it.
    let from = |init_trunk: Option<std::path::PathBuf>| {
        let run = LocaliseConfig { steps: 1, report_every: 1, init_trunk, ..config.clone() };
        localise(&dir.join("panda"), &run, tch::Device::Cpu)
    };
    let (scratch_start, trunk_start) = (from(None).unwrap().curve[0].train, from(Some(trunk_file.clone())).unwrap());
    assert_ne!(scratch_start, trunk_start.curve[0].train);
    let err = format!("{:#}", from(Some(dir.join("no-trunk.safetensors"))).unwrap_err());
    assert!(err.contains("no-trunk.safetensors"), "{err}");
    // Augmented training frames (same seed, same batches) train a different trunk.
    assert_ne!(last_train[1], last_train[2]);
    // The trained trunk starts a policy of the same widths through `model.pretrained_backbone`: every one of the
    // policy's trunk tensors (batch-norm statistics included) is the saved one.
    let saved: std::collections::HashMap<String, tch::Tensor> =
        tch::Tensor::read_safetensors(&trunk_file).unwrap().into_iter().collect();
    let model = oneshot_lab::model::config::ModelConfig {
        backbone_width: 8,
        backbone_stages: 2,
        pretrained_backbone: Some(trunk_file.to_string_lossy().into()),
        ..Default::default()
    };
    let (vs, _) = oneshot_lab::train::build_policy(&model, tch::Device::Cpu).unwrap();
    let trunk: Vec<_> = vs.variables().into_iter().filter(|(n, _)| n.starts_with("backbone.")).collect();
    assert_eq!(trunk.len(), saved.len());
    for (name, t) in &trunk {
        assert!(t.equal(&saved[&name["backbone.".len()..]]), "{name}");
    }

    // Shared layouts are held out by environment: every trajectory of an environment on one side.
    let shared = CollectConfig {
        settings: CollectSettings { layouts: LayoutSharing::Shared, ..collection.settings.clone() },
        ..collection.clone()
    };
    collect(&shared, &dir.join("shared"), 2, false).unwrap();
    let envs: Vec<u64> =
        Manifest::load(&dir.join("shared")).unwrap().trajectories.iter().map(|e| e.environment.unwrap()).collect();
    let held = envs.iter().filter(|&&e| e % 5 == 0).count();
    assert!(held > 0 && held < envs.len(), "{envs:?}");
    let r = localise(
        &dir.join("shared"),
        &LocaliseConfig { steps: 1, report_every: 1, ..config.clone() },
        tch::Device::Cpu,
    )
    .unwrap();
    assert_eq!((r.train_frames, r.held_out_frames), (envs.len() - held, held));

    let untold = LocaliseConfig { target: LocaliseTarget::Objects, object_attention: true, ..config.clone() };
    let err = localise(&dir.join("panda"), &untold, tch::Device::Cpu).unwrap_err().to_string();
    assert!(err.contains("object attention") && err.contains("grasp"), "{err}");

    let missing = localise(&dir.join("nowhere"), &config, tch::Device::Cpu).unwrap_err();
    assert!(format!("{missing:#}").contains("nowhere"), "{missing:#}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_filmed_episode_replays_to_the_same_frames_and_renders_larger_for_its_video() {
    use oneshot_lab::eval::EpisodeResult;
    use oneshot_lab::eval::video::{replay, video_size};
    use oneshot_lab::sim::env::Env;
    use oneshot_lab::sim::expert::Expert;
    use oneshot_lab::sim::robot::Robot;
    use oneshot_lab::sim::task::{Instance, Task};
    // An episode as the evaluation runs it: the agent's scene stepped by its actions, its frames rendered.
    let world = world();
    let task = Task::from_id(6).unwrap();
    let (agent_seed, demo_seed) = (11, 12);
    let mut env = Env::new(Robot::Panda, &world, true).unwrap();
    env.reset(&Instance::sample(task, agent_seed)).unwrap();
    let mut expert = Expert::new(&env);
    let (mut frames, mut actions) = (vec![env.render().unwrap()], vec![]);
    for _ in 0..40 {
        let a = expert.act(&env);
        env.step(&a);
        actions.push(a);
        frames.push(env.render().unwrap());
    }
    let m = env.milestones();
    let result = EpisodeResult {
        index: 0,
        task: 6,
        agent_seed,
        demo_seed,
        reached: m.reached,
        picked: m.picked,
        placed: m.placed,
        wrong_bin: false,
        steps: actions.len(),
        first_reached: None,
        first_picked: None,
        first_placed: None,
        first_close: None,
    };
    assert!(m.picked, "the expert picks within 40 actions");

    // At the policy's size the replay is the episode, frame for frame.
    let (demo, agent) = replay(&world, world.image, &result, Object::ALL, &actions, 100).unwrap();
    assert_eq!(agent.len(), frames.len());
    assert!(agent.iter().zip(&frames).all(|((a, _), f)| a == f), "the replay renders the episode's own frames");
    assert!(!demo.is_empty() && demo[0].len() == frames[0].len());

    // At the video's size, the same path, four times as wide and high.
    let big = video_size(world.image, 160);
    assert_eq!((big.height, big.width), (128, 160));
    let (demo, agent) = replay(&world, big, &result, Object::ALL, &actions, 100).unwrap();
    assert_eq!(agent.len(), frames.len());
    assert!(agent.iter().map(|(f, _)| f).chain(&demo).all(|f| f.len() == big.rgb_len()));
    assert_eq!(agent.last().unwrap().1, m);
    assert_eq!(video_size(world.image, 40), world.image, "frames already as wide are kept");

    // A replay that does not end where the episode did is refused.
    let claimed = EpisodeResult { placed: !m.placed, ..result };
    let err = replay(&world, world.image, &claimed, Object::ALL, &actions, 100).unwrap_err().to_string();
    assert!(err.contains("replay of episode 0"), "{err}");
}

#[test]
fn traces_record_every_step_of_every_episode_as_the_episodes_saw_it() {
    use oneshot_lab::eval::EpisodeTrace;
    use oneshot_lab::eval::run::{EPISODES_FILE, TRACES_FILE};
    let _rng = torch_rng();
    let out = scratch("eval-traces");
    let none = HashSet::new();
    let traced = EvalConfig { traces: true, ..config(4, 40) };
    let err = run_eval(&Actor::Expert, Some(&world()), &traced, &Layouts::Fresh(none.clone()), 1, None).unwrap_err();
    assert!(err.to_string().contains("--out"), "{err}");
    let (episodes, summary) =
        run_eval(&Actor::Expert, Some(&world()), &traced, &Layouts::Fresh(none.clone()), 1, Some(&out)).unwrap();
    // The expert holds its object on the table in every episode, never lets go there, and lifts it.
    let holds = summary.holds.expect("traced evaluations summarise the holds");
    assert_eq!((holds.episodes, holds.opened), (4, 0.0), "{holds:?}");
    assert!(holds.lifted > 0.0 && holds.steps >= 4, "{holds:?}");
    let lines = std::fs::read_to_string(out.join(TRACES_FILE)).unwrap();
    let traces: Vec<EpisodeTrace> = lines.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(traces.len(), episodes.len());
    for (trace, episode) in traces.iter().zip(&episodes) {
        assert_eq!(trace.index, episode.index);
        assert_eq!(trace.steps.len(), episode.steps, "one line per step taken");
        let last = trace.steps.last().unwrap();
        assert_eq!((last.reached, last.picked, last.placed), (episode.reached, episode.picked, episode.placed));
        let close = episode.first_close.expect("the expert closes");
        let first = trace.steps.iter().find(|s| s.action[7] > 0.0).unwrap();
        assert_eq!((first.step, first.object_in_gripper), (close.step, close.object_in_gripper));
        // Closed on its object, the fingers stop apart (they meet only on air), and the lift raises the gripper.
        let held = trace.steps.iter().find(|s| s.picked).expect("the expert picks");
        assert!(held.fingers[0] - held.fingers[1] > 0.01, "{:?}", held.fingers);
        assert!(held.gripper_pos[2] > first.gripper_pos[2] + 0.03);
    }
    // Untraced, the folder holds no traces, and the episodes are the same.
    let plain = scratch("eval-untraced");
    let (again, untraced) =
        run_eval(&Actor::Expert, Some(&world()), &config(4, 40), &Layouts::Fresh(none), 1, Some(&plain)).unwrap();
    assert_eq!(again, episodes);
    assert!(untraced.holds.is_none());
    assert!(plain.join(EPISODES_FILE).exists() && !plain.join(TRACES_FILE).exists());
}
