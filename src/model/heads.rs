//! Small heads of the policy: spatial softmax, the normalised embedding MLP, the 2-D Gaussian point head, and the
//! action, inverse-dynamics and point heads that every architecture with the paper's losses ends in.
use super::config::{ModelConfig, PoseHeadInput};
use super::mixture::{MixtureHead, MixtureSpec};
use super::output::{PointPrediction, PolicyOutput};
use crate::sim::action::ACTION_RANGES;
use crate::sim::env::{STATE_DIM, STATE_FINGERS};
use crate::sim::task::NUM_TASKS;
use tch::nn::{self, Module, ModuleT};
use tch::{Kind, Tensor};

/// Expected (x, y) in [-1, 1] of each channel's spatial softmax: `[N, C, H, W]` to `[N, 2C]`.
pub fn spatial_softmax(x: &Tensor) -> Tensor {
    let (n, c, h, w) = x.size4().expect("features are [N, C, H, W]");
    let p = x.view([n, c, h * w]).softmax(-1, Kind::Float).view([n, c, h, w]);
    let opts = (Kind::Float, x.device());
    let xs = Tensor::linspace(-1.0, 1.0, w, opts);
    let ys = Tensor::linspace(-1.0, 1.0, h, opts);
    let ex = (p.sum_dim_intlist([2i64].as_slice(), false, Kind::Float) * xs).sum_dim_intlist(
        [-1i64].as_slice(),
        false,
        Kind::Float,
    );
    let ey = (p.sum_dim_intlist([3i64].as_slice(), false, Kind::Float) * ys).sum_dim_intlist(
        [-1i64].as_slice(),
        false,
        Kind::Float,
    );
    Tensor::cat(&[ex, ey], 1)
}

/// `model.object_attention`: attention from the task embedding over each agent frame's spatial tokens. Each head
/// projects the task to a query and every token of the frame to a key; its softmax over the frame's positions
/// gives a map whose expected (x, y) in [-1, 1] says where the demonstrated thing is in the agent's own view.
#[derive(Debug)]
pub struct ObjectAttention {
    query: nn::Linear,
    key: nn::Linear,
    heads: i64,
}

impl ObjectAttention {
    /// Attention of `heads` heads of `inner / heads` channels each, from `latent`-wide task embeddings over
    /// `channels`-wide tokens.
    pub fn new(vs: &nn::Path, latent: i64, channels: i64, heads: i64, inner: i64) -> ObjectAttention {
        let nobias = nn::LinearConfig { bias: false, ..Default::default() };
        ObjectAttention {
            query: nn::linear(vs / "query", latent, inner, nobias),
            key: nn::linear(vs / "key", channels, inner, nobias),
            heads,
        }
    }

    /// Output width: an (x, y) per head.
    pub fn width(&self) -> i64 {
        2 * self.heads
    }

    /// Expected positions `[B, Ta, 2 * heads]` (x then y per head) for task embeddings `[B, latent]` over frames
    /// `[B, Ta, C, h, w]`.
    pub fn forward(&self, task: &Tensor, frames: &Tensor) -> Tensor {
        let (b, ta, c, h, w) = frames.size5().expect("frames are [B, Ta, C, h, w]");
        let tokens = frames.permute([0, 1, 3, 4, 2]).reshape([b, ta, h * w, c]);
        let keys = self.key.forward(&tokens).view([b, ta, h * w, self.heads, -1]).permute([0, 1, 3, 2, 4]);
        let d = keys.size()[4];
        let query = self.query.forward(task).view([b, 1, self.heads, 1, d]);
        let scores = (keys * query).sum_dim_intlist([-1i64].as_slice(), false, Kind::Float) / (d as f64).sqrt();
        let maps = scores.softmax(-1, Kind::Float);
        let opts = (Kind::Float, frames.device());
        let xs = Tensor::linspace(-1.0, 1.0, w, opts).repeat([h]);
        let ys = Tensor::linspace(-1.0, 1.0, h, opts).repeat_interleave_self_int(w, 0, None);
        let grid = Tensor::stack(&[xs, ys], 1);
        maps.matmul(&grid).reshape([b, ta, 2 * self.heads])
    }
}

/// Linear -> dropout -> ReLU -> Linear -> L2 normalisation.
#[derive(Debug)]
pub struct EmbeddingMlp {
    hidden: nn::Linear,
    out: nn::Linear,
    dropout: f64,
}

impl EmbeddingMlp {
    /// An MLP from `input` to a unit vector of `latent` entries.
    pub fn new(vs: &nn::Path, input: i64, hidden: i64, latent: i64, dropout: f64) -> EmbeddingMlp {
        EmbeddingMlp {
            hidden: nn::linear(vs / "hidden", input, hidden, Default::default()),
            out: nn::linear(vs / "out", hidden, latent, Default::default()),
            dropout,
        }
    }
}

impl ModuleT for EmbeddingMlp {
    fn forward_t(&self, x: &Tensor, train: bool) -> Tensor {
        let y = self.hidden.forward(x).dropout(self.dropout, train).relu();
        let y = self.out.forward(&y);
        let norm = y.square().sum_dim_intlist([-1i64].as_slice(), true, Kind::Float).sqrt().clamp_min(1e-8);
        y / norm
    }
}

/// Linear -> ReLU -> Linear 5 -> (mean, Cholesky with softplus + 0.03 diagonal).
#[derive(Debug)]
pub struct PointHead {
    hidden: nn::Linear,
    out: nn::Linear,
}

impl PointHead {
    /// A head reading `input`-wide task embeddings.
    pub fn new(vs: &nn::Path, input: i64, hidden: i64) -> PointHead {
        PointHead {
            hidden: nn::linear(vs / "hidden", input, hidden, Default::default()),
            out: nn::linear(vs / "out", hidden, 5, Default::default()),
        }
    }

    /// The prediction for embeddings `[B, input]`.
    pub fn forward(&self, x: &Tensor) -> PointPrediction {
        let y = self.out.forward(&self.hidden.forward(x).relu());
        let mean = y.narrow(1, 0, 2);
        let a = y.narrow(1, 2, 1).softplus() + 0.03;
        let c = y.narrow(1, 3, 1);
        let b = y.narrow(1, 4, 1).softplus() + 0.03;
        PointPrediction { mean, cholesky: Tensor::cat(&[a, c, b], 1) }
    }
}

/// The paper's heads over a task embedding and per-frame embeddings: the action from [task, frame], inverse
/// dynamics from consecutive frames (through the same mixture head), the point from the task.
#[derive(Debug)]
pub struct PolicyHeads {
    policy: nn::Linear,
    inverse: nn::Linear,
    action_head: MixtureHead,
    point_head: PointHead,
    /// `model.pose_head`: its input (`model.pose_head_input`) -> hidden -> grasp and drop positions.
    pose_head: Option<(nn::Linear, nn::Linear)>,
    pose_input: PoseHeadInput,
    /// How many of the frame features' last entries are the object attention's positions.
    object_width: i64,
    /// `model.task_head`: task embedding -> logits of the sixteen tasks.
    task_head: Option<nn::Linear>,
    /// `model.concat_state`: the robot's state joins each frame's features where the action is read.
    concat_state: bool,
    /// `model.finger_motion`: the fingers' change since the previous frame joins it too.
    finger_motion: bool,
}

impl PolicyHeads {
    /// Heads over `latent`-wide task embeddings and `frame`-wide frame features (of which the last `object` are
    /// the object attention's positions), under `vs` (parameters `policy`, `inverse`, `action_head`,
    /// `point_head`, and `pose_head` and `task_head` when the model has them).
    pub fn new(vs: &nn::Path, latent: i64, frame: i64, object: i64, config: &ModelConfig) -> PolicyHeads {
        let state = match (config.concat_state, config.finger_motion) {
            (false, _) => 0,
            (true, false) => STATE_DIM as i64,
            (true, true) => STATE_DIM as i64 + 2,
        };
        let joint = latent + frame + state;
        let pose_width = match config.pose_head_input {
            PoseHeadInput::Joint => joint,
            PoseHeadInput::Object => latent + object,
        };
        PolicyHeads {
            policy: nn::linear(vs / "policy", joint, config.policy_hidden, Default::default()),
            inverse: nn::linear(vs / "inverse", 2 * frame, config.policy_hidden, Default::default()),
            action_head: MixtureHead::new(&(vs / "action_head"), config.policy_hidden, MixtureSpec::for_model(config)),
            point_head: PointHead::new(&(vs / "point_head"), latent, config.point_hidden),
            pose_head: config.pose_head.then(|| {
                let p = vs / "pose_head";
                (
                    nn::linear(&p / "hidden", pose_width, config.point_hidden, Default::default()),
                    nn::linear(&p / "out", config.point_hidden, 6, Default::default()),
                )
            }),
            pose_input: config.pose_head_input,
            object_width: object,
            task_head: config
                .task_head
                .then(|| nn::linear(vs / "task_head", latent, NUM_TASKS as i64, Default::default())),
            concat_state: config.concat_state,
            finger_motion: config.finger_motion,
        }
    }

    /// Outputs for a task embedding `[B, latent]` and frame features `[B, Ta, frame]` whose last `object`
    /// entries (see [`PolicyHeads::new`]) are the object attention's positions, and (with `model.concat_state`)
    /// the robot's state at each frame `[B, Ta, STATE_DIM]`.
    ///
    /// # Panics
    /// With `model.concat_state` and no states.
    pub fn forward(&self, task: &Tensor, frames: &Tensor, states: Option<&Tensor>) -> PolicyOutput {
        let (b, ta) = (frames.size()[0], frames.size()[1]);
        let task_per_frame = task.unsqueeze(1).expand([b, ta, -1], false);
        let joint = match (self.concat_state, states) {
            (false, _) => Tensor::cat(&[&task_per_frame, frames], -1),
            (true, Some(s)) => {
                let s = match self.finger_motion {
                    false => s.shallow_clone(),
                    true => Tensor::cat(&[s, &finger_motion(s)], -1),
                };
                Tensor::cat(&[&task_per_frame, frames, &s.to_kind(frames.kind())], -1)
            }
            (true, None) => panic!("model.concat_state: the network needs the robot's state at each agent frame"),
        };
        let hidden = self.policy.forward(&joint).relu();
        let pairs = Tensor::cat(&[frames.narrow(1, 0, ta - 1), frames.narrow(1, 1, ta - 1)], -1);
        PolicyOutput {
            actions: self.action_head.forward(&hidden),
            inverse: Some(self.action_head.forward(&self.inverse.forward(&pairs).relu())),
            point: Some(self.point_head.forward(task)),
            poses: self.pose_head.as_ref().map(|(h, o)| {
                let input = match self.pose_input {
                    PoseHeadInput::Joint => joint.shallow_clone(),
                    PoseHeadInput::Object => {
                        let width = self.object_width;
                        let object = frames.narrow(-1, frames.size()[2] - width, width);
                        Tensor::cat(&[task_per_frame.detach(), object], -1)
                    }
                };
                workspace_positions(&o.forward(&h.forward(&input).relu()))
            }),
            task_logits: self.task_logits(task),
        }
    }

    /// The task head's logits for task embeddings `[B, latent]` (none without `model.task_head`).
    pub fn task_logits(&self, task: &Tensor) -> Option<Tensor> {
        self.task_head.as_ref().map(|h| h.forward(task))
    }
}

/// Grasp and drop positions in metres `[..., 6]` from outputs `[..., 6]` in the units the actions are
/// normalised to (each coordinate's action range mapped to [-1, 1]). A head regressing metres directly starts
/// about a metre from its targets and spends its first hundreds of Adam steps moving its bias there; in these
/// units it starts in the workspace and one unit is a bin's width, as for the action head.
pub fn workspace_positions(normalised: &Tensor) -> Tensor {
    let (lo, span): (Vec<f32>, Vec<f32>) = (0..6)
        .map(|i| {
            let [lo, hi] = ACTION_RANGES[i % 3];
            (lo as f32, (hi - lo) as f32)
        })
        .unzip();
    let device = normalised.device();
    let (lo, span) = (Tensor::from_slice(&lo).to_device(device), Tensor::from_slice(&span).to_device(device));
    (normalised.to_kind(Kind::Float) + 1.0) * 0.5 * span + lo
}

/// Mean negative log-likelihood of targets `[B, 2]` under the predicted Gaussians.
pub fn point_nll(p: &PointPrediction, target: &Tensor) -> Tensor {
    // In fp32 whatever the forward pass ran in.
    let (mean, cholesky) = (p.mean.to_kind(Kind::Float), p.cholesky.to_kind(Kind::Float));
    let d = target - &mean;
    let (a, c, b) = (cholesky.select(1, 0), cholesky.select(1, 1), cholesky.select(1, 2));
    let z1 = d.select(1, 0) / &a;
    let z2 = (d.select(1, 1) - &c * &z1) / &b;
    let nll = (z1.square() + z2.square()) * 0.5 + a.log() + b.log() + (2.0 * std::f64::consts::PI).ln();
    nll.mean(Kind::Float)
}

/// How much a change of the fingers' state entries (each a joint over its 0.04 m travel) is magnified: a finger
/// that moved 5 mm since the previous frame reads 1.
const FINGER_MOTION_SCALE: f64 = 8.0;

/// Each frame's change of the two finger entries of the robot's state `[B, Ta, STATE_DIM]` since the window's
/// previous frame, scaled (`[B, Ta, 2]`; zero at the first frame, which has no previous one).
fn finger_motion(states: &Tensor) -> Tensor {
    let fingers = states.narrow(-1, STATE_FINGERS as i64, 2);
    let ta = fingers.size()[1];
    let first = fingers.narrow(1, 0, 1).zeros_like();
    let change = fingers.narrow(1, 1, ta - 1) - fingers.narrow(1, 0, ta - 1);
    Tensor::cat(&[first, change], 1) * FINGER_MOTION_SCALE
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finger_motion_is_the_scaled_change_since_the_previous_frame_and_none_at_the_first() {
        let states = Tensor::zeros([1, 3, STATE_DIM as i64], (Kind::Float, tch::Device::Cpu));
        // The first finger closes by 0.25 of its travel (1 cm) between frames 0 and 1, then stays; the second
        // stays; the other entries change without moving anything.
        let _ = states.narrow(2, STATE_FINGERS as i64, 1).narrow(1, 0, 1).fill_(1.0);
        let _ = states.narrow(2, STATE_FINGERS as i64, 1).narrow(1, 1, 2).fill_(0.75);
        let _ = states.narrow(2, 0, 3).narrow(1, 2, 1).fill_(5.0);
        let m = Vec::<f32>::try_from(finger_motion(&states).view([-1])).unwrap();
        assert_eq!(m.len(), 6);
        let expected = [0.0, 0.0, -2.0, 0.0, 0.0, 0.0];
        assert!(m.iter().zip(expected).all(|(a, b)| (a - b).abs() < 1e-6), "{m:?}");
    }

    #[test]
    fn spatial_softmax_finds_a_peak() {
        let x = Tensor::zeros([1, 1, 3, 5], (Kind::Float, tch::Device::Cpu));
        let _ = x.get(0).get(0).get(2).get(4).fill_(50.0);
        let s = spatial_softmax(&x);
        assert!((s.double_value(&[0, 0]) - 1.0).abs() < 1e-4 && (s.double_value(&[0, 1]) - 1.0).abs() < 1e-4);
    }

    #[test]
    fn object_attention_returns_the_position_of_the_object_the_task_names() {
        // Object A lights channel 0 at the top-left cell, object B channel 1 at the bottom-right one. The key is
        // channel 0 minus channel 1, the query the task's one entry: a positive task looks at A, a negative at B.
        let vs = nn::VarStore::new(tch::Device::Cpu);
        let attention = ObjectAttention::new(&vs.root(), 1, 2, 1, 1);
        tch::no_grad(|| {
            let mut vars = vs.variables();
            vars.get_mut("key.weight").unwrap().copy_(&Tensor::from_slice(&[1.0f32, -1.0]).view([1, 2]));
            vars.get_mut("query.weight").unwrap().copy_(&Tensor::from_slice(&[1.0f32]).view([1, 1]));
        });
        let frames = Tensor::zeros([1, 1, 2, 3, 5], (Kind::Float, tch::Device::Cpu));
        let _ = frames.get(0).get(0).get(0).get(0).get(0).fill_(1.0);
        let _ = frames.get(0).get(0).get(1).get(2).get(4).fill_(1.0);
        let at = |task: f32| -> Vec<f32> {
            let task = Tensor::from_slice(&[task]).view([1, 1]);
            Vec::try_from(attention.forward(&task, &frames).view([-1])).unwrap()
        };
        let (a, b) = (at(40.0), at(-40.0));
        assert!(a.iter().all(|v| (v + 1.0).abs() < 1e-3), "object A at (-1, -1): {a:?}");
        assert!(b.iter().all(|v| (v - 1.0).abs() < 1e-3), "object B at (1, 1): {b:?}");
        assert_eq!(attention.width(), 2);
    }

    #[test]
    fn an_object_pose_head_trains_the_object_positions_and_not_the_task_embedding() {
        let pose_gradients = |input: PoseHeadInput| {
            let vs = nn::VarStore::new(tch::Device::Cpu);
            let config = ModelConfig { pose_head: true, pose_head_input: input, ..ModelConfig::default() };
            let heads = PolicyHeads::new(&vs.root(), 3, 5, 2, &config);
            let opts = (Kind::Float, tch::Device::Cpu);
            let task = Tensor::randn([2, 3], opts).set_requires_grad(true);
            let frames = Tensor::randn([2, 4, 5], opts).set_requires_grad(true);
            heads.forward(&task, &frames, None).poses.unwrap().sum(Kind::Float).backward();
            let per_entry = frames.grad().abs().sum_dim_intlist([0i64, 1].as_slice(), false, Kind::Float);
            // An undefined gradient: nothing reached the task embedding.
            let task_grad = task.grad();
            let task_grad = if task_grad.defined() { task_grad.abs().sum(Kind::Float).double_value(&[]) } else { 0.0 };
            (task_grad, Vec::<f32>::try_from(per_entry).unwrap())
        };
        let (task, frame) = pose_gradients(PoseHeadInput::Object);
        assert_eq!(task, 0.0, "the pose loss must not reach the task embedding");
        assert!(frame[..3].iter().all(|g| *g == 0.0) && frame[3..].iter().all(|g| *g > 0.0), "{frame:?}");
        let (task, frame) = pose_gradients(PoseHeadInput::Joint);
        assert!(task > 0.0 && frame.iter().all(|g| *g > 0.0), "{task} {frame:?}");
    }

    #[test]
    fn workspace_positions_map_the_unit_range_onto_the_action_ranges() {
        let ends = Tensor::from_slice(&[-1.0f32, -1.0, -1.0, 1.0, 1.0, 1.0]).view([1, 6]);
        let m: Vec<f32> = Vec::try_from(workspace_positions(&ends).view([-1])).unwrap();
        let want = [0.44, -0.33, 0.82, 0.74, 0.5, 1.11];
        assert!(m.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-6), "{m:?}");
    }

    #[test]
    fn point_nll_matches_the_standard_normal_density() {
        // a = b = 1, c = 0 and mean 0 is the standard normal: NLL = log(2 pi) + |x|^2 / 2.
        let p = PointPrediction {
            mean: Tensor::zeros([1, 2], (Kind::Float, tch::Device::Cpu)),
            cholesky: Tensor::from_slice(&[1.0f32, 0.0, 1.0]).view([1, 3]),
        };
        let x = Tensor::from_slice(&[0.3f32, -0.4]).view([1, 2]);
        let expected = (2.0 * std::f64::consts::PI).ln() + 0.125;
        assert!((point_nll(&p, &x).double_value(&[]) - expected).abs() < 1e-5);
    }
}
