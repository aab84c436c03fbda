//! The chain learns: a small collection of two tasks, the sixteen-task recipe's trunk pretraining and policy at a
//! tiny scale, and in closed loop the policy picks up the demonstrated object on its training layouts, which a
//! random policy never does.
use crate::helpers::{scratch, torch_rng};
use oneshot_lab::data::collect::collect;
use oneshot_lab::data::collect_config::{CollectConfig, CollectSettings};
use oneshot_lab::data::manifest::Manifest;
use oneshot_lab::data::pairs::{Split, split_of};
use oneshot_lab::eval::layouts::Layouts;
use oneshot_lab::eval::run::run_eval;
use oneshot_lab::eval::{ActionChoice, EpisodeResult, EvalConfig};
use oneshot_lab::eval::{Actor, Weights};
use oneshot_lab::model::config::{ModelConfig, ObjectAttentionInput, ObjectAttentionQuery, PoseHeadInput};
use oneshot_lab::sim::camera::{ImageSize, Visuals};
use oneshot_lab::sim::env::WorldConfig;
use oneshot_lab::sim::robot::Robot;
use oneshot_lab::train::config::{LossWeights, LrSchedule, MemoryFormat, PoseFrames, TrainConfig};
use oneshot_lab::train::pretrain::{PretrainConfig, localise};
use oneshot_lab::train::{TrainRun, train};
use tch::Device;

/// Stages reached, picked and placed over the episodes on training layouts.
fn stages(episodes: &[EpisodeResult], training: &[bool]) -> [usize; 3] {
    let on_training = || episodes.iter().filter(|e| training[e.index]);
    [
        on_training().filter(|e| e.reached).count(),
        on_training().filter(|e| e.picked).count(),
        on_training().filter(|e| e.placed).count(),
    ]
}

#[test]
fn a_briefly_trained_policy_picks_up_the_demonstrated_object_in_closed_loop() {
    let _rng = torch_rng();
    let dir = scratch("learning");
    // learn_cpu16.toml's world at a third of its frame size: collision geometry, experts closing on arrival.
    let world = WorldConfig {
        image: ImageSize { height: 48, width: 64 },
        visuals: Visuals::Collision,
        close_on_arrival: true,
        ..WorldConfig::default()
    };
    // The authors' shared layouts: 16 slots of each task drawn from a pool of 16 environments, the last 4 of which
    // validate.
    let settings = CollectSettings { tasks: vec![1, 14], ..CollectSettings::default() };
    let collection = |robot| CollectConfig {
        per_task: 16,
        world: world.clone(),
        settings: settings.clone(),
        ..CollectConfig::paper(robot)
    };
    for robot in Robot::ALL {
        collect(&collection(robot), &dir.join(robot.name()), 2, false).unwrap();
    }
    let (demos, agents) = (dir.join("sawyer"), dir.join("panda"));

    // The recipe's pretraining, shortened: the trunk finds the four objects, then an object attention finds the
    // one each task names.
    let model = ModelConfig {
        backbone_width: 16,
        backbone_stages: 3,
        attention_inner: 32,
        embed_hidden: 64,
        dropout: 0.0,
        object_attention: true,
        object_attention_input: ObjectAttentionInput::FrozenTrunk,
        object_attention_query: ObjectAttentionQuery::TaskHead,
        task_head: true,
        pose_head: true,
        pose_head_input: PoseHeadInput::Object,
        ..ModelConfig::default()
    };
    let pretrain = PretrainConfig { steps: 1000, object_attention_steps: 1000, ..PretrainConfig::default() };
    let (trunk, attention) = (dir.join("trunk.safetensors"), dir.join("object_attention.safetensors"));
    let trunk_config = pretrain.localise((model.backbone_width, model.backbone_stages), None, 0, Some(trunk.clone()));
    localise(&agents, &trunk_config, Device::Cpu).unwrap();
    let shape = (model.attention_heads, model.attention_inner);
    let attention_config = pretrain.attention_phase(&trunk_config, shape, trunk.clone(), attention.clone()).unwrap();
    localise(&agents, &attention_config, Device::Cpu).unwrap();

    let model = ModelConfig {
        pretrained_backbone: Some(trunk.to_string_lossy().into_owned()),
        pretrained_object_attention: Some(attention.to_string_lossy().into_owned()),
        ..model
    };
    let config = TrainConfig {
        steps: 1500,
        batch_size: 8,
        lr: 3e-3,
        lr_schedule: LrSchedule::Cosine,
        lr_warmup: 100,
        device: "cpu".into(),
        val_interval: 1500,
        val_batches: 1,
        checkpoint_interval: 1500,
        val_fraction: 0.25,
        augment: false,
        loss: LossWeights { pose: 100.0, ..LossWeights::default() },
        pose_frames: PoseFrames::First,
        window_start: 0.5,
        action_resolution: 0,
        prefetch: 0,
        memory_format: MemoryFormat::ChannelsLast,
        ..TrainConfig::default()
    };
    let out = dir.join("model");
    let run = TrainRun { demo_dir: &demos, agent_dir: &agents, per_task: None, out: &out, progress: false };
    train(&model, &config, &run).unwrap();

    // Episode i runs agent trajectory i's layout with the same slot's demonstration.
    let layouts = Layouts::Training { demos: demos.clone(), agents: agents.clone() };
    let eval = EvalConfig {
        episodes: 32,
        horizon: 40,
        batch: 16,
        device: "cpu".into(),
        action: ActionChoice::Mode,
        ..EvalConfig::default()
    };
    let policy = Actor::Network(Weights { at: out.clone(), step: None });
    let (learned, _) = run_eval(&policy, None, &eval, &layouts, 2, None).unwrap();
    let (random, _) = run_eval(&Actor::Random, Some(&world), &eval, &layouts, 2, None).unwrap();
    let manifest = Manifest::load(&agents).unwrap();
    let training: Vec<bool> = manifest
        .trajectories
        .iter()
        .map(|e| split_of(e, &manifest.config, config.val_fraction) == Split::Train)
        .collect();
    let n = training.iter().filter(|&&t| t).count();
    let [reached, picked, placed] = stages(&learned, &training);
    let [random_reached, random_picked, _] = stages(&random, &training);
    eprintln!(
        "trained policy on its {n} training layouts: reached {reached}, picked {picked}, placed {placed}; random: \
         reached {random_reached}, picked {random_picked}"
    );
    // Measured over six training seeds and both layout schemes (docs/research/sixteen-tasks.md): 5 to 12 picked and
    // 3 to 10 placed of about 25, a random policy none; the bounds leave room for another machine's arithmetic.
    assert!(n >= 20, "{n} training layouts: the pool's last 4 environments validate");
    assert!(reached * 4 >= n * 3, "the trained policy reached {reached}/{n}");
    assert!(picked >= 3, "the trained policy picked {picked}/{n}");
    assert!(placed >= 1, "the trained policy placed {placed}/{n}");
    assert_eq!(random_picked, 0, "random picked {random_picked}/{n}");
    std::fs::remove_dir_all(&dir).unwrap();
}
