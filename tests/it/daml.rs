//! DAML's meta-learning: the inner step on the learned loss, and the second-order outer gradient.
use crate::helpers::{random_batch, seeded};
use oneshot_lab::model::architectures::daml::Daml;
use oneshot_lab::model::architectures::daml_trunk::TrunkKind;
use oneshot_lab::model::config::{Architecture, ModelConfig};
use oneshot_lab::model::mixture::MixtureSpec;
use oneshot_lab::model::policy::PolicyNet;
use tch::{Device, Kind, Tensor, nn};

fn tiny() -> ModelConfig {
    ModelConfig {
        architecture: Architecture::named("daml"),
        backbone_width: 8,
        backbone_stages: 3,
        embed_hidden: 32,
        ..ModelConfig::default()
    }
}

/// Both trunks, each with the prefix of one of its adapted weights' names.
const TRUNKS: [(TrunkKind, &str); 2] = [(TrunkKind::Conv, "conv3."), (TrunkKind::ResNet, "backbone.layer2.0.bn1.")];

/// The largest gradient entry of the variables whose names start with `prefix` (0 where none has a gradient).
fn largest_grad(vs: &nn::VarStore, prefix: &str) -> f64 {
    let vars = vs.variables();
    let grads: Vec<f64> = vars
        .iter()
        .filter(|(name, _)| name.starts_with(prefix))
        .map(|(_, t)| {
            let g = t.grad();
            if g.defined() { g.abs().max().double_value(&[]) } else { 0.0 }
        })
        .collect();
    assert!(!grads.is_empty(), "no variable is named {prefix}*");
    grads.into_iter().fold(0.0, f64::max)
}

#[test]
fn the_inner_step_adapts_every_trunk_and_action_weight_per_task() {
    for (trunk, _) in TRUNKS {
        inner_step_adapts_every_weight(trunk);
    }
}

fn inner_step_adapts_every_weight(trunk: TrunkKind) {
    let _rng = seeded(0);
    let vs = nn::VarStore::new(Device::Cpu);
    let daml = Daml::new(&vs.root(), &tiny(), trunk);
    let context = Tensor::randn([2, 4, 3, 32, 40], (Kind::Float, Device::Cpu));
    let adapted = daml.adapt(&context, true);
    let initial = daml.initial_weights();
    assert_eq!(adapted.len(), initial.len());
    for (k, (a, w)) in adapted.iter().zip(&initial).enumerate() {
        assert_eq!(a.size()[0], 2, "weight {k} has one adapted copy per task");
        for task in 0..2 {
            let change = (a.get(task) - w).abs().max().double_value(&[]);
            assert!(change > 0.0, "{trunk:?}: weight {k} of task {task} was not changed by the inner step");
        }
    }
    let between_tasks = (adapted[0].get(0) - adapted[0].get(1)).abs().max().double_value(&[]);
    assert!(between_tasks > 0.0, "{trunk:?}: another demonstration adapts differently");
}

#[test]
fn a_task_acts_the_same_alone_and_beside_another_task() {
    for (trunk, _) in TRUNKS {
        tasks_are_independent(trunk);
    }
}

fn tasks_are_independent(trunk: TrunkKind) {
    let _rng = seeded(3);
    let vs = nn::VarStore::new(Device::Cpu);
    let daml = Daml::new(&vs.root(), &tiny(), trunk);
    let b = random_batch();
    let together = daml.forward_t(&b.context, &b.agent, None, false).actions;
    let alone = daml.forward_t(&b.context.narrow(0, 0, 1), &b.agent.narrow(0, 0, 1), None, false).actions;
    let gap = (together.means.narrow(0, 0, 1) - &alone.means).abs().max().double_value(&[]);
    // Grouped and single-group convolutions round differently (about 1e-5 after the inner step); a leak between
    // tasks would move the actions by orders of magnitude more.
    assert!(gap < 1e-4, "{trunk:?}: task 0's actions depend on task 1 (largest difference {gap})");
    let other = daml.forward_t(&b.context.narrow(0, 1, 1), &b.agent.narrow(0, 0, 1), None, false).actions;
    let gap = (other.means - &alone.means).abs().max().double_value(&[]);
    assert!(gap > 1e-3, "{trunk:?}: another demonstration changes the actions (by {gap}), well beyond rounding");
}

#[test]
fn the_outer_gradient_reaches_the_learned_loss_only_through_the_second_order_step() {
    for (trunk, adapted) in TRUNKS {
        outer_gradient_is_second_order(trunk, adapted);
    }
}

fn outer_gradient_is_second_order(trunk: TrunkKind, adapted: &str) {
    let _rng = seeded(1);
    let config = tiny();
    let vs = nn::VarStore::new(Device::Cpu);
    let daml = Daml::new(&vs.root(), &config, trunk);
    let spec = MixtureSpec::for_model(&config);
    let b = random_batch();

    // Training (second order): behaviour cloning and pose regression reach the initial weights and the learned loss.
    let l = daml.losses(&b, spec, true);
    (&l.bc + &l.pose).backward();
    assert!(largest_grad(&vs, adapted) > 0.0, "{trunk:?}: the initial trunk weights get a gradient");
    assert!(largest_grad(&vs, "action_mlp.") > 0.0, "the initial action weights get a gradient");
    assert!(largest_grad(&vs, "pose.") > 0.0, "the pose head gets a gradient");
    assert!(largest_grad(&vs, "learned_loss.") > 0.0, "the learned loss is trained through the inner step");

    // A first-order step: the same outer loss leaves the learned loss without a gradient.
    let fresh = nn::VarStore::new(Device::Cpu);
    let first_order = Daml::new(&fresh.root(), &config, trunk);
    let l = first_order.losses(&b, spec, false);
    (&l.bc + &l.pose).backward();
    assert!(largest_grad(&fresh, adapted) > 0.0, "{trunk:?}: first order still trains the initial weights");
    assert_eq!(largest_grad(&fresh, "learned_loss."), 0.0, "{trunk:?}: first order never trains the learned loss");
}

#[test]
fn predicted_poses_come_from_the_first_agent_frame() {
    for (trunk, _) in TRUNKS {
        poses_from_first_frame(trunk);
    }
}

fn poses_from_first_frame(trunk: TrunkKind) {
    let _rng = seeded(2);
    let vs = nn::VarStore::new(Device::Cpu);
    let daml = Daml::new(&vs.root(), &tiny(), trunk);
    let b = random_batch();
    let poses = daml.predict_poses(&b.context, &b.agent).expect("DAML has a pose head");
    assert_eq!(poses.size(), [2, 6]);
    let later = b.agent.copy();
    let _ = later.narrow(1, 1, 6).fill_(2.0);
    let same = daml.predict_poses(&b.context, &later).unwrap();
    assert!(
        (&poses - &same).abs().max().double_value(&[]) < 1e-6,
        "{trunk:?}: later frames do not change the prediction"
    );
}

#[test]
fn the_resnet_trunk_updates_its_batch_norm_statistics_in_training_only() {
    let _rng = seeded(4);
    let config = tiny();
    let vs = nn::VarStore::new(Device::Cpu);
    let daml = Daml::new(&vs.root(), &config, TrunkKind::ResNet);
    let statistic = || vs.variables()["backbone.layer1.0.bn1.running_mean"].copy();
    let before = statistic();
    let b = random_batch();
    let _ = daml.forward_t(&b.context, &b.agent, None, false);
    assert!(before.equal(&statistic()), "evaluation leaves the running statistics alone");
    let _ = daml.losses(&b, MixtureSpec::for_model(&config), true);
    let moved = (statistic() - &before).abs().max().double_value(&[]);
    assert!(moved > 1e-4, "training moves the running statistics (by {moved})");
}
