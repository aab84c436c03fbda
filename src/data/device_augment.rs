//! The augmentation of [`super::augment`] as tensor operations, run where the network runs: raw RGB bytes and
//! each frame's draw go to the device, which resamples (crop, stretch, shift with black borders), jitters in HSV
//! and normalises. The same draws give the same frames as the host path, up to float rounding; on a GPU it takes
//! the per-pixel work and three quarters of the copied bytes off the host.
use super::augment::{MEAN, STD};
use tch::{Device, Kind, Tensor};

/// Frames `[N, H, W, 3]` (bytes, interleaved RGB) and draws `[N, DRAW_LEN]` (rows of
/// [`super::augment::AugmentDraw::row`]) to normalised planar frames `[N, 3, H, W]` (f32) on the frames' device;
/// `jitter` applies the HSV change (the host path applies it whenever a draw carries one).
pub fn augment_frames(frames: &Tensor, draws: &Tensor, jitter: bool) -> Tensor {
    let (n, h, w, _) = frames.size4().expect("frames are [N, H, W, 3]");
    let device = frames.device();
    let images = frames.permute([0, 3, 1, 2]).to_kind(Kind::Float);
    let draws = draws.to_device(device).to_kind(Kind::Float);
    let column = |k: i64| draws.select(1, k).view([n, 1]);
    // Source pixel of output position i along an axis (as the host's taps): offset + (i - shift + 0.5) * scale
    // - 0.5, then grid_sample's normalised coordinate (2 s + 1) / len - 1 (align_corners = false).
    let axis = |len: i64, offset: i64, extent: i64, shift: i64| {
        let i = Tensor::arange(len, (Kind::Float, device)).view([1, len]);
        let source = column(offset) + (i - column(shift) + 0.5) * (column(extent) / len as f64) - 0.5;
        (source * 2.0 + 1.0) / len as f64 - 1.0
    };
    let ys = axis(h, 0, 2, 4).view([n, h, 1]).expand([n, h, w], false);
    let xs = axis(w, 1, 3, 5).view([n, 1, w]).expand([n, h, w], false);
    let grid = Tensor::stack(&[xs, ys], 3);
    // Bilinear (0), zeros outside the frame (0): the host path's black borders.
    let mut rgb = Tensor::grid_sampler_2d(&images, &grid, 0, 0, false) / 255.0;
    if jitter {
        rgb = jitter_hsv(&rgb, &draws.narrow(1, 6, 3));
    }
    let mean = Tensor::from_slice(&MEAN).to_device(device).view([1, 3, 1, 1]);
    let std = Tensor::from_slice(&STD).to_device(device).view([1, 3, 1, 1]);
    (rgb - mean) / std
}

/// RGB `[N, 3, H, W]` in [0, 1] shifted in HSV by `delta` `[N, 3]` (hue degrees, saturation, value) and back,
/// clipped to [0, 1]: the host path's `jitter_hsv`, branch for branch.
fn jitter_hsv(rgb: &Tensor, delta: &Tensor) -> Tensor {
    let n = rgb.size()[0];
    let change = |k: i64| delta.select(1, k).view([n, 1, 1]);
    let (r, g, b) = (rgb.select(1, 0), rgb.select(1, 1), rgb.select(1, 2));
    let v = r.maximum(&g).maximum(&b);
    let spread = &v - r.minimum(&g).minimum(&b);
    let zero = v.zeros_like();
    let s = (&spread / v.clamp_min(f64::MIN_POSITIVE)).where_self(&v.gt(0.0), &zero);
    let safe = spread.clamp_min(f64::MIN_POSITIVE);
    let hue_r = (&g - &b) / &safe * 60.0;
    let hue_g = (&b - &r) / &safe * 60.0 + 120.0;
    let hue_b = (&r - &g) / &safe * 60.0 + 240.0;
    let hue = hue_r.where_self(&v.eq_tensor(&r), &hue_g.where_self(&v.eq_tensor(&g), &hue_b));
    let hue = zero.where_self(&spread.le(0.0), &hue);
    let hue = (hue + change(0)).remainder(360.0);
    let s = (s + change(1)).clamp(0.0, 1.0);
    let v = (v + change(2)).clamp(0.0, 1.0);
    let c = &v * &s;
    let x = &c * (((&hue / 60.0).remainder(2.0) - 1.0).abs() * -1.0 + 1.0);
    let sector = (&hue / 60.0).floor().clamp(0.0, 5.0);
    let is = |ks: &[f64]| ks.iter().map(|&k| sector.eq(k)).reduce(|a, b| a.logical_or(&b)).expect("sectors");
    let pick = |full: &[f64], partial: &[f64]| c.where_self(&is(full), &x.where_self(&is(partial), &zero));
    let m = &v - &c;
    let r1 = pick(&[0.0, 5.0], &[1.0, 4.0]);
    let g1 = pick(&[1.0, 2.0], &[0.0, 3.0]);
    let b1 = pick(&[3.0, 4.0], &[2.0, 5.0]);
    Tensor::stack(&[r1 + &m, g1 + &m, b1 + &m], 1).clamp(0.0, 1.0)
}

/// Copies a host tensor of bytes to `device`; from pinned memory the copy does not block the host (from pageable
/// memory a non-blocking copy is an ordinary one).
pub fn bytes_to_device(host: &Tensor, device: Device) -> Tensor {
    match device {
        Device::Cpu => host.shallow_clone(),
        _ => host.to_device_(device, Kind::Uint8, true, false),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::augment::{AugmentDraw, Augmentation, DRAW_LEN};
    use rand::{Rng, SeedableRng};

    #[test]
    fn the_device_path_gives_the_host_paths_frames() {
        let (h, w) = (24, 32);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        // Random colours (saturated, grey and dark pixels alike) in each of 6 frames.
        let frames: Vec<Vec<u8>> = (0..6).map(|_| (0..h * w * 3).map(|_| rng.random::<u8>()).collect()).collect();
        let mut draws = vec![AugmentDraw::identity(h, w)];
        draws.extend((0..5).map(|_| AugmentDraw::sample(&mut rng, &Augmentation::default(), h, w)));
        for jitter in [false, true] {
            let used: Vec<AugmentDraw> = if jitter { draws.clone() } else { vec![AugmentDraw::identity(h, w); 6] };
            let bytes = Tensor::from_slice(&frames.concat()).view([6, h as i64, w as i64, 3]);
            let rows: Vec<f32> = used.iter().flat_map(AugmentDraw::row).collect();
            let rows = Tensor::from_slice(&rows).view([6, DRAW_LEN as i64]);
            let device = augment_frames(&bytes, &rows, jitter);
            for (k, (rgb, d)) in frames.iter().zip(&used).enumerate() {
                let mut host = vec![0.0f32; 3 * h * w];
                d.apply(rgb, h, w, &mut host);
                let got = Vec::<f32>::try_from(device.get(k as i64).flatten(0, -1)).unwrap();
                let worst = host.iter().zip(&got).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
                assert!(worst < 1e-3, "frame {k} (jitter {jitter}): largest difference {worst}");
            }
        }
    }
}
