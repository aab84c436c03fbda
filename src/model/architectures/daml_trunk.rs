//! DAML's per-frame feature networks, applied with one copy of their weights per task: the authors' `DAMLNetwork`
//! builds either a conv stack (VGG-16's first block, then three 3x3 convolutions of strides 2, 2, 1) or, with
//! `n_final_convs = "resnet"`, a ResNet-18 whose spatial-softmax features pass through a small MLP (Linear to 256,
//! Dropout 0.2, ReLU, Linear to 256). The tasks of a batch run as the groups of grouped convolutions: frames become
//! the batch, each task's channels one group, so that every task sees its own adapted weights in one call.
use crate::model::heads::spatial_softmax;
use std::slice::Iter;
use tch::nn;
use tch::{Kind, Tensor};

/// Which feature network DAML adapts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TrunkKind {
    /// The authors' default: VGG-16's first block and three more convolutions (`n_final_convs` channels).
    Conv,
    /// The authors' `n_final_convs = "resnet"`: ResNet-18, spatial softmax and an embedding MLP.
    ResNet,
}

/// Dropout of the ResNet trunk's embedding MLP (the authors' 0.2).
const EMBED_DROPOUT: f64 = 0.2;

/// A convolution whose kernel (and bias) the caller supplies per task.
#[derive(Debug)]
struct Conv {
    layer: nn::Conv2D,
    input: i64,
    output: i64,
    kernel: i64,
    stride: i64,
}

impl Conv {
    fn new(vs: nn::Path, input: i64, output: i64, kernel: i64, stride: i64, bias: bool) -> Conv {
        let config = nn::ConvConfig { stride, padding: kernel / 2, bias, ..Default::default() };
        Conv { layer: nn::conv2d(vs, input, output, kernel, config), input, output, kernel, stride }
    }

    fn params(&self) -> Vec<Tensor> {
        std::iter::once(self.layer.ws.shallow_clone()).chain(self.layer.bs.iter().map(Tensor::shallow_clone)).collect()
    }

    /// `x` is `[N, tasks * input, H, W]`; the next weights are this layer's, `[tasks, ...]` each.
    fn apply(&self, weights: &mut Iter<Tensor>, x: &Tensor, tasks: i64) -> Tensor {
        let kernel = next(weights).reshape([tasks * self.output, self.input, self.kernel, self.kernel]);
        let bias = self.layer.bs.as_ref().map(|_| next(weights).reshape([-1]));
        x.conv2d(&kernel, bias.as_ref(), [self.stride], [self.kernel / 2], [1], tasks)
    }
}

/// A batch norm whose scale and shift the caller supplies per task. In training each task's channels are
/// normalised over that task's frames (as the authors' per-task loop does); the running statistics stay shared,
/// updated with the tasks' average.
#[derive(Debug)]
struct Norm(nn::BatchNorm);

impl Norm {
    fn new(vs: nn::Path, channels: i64) -> Norm {
        Norm(nn::batch_norm2d(vs, channels, Default::default()))
    }

    fn params(&self) -> Vec<Tensor> {
        [&self.0.ws, &self.0.bs].iter().map(|t| t.as_ref().expect("affine batch norm").shallow_clone()).collect()
    }

    fn apply(&self, weights: &mut Iter<Tensor>, x: &Tensor, tasks: i64, train: bool) -> Tensor {
        let (scale, shift) = (next(weights).reshape([-1]), next(weights).reshape([-1]));
        let mean = self.0.running_mean.repeat([tasks]);
        let var = self.0.running_var.repeat([tasks]);
        let y = x.batch_norm(Some(&scale), Some(&shift), Some(&mean), Some(&var), train, 0.1, 1e-5, false);
        if train {
            tch::no_grad(|| {
                self.0.running_mean.shallow_clone().copy_(&mean.view([tasks, -1]).mean_dim(0, false, Kind::Float));
                self.0.running_var.shallow_clone().copy_(&var.view([tasks, -1]).mean_dim(0, false, Kind::Float));
            });
        }
        y
    }
}

/// ResNet-18's basic block: two 3x3 convolutions with a (projected) shortcut.
#[derive(Debug)]
struct Block {
    conv1: Conv,
    bn1: Norm,
    conv2: Conv,
    bn2: Norm,
    downsample: Option<(Conv, Norm)>,
}

impl Block {
    fn new(vs: &nn::Path, input: i64, output: i64, stride: i64) -> Block {
        let downsample = (stride != 1 || input != output).then(|| {
            (
                Conv::new(vs / "downsample" / "0", input, output, 1, stride, false),
                Norm::new(vs / "downsample" / "1", output),
            )
        });
        Block {
            conv1: Conv::new(vs / "conv1", input, output, 3, stride, false),
            bn1: Norm::new(vs / "bn1", output),
            conv2: Conv::new(vs / "conv2", output, output, 3, 1, false),
            bn2: Norm::new(vs / "bn2", output),
            downsample,
        }
    }

    fn params(&self) -> Vec<Tensor> {
        let mut p = self.conv1.params();
        p.extend(self.bn1.params());
        p.extend(self.conv2.params());
        p.extend(self.bn2.params());
        if let Some((c, n)) = &self.downsample {
            p.extend(c.params());
            p.extend(n.params());
        }
        p
    }

    fn apply(&self, w: &mut Iter<Tensor>, x: &Tensor, tasks: i64, train: bool) -> Tensor {
        let y = self.conv1.apply(w, x, tasks);
        let y = self.bn1.apply(w, &y, tasks, train).relu();
        let y = self.conv2.apply(w, &y, tasks);
        let y = self.bn2.apply(w, &y, tasks, train);
        let shortcut = match &self.downsample {
            Some((c, n)) => {
                let projected = c.apply(w, x, tasks);
                n.apply(w, &projected, tasks, train)
            }
            None => x.shallow_clone(),
        };
        (y + shortcut).relu()
    }
}

/// The layers of one trunk, in the order their weights are listed.
#[derive(Debug)]
enum Layers {
    /// Convolutions (each followed by ReLU; a 2x2 max-pool after the second).
    Conv(Vec<Conv>),
    /// ResNet-18's stem and blocks, then the embedding MLP's two layers.
    ResNet { stem: Box<(Conv, Norm)>, blocks: Vec<Block>, embed: Box<[nn::Linear; 2]> },
}

/// DAML's per-frame feature network.
#[derive(Debug)]
pub struct Trunk {
    layers: Layers,
    features: i64,
}

impl Trunk {
    /// The conv trunk (`width` channels throughout: VGG-16's 64 at the paper's size) under `vs`, named like
    /// torchvision's VGG-16 for its first block (`backbone.features.0`, `backbone.features.2`).
    pub fn conv(vs: &nn::Path, width: i64) -> Trunk {
        let backbone = vs / "backbone" / "features";
        let convs = vec![
            Conv::new(&backbone / "0", 3, width, 3, 1, true),
            Conv::new(&backbone / "2", width, width, 3, 1, true),
            Conv::new(vs / "conv3", width, width, 3, 2, true),
            Conv::new(vs / "conv4", width, width, 3, 2, true),
            Conv::new(vs / "conv5", width, width, 3, 1, true),
        ];
        Trunk { layers: Layers::Conv(convs), features: 2 * width }
    }

    /// ResNet-18 of base width `width` with its first `stages` residual stages, named like torchvision's
    /// (`backbone.layer1.0.conv1.weight`, ...), then the embedding MLP to `embed` features (the authors' 256).
    pub fn resnet(vs: &nn::Path, width: i64, stages: usize, embed: i64) -> Trunk {
        let backbone = vs / "backbone";
        let stem =
            Box::new((Conv::new(&backbone / "conv1", 3, width, 7, 2, false), Norm::new(&backbone / "bn1", width)));
        let mut blocks = Vec::with_capacity(2 * stages);
        let mut channels = width;
        for layer in 0..stages {
            let out = width << layer;
            let path = &backbone / format!("layer{}", layer + 1);
            blocks.push(Block::new(&(&path / "0"), channels, out, if layer == 0 { 1 } else { 2 }));
            blocks.push(Block::new(&(&path / "1"), out, out, 1));
            channels = out;
        }
        let mlp = vs / "resnet_embed";
        let layers = Box::new([
            nn::linear(&mlp / "0", 2 * channels, embed, Default::default()),
            nn::linear(&mlp / "1", embed, embed, Default::default()),
        ]);
        Trunk { layers: Layers::ResNet { stem, blocks, embed: layers }, features: embed }
    }

    /// Width of a frame's features.
    pub fn features(&self) -> i64 {
        self.features
    }

    /// The weights the inner step adapts, in the order [`Trunk::embed`] consumes them.
    pub fn params(&self) -> Vec<Tensor> {
        match &self.layers {
            Layers::Conv(convs) => convs.iter().flat_map(Conv::params).collect(),
            Layers::ResNet { stem, blocks, embed } => {
                let mut p = stem.0.params();
                p.extend(stem.1.params());
                p.extend(blocks.iter().flat_map(Block::params));
                p.extend(embed.iter().flat_map(|l| [l.ws.shallow_clone(), bias(&l.bs)]));
                p
            }
        }
    }

    /// Features `[B, T, features]` of normalised frames `[B, T, 3, H, W]`, task `b` seen through its own weights
    /// (`weights` as [`Trunk::params`] lists them, each `[B, ...]`). `train` selects batch statistics and dropout.
    pub fn embed(&self, weights: &[Tensor], frames: &Tensor, train: bool, channels_last: bool) -> Tensor {
        let &[b, t, c, h, w] = frames.size().as_slice() else { panic!("frames are [B, T, 3, H, W]") };
        let mut y = frames.transpose(0, 1).reshape([t, b * c, h, w]);
        if channels_last {
            y = y.permute([0, 2, 3, 1]).contiguous().permute([0, 3, 1, 2]);
        }
        let mut weights = weights.iter();
        let w = &mut weights;
        let maps = match &self.layers {
            Layers::Conv(convs) => {
                for (k, conv) in convs.iter().enumerate() {
                    y = conv.apply(w, &y, b).relu();
                    if k == 1 {
                        y = y.max_pool2d([2, 2], [2, 2], [0, 0], [1, 1], false);
                    }
                }
                y
            }
            Layers::ResNet { stem, blocks, .. } => {
                y = stem.0.apply(w, &y, b);
                y = stem.1.apply(w, &y, b, train).relu();
                y = y.max_pool2d([3, 3], [2, 2], [1, 1], [1, 1], false);
                blocks.iter().fold(y, |y, block| block.apply(w, &y, b, train))
            }
        };
        let &[_, _, fh, fw] = maps.size().as_slice() else { panic!("feature maps are 4-D") };
        let maps = maps.reshape([t, b, -1, fh, fw]).transpose(0, 1).reshape([b * t, -1, fh, fw]);
        let points = spatial_softmax(&maps).reshape([b, t, -1]);
        match &self.layers {
            Layers::Conv(_) => points,
            Layers::ResNet { .. } => {
                let first = linear(w, &points).dropout(EMBED_DROPOUT, train).relu();
                linear(w, &first)
            }
        }
    }
}

/// `x` `[B, T, in]` through a linear layer whose weights `[B, out, in]` and bias `[B, out]` come next.
pub fn linear(weights: &mut Iter<Tensor>, x: &Tensor) -> Tensor {
    let (kernel, bias) = (next(weights), next(weights));
    x.matmul(&kernel.transpose(1, 2)) + bias.unsqueeze(1)
}

fn next<'a>(weights: &mut Iter<'a, Tensor>) -> &'a Tensor {
    weights.next().expect("one weight per parameter of the trunk")
}

/// A layer's bias (every layer here has one).
pub(super) fn bias(b: &Option<Tensor>) -> Tensor {
    b.as_ref().expect("layers are built with a bias").shallow_clone()
}
