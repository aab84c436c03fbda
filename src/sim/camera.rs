//! Headless rendering of the `frontview` camera (EGL) and projection of world points to its pixels.
//!
//! The field of view is the authors' (their robosuite fork and data pipeline): a 320x320 render of a camera at
//! (1.6, 0.1, 1.75) with Euler angles (3.14, 2.0097, pi/2) and a 45-degree vertical field of view; rows [80:] of
//! mujoco-py's bottom-up image kept and columns flipped (the stored 240x320 frame), then `crop: [100, 0, 0, 0]`
//! dropping 100 more rows before resizing back to 240x320. That camera is mounted upside down, so the stored
//! frames are the scene upright, and the policy sees the camera's top 140 of 320 rows: the two bins and the space
//! above them. Here the same region is rendered directly at the training size through the camera's intrinsics
//! (stretched vertically by 240/140 like the authors' resize), then turned by 180 degrees.
use anyhow::{Result, anyhow, bail};
use mujoco_rs::prelude::*;
use mujoco_rs::renderer::MjRenderer;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Which geometry the camera sees.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, Default, schemars::JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum Visuals {
    /// The robots' visual meshes (what the paper filmed).
    #[default]
    Full,
    /// Collision geometry only: ~10x faster to render on CPU.
    Collision,
}

/// Position of the authors' `frontview` camera.
pub const CAMERA_POS: [f64; 3] = [1.6, 0.1, 1.75];
/// Its orientation as MuJoCo Euler angles (intrinsic x, y, z; radians). The first angle is the authors' 3.14, not pi:
/// the camera is turned a hair short of upside down.
#[allow(clippy::approx_constant)]
pub const CAMERA_EULER: [f64; 3] = [3.14, 2.0096641371956415, std::f64::consts::FRAC_PI_2];
/// Vertical field of view (degrees) of the authors' square render.
const SQUARE_FOVY: f64 = 45.0;
/// Side of the authors' square render, and the rows of it the policy sees (from the camera's top).
const SQUARE: f64 = 320.0;
const KEPT_ROWS: f64 = 140.0;

/// Size of the frames handed to the policy (the authors': 240 x 320); a side left out keeps its default.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ImageSize {
    /// Rows of each frame.
    pub height: usize,
    /// Columns of each frame.
    pub width: usize,
}

impl Default for ImageSize {
    fn default() -> Self {
        ImageSize { height: 240, width: 320 }
    }
}

impl ImageSize {
    /// Checks that the size can be rendered.
    pub fn validate(&self) -> Result<()> {
        if !(16..=2048).contains(&self.width) || !(16..=2048).contains(&self.height) {
            bail!(
                "world.image = {}x{} (height x width) out of range: each side must be in 16..=2048",
                self.height,
                self.width
            );
        }
        Ok(())
    }

    /// Bytes in one RGB frame.
    pub fn rgb_len(&self) -> usize {
        self.height * self.width * 3
    }
}

/// Pinhole intrinsics (pixels) of the camera as mounted (upside down), for frames of a given size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    /// Principal point (column, row) measured from the top-left of the camera's own image.
    pub cx: f64,
    pub cy: f64,
}

impl Intrinsics {
    /// The authors' kept region at `size`: their square render's focal length scaled by `width / 320`
    /// horizontally and by `height / 140` vertically, its principal point scaled alike.
    pub fn for_size(size: ImageSize) -> Intrinsics {
        let f = (SQUARE / 2.0) / (SQUARE_FOVY.to_radians() / 2.0).tan();
        let (sx, sy) = (size.width as f64 / SQUARE, size.height as f64 / KEPT_ROWS);
        Intrinsics { fx: f * sx, fy: f * sy, cx: SQUARE / 2.0 * sx, cy: SQUARE / 2.0 * sy }
    }

    /// MJCF attributes of a camera with these intrinsics (`principalpixel` is the offset from the image centre,
    /// positive towards the image top).
    pub fn mjcf_attributes(&self, size: ImageSize) -> String {
        format!(
            r#"resolution="{w} {h}" sensorsize="1 1" focalpixel="{fx} {fy}" principalpixel="{px} {py}""#,
            w = size.width,
            h = size.height,
            fx = self.fx,
            fy = self.fy,
            px = self.cx - size.width as f64 / 2.0,
            py = size.height as f64 / 2.0 - self.cy,
        )
    }
}

/// Offscreen renderer for the scene's fixed camera.
pub struct Camera {
    /// Always `Some` but while it is dropped (under [`GL_LOCK`]).
    renderer: Option<MjRenderer>,
    size: ImageSize,
}

/// Serialises every OpenGL call of the process (opening, rendering, closing): an evaluation whose workers
/// rendered on their own threads died twice in Mesa's software driver (a general protection fault in
/// `swrast_dri.so`, 2026-12-03), with a training or another process beside it.
static GL_LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn gl_lock() -> std::sync::MutexGuard<'static, ()> {
    GL_LOCK.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl Drop for Camera {
    fn drop(&mut self) {
        let _gl = gl_lock();
        drop(self.renderer.take());
    }
}

impl Camera {
    /// Opens an EGL context and renderer for `model`.
    pub fn new(model: &MjModel, camera_id: usize, size: ImageSize, visuals: Visuals) -> Result<Camera> {
        size.validate()?;
        // Geom group 0: robot collision shapes; 1: robot and arena visual meshes; 2: objects (both modes).
        // Sites (markers) are hidden.
        let opts = MjvOption {
            sitegroup: [0; 6],
            geomgroup: match visuals {
                Visuals::Full => [0, 1, 1, 0, 0, 0],
                Visuals::Collision => [1, 0, 1, 0, 0, 0],
            },
            ..MjvOption::default()
        };
        let _gl = gl_lock();
        let renderer = MjRenderer::builder()
            .width(size.width as u32)
            .height(size.height as u32)
            .camera(MjvCamera::new_fixed(camera_id))
            .opts(opts)
            .build(model)
            .map_err(|e| anyhow!("opening a headless EGL renderer: {e}"))?;
        Ok(Camera { renderer: Some(renderer), size })
    }

    /// Renders the current state: `height * width * 3` bytes, row-major from the top row of the upright scene.
    pub fn render(&mut self, data: &mut MjData<Arc<MjModel>>) -> Result<Vec<u8>> {
        let _gl = gl_lock();
        let renderer = self.renderer.as_mut().expect("a camera holds its renderer until it is dropped");
        renderer.sync_data(data).map_err(|e| anyhow!("render sync: {e}"))?;
        renderer.render().map_err(|e| anyhow!("render: {e}"))?;
        let rgb = renderer.rgb_flat().ok_or_else(|| anyhow!("renderer produced no RGB buffer"))?;
        if rgb.len() != self.size.rgb_len() {
            bail!("renderer returned {} bytes, expected {}", rgb.len(), self.size.rgb_len());
        }
        // The camera hangs upside down: turning its image by 180 degrees reverses the pixel order.
        Ok(rgb.chunks_exact(3).rev().flatten().copied().collect())
    }
}

/// Pixel (column, row) of world point `p` in an upright frame of `size` from camera `camera_id`; pixel (c, r)
/// covers [c, c + 1) x [r, r + 1).
pub fn project<M: mujoco_rs::wrappers::mj_model::traits::ModelType>(
    data: &MjData<M>,
    camera_id: usize,
    size: ImageSize,
    p: [f64; 3],
) -> [f64; 2] {
    let c = data.cam_xpos()[camera_id];
    let m = data.cam_xmat()[camera_id];
    let d = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
    // Camera frame: x right, y up, looking along -z. Rows of cam_xmat's transpose = columns of cam_xmat.
    let xc = m[0] * d[0] + m[3] * d[1] + m[6] * d[2];
    let yc = m[1] * d[0] + m[4] * d[1] + m[7] * d[2];
    let zc = m[2] * d[0] + m[5] * d[1] + m[8] * d[2];
    let k = Intrinsics::for_size(size);
    let col = k.cx + k.fx * xc / -zc;
    let row = k.cy - k.fy * yc / -zc;
    [size.width as f64 - col, size.height as f64 - row]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn intrinsics_scale_the_authors_square_render() {
        let k = Intrinsics::for_size(ImageSize::default());
        let f = 160.0 / 22.5f64.to_radians().tan();
        assert!((k.fx - f).abs() < 1e-9 && (k.fy - f * 240.0 / 140.0).abs() < 1e-9);
        assert!((k.cx - 160.0).abs() < 1e-9 && (k.cy - 160.0 * 240.0 / 140.0).abs() < 1e-9);
        let half = Intrinsics::for_size(ImageSize { height: 120, width: 160 });
        assert!((half.fx - k.fx / 2.0).abs() < 1e-9 && (half.cy - k.cy / 2.0).abs() < 1e-9);
    }
}
