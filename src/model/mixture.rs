//! The discretised logistic mixture action head (PixelCNN++ style, as in the paper's code): per action dimension a
//! mixture of logistics over [-1, 1] cut into `bins` classes, with a learned constant log-scale per dimension.
use super::config::{LogScaleInit, ModelConfig};
use crate::sim::action::ACTION_DIM;
use tch::nn::{self, Module};
use tch::{Kind, Tensor};

/// Mixture parameters for a batch of steps: each `[.., dims, mixtures]`.
pub struct MixtureParams {
    pub means: Tensor,
    pub log_scales: Tensor,
    pub logits: Tensor,
}

/// Distribution settings of the head.
#[derive(Debug, Clone, Copy)]
pub struct MixtureSpec {
    pub dims: i64,
    pub mixtures: i64,
    pub bins: i64,
    pub log_scale_min: f64,
    pub log_scale_init: LogScaleInit,
}

impl MixtureSpec {
    /// The action distribution of a model: one mixture per action dimension.
    pub fn for_model(config: &ModelConfig) -> MixtureSpec {
        MixtureSpec {
            dims: ACTION_DIM as i64,
            mixtures: config.mixtures,
            bins: config.bins,
            log_scale_min: config.log_scale_min,
            log_scale_init: config.log_scale_init,
        }
    }
}

/// Maps a hidden vector to mixture parameters.
#[derive(Debug)]
pub struct MixtureHead {
    spec: MixtureSpec,
    params: nn::Linear,
    log_scale: Tensor,
}

impl MixtureHead {
    /// A head reading `hidden`-wide vectors.
    pub fn new(vs: &nn::Path, hidden: i64, spec: MixtureSpec) -> MixtureHead {
        let params = nn::linear(vs / "params", hidden, 2 * spec.dims * spec.mixtures, Default::default());
        let log_scale = match spec.log_scale_init {
            LogScaleInit::Zero => vs.zeros("log_scale", &[spec.dims, 1]),
            LogScaleInit::Random => {
                vs.var("log_scale", &[spec.dims, 1], nn::Init::Randn { mean: 0.0, stdev: 1.0 / 8f64.sqrt() })
            }
        };
        MixtureHead { spec, params, log_scale }
    }

    /// Parameters for hidden vectors `h` of shape `[.., hidden]`.
    pub fn forward(&self, h: &Tensor) -> MixtureParams {
        let mut shape = h.size();
        shape.pop();
        shape.extend([self.spec.dims, 2 * self.spec.mixtures]);
        let out = self.params.forward(h).view(shape.as_slice());
        let parts = out.split(self.spec.mixtures, -1);
        let log_scales = self.log_scale.clamp_min(self.spec.log_scale_min).expand_as(&parts[0]);
        MixtureParams { means: parts[0].shallow_clone(), log_scales, logits: parts[1].shallow_clone() }
    }

    /// The distribution settings.
    pub fn spec(&self) -> MixtureSpec {
        self.spec
    }
}

/// Negative log-likelihood of targets `x` (`[.., dims]`, in [-1, 1]) under the mixture, averaged over all entries.
pub fn mixture_nll(p: &MixtureParams, x: &Tensor, spec: MixtureSpec) -> Tensor {
    // In fp32 whatever the forward pass ran in: bins are 1/255 wide, finer than bf16 resolves near 1.
    let (means, log_scales, logits) =
        (p.means.to_kind(Kind::Float), p.log_scales.to_kind(Kind::Float), p.logits.to_kind(Kind::Float));
    let half_bin = 1.0 / (spec.bins as f64 - 1.0);
    let x = x.unsqueeze(-1);
    let log_scales = log_scales.clamp_min(spec.log_scale_min);
    let centered = &x - &means;
    let inv_s = (-&log_scales).exp();
    let plus_in = &inv_s * (&centered + half_bin);
    let min_in = &inv_s * (&centered - half_bin);
    let cdf_delta = plus_in.sigmoid() - min_in.sigmoid();
    // log CDF at the upper edge (the first bin), log (1 - CDF) at the lower edge (the last bin).
    let log_cdf_plus = &plus_in - plus_in.softplus();
    let log_one_minus_cdf_min = -min_in.softplus();
    let mid_in = &inv_s * &centered;
    let log_pdf_mid = &mid_in - &log_scales - 2.0 * mid_in.softplus();
    let interior = cdf_delta
        .clamp_min(1e-12)
        .log()
        .where_self(&cdf_delta.gt(1e-5), &(log_pdf_mid - ((spec.bins as f64 - 1.0) / 2.0).ln()));
    let upper = log_one_minus_cdf_min.where_self(&x.gt(0.999), &interior);
    let log_probs = log_cdf_plus.where_self(&x.lt(-0.999), &upper);
    let mixed = (log_probs + logits.log_softmax(-1, Kind::Float)).logsumexp([-1], false);
    -mixed.mean(Kind::Float)
}

/// The mean of each entry's most probable component, clamped to [-1, 1]: the most likely action, nearly.
pub fn mixture_mode(p: &MixtureParams) -> Tensor {
    let k = p.logits.argmax(-1, true);
    p.means.gather(-1, &k, false).squeeze_dim(-1).clamp(-1.0, 1.0)
}

/// Draws one component index per entry (`[.., dims, 1]`) with probability softmax(logits): the Gumbel-max trick.
fn sample_component(p: &MixtureParams) -> Tensor {
    let u = Tensor::rand_like(&p.logits) * (1.0 - 2e-5) + 1e-5;
    let gumbel = -(-u.log()).log();
    (&p.logits + gumbel).argmax(-1, true)
}

/// Draws one sample per entry: a Gumbel-max component, then a logistic sample from it clamped to [-1, 1].
pub fn mixture_sample(p: &MixtureParams) -> Tensor {
    let k = sample_component(p);
    let mean = p.means.gather(-1, &k, false).squeeze_dim(-1);
    let log_scale = p.log_scales.gather(-1, &k, false).squeeze_dim(-1);
    let u = Tensor::rand_like(&mean) * (1.0 - 2e-5) + 1e-5;
    (mean + log_scale.exp() * (u.log() - u.neg().log1p())).clamp(-1.0, 1.0)
}

/// The mean of a sampled component per entry, clamped to [-1, 1]: the sample's choice between components without
/// the logistic spread within one.
pub fn mixture_component_mean(p: &MixtureParams) -> Tensor {
    let k = sample_component(p);
    p.means.gather(-1, &k, false).squeeze_dim(-1).clamp(-1.0, 1.0)
}

/// Each entry's probability under the mixture that dimension `dim` of its action exceeds `threshold` (one value
/// per entry, shaped as the entries `[..]`, normalised units inside (-1, 1)): the share of samples that would.
pub fn mixture_above(p: &MixtureParams, dim: i64, threshold: &Tensor) -> Tensor {
    let of_dim = |t: &Tensor| t.select(-2, dim).to_kind(Kind::Float);
    let weights = of_dim(&p.logits).softmax(-1, Kind::Float);
    let scaled = (of_dim(&p.means) - threshold.to_kind(Kind::Float).unsqueeze(-1)) * (-of_dim(&p.log_scales)).exp();
    (weights * scaled.sigmoid()).sum_dim_intlist([-1i64].as_slice(), false, Kind::Float)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sigmoid(x: f64) -> f64 {
        1.0 / (1.0 + (-x).exp())
    }

    const SPEC: MixtureSpec =
        MixtureSpec { dims: 1, mixtures: 2, bins: 256, log_scale_min: -7.0, log_scale_init: LogScaleInit::Zero };

    fn params(means: [f64; 2], log_scales: [f64; 2], logits: [f64; 2]) -> MixtureParams {
        let t = |v: [f64; 2]| Tensor::from_slice(&v).to_kind(Kind::Float).view([1, 1, 2]);
        MixtureParams { means: t(means), log_scales: t(log_scales), logits: t(logits) }
    }

    /// The same one-entry mixture `n` times over: `[n, 1, 2]`.
    fn repeated(p: MixtureParams, n: i64) -> MixtureParams {
        let many = |t: &Tensor| t.expand([n, 1, 2], false);
        MixtureParams { means: many(&p.means), log_scales: many(&p.log_scales), logits: many(&p.logits) }
    }

    /// The bin probability computed by hand from logistic CDFs.
    fn hand_prob(x: f64, means: [f64; 2], log_scales: [f64; 2], logits: [f64; 2]) -> f64 {
        let h = 1.0 / 255.0;
        let z: f64 = logits.iter().map(|l| l.exp()).sum();
        (0..2)
            .map(|k| {
                let s = log_scales[k].exp();
                let cdf = |v: f64| sigmoid((v - means[k]) / s);
                let p = if x < -0.999 {
                    cdf(x + h)
                } else if x > 0.999 {
                    1.0 - cdf(x - h)
                } else {
                    cdf(x + h) - cdf(x - h)
                };
                logits[k].exp() / z * p
            })
            .sum()
    }

    #[test]
    fn nll_matches_hand_computation_in_interior_and_edge_bins() {
        let (means, log_scales, logits) = ([0.1, -0.6], [-2.0, -1.5], [0.3, -0.2]);
        let p = params(means, log_scales, logits);
        for x in [-1.0, -0.3, 0.1, 0.5, 1.0] {
            let target = Tensor::from_slice(&[x as f32]).view([1, 1]);
            let nll = mixture_nll(&p, &target, SPEC).double_value(&[]);
            let expected = -hand_prob(x, means, log_scales, logits).ln();
            assert!((nll - expected).abs() < 1e-4, "x = {x}: {nll} vs {expected}");
        }
    }

    #[test]
    fn samples_match_the_mixture_mean_and_spread() {
        tch::manual_seed(7);
        let (means, log_scales, logits) = ([0.3, -0.4], [-2.5, -3.0], [0.0, 2.0f64.ln()]);
        let big = repeated(params(means, log_scales, logits), 100_000);
        let s = mixture_sample(&big);
        let (w0, w1) = (1.0 / 3.0, 2.0 / 3.0);
        let mean = w0 * means[0] + w1 * means[1];
        // Logistic variance: s^2 pi^2 / 3.
        let var_k = |k: usize| (2.0 * log_scales[k]).exp() * std::f64::consts::PI.powi(2) / 3.0;
        let var = w0 * (var_k(0) + means[0].powi(2)) + w1 * (var_k(1) + means[1].powi(2)) - mean.powi(2);
        let got_mean = s.mean(Kind::Double).double_value(&[]);
        let got_var = s.var(true).double_value(&[]);
        assert!((got_mean - mean).abs() < 0.005, "{got_mean} vs {mean}");
        assert!((got_var - var).abs() / var < 0.03, "{got_var} vs {var}");
        assert!(s.abs().max().double_value(&[]) <= 1.0);
    }

    #[test]
    fn component_means_pick_each_component_as_often_as_its_weight() {
        tch::manual_seed(11);
        let (means, log_scales, logits) = ([0.3, -0.4], [-1.0, -1.0], [0.0, 3.0f64.ln()]);
        let big = repeated(params(means, log_scales, logits), 40_000);
        let s = Vec::<f32>::try_from(mixture_component_mean(&big).flatten(0, -1)).unwrap();
        let first = s.iter().filter(|&&v| (f64::from(v) - means[0]).abs() < 1e-6).count();
        let second = s.iter().filter(|&&v| (f64::from(v) - means[1]).abs() < 1e-6).count();
        // Every value is one of the two means exactly (no spread), in the weights' proportion 1 : 3.
        assert_eq!(first + second, s.len());
        let share = first as f64 / s.len() as f64;
        assert!((share - 0.25).abs() < 0.01, "first component's share {share}");
    }

    #[test]
    fn the_probability_above_a_threshold_is_the_share_of_samples_above_it() {
        tch::manual_seed(5);
        let (means, log_scales, logits) = ([0.3, -0.4], [-2.0, -2.5], [0.0, 2.0f64.ln()]);
        let one = params(means, log_scales, logits);
        let n = 100_000;
        let samples = mixture_sample(&repeated(params(means, log_scales, logits), n));
        for threshold in [-0.6, -0.4, 0.0, 0.3, 0.45] {
            let p = mixture_above(&one, 0, &Tensor::from_slice(&[threshold as f32]).view([1])).double_value(&[0]);
            let share = samples.gt(threshold).to_kind(Kind::Double).mean(Kind::Double).double_value(&[]);
            assert!((p - share).abs() < 0.01, "threshold {threshold}: {p} against the samples' {share}");
        }
        // By hand from the logistic CDFs, for two thresholds at once.
        let by_hand = |x: f64| {
            let w = [1.0 / 3.0, 2.0 / 3.0];
            (0..2).map(|k| w[k] * sigmoid((means[k] - x) / log_scales[k].exp())).sum::<f64>()
        };
        let two = mixture_above(&one, 0, &Tensor::from_slice(&[0.3f32, -0.05]).view([2])).to_kind(Kind::Double);
        let two = Vec::<f64>::try_from(&two).unwrap();
        assert!((two[0] - by_hand(0.3)).abs() < 1e-5 && (two[1] - by_hand(-0.05)).abs() < 1e-5, "{two:?}");
    }
}
