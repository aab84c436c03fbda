//! Inverse kinematics: damped least squares on MuJoCo's site Jacobians with a rest-pose term in the
//! Jacobian's null space, solved on a scratch copy of the state so the simulation is untouched.
use super::ids::SceneIds;
use super::rotation::{mat_from_mj, rotation_error};
use mujoco_rs::prelude::*;
use nalgebra::{Matrix3, SMatrix, SVector, Vector3};
use std::sync::Arc;

type Jac = SMatrix<f64, 6, 7>;

/// Solver settings.
#[derive(Debug, Clone, Copy)]
pub struct IkSettings {
    /// Damping of the least-squares step.
    pub damping: f64,
    /// Gain pulling the joints towards the rest pose inside the null space.
    pub rest_gain: f64,
    /// Iteration cap.
    pub max_iters: usize,
    /// Largest joint change per iteration (rad).
    pub max_step: f64,
    /// Stop when position error (m) and rotation error (rad) fall below these.
    pub tol_pos: f64,
    pub tol_rot: f64,
}

impl Default for IkSettings {
    fn default() -> Self {
        IkSettings { damping: 0.05, rest_gain: 0.05, max_iters: 150, max_step: 0.2, tol_pos: 5e-4, tol_rot: 5e-3 }
    }
}

/// Result of one solve.
#[derive(Debug, Clone, Copy)]
pub struct IkSolution {
    pub q: [f64; 7],
    pub pos_err: f64,
    pub rot_err: f64,
}

/// IK solver owning a scratch `MjData`.
pub struct IkSolver {
    scratch: MjData<Arc<MjModel>>,
    ids: SceneIds,
    rest: [f64; 7],
    limits: [[f64; 2]; 7],
    pub settings: IkSettings,
}

impl IkSolver {
    /// Solver for the arm in `model`; `rest` is the preferred posture.
    pub fn new(model: Arc<MjModel>, ids: SceneIds, rest: [f64; 7]) -> IkSolver {
        let limits = ids.arm_joint.map(|j| model.jnt_range()[j]);
        IkSolver { scratch: MjData::new(model), ids, rest, limits, settings: IkSettings::default() }
    }

    /// End-effector position and rotation for arm joints `q`.
    pub fn forward(&mut self, q: &[f64; 7]) -> (Vector3<f64>, Matrix3<f64>) {
        self.set_q(q);
        self.ee_pose()
    }

    /// Joints that put the end-effector at `pos` with rotation `rot`, starting from `q0`.
    pub fn solve(&mut self, q0: &[f64; 7], pos: &Vector3<f64>, rot: &Matrix3<f64>) -> IkSolution {
        let s = self.settings;
        let mut q = SVector::<f64, 7>::from(*q0);
        let mut best = IkSolution { q: *q0, pos_err: f64::INFINITY, rot_err: f64::INFINITY };
        for _ in 0..s.max_iters {
            self.set_q(&q.into());
            let (p, r) = self.ee_pose();
            let ep = pos - p;
            let er = rotation_error(rot, &r);
            let (pe, re) = (ep.norm(), er.norm());
            if pe + 0.1 * re < best.pos_err + 0.1 * best.rot_err {
                best = IkSolution { q: q.into(), pos_err: pe, rot_err: re };
            }
            if pe < s.tol_pos && re < s.tol_rot {
                break;
            }
            let j = self.jacobian();
            let e = SVector::<f64, 6>::from_iterator(ep.iter().chain(er.iter()).copied());
            let jjt = j * j.transpose() + SMatrix::<f64, 6, 6>::identity() * s.damping.powi(2);
            let Some(inv) = jjt.try_inverse() else { break };
            let pinv = j.transpose() * inv;
            let null = SMatrix::<f64, 7, 7>::identity() - pinv * j;
            let rest = SVector::<f64, 7>::from(self.rest) - q;
            let mut dq = pinv * e + null * rest * s.rest_gain;
            let m = dq.amax();
            if m > s.max_step {
                dq *= s.max_step / m;
            }
            q += dq;
            for (i, [lo, hi]) in self.limits.iter().enumerate() {
                q[i] = q[i].clamp(*lo, *hi);
            }
        }
        best
    }

    fn set_q(&mut self, q: &[f64; 7]) {
        let qpos = self.scratch.qpos_mut();
        for (i, &a) in self.ids.arm_qpos.iter().enumerate() {
            qpos[a] = q[i];
        }
        self.scratch.kinematics();
        self.scratch.com_pos();
    }

    fn ee_pose(&self) -> (Vector3<f64>, Matrix3<f64>) {
        let site = self.ids.ee_site;
        (Vector3::from(self.scratch.site_xpos()[site]), mat_from_mj(&self.scratch.site_xmat()[site]))
    }

    fn jacobian(&self) -> Jac {
        let (jp, jr) = self.scratch.jac_site(true, true, self.ids.ee_site);
        let nv = jp.len() / 3;
        Jac::from_fn(|r, c| {
            let col = self.ids.arm_dof[c];
            if r < 3 { jp[r * nv + col] } else { jr[(r - 3) * nv + col] }
        })
    }
}
