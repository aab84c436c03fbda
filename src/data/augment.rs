//! Image augmentation (design.md): colour jitter, random crop + resize and random translation, applied in one
//! bilinear resampling pass, then ImageNet normalisation into planar f32.
use rand::Rng;

/// ImageNet channel means and standard deviations.
const MEAN: [f32; 3] = [0.485, 0.456, 0.406];
const STD: [f32; 3] = [0.229, 0.224, 0.225];
/// Largest crop per side and largest shift, as fractions of the 240 x 320 frame (12 rows, 16 columns).
const CROP_FRAC: [f32; 2] = [12.0 / 240.0, 16.0 / 320.0];
const SHIFT_FRAC: [f32; 2] = [12.0 / 240.0, 16.0 / 320.0];
/// Hue rotation (radians) and saturation / value scale ranges of the colour jitter.
const HUE: f32 = 0.1 * std::f32::consts::PI;
const SATURATION: [f32; 2] = [0.7, 1.3];
const VALUE: [f32; 2] = [0.7, 1.3];

/// One random draw of all augmentation parameters; the identity when augmentation is off.
#[derive(Debug, Clone, Copy)]
pub struct AugmentDraw {
    /// Source rectangle (top, left, height, width) in pixels that is stretched over the frame.
    crop: [f32; 4],
    /// Shift (rows, columns) of the result.
    shift: [f32; 2],
    /// Colour transform applied to RGB in [0, 1].
    colour: [[f32; 3]; 3],
}

impl AugmentDraw {
    /// No change.
    pub fn identity(height: usize, width: usize) -> AugmentDraw {
        let colour = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        AugmentDraw { crop: [0.0, 0.0, height as f32, width as f32], shift: [0.0, 0.0], colour }
    }

    /// A random draw for frames of `height x width`.
    pub fn sample<R: Rng>(rng: &mut R, height: usize, width: usize) -> AugmentDraw {
        let (h, w) = (height as f32, width as f32);
        let (max_r, max_c) = (CROP_FRAC[0] * h, CROP_FRAC[1] * w);
        let (top, bottom) = (rng.random_range(0.0..=max_r), rng.random_range(0.0..=max_r));
        let (left, right) = (rng.random_range(0.0..=max_c), rng.random_range(0.0..=max_c));
        let shift = [
            rng.random_range(-SHIFT_FRAC[0] * h..=SHIFT_FRAC[0] * h).round(),
            rng.random_range(-SHIFT_FRAC[1] * w..=SHIFT_FRAC[1] * w).round(),
        ];
        let hue = rng.random_range(-HUE..=HUE);
        let sat = rng.random_range(SATURATION[0]..=SATURATION[1]);
        let val = rng.random_range(VALUE[0]..=VALUE[1]);
        AugmentDraw {
            crop: [top, left, h - top - bottom, w - left - right],
            shift,
            colour: colour_matrix(hue, sat, val),
        }
    }

    /// Applies the draw to interleaved RGB bytes, writing normalised planar `[3, H, W]` values into `out`.
    pub fn apply(&self, rgb: &[u8], height: usize, width: usize, out: &mut [f32]) {
        let plane = height * width;
        let [top, left, ch, cw] = self.crop;
        let (sy, sx) = (ch / height as f32, cw / width as f32);
        for r in 0..height {
            for c in 0..width {
                let src_r = top + (r as f32 - self.shift[0] + 0.5) * sy - 0.5;
                let src_c = left + (c as f32 - self.shift[1] + 0.5) * sx - 0.5;
                let px = bilinear(rgb, height, width, src_r, src_c);
                for k in 0..3 {
                    let m = self.colour[k];
                    let v = (m[0] * px[0] + m[1] * px[1] + m[2] * px[2]).clamp(0.0, 1.0);
                    out[k * plane + r * width + c] = (v - MEAN[k]) / STD[k];
                }
            }
        }
    }
}

/// Hue rotation about the grey axis, saturation scaling towards grey, then value scaling.
fn colour_matrix(hue: f32, saturation: f32, value: f32) -> [[f32; 3]; 3] {
    let (s, c) = hue.sin_cos();
    let third: f32 = 1.0 / 3.0;
    let root = third.sqrt();
    // Rodrigues rotation about (1, 1, 1) / sqrt(3).
    let rot = |i: usize, j: usize| {
        let diag = if i == j { c + (1.0 - c) * third } else { (1.0 - c) * third };
        let cross = match (3 + j - i) % 3 {
            1 => -root * s,
            2 => root * s,
            _ => 0.0,
        };
        diag + cross
    };
    std::array::from_fn(|i| {
        std::array::from_fn(|j| {
            let grey = third;
            let mix: f32 = (0..3)
                .map(|k| ((if i == k { 1.0 } else { 0.0 }) * saturation + grey * (1.0 - saturation)) * rot(k, j))
                .sum();
            value * mix
        })
    })
}

/// RGB in [0, 1] at a fractional position; black outside the frame.
fn bilinear(rgb: &[u8], height: usize, width: usize, r: f32, c: f32) -> [f32; 3] {
    let (r0, c0) = (r.floor(), c.floor());
    let (fr, fc) = (r - r0, c - c0);
    let mut acc = [0.0f32; 3];
    for (dr, wr) in [(0, 1.0 - fr), (1, fr)] {
        for (dc, wc) in [(0, 1.0 - fc), (1, fc)] {
            let (rr, cc) = (r0 as i64 + dr, c0 as i64 + dc);
            if rr < 0 || cc < 0 || rr >= height as i64 || cc >= width as i64 {
                continue;
            }
            let i = (rr as usize * width + cc as usize) * 3;
            for k in 0..3 {
                acc[k] += wr * wc * f32::from(rgb[i + k]) / 255.0;
            }
        }
    }
    acc
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
    fn colour_matrix_keeps_grey_under_hue_and_saturation_changes() {
        let m = colour_matrix(0.7, 1.4, 1.0);
        for row in m {
            assert!((row.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        }
    }

    #[test]
    fn random_draws_change_the_image_and_differ() {
        let (h, w) = (24, 32);
        let rgb = gradient(h, w);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (mut a, mut b, mut id) = (vec![0.0; 3 * h * w], vec![0.0; 3 * h * w], vec![0.0; 3 * h * w]);
        AugmentDraw::sample(&mut rng, h, w).apply(&rgb, h, w, &mut a);
        AugmentDraw::sample(&mut rng, h, w).apply(&rgb, h, w, &mut b);
        AugmentDraw::identity(h, w).apply(&rgb, h, w, &mut id);
        let diff = |x: &[f32], y: &[f32]| x.iter().zip(y).map(|(p, q)| (p - q).abs()).sum::<f32>();
        assert!(diff(&a, &id) > 1.0 && diff(&a, &b) > 1.0);
    }
}
