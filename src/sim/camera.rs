//! Headless rendering of the `frontview` camera (EGL) and projection of world points to its pixels.
use super::scene::{CAMERA_FOVY, Visuals};
use anyhow::{Result, anyhow, bail};
use mujoco_rs::prelude::*;
use mujoco_rs::renderer::MjRenderer;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Size of the frames handed to the policy. The camera renders a `width` x `width` square and keeps its
/// bottom `height` rows, as the paper's code kept rows [80:] of a 320x320 render.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImageSize {
    pub height: usize,
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
        if self.width < 16 || self.height < 16 || self.width > 2048 {
            bail!("image size {}x{} out of range: each side must be in 16..=2048", self.height, self.width);
        }
        if self.height > self.width {
            bail!(
                "image height {} exceeds width {}: frames are the bottom rows of a square render",
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

/// Offscreen renderer for the scene's fixed camera.
pub struct Camera {
    renderer: MjRenderer,
    size: ImageSize,
    camera_id: usize,
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
        let renderer = MjRenderer::builder()
            .width(size.width as u32)
            .height(size.width as u32)
            .camera(MjvCamera::new_fixed(camera_id))
            .opts(opts)
            .build(model)
            .map_err(|e| anyhow!("opening a headless EGL renderer: {e}"))?;
        Ok(Camera { renderer, size, camera_id })
    }

    /// Renders the current state: `height * width * 3` bytes, row-major from the top row.
    pub fn render(&mut self, data: &mut MjData<Arc<MjModel>>) -> Result<Vec<u8>> {
        self.renderer.sync_data(data).map_err(|e| anyhow!("render sync: {e}"))?;
        self.renderer.render().map_err(|e| anyhow!("render: {e}"))?;
        let rgb = self.renderer.rgb_flat().ok_or_else(|| anyhow!("renderer produced no RGB buffer"))?;
        let skip = (self.size.width - self.size.height) * self.size.width * 3;
        Ok(rgb[skip..].to_vec())
    }

    /// Pixel (column, row) of world point `p` in the cropped frame, as floats.
    pub fn project(&self, data: &MjData<Arc<MjModel>>, p: [f64; 3]) -> [f64; 2] {
        project(data, self.camera_id, self.size, p)
    }
}

/// Pixel (column, row) of world point `p` in a frame of `size` from camera `camera_id`.
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
    let w = size.width as f64;
    let f = (w / 2.0) / (CAMERA_FOVY.to_radians() / 2.0).tan();
    let col = w / 2.0 + f * xc / -zc;
    let row_square = w / 2.0 - f * yc / -zc;
    [col, row_square - (size.width - size.height) as f64]
}
