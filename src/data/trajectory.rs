//! One recorded trajectory and its on-disk form: a safetensors file per trajectory.
//!
//! Tensors (T = number of steps, all little-endian):
//! - `frames_jpeg` u8 [total bytes]: the JPEG frames back to back; `frame_offsets` i64 [T + 1] delimits them.
//! - `eef_pos` f32 [T, 3]; `eef_rot` f32 [T, 4] as (angle / pi, axis); `eef_pixel` f32 [T, 2] as (column, row);
//!   `joint_pos`, `joint_vel` f32 [T, 7]; `gripper_qpos` f32 [T, 2]; `object_poses` f32 [T, 4, 7] as
//!   (x, y, z, qw, qx, qy, qz) in object order milk, bread, cereal, can; `stages` u8 [T, 3] (reached, picked, placed).
//! - `actions` f32 [T - 1, 8]: the absolute action taken at each step but the last (the last step has none).
//!
//! The header's `__metadata__` holds one key, `oneshot`, whose value is the JSON of [`TrajectoryMeta`].
//! From Python: `safetensors.numpy.load_file(path)` and decode frames with any JPEG decoder.
use crate::sim::env::{STATE_DIM, robot_state};
use crate::sim::milestones::Milestones;
use crate::sim::robot::Robot;
use crate::sim::rollout::Episode;
use anyhow::{Context, Result, bail};
use image::codecs::jpeg::JpegEncoder;
use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use std::path::Path;

/// Version of this file layout; bump on any change.
pub const FORMAT_VERSION: u32 = 1;

/// Facts about a trajectory that are not per step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrajectoryMeta {
    pub format_version: u32,
    pub robot: Robot,
    pub task: usize,
    /// Seed of the task instance (layout).
    pub instance_seed: u64,
    pub height: usize,
    pub width: usize,
    /// Final stages the episode achieved.
    pub stages: Milestones,
}

/// A trajectory in memory: JPEG frames plus per-step arrays.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    pub meta: TrajectoryMeta,
    pub frames_jpeg: Vec<Vec<u8>>,
    pub eef_pos: Vec<[f32; 3]>,
    pub eef_rot: Vec<[f32; 4]>,
    pub eef_pixel: Vec<[f32; 2]>,
    pub joint_pos: Vec<[f32; 7]>,
    pub joint_vel: Vec<[f32; 7]>,
    pub gripper_qpos: Vec<[f32; 2]>,
    pub object_poses: Vec<[[f32; 7]; 4]>,
    pub stages: Vec<[u8; 3]>,
    pub actions: Vec<[f32; 8]>,
}

/// The end-effector position where the gripper first closes, then where it last is open (after the release),
/// in metres, from a trajectory's actions and end-effector positions: the targets of DAML's auxiliary head (the
/// authors' `aux_pose`). A trajectory that never closes the gripper has both at its last open step.
pub fn grasp_and_drop(actions: &[[f32; 8]], eef_pos: &[[f32; 3]]) -> [f32; 6] {
    let closed = |t: &usize| actions[*t][7] > 0.0;
    let grasp = (0..actions.len()).find(closed);
    let drop = (0..actions.len()).rev().find(|t| !closed(t));
    let last = eef_pos.len().saturating_sub(1);
    let at = |t: Option<usize>| eef_pos[t.unwrap_or(last).min(last)];
    let (g, d) = (at(grasp.or(drop)), at(drop));
    [g[0], g[1], g[2], d[0], d[1], d[2]]
}

fn f32s<const N: usize>(v: [f64; N]) -> [f32; N] {
    v.map(|x| x as f32)
}

impl Trajectory {
    /// Number of steps (frames).
    pub fn len(&self) -> usize {
        self.frames_jpeg.len()
    }

    /// Whether the trajectory has no steps.
    pub fn is_empty(&self) -> bool {
        self.frames_jpeg.is_empty()
    }

    /// The robot's own state at frame `t` (see [`crate::sim::env::robot_state`]).
    pub fn robot_state(&self, t: usize) -> [f32; STATE_DIM] {
        robot_state(self.eef_pos[t].map(f64::from), self.eef_rot[t].map(f64::from), self.gripper_qpos[t].map(f64::from))
    }

    /// The targets of DAML's auxiliary head: see [`grasp_and_drop`].
    pub fn grasp_and_drop(&self) -> [f32; 6] {
        grasp_and_drop(&self.actions, &self.eef_pos)
    }

    /// Encodes a rendered expert episode; every step must carry a frame.
    pub fn from_episode(meta: TrajectoryMeta, episode: &Episode, jpeg_quality: u8) -> Result<Trajectory> {
        let mut frames_jpeg = Vec::with_capacity(episode.steps.len());
        for step in &episode.steps {
            let frame = step.frame.as_ref().context("episode was recorded without frames")?;
            frames_jpeg.push(encode_jpeg(frame, meta.height, meta.width, jpeg_quality)?);
        }
        let obs = || episode.steps.iter().map(|s| &s.observation);
        let stage = |s: Milestones| [s.reached as u8, s.picked as u8, s.placed as u8];
        Ok(Trajectory {
            frames_jpeg,
            eef_pos: obs().map(|o| f32s(o.eef_pos)).collect(),
            eef_rot: obs().map(|o| f32s(o.eef_rot)).collect(),
            eef_pixel: obs().map(|o| f32s(o.eef_pixel)).collect(),
            joint_pos: obs().map(|o| f32s(o.joint_pos)).collect(),
            joint_vel: obs().map(|o| f32s(o.joint_vel)).collect(),
            gripper_qpos: obs().map(|o| f32s(o.gripper_qpos)).collect(),
            object_poses: obs().map(|o| o.object_poses.map(f32s)).collect(),
            stages: obs().map(|o| stage(o.milestones)).collect(),
            actions: episode.steps.iter().filter_map(|s| s.action.map(|a| f32s(a.0))).collect(),
            meta,
        })
    }

    /// Decodes frame `t` into `height * width * 3` RGB bytes.
    pub fn frame_rgb(&self, t: usize) -> Result<Vec<u8>> {
        let img = image::load_from_memory_with_format(&self.frames_jpeg[t], image::ImageFormat::Jpeg)
            .with_context(|| format!("decoding frame {t}"))?
            .to_rgb8();
        if (img.height() as usize, img.width() as usize) != (self.meta.height, self.meta.width) {
            bail!(
                "frame {t} is {}x{}, metadata says {}x{}",
                img.height(),
                img.width(),
                self.meta.height,
                self.meta.width
            );
        }
        Ok(img.into_raw())
    }

    /// Serialises to safetensors bytes (deterministic: same trajectory, same bytes).
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        let t = self.len();
        let mut offsets = Vec::with_capacity(t + 1);
        let mut jpeg = Vec::new();
        offsets.push(0i64);
        for f in &self.frames_jpeg {
            jpeg.extend_from_slice(f);
            offsets.push(jpeg.len() as i64);
        }
        let offsets_bytes: Vec<u8> = offsets.iter().flat_map(|o| o.to_le_bytes()).collect();
        let stages: Vec<u8> = self.stages.iter().flatten().copied().collect();
        let poses: Vec<[f32; 7]> = self.object_poses.iter().flatten().copied().collect();
        let buffers: Vec<(&str, Dtype, Vec<usize>, Vec<u8>)> = vec![
            ("frames_jpeg", Dtype::U8, vec![jpeg.len()], jpeg),
            ("frame_offsets", Dtype::I64, vec![t + 1], offsets_bytes),
            ("eef_pos", Dtype::F32, vec![t, 3], le_bytes(&self.eef_pos)),
            ("eef_rot", Dtype::F32, vec![t, 4], le_bytes(&self.eef_rot)),
            ("eef_pixel", Dtype::F32, vec![t, 2], le_bytes(&self.eef_pixel)),
            ("joint_pos", Dtype::F32, vec![t, 7], le_bytes(&self.joint_pos)),
            ("joint_vel", Dtype::F32, vec![t, 7], le_bytes(&self.joint_vel)),
            ("gripper_qpos", Dtype::F32, vec![t, 2], le_bytes(&self.gripper_qpos)),
            ("object_poses", Dtype::F32, vec![t, 4, 7], le_bytes(&poses)),
            ("stages", Dtype::U8, vec![t, 3], stages),
            ("actions", Dtype::F32, vec![self.actions.len(), 8], le_bytes(&self.actions)),
        ];
        let mut views = Vec::with_capacity(buffers.len());
        for (name, dtype, shape, bytes) in &buffers {
            views.push((*name, TensorView::new(*dtype, shape.clone(), bytes)?));
        }
        let meta = HashMap::from([("oneshot".to_string(), serde_json::to_string(&self.meta)?)]);
        Ok(safetensors::serialize(views, Some(meta))?)
    }

    /// Parses safetensors bytes written by [`Trajectory::to_bytes`].
    pub fn from_bytes(bytes: &[u8]) -> Result<Trajectory> {
        let st = SafeTensors::deserialize(bytes)?;
        let (_, header) = SafeTensors::read_metadata(bytes)?;
        let meta_json = header.metadata().as_ref().and_then(|m| m.get("oneshot")).context("no `oneshot` metadata")?;
        let meta: TrajectoryMeta = serde_json::from_str(meta_json).context("parsing `oneshot` metadata")?;
        if meta.format_version != FORMAT_VERSION {
            bail!("trajectory format version {} (this build reads {FORMAT_VERSION})", meta.format_version);
        }
        let jpeg = st.tensor("frames_jpeg")?;
        let offsets: Vec<usize> =
            st.tensor("frame_offsets")?.data().chunks_exact(8).map(|c| i64_le(c) as usize).collect();
        if offsets.windows(2).any(|w| w[0] > w[1]) || offsets.last() != Some(&jpeg.data().len()) {
            bail!("frame_offsets do not delimit frames_jpeg");
        }
        let frames_jpeg = offsets.windows(2).map(|w| jpeg.data()[w[0]..w[1]].to_vec()).collect();
        let stages = st.tensor("stages")?.data().chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let poses: Vec<[f32; 7]> = rows(&st, "object_poses")?;
        let traj = Trajectory {
            meta,
            frames_jpeg,
            eef_pos: rows(&st, "eef_pos")?,
            eef_rot: rows(&st, "eef_rot")?,
            eef_pixel: rows(&st, "eef_pixel")?,
            joint_pos: rows(&st, "joint_pos")?,
            joint_vel: rows(&st, "joint_vel")?,
            gripper_qpos: rows(&st, "gripper_qpos")?,
            object_poses: poses.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect(),
            stages,
            actions: rows(&st, "actions")?,
        };
        let t = traj.len();
        let lens = [traj.eef_pos.len(), traj.eef_pixel.len(), traj.joint_pos.len(), traj.object_poses.len()];
        if t == 0 || lens.iter().any(|&l| l != t) || traj.actions.len() + 1 != t {
            bail!("inconsistent lengths: {t} frames, arrays {lens:?}, {} actions", traj.actions.len());
        }
        Ok(traj)
    }

    /// Writes the file at `path`.
    pub fn save(&self, path: &Path) -> Result<()> {
        std::fs::write(path, self.to_bytes()?).with_context(|| format!("writing {}", path.display()))
    }

    /// Reads the file at `path`.
    pub fn load(path: &Path) -> Result<Trajectory> {
        let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
        Trajectory::from_bytes(&bytes).with_context(|| format!("parsing {}", path.display()))
    }
}

/// Encodes an RGB frame as JPEG.
pub fn encode_jpeg(rgb: &[u8], height: usize, width: usize, quality: u8) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    JpegEncoder::new_with_quality(&mut out, quality).encode(
        rgb,
        width as u32,
        height as u32,
        image::ExtendedColorType::Rgb8,
    )?;
    Ok(out)
}

/// `rgb` after a JPEG encoding at `quality` and decoding: what a stored frame looks like when read back.
pub fn jpeg_round_trip(rgb: &[u8], height: usize, width: usize, quality: u8) -> Result<Vec<u8>> {
    let jpeg = encode_jpeg(rgb, height, width, quality)?;
    Ok(image::load_from_memory_with_format(&jpeg, image::ImageFormat::Jpeg)?.to_rgb8().into_raw())
}

fn le_bytes<const N: usize>(rows: &[[f32; N]]) -> Vec<u8> {
    rows.iter().flatten().flat_map(|v| v.to_le_bytes()).collect()
}

fn i64_le(c: &[u8]) -> i64 {
    i64::from_le_bytes(c.try_into().expect("chunk of 8 bytes"))
}

fn rows<const N: usize>(st: &SafeTensors, name: &str) -> Result<Vec<[f32; N]>> {
    let view = st.tensor(name)?;
    if view.dtype() != Dtype::F32 || view.shape().last() != Some(&N) && !view.data().is_empty() {
        bail!("tensor `{name}` has dtype {:?} and shape {:?}", view.dtype(), view.shape());
    }
    let values: Vec<f32> =
        view.data().chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().expect("chunk of 4 bytes"))).collect();
    Ok(values.chunks_exact(N).map(|c| c.try_into().expect("chunk of N values")).collect())
}
