//! ResNet-18 up to layer4 (no pooling or classifier), with a configurable base width (64 is the standard net).
//! Parameter names follow torchvision's (`conv1.weight`, `layer1.0.bn1.running_mean`, ...), so ImageNet weights
//! exported to safetensors load by name.
use tch::Tensor;
use tch::nn::{self, ModuleT};

fn conv(vs: nn::Path, i: i64, o: i64, k: i64, stride: i64) -> nn::Conv2D {
    let config = nn::ConvConfig { stride, padding: k / 2, bias: false, ..Default::default() };
    nn::conv2d(vs, i, o, k, config)
}

fn bn(vs: nn::Path, c: i64) -> nn::BatchNorm {
    nn::batch_norm2d(vs, c, Default::default())
}

/// One basic block: two 3x3 convolutions with a (projected) shortcut.
#[derive(Debug)]
struct BasicBlock {
    conv1: nn::Conv2D,
    bn1: nn::BatchNorm,
    conv2: nn::Conv2D,
    bn2: nn::BatchNorm,
    downsample: Option<(nn::Conv2D, nn::BatchNorm)>,
}

impl BasicBlock {
    fn new(vs: &nn::Path, i: i64, o: i64, stride: i64) -> BasicBlock {
        let downsample = (stride != 1 || i != o)
            .then(|| (conv(vs / "downsample" / "0", i, o, 1, stride), bn(vs / "downsample" / "1", o)));
        BasicBlock {
            conv1: conv(vs / "conv1", i, o, 3, stride),
            bn1: bn(vs / "bn1", o),
            conv2: conv(vs / "conv2", o, o, 3, 1),
            bn2: bn(vs / "bn2", o),
            downsample,
        }
    }
}

impl ModuleT for BasicBlock {
    fn forward_t(&self, x: &Tensor, train: bool) -> Tensor {
        let y = x.apply(&self.conv1).apply_t(&self.bn1, train).relu().apply(&self.conv2).apply_t(&self.bn2, train);
        let shortcut = match &self.downsample {
            Some((c, b)) => x.apply(c).apply_t(b, train),
            None => x.shallow_clone(),
        };
        (y + shortcut).relu()
    }
}

/// The trunk: images `[N, 3, H, W]` to features `[N, 8 * width, H / 32, W / 32]` (rounded up), or with fewer
/// stages `[N, 2^(stages-1) * width, H / 2^(stages+1), W / 2^(stages+1)]`.
#[derive(Debug)]
pub struct ResNet18 {
    conv1: nn::Conv2D,
    bn1: nn::BatchNorm,
    blocks: Vec<BasicBlock>,
    out_channels: i64,
    channels_last: bool,
}

impl ResNet18 {
    /// A ResNet-18 trunk with base width `width` and its first `stages` residual stages (4: the whole trunk)
    /// under `vs`.
    pub fn new(vs: &nn::Path, width: i64, stages: usize) -> ResNet18 {
        let mut blocks = Vec::with_capacity(2 * stages);
        let mut channels = width;
        for layer in 0..stages {
            let out = width << layer;
            let stride = if layer == 0 { 1 } else { 2 };
            let path = vs / format!("layer{}", layer + 1);
            blocks.push(BasicBlock::new(&(&path / "0"), channels, out, stride));
            blocks.push(BasicBlock::new(&(&path / "1"), out, out, 1));
            channels = out;
        }
        ResNet18 {
            conv1: conv(vs / "conv1", 3, width, 7, 2),
            bn1: bn(vs / "bn1", width),
            blocks,
            out_channels: channels,
            channels_last: false,
        }
    }

    /// Runs on channels-last (NHWC-strided) tensors: the same numbers, faster kernels on most hardware.
    pub fn set_channels_last(&mut self, on: bool) {
        self.channels_last = on;
    }

    /// Channels of the output features.
    pub fn out_channels(&self) -> i64 {
        self.out_channels
    }
}

impl ModuleT for ResNet18 {
    fn forward_t(&self, x: &Tensor, train: bool) -> Tensor {
        // A channels-last view keeps NCHW sizes with NHWC strides; the layers keep that layout.
        let x = if self.channels_last {
            x.permute([0, 2, 3, 1]).contiguous().permute([0, 3, 1, 2])
        } else {
            x.shallow_clone()
        };
        let mut y =
            x.apply(&self.conv1).apply_t(&self.bn1, train).relu().max_pool2d([3, 3], [2, 2], [1, 1], [1, 1], false);
        for b in &self.blocks {
            y = b.forward_t(&y, train);
        }
        y
    }
}
