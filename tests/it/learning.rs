//! The chain learns: a handful of collected trajectories, a short training run, and in closed loop the policy
//! goes to the demonstrated object on its training layouts, which a random policy rarely does.
use crate::helpers::torch_rng;
use oneshot_lab::data::collect::collect;
use oneshot_lab::data::collect_config::{CollectConfig, CollectSettings, LayoutSharing};
use oneshot_lab::data::manifest::Manifest;
use oneshot_lab::eval::layouts::Layouts;
use oneshot_lab::eval::run::run_eval;
use oneshot_lab::eval::{ActionChoice, EpisodeResult, EvalConfig};
use oneshot_lab::eval::{Actor, Weights};
use oneshot_lab::model::config::ModelConfig;
use oneshot_lab::sim::camera::ImageSize;
use oneshot_lab::sim::camera::Visuals;
use oneshot_lab::sim::env::WorldConfig;
use oneshot_lab::sim::robot::Robot;
use oneshot_lab::train::config::{LrSchedule, MemoryFormat, TrainConfig};
use oneshot_lab::train::{TrainRun, train};

#[test]
fn a_briefly_trained_policy_goes_to_the_demonstrated_object_in_closed_loop() {
    let _rng = torch_rng();
    let dir = std::env::temp_dir().join(format!("oneshot-test-learning-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let world = WorldConfig {
        image: ImageSize { height: 48, width: 64 },
        visuals: Visuals::Collision,
        ..WorldConfig::default()
    };
    // Each slot a layout of its own, so that the last slot of each task is the held-out one.
    let settings = CollectSettings { tasks: vec![1, 14], layouts: LayoutSharing::Unique, ..CollectSettings::default() };
    for robot in Robot::ALL {
        let config = CollectConfig {
            per_task: 4,
            world: world.clone(),
            settings: settings.clone(),
            ..CollectConfig::paper(robot)
        };
        collect(&config, &dir.join(robot.name()), 2, false).unwrap();
    }
    let model = ModelConfig {
        backbone_width: 16,
        backbone_stages: 3,
        attention_inner: 32,
        embed_hidden: 64,
        ..ModelConfig::default()
    };
    let config = TrainConfig {
        steps: 600,
        batch_size: 8,
        lr: 3e-3,
        lr_schedule: LrSchedule::Cosine,
        lr_warmup: 50,
        device: "cpu".into(),
        val_interval: 600,
        val_batches: 1,
        checkpoint_interval: 600,
        val_fraction: 0.25,
        augment: false,
        prefetch: 0,
        memory_format: MemoryFormat::ChannelsLast,
        // Exact actions, as this run was calibrated with. Its outcome hangs on the targets' last bits: quantised to
        // 1/1024 (0.02 mm) it reached 2/6, to the authors' 1/128 0/6 (2026-12-03): a 600-step run on 12
        // trajectories is that fragile (docs/research/sixteen-tasks.md).
        action_resolution: 0,
        ..TrainConfig::default()
    };
    let (demos, agents) = (dir.join("sawyer"), dir.join("panda"));
    let out = dir.join("model");
    train(
        &model,
        &config,
        &TrainRun { demo_dir: &demos, agent_dir: &agents, per_task: None, out: &out, progress: false },
    )
    .unwrap();

    let layouts = Layouts::Training { demos: demos.clone(), agents: agents.clone() };
    let eval = EvalConfig {
        episodes: 8,
        horizon: 40,
        batch: 8,
        device: "cpu".into(),
        action: ActionChoice::Mode,
        ..EvalConfig::default()
    };
    let policy = Actor::Network(Weights { at: out.clone(), step: None });
    let (learned, _) = run_eval(&policy, None, &eval, &layouts, 2, None).unwrap();
    let (random, _) = run_eval(&Actor::Random, Some(&world), &eval, &layouts, 2, None).unwrap();
    // Episode i runs agent trajectory i's layout; the last slot of each task was held out for validation.
    let slots: Vec<usize> = Manifest::load(&agents).unwrap().trajectories.iter().map(|e| e.index).collect();
    let trained = |e: &&EpisodeResult| slots[e.index] < 3;
    let count = |episodes: &[EpisodeResult], stage: fn(&EpisodeResult) -> bool| {
        episodes.iter().filter(trained).filter(|e| stage(e)).count()
    };
    let (reached, picked) = (count(&learned, |e| e.reached), count(&learned, |e| e.picked));
    let (random_reached, random_picked) = (count(&random, |e| e.reached), count(&random, |e| e.picked));
    eprintln!(
        "trained policy on its 6 training layouts: reached {reached}, picked {picked}, placed {}; random: reached \
         {random_reached}, picked {random_picked}",
        count(&learned, |e| e.placed)
    );
    // What 600 steps on 12 trajectories achieve: the policy goes to the demonstrated object on the layouts it was
    // trained on, which a random policy rarely does; grasping it is not learned at this scale (see docs/research/).
    assert!(reached >= 5, "the trained policy reached {reached}/6");
    assert!(random_reached <= 2 && random_picked == 0, "random reached {random_reached}/6, picked {random_picked}/6");
    std::fs::remove_dir_all(&dir).unwrap();
}
