//! bf16 autocast (`train.precision = "bf16"`): on inside its scope only, and a training step's losses and gradients
//! stay close to the fp32 step's for every architecture.
use crate::helpers::{random_batch, torch_rng};
use oneshot_lab::autocast::{Autocast, full_precision};
use oneshot_lab::model::architectures::ARCHITECTURES;
use oneshot_lab::model::batch::DeviceBatch;
use oneshot_lab::model::config::{Architecture, ModelConfig};
use oneshot_lab::model::policy::Policy;
use oneshot_lab::train::config::{LossWeights, Precision, TrainConfig, check_precision};
use tch::{Device, Kind, Tensor, nn};

#[test]
fn autocast_runs_matrix_products_in_bf16_inside_its_scope_only() {
    let opts = (Kind::Float, Device::Cpu);
    let (a, b) = (Tensor::ones([4, 8], opts), Tensor::ones([8, 3], opts));
    assert_eq!(a.matmul(&b).kind(), Kind::Float);
    {
        let _scope = Precision::Bf16.scope(Device::Cpu);
        assert!(Autocast::active(Device::Cpu));
        assert_eq!(a.matmul(&b).kind(), Kind::BFloat16);
        assert_eq!(a.exp().kind(), Kind::Float, "elementwise operations keep their type");
        assert_eq!(full_precision(|| a.matmul(&b)).kind(), Kind::Float, "full_precision suspends autocast");
        assert!(Autocast::active(Device::Cpu), "and restores it after");
    }
    assert!(!Autocast::active(Device::Cpu), "the scope's end restores fp32");
    assert_eq!(a.matmul(&b).kind(), Kind::Float);
    assert!(Precision::Fp32.scope(Device::Cpu).is_none());
}

/// The weighted loss of one batch and the gradient of every parameter, flattened, at `precision`.
fn step(vs: &nn::VarStore, policy: &Policy, batch: &DeviceBatch, precision: Precision) -> (f64, Tensor) {
    let mut vs_grads = vs.trainable_variables();
    for v in &mut vs_grads {
        v.zero_grad();
    }
    let total = {
        let _scope = precision.scope(Device::Cpu);
        LossWeights::default().total(&policy.losses(batch, false))
    };
    assert_eq!(total.kind(), Kind::Float, "losses are computed in fp32");
    total.backward();
    let grads: Vec<Tensor> =
        vs_grads.iter().filter(|v| v.grad().defined()).map(|v| v.grad().to_kind(Kind::Float).flatten(0, -1)).collect();
    (total.double_value(&[]), Tensor::cat(&grads, 0))
}

#[test]
fn a_bf16_step_stays_close_to_the_fp32_step_for_every_architecture() {
    let _rng = torch_rng();
    for registration in ARCHITECTURES.iter().filter(|r| r.bf16) {
        tch::manual_seed(7);
        let config = ModelConfig {
            architecture: Architecture::named(registration.name),
            backbone_width: 8,
            attention_inner: 16,
            embed_hidden: 32,
            dropout: 0.0,
            ..ModelConfig::default()
        };
        let vs = nn::VarStore::new(Device::Cpu);
        let policy = Policy::new(&vs.root(), &config);
        let batch = random_batch();
        let (loss32, grad32) = step(&vs, &policy, &batch, Precision::Fp32);
        let (loss16, grad16) = step(&vs, &policy, &batch, Precision::Bf16);
        let name = registration.name;
        let relative = (loss16 - loss32).abs() / loss32.abs();
        assert!(relative > 0.0, "{name}: bf16 gave exactly the fp32 loss, so autocast did nothing");
        assert!(relative < 0.02, "{name}: bf16 loss {loss16} is {relative:.4} away from fp32's {loss32}");
        let cosine = (&grad32 * &grad16).sum(Kind::Float).double_value(&[])
            / (grad32.norm().double_value(&[]) * grad16.norm().double_value(&[]));
        assert!(cosine > 0.98, "{name}: bf16 gradient at cosine {cosine:.4} from fp32's");
        eprintln!("{name}: loss {loss32:.4} (fp32) {loss16:.4} (bf16), gradient cosine {cosine:.5}");
    }
}

#[test]
fn bf16_is_refused_for_an_architecture_it_does_not_train_faithfully() {
    let model = ModelConfig { architecture: Architecture::named("daml"), ..ModelConfig::default() };
    let train = TrainConfig { precision: Precision::Bf16, ..TrainConfig::default() };
    let err = check_precision(&model, &train).unwrap_err().to_string();
    assert!(err.contains("train.precision") && err.contains("daml"), "{err}");
    assert!(check_precision(&model, &TrainConfig::default()).is_ok());
    assert!(check_precision(&ModelConfig::default(), &train).is_ok(), "the transformer trains in bf16");
}
