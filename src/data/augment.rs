//! Image augmentation as the authors' `randomize_video` (`hem/datasets/util.py`) does it: a jitter in HSV space,
//! a random crop resized back to the frame, and a random translation with black borders, here applied in one
//! bilinear resampling pass before ImageNet normalisation into planar f32.
use rand::Rng;
use serde::{Deserialize, Serialize};

/// ImageNet channel means and standard deviations.
pub const MEAN: [f32; 3] = [0.485, 0.456, 0.406];
pub const STD: [f32; 3] = [0.229, 0.224, 0.225];
/// Numbers in a draw's [`AugmentDraw::row`].
pub const DRAW_LEN: usize = 9;
/// The frame size the authors' pixel ranges refer to.
const AUTHORS_FRAME: [f64; 2] = [240.0, 320.0];

/// Augmentation ranges, the authors' by default (`color_jitter`, `rand_crop`, `rand_translate` of their
/// `experiments/base.yaml`). Pixel ranges refer to a 240 x 320 frame and scale with the frame size.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Augmentation {
    /// Largest additive change of hue (in half turns: 0.4 is 72 degrees), saturation (0..1) and value (0..255).
    pub hsv: [f64; 3],
    /// Largest crop per side, rows and columns, drawn from 0 up to (not including) these.
    pub crop: [f64; 2],
    /// Largest translation, columns and rows (as the authors' `warpAffine` offsets x, y).
    pub shift: [f64; 2],
}

impl Default for Augmentation {
    fn default() -> Self {
        Augmentation { hsv: [0.4, 0.4, 0.4], crop: [12.0, 16.0], shift: [12.0, 16.0] }
    }
}

impl Augmentation {
    /// Checks ranges; errors name the key.
    pub fn validate(&self) -> anyhow::Result<()> {
        let all = self.hsv.iter().chain(&self.crop).chain(&self.shift);
        if all.clone().any(|v| !(v.is_finite() && *v >= 0.0)) {
            anyhow::bail!("train.augmentation ranges must be non-negative numbers: {self:?}");
        }
        if self.crop[0] * 2.0 >= AUTHORS_FRAME[0] || self.crop[1] * 2.0 >= AUTHORS_FRAME[1] {
            anyhow::bail!("train.augmentation.crop = {:?} would crop the whole frame", self.crop);
        }
        Ok(())
    }
}

/// One random draw of all augmentation parameters; the identity when augmentation is off.
#[derive(Debug, Clone, Copy)]
pub struct AugmentDraw {
    /// Source rectangle (top, left, height, width) in pixels that is stretched over the frame.
    crop: [f32; 4],
    /// Shift (rows, columns) of the result.
    shift: [f32; 2],
    /// Additive change of hue (degrees), saturation (0..1) and value (0..1); none when all are zero.
    hsv: Option<[f32; 3]>,
}

impl AugmentDraw {
    /// No change.
    pub fn identity(height: usize, width: usize) -> AugmentDraw {
        AugmentDraw { crop: [0.0, 0.0, height as f32, width as f32], shift: [0.0, 0.0], hsv: None }
    }

    /// A random draw within `ranges` for frames of `height x width`.
    pub fn sample<R: Rng>(rng: &mut R, ranges: &Augmentation, height: usize, width: usize) -> AugmentDraw {
        let (h, w) = (height as f64, width as f64);
        let (sy, sx) = (h / AUTHORS_FRAME[0], w / AUTHORS_FRAME[1]);
        let mut below = |max: f64| if max > 0.0 { rng.random_range(0.0..max) } else { 0.0 };
        let (top, bottom) = (below(ranges.crop[0]) * sy, below(ranges.crop[0]) * sy);
        let (left, right) = (below(ranges.crop[1]) * sx, below(ranges.crop[1]) * sx);
        let mut within = |max: f64| if max > 0.0 { rng.random_range(-max..=max) } else { 0.0 };
        let (dx, dy) = (within(ranges.shift[0]) * sx, within(ranges.shift[1]) * sy);
        let [hue, sat, val] = ranges.hsv.map(within);
        AugmentDraw {
            crop: [top, left, h - top - bottom, w - left - right].map(|v| v as f32),
            shift: [dy as f32, dx as f32],
            hsv: Some([(hue * 180.0) as f32, sat as f32, (val / 255.0) as f32]),
        }
    }

    /// The draw as numbers, for [`super::device_augment::augment_frames`]: crop (top, left, height, width), shift
    /// (rows, columns), HSV change (zero where the draw has none).
    pub fn row(&self) -> [f32; DRAW_LEN] {
        let [top, left, height, width] = self.crop;
        let [rows, columns] = self.shift;
        let [hue, sat, val] = self.hsv.unwrap_or([0.0; 3]);
        [top, left, height, width, rows, columns, hue, sat, val]
    }

    /// Whether the draw changes colours (the host path jitters only then).
    pub fn jitters(&self) -> bool {
        self.hsv.is_some()
    }

    /// Applies the draw to interleaved RGB bytes, writing normalised planar `[3, H, W]` values into `out`.
    pub fn apply(&self, rgb: &[u8], height: usize, width: usize, out: &mut [f32]) {
        let plane = height * width;
        let [top, left, ch, cw] = self.crop;
        // The resampling is separable: each output row reads two source rows, each output column two source columns.
        let rows = taps(height, top, ch / height as f32, self.shift[0]);
        let columns = taps(width, left, cw / width as f32, self.shift[1]);
        for (r, row) in rows.iter().enumerate() {
            for (c, column) in columns.iter().enumerate() {
                let mut px = [0.0f32; 3];
                for (&sr, &wr) in row.index.iter().zip(&row.weight) {
                    for (&sc, &wc) in column.index.iter().zip(&column.weight) {
                        let weight = wr * wc;
                        if weight != 0.0 {
                            let i = (sr * width + sc) * 3;
                            for k in 0..3 {
                                px[k] += weight * f32::from(rgb[i + k]);
                            }
                        }
                    }
                }
                px = px.map(|v| v / 255.0);
                if let Some(delta) = self.hsv {
                    px = jitter_hsv(px, delta);
                }
                for k in 0..3 {
                    out[k * plane + r * width + c] = (px[k] - MEAN[k]) / STD[k];
                }
            }
        }
    }
}

/// The two source pixels an output pixel reads along one axis, and their bilinear weights (zero for a pixel
/// outside the frame, which reads as black).
struct Taps {
    index: [usize; 2],
    weight: [f32; 2],
}

/// Taps of each of the `len` output positions of an axis whose source window starts at `offset`, is stretched by
/// `scale` source pixels per output pixel, and is shifted by `shift` output pixels.
fn taps(len: usize, offset: f32, scale: f32, shift: f32) -> Vec<Taps> {
    (0..len)
        .map(|i| {
            let source = offset + (i as f32 - shift + 0.5) * scale - 0.5;
            let first = source.floor();
            let fraction = source - first;
            let mut t = Taps { index: [0, 0], weight: [0.0, 0.0] };
            for (k, (at, weight)) in
                [(first as i64, 1.0 - fraction), (first as i64 + 1, fraction)].into_iter().enumerate()
            {
                if at >= 0 && (at as usize) < len {
                    t.index[k] = at as usize;
                    t.weight[k] = weight;
                }
            }
            t
        })
        .collect()
}

/// RGB in [0, 1] shifted in HSV by (hue degrees, saturation, value) and back, clipped to [0, 1].
fn jitter_hsv([r, g, b]: [f32; 3], [dh, ds, dv]: [f32; 3]) -> [f32; 3] {
    let v = r.max(g).max(b);
    let delta = v - r.min(g).min(b);
    let s = if v > 0.0 { delta / v } else { 0.0 };
    let h = if delta <= 0.0 {
        0.0
    } else if v == r {
        60.0 * ((g - b) / delta)
    } else if v == g {
        60.0 * ((b - r) / delta) + 120.0
    } else {
        60.0 * ((r - g) / delta) + 240.0
    };
    let (h, s, v) = ((h + dh).rem_euclid(360.0), (s + ds).clamp(0.0, 1.0), (v + dv).clamp(0.0, 1.0));
    let c = v * s;
    let x = c * (1.0 - ((h / 60.0).rem_euclid(2.0) - 1.0).abs());
    let (r1, g1, b1) = match (h / 60.0) as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = v - c;
    [r1 + m, g1 + m, b1 + m].map(|u| u.clamp(0.0, 1.0))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn gradient(h: usize, w: usize) -> Vec<u8> {
        (0..h * w).flat_map(|i| [(i % w * 255 / w) as u8, (i / w * 255 / h) as u8, 90]).collect()
    }

    #[test]
    fn identity_only_normalises() {
        let (h, w) = (6, 8);
        let rgb = gradient(h, w);
        let mut out = vec![0.0; 3 * h * w];
        AugmentDraw::identity(h, w).apply(&rgb, h, w, &mut out);
        for (i, px) in rgb.chunks(3).enumerate() {
            for k in 0..3 {
                let expected = (f32::from(px[k]) / 255.0 - MEAN[k]) / STD[k];
                assert!((out[k * h * w + i] - expected).abs() < 1e-5);
            }
        }
    }

    #[test]
    fn a_whole_pixel_shift_moves_the_picture_and_fills_the_border_black() {
        let (h, w) = (6, 8);
        let rgb = gradient(h, w);
        let shift = AugmentDraw { crop: [0.0, 0.0, h as f32, w as f32], shift: [1.0, 2.0], hsv: None };
        let (mut moved, mut id) = (vec![0.0; 3 * h * w], vec![0.0; 3 * h * w]);
        shift.apply(&rgb, h, w, &mut moved);
        AugmentDraw::identity(h, w).apply(&rgb, h, w, &mut id);
        for k in 0..3 {
            for r in 0..h {
                for c in 0..w {
                    let got = moved[k * h * w + r * w + c];
                    let want = if r >= 1 && c >= 2 { id[k * h * w + (r - 1) * w + c - 2] } else { -MEAN[k] / STD[k] };
                    assert!((got - want).abs() < 1e-5, "channel {k} row {r} column {c}: {got} vs {want}");
                }
            }
        }
    }

    #[test]
    fn hsv_jitter_turns_hues_and_keeps_greys() {
        let red = [0.8, 0.1, 0.1];
        assert_eq!(jitter_hsv(red, [0.0, 0.0, 0.0]).map(|v| (v * 1000.0).round()), red.map(|v| (v * 1000.0).round()));
        let turned = jitter_hsv(red, [120.0, 0.0, 0.0]);
        assert!(turned[1] > 0.7 && turned[0] < 0.2, "red turned by 120 degrees is green: {turned:?}");
        let grey = jitter_hsv([0.5, 0.5, 0.5], [72.0, 0.0, 0.0]);
        assert!(grey.iter().all(|v| (v - 0.5).abs() < 1e-6), "hue does not move a grey: {grey:?}");
        let paler = jitter_hsv(red, [0.0, -0.4, 0.0]);
        assert!(paler[1] > 0.1 && paler[0] > 0.7, "less saturation moves towards grey: {paler:?}");
    }

    #[test]
    fn random_draws_change_the_image_and_differ() {
        let (h, w) = (24, 32);
        let rgb = gradient(h, w);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (mut a, mut b, mut id) = (vec![0.0; 3 * h * w], vec![0.0; 3 * h * w], vec![0.0; 3 * h * w]);
        AugmentDraw::sample(&mut rng, &Augmentation::default(), h, w).apply(&rgb, h, w, &mut a);
        AugmentDraw::sample(&mut rng, &Augmentation::default(), h, w).apply(&rgb, h, w, &mut b);
        AugmentDraw::identity(h, w).apply(&rgb, h, w, &mut id);
        let diff = |x: &[f32], y: &[f32]| x.iter().zip(y).map(|(p, q)| (p - q).abs()).sum::<f32>();
        assert!(diff(&a, &id) > 1.0 && diff(&a, &b) > 1.0);
    }
}
