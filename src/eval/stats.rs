//! Success rates with 95% confidence intervals: Wilson score intervals for pooled episodes, and Student-t
//! intervals of the mean over training seeds.
use serde::{Deserialize, Serialize};

/// z for a two-sided 95% interval.
const Z95: f64 = 1.959_963_984_540_054;

/// A rate with its 95% interval, all as fractions.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Rate {
    pub value: f64,
    pub low: f64,
    pub high: f64,
    /// Episodes (pooled) or seeds (mean over seeds) behind the rate.
    pub n: usize,
}

/// Wilson score interval of `successes` out of `n`.
pub fn wilson(successes: usize, n: usize) -> Rate {
    if n == 0 {
        return Rate { value: f64::NAN, low: f64::NAN, high: f64::NAN, n };
    }
    let (k, n_f) = (successes as f64, n as f64);
    let p = k / n_f;
    let z2 = Z95 * Z95;
    let centre = (p + z2 / (2.0 * n_f)) / (1.0 + z2 / n_f);
    let half = Z95 / (1.0 + z2 / n_f) * (p * (1.0 - p) / n_f + z2 / (4.0 * n_f * n_f)).sqrt();
    Rate { value: p, low: (centre - half).max(0.0), high: (centre + half).min(1.0), n }
}

/// Two-sided 97.5% quantile of Student's t with `df` degrees of freedom.
fn t975(df: usize) -> f64 {
    const TABLE: [f64; 30] = [
        12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131,
        2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042,
    ];
    TABLE.get(df.wrapping_sub(1)).copied().unwrap_or(Z95)
}

/// Mean of per-seed rates with a t interval; a single seed has no spread (its interval is the value itself).
pub fn mean_over_seeds(rates: &[f64]) -> Rate {
    let n = rates.len();
    if n == 0 {
        return Rate { value: f64::NAN, low: f64::NAN, high: f64::NAN, n };
    }
    let mean = rates.iter().sum::<f64>() / n as f64;
    if n == 1 {
        return Rate { value: mean, low: mean, high: mean, n };
    }
    let var = rates.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    let half = t975(n - 1) * (var / n as f64).sqrt();
    Rate { value: mean, low: (mean - half).max(0.0), high: (mean + half).min(1.0), n }
}

/// How many episodes reached each stage.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Counts {
    pub episodes: usize,
    pub reached: usize,
    pub picked: usize,
    pub placed: usize,
    /// Episodes that left the object in another quadrant of the target bin (none where the store holds
    /// episodes recorded before this was).
    pub wrong_bin: Option<usize>,
}

impl Counts {
    /// The counts of `episodes`.
    pub fn of<'a>(episodes: impl IntoIterator<Item = &'a super::EpisodeResult>) -> Counts {
        episodes.into_iter().fold(Counts::default(), |c, e| Counts {
            episodes: c.episodes + 1,
            reached: c.reached + e.reached as usize,
            picked: c.picked + e.picked as usize,
            placed: c.placed + e.placed as usize,
            wrong_bin: Some(c.wrong_bin.unwrap_or(0) + e.wrong_bin as usize),
        })
    }

    /// Both together.
    pub fn plus(&self, o: &Counts) -> Counts {
        Counts {
            episodes: self.episodes + o.episodes,
            reached: self.reached + o.reached,
            picked: self.picked + o.picked,
            placed: self.placed + o.placed,
            wrong_bin: match (self.episodes, o.episodes) {
                (0, _) => o.wrong_bin,
                (_, 0) => self.wrong_bin,
                _ => self.wrong_bin.zip(o.wrong_bin).map(|(a, b)| a + b),
            },
        }
    }
}

/// Rates of the three stages.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StageRates {
    pub reached: Rate,
    pub picked: Rate,
    pub placed: Rate,
}

impl StageRates {
    /// Wilson rates of pooled counts.
    pub fn of(c: &Counts) -> StageRates {
        StageRates {
            reached: wilson(c.reached, c.episodes),
            picked: wilson(c.picked, c.episodes),
            placed: wilson(c.placed, c.episodes),
        }
    }

    /// The mean of per-seed rates, with Student-t intervals.
    pub fn mean_over(per_seed: &[StageRates]) -> StageRates {
        let mean =
            |f: fn(&StageRates) -> Rate| mean_over_seeds(&per_seed.iter().map(|r| f(r).value).collect::<Vec<_>>());
        StageRates { reached: mean(|r| r.reached), picked: mean(|r| r.picked), placed: mean(|r| r.placed) }
    }

    /// [reached, picked, placed].
    pub fn rates(&self) -> [Rate; 3] {
        [self.reached, self.picked, self.placed]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wilson_matches_known_intervals() {
        let r = wilson(88, 100);
        assert!((r.low - 0.802).abs() < 5e-4 && (r.high - 0.930).abs() < 5e-4, "{r:?}");
        let zero = wilson(0, 20);
        assert_eq!(zero.low, 0.0);
        assert!((zero.high - 0.1611).abs() < 5e-4, "{zero:?}");
        let all = wilson(160, 160);
        assert!((all.low - 0.9766).abs() < 5e-4 && all.high == 1.0, "{all:?}");
    }

    #[test]
    fn wrong_bin_counts_add_up_and_stay_unknown_where_any_part_is() {
        let known = Counts { episodes: 4, reached: 3, picked: 2, placed: 1, wrong_bin: Some(1) };
        let old = Counts { episodes: 2, wrong_bin: None, ..known };
        assert_eq!(known.plus(&known).wrong_bin, Some(2));
        assert_eq!(known.plus(&old).wrong_bin, None);
        assert_eq!(Counts::default().plus(&known).wrong_bin, Some(1));
    }

    #[test]
    fn mean_over_seeds_uses_student_t() {
        let r = mean_over_seeds(&[0.8, 0.9, 1.0]);
        // mean 0.9, sd 0.1, t(2) = 4.303: half-width 0.248, clipped at 1.
        assert!((r.value - 0.9).abs() < 1e-12 && (r.low - (0.9 - 4.303 * 0.1 / 3f64.sqrt())).abs() < 1e-9);
        assert_eq!(r.high, 1.0);
        assert_eq!(mean_over_seeds(&[0.5]).low, 0.5);
    }
}
