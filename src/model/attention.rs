//! The non-local (self-)attention layer over all T*H*W feature tokens, with frame-level masking,
//! and the sinusoidal positional encoding of the tokens.
use tch::nn::{self, Module};
use tch::{Device, Kind, Tensor};

/// Sinusoidal encoding `[tokens, channels]` of token index t*H*W + h*W + w (Vaswani et al.).
pub fn positional_encoding(tokens: i64, channels: i64, device: Device) -> Tensor {
    let pos = Tensor::arange(tokens, (Kind::Float, device)).unsqueeze(1);
    let i = Tensor::arange_start_step(0, channels, 2, (Kind::Float, device));
    let freq = (i * (-(10_000f64.ln()) / channels as f64)).exp().unsqueeze(0);
    let angle = pos * freq;
    Tensor::stack(&[angle.sin(), angle.cos()], 2).view([tokens, channels])
}

/// Boolean mask `[tokens, tokens]`, true where a query token may attend to a key token: keys in any of the first
/// `visible` frames, or in a frame no later than the query's.
pub fn frame_causal_mask(frames: i64, tokens_per_frame: i64, visible: i64, device: Device) -> Tensor {
    let frame = Tensor::arange(frames, (Kind::Int64, device)).repeat_interleave_self_int(tokens_per_frame, 0, None);
    let q = frame.unsqueeze(1);
    let k = frame.unsqueeze(0);
    k.le_tensor(&q).logical_or(&k.lt(visible))
}

/// Settings of one attention layer.
#[derive(Debug, Clone, Copy)]
pub struct AttentionSpec {
    pub channels: i64,
    pub inner: i64,
    pub heads: i64,
    pub temperature: f64,
    pub dropout: f64,
}

/// Channel dropout of tokens `[B, N, C]`: each (sample, channel) is zeroed across all tokens with probability `p`
/// and the rest scaled by 1 / (1 - p), as `Dropout3d` does to `[B, C, T, H, W]` volumes.
pub fn channel_dropout(x: &Tensor, p: f64, train: bool) -> Tensor {
    if !train || p == 0.0 {
        return x.shallow_clone();
    }
    let (b, _, c) = x.size3().expect("tokens are [B, N, C]");
    let keep = Tensor::rand([b, 1, c], (Kind::Float, x.device())).ge(p).to_kind(x.kind());
    x * keep / (1.0 - p)
}

/// Multi-head attention with 1x1x1 projections, ReLU + channel dropout on the output, a residual and batch norm
/// (the authors' non-local block).
#[derive(Debug)]
pub struct AttentionLayer {
    spec: AttentionSpec,
    query: nn::Linear,
    key: nn::Linear,
    value: nn::Linear,
    out: nn::Linear,
    norm: nn::BatchNorm,
}

impl AttentionLayer {
    /// A layer under `vs`.
    pub fn new(vs: &nn::Path, spec: AttentionSpec) -> AttentionLayer {
        let nobias = nn::LinearConfig { bias: false, ..Default::default() };
        AttentionLayer {
            spec,
            query: nn::linear(vs / "query", spec.channels, spec.inner, nobias),
            key: nn::linear(vs / "key", spec.channels, spec.inner, nobias),
            value: nn::linear(vs / "value", spec.channels, spec.inner, nobias),
            out: nn::linear(vs / "out", spec.inner, spec.channels, Default::default()),
            norm: nn::batch_norm1d(vs / "norm", spec.channels, Default::default()),
        }
    }

    /// Tokens `[B, N, C]` to tokens `[B, N, C]`; `mask` `[N, N]` (true = may attend) or none for full attention.
    pub fn forward(&self, x: &Tensor, mask: Option<&Tensor>, train: bool) -> Tensor {
        let (b, n, _) = x.size3().expect("tokens are [B, N, C]");
        let heads = self.spec.heads;
        let split = |t: Tensor| t.view([b, n, heads, -1]).transpose(1, 2);
        let (q, k, v) = (split(self.query.forward(x)), split(self.key.forward(x)), split(self.value.forward(x)));
        let mut scores = q.matmul(&k.transpose(-2, -1)) / self.spec.temperature;
        if let Some(m) = mask {
            scores = scores.masked_fill(&m.logical_not(), f64::NEG_INFINITY);
        }
        let attended = scores.softmax(-1, Kind::Float).matmul(&v).transpose(1, 2).reshape([b, n, self.spec.inner]);
        let y = channel_dropout(&self.out.forward(&attended).relu(), self.spec.dropout, train);
        (x + y).transpose(1, 2).apply_t(&self.norm, train).transpose(1, 2)
    }
}

/// The "no attention" block (the authors' `TempConvLayer`): a bottleneck of 1x1x1 convolution to `inner` channels,
/// ReLU, 5x5x5 convolution (padded only towards the past when causal), ReLU, 1x1x1 convolution back, ReLU,
/// channel dropout, a residual and batch norm. Tokens in and out, like [`AttentionLayer`].
#[derive(Debug)]
pub struct ConvBlock {
    reduce: nn::Conv<[i64; 3]>,
    conv: nn::Conv<[i64; 3]>,
    expand: nn::Conv<[i64; 3]>,
    norm: nn::BatchNorm,
    causal: bool,
    dropout: f64,
}

/// A unit-stride, biased 3-D convolution configuration with `padding` (time, height, width).
pub fn conv3d_config(padding: [i64; 3]) -> nn::ConvConfigND<[i64; 3]> {
    let d = nn::ConvConfig::default();
    nn::ConvConfigND {
        stride: [1, 1, 1],
        padding,
        dilation: [1, 1, 1],
        groups: 1,
        bias: true,
        ws_init: d.ws_init,
        bs_init: d.bs_init,
        padding_mode: d.padding_mode,
    }
}

/// Temporal (and spatial) extent of the convolution.
const CONV_KERNEL: i64 = 5;

impl ConvBlock {
    /// A block under `vs` over `channels` channels with an `inner`-channel bottleneck.
    pub fn new(vs: &nn::Path, channels: i64, inner: i64, causal: bool, dropout: f64) -> ConvBlock {
        let pointwise = conv3d_config([0, 0, 0]);
        ConvBlock {
            reduce: nn::conv(vs / "reduce", channels, inner, [1, 1, 1], pointwise),
            conv: nn::conv(vs / "conv", inner, inner, [CONV_KERNEL; 3], conv3d_config([0, 2, 2])),
            expand: nn::conv(vs / "expand", inner, channels, [1, 1, 1], pointwise),
            norm: nn::batch_norm3d(vs / "norm", channels, Default::default()),
            causal,
            dropout,
        }
    }

    /// Tokens `[B, T*h*w, C]` of `frames` frames of `h x w` to tokens of the same shape.
    pub fn forward(&self, x: &Tensor, frames: i64, h: i64, w: i64, train: bool) -> Tensor {
        let (b, _, c) = x.size3().expect("tokens are [B, N, C]");
        let volume = x.view([b, frames, h, w, c]).permute([0, 4, 1, 2, 3]);
        // Pad time only: all of it before the first frame when causal, split evenly otherwise.
        let (past, future) = if self.causal { (CONV_KERNEL - 1, 0) } else { (CONV_KERNEL / 2, CONV_KERNEL / 2) };
        let reduced = volume.apply(&self.reduce).relu().constant_pad_nd([0, 0, 0, 0, past, future]);
        let y = reduced.apply(&self.conv).relu().apply(&self.expand).relu();
        let y = y.feature_dropout(self.dropout, train);
        let out = (volume + y).apply_t(&self.norm, train);
        out.permute([0, 2, 3, 4, 1]).reshape([b, frames * h * w, c])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mask_lets_tokens_see_visible_frames_and_the_past_only() {
        let m = frame_causal_mask(4, 2, 2, Device::Cpu);
        let allowed = |q: i64, k: i64| m.int64_value(&[q, k]) == 1;
        // Token 1 is in frame 0 (visible frame), token 7 in frame 3.
        assert!(allowed(1, 3), "visible frames see each other");
        assert!(allowed(4, 0) && allowed(6, 5) && allowed(7, 6));
        assert!(!allowed(4, 6) && !allowed(0, 4) && !allowed(5, 7));
    }

    #[test]
    fn with_no_visible_frames_the_mask_is_lower_triangular_over_all_frames() {
        let (frames, per) = (5, 3);
        let m = frame_causal_mask(frames, per, 0, Device::Cpu);
        for q in 0..frames * per {
            for k in 0..frames * per {
                assert_eq!(m.int64_value(&[q, k]) == 1, k / per <= q / per, "query {q}, key {k}");
            }
        }
    }

    #[test]
    fn channel_dropout_zeroes_whole_channels() {
        tch::manual_seed(0);
        let x = Tensor::ones([4, 10, 32], (Kind::Float, Device::Cpu));
        let y = channel_dropout(&x, 0.5, true);
        for b in 0..4 {
            for c in 0..32 {
                let col = y.get(b).select(1, c);
                let (lo, hi) = (col.min().double_value(&[]), col.max().double_value(&[]));
                assert!(lo == hi && (lo == 0.0 || lo == 2.0), "channel {c} of sample {b}: {lo}..{hi}");
            }
        }
        assert!(channel_dropout(&x, 0.5, false).equal(&x));
    }

    #[test]
    fn the_no_attention_block_is_the_authors_bottleneck() {
        let vs = nn::VarStore::new(Device::Cpu);
        let _block = ConvBlock::new(&vs.root(), 512, 128, true, 0.2);
        let params: i64 = vs.trainable_variables().iter().map(|t| t.numel() as i64).sum();
        // 512*128 + 128 + 128*128*125 + 128 + 128*512 + 512 + 2*512 (batch norm).
        assert_eq!(params, 2_180_864);
    }

    #[test]
    fn encoding_is_distinct_per_token_and_bounded() {
        let pe = positional_encoding(50, 16, Device::Cpu);
        assert_eq!(pe.size(), [50, 16]);
        assert!(pe.abs().max().double_value(&[]) <= 1.0);
        let d = (pe.get(3) - pe.get(4)).abs().sum(Kind::Float).double_value(&[]);
        assert!(d > 0.1);
    }
}
