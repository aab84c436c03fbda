//! One robot in the bins scene: reset to a task instance, step with end-effector actions (IK + PD with
//! gravity compensation), observe, render and track staged success.
use super::action::Action;
use super::camera::Visuals;
use super::camera::{Camera, ImageSize, project};
use super::ids::SceneIds;
use super::ik::IkSolver;
use super::milestones::{MilestoneInputs, Milestones};
use super::object::{Object, Split, environment_objects};
use super::robot::Robot;
use super::rotation::{downward, from_angle_axis, mat_from_mj, state_angle_axis, to_angle_axis, yaw_of};
use super::scene::build_model;
use super::task::{Instance, NUM_OBJECTS, NUM_TARGETS, in_quadrant};
use anyhow::{Result, bail};
use mujoco_rs::prelude::*;
use nalgebra::{DMatrix, Vector3};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// How a robot's scripted expert turns its downward-pointing gripper about the vertical.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum GripperYaw {
    /// One orientation for the whole episode, the robot's rest yaw (the authors' Panda expert): the agent's task
    /// is then mostly 3-DOF, as the paper says.
    Fixed,
    /// Turned towards the object's bearing from the gripper at the start, the cereal box a further pi/3 (the
    /// authors' Sawyer expert).
    Heading,
    /// Turned so that the fingers close across the object's narrow side.
    ObjectYaw,
}

/// World settings shared by collection and evaluation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct WorldConfig {
    /// Frame size handed to the policy.
    pub image: ImageSize,
    /// Visual meshes or collision geometry only.
    pub visuals: Visuals,
    /// Policy rate (Hz).
    pub policy_hz: f64,
    /// Controller updates per action.
    pub control_substeps: usize,
    /// Physics time step (s).
    pub physics_dt: f64,
    /// Joint PD natural frequency (rad/s) of the computed-torque loop.
    pub pd_omega: f64,
    /// Gripper yaw of the agent's (Panda's) expert.
    pub agent_yaw: GripperYaw,
    /// Gripper yaw of the demonstrator's (Sawyer's) expert. The authors' Sawyer turns by the object's bearing
    /// (`heading`); with this world's Rethink gripper that places about 80% of the time (`expert-check --robot
    /// sawyer --gripper-yaw heading`), under the 95% a demonstrator needs, so the default closes the fingers
    /// across the object's narrow side (`object_yaw`), which also turns the gripper with the object.
    pub demo_yaw: GripperYaw,
    /// When the experts close the gripper during the descent: `false` at the descent's 8th step, as the authors'
    /// expert times it; `true` as soon as the grip site is within 1 cm of the grasp point (8 steps at the
    /// latest), so that the gripper does not wait, motionless, at the bottom: from a few recent frames a policy
    /// cannot tell that wait from the closing it must follow with a rise.
    pub close_on_arrival: bool,
    /// When the experts rise after closing: `false` after 3 steps closed in place (this world's *fixed* departure:
    /// the authors rise while closing, which here loses most objects); `true` once a step has left the fingers
    /// still (2 steps at the earliest, 3 at the latest), so that they rest on the object one step rather than up
    /// to two before the rise: from a few recent frames a policy cannot tell how long they have rested.
    pub rise_on_grip: bool,
    /// The objects: `base` (the four of the paper's main experiment) or `library` (the appendix's multi-object
    /// environments: each environment lays out four of the 30 library objects, drawn by its own seed).
    pub objects: ObjectSet,
}

/// Which objects a world holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum ObjectSet {
    /// Milk, bread, cereal and can, in every layout.
    #[default]
    Base,
    /// The 30 procedural objects of `sim::object` (26 for training, 4 held out), four per environment.
    Library,
}

impl ObjectSet {
    /// Every object a scene of this set is built with.
    pub fn objects(self) -> Vec<Object> {
        match self {
            ObjectSet::Base => Object::ALL.to_vec(),
            ObjectSet::Library => Object::library().collect(),
        }
    }

    /// The four objects, by slot, of the environment with seed `seed` drawn from `split` (the base world's four
    /// whatever the seed).
    pub fn environment(self, split: Split, seed: u64) -> [Object; NUM_OBJECTS] {
        match self {
            ObjectSet::Base => Object::ALL,
            ObjectSet::Library => environment_objects(split, seed),
        }
    }
}

impl Default for WorldConfig {
    fn default() -> Self {
        WorldConfig {
            image: ImageSize::default(),
            visuals: Visuals::Full,
            policy_hz: 10.0,
            control_substeps: 10,
            physics_dt: 0.002,
            pd_omega: 30.0,
            agent_yaw: GripperYaw::Fixed,
            demo_yaw: GripperYaw::ObjectYaw,
            close_on_arrival: false,
            rise_on_grip: false,
            objects: ObjectSet::Base,
        }
    }
}

impl WorldConfig {
    /// Physics steps per controller update.
    pub fn physics_per_substep(&self) -> usize {
        (1.0 / (self.policy_hz * self.control_substeps as f64 * self.physics_dt)).round().max(1.0) as usize
    }

    /// The expert's gripper-yaw rule for `robot`.
    pub fn gripper_yaw(&self, robot: Robot) -> GripperYaw {
        match robot {
            Robot::Sawyer => self.demo_yaw,
            Robot::Panda => self.agent_yaw,
        }
    }

    /// Checks ranges; errors name the key.
    pub fn validate(&self) -> Result<()> {
        self.image.validate()?;
        if !(self.policy_hz > 0.0 && self.policy_hz <= 100.0) {
            bail!("world.policy_hz = {} out of range (0, 100]", self.policy_hz);
        }
        if self.control_substeps == 0 || self.control_substeps > 100 {
            bail!("world.control_substeps = {} out of range 1..=100", self.control_substeps);
        }
        if !(self.physics_dt > 0.0 && self.physics_dt <= 0.01) {
            bail!("world.physics_dt = {} out of range (0, 0.01]", self.physics_dt);
        }
        if !(self.pd_omega > 0.0 && self.pd_omega <= 200.0) {
            bail!("world.pd_omega = {} out of range (0, 200]", self.pd_omega);
        }
        Ok(())
    }
}

/// Entries of the agent's own state as a network reads it ([`robot_state`]).
pub const STATE_DIM: usize = 9;

/// Version of [`robot_state`]'s encoding, part of the key of every training that reads it (2: the orientation
/// continuous, in the authors' range: [`state_angle_axis`]).
pub const STATE_VERSION: u32 = 2;

/// Where the two finger joints lie in [`robot_state`] (each divided by its travel, 0.04 m).
pub const STATE_FINGERS: usize = 7;

/// The robot's own state as a network reads it (`model.concat_state`, the authors' `ee_aa` and `gripper_qpos`):
/// the end-effector position (metres), its orientation (`eef_rot` in the action's form, read in the authors'
/// continuous form: angle / pi, axis) and the two finger joints divided by their travel (the Panda's run 0..0.04
/// and -0.04..0 m), so that every entry is of order one.
pub fn robot_state(eef_pos: [f64; 3], eef_rot: [f64; 4], fingers: [f64; 2]) -> [f32; STATE_DIM] {
    const FULL_OPENING: f64 = 0.04;
    let (angle, axis) = state_angle_axis(eef_rot[0], [eef_rot[1], eef_rot[2], eef_rot[3]]);
    let orientation = [angle, axis[0], axis[1], axis[2]];
    let mut s = [0.0f32; STATE_DIM];
    for (out, v) in
        s.iter_mut().zip(eef_pos.iter().chain(&orientation).copied().chain(fingers.map(|f| f / FULL_OPENING)))
    {
        *out = v as f32;
    }
    s
}

/// What the robot senses at one step (privileged object state included).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Observation {
    pub eef_pos: [f64; 3],
    /// End-effector orientation as (angle / pi, axis x, y, z), the action's form.
    pub eef_rot: [f64; 4],
    /// End-effector pixel (column, row) in the frame.
    pub eef_pixel: [f64; 2],
    pub joint_pos: [f64; 7],
    pub joint_vel: [f64; 7],
    pub gripper_qpos: [f64; 2],
    /// Pose (x, y, z, qw, qx, qy, qz) of each object, in `Object::ALL` order.
    pub object_poses: [[f64; 7]; NUM_OBJECTS],
    pub milestones: Milestones,
}

impl Observation {
    /// The robot's own state as a network reads it.
    pub fn robot_state(&self) -> [f32; STATE_DIM] {
        robot_state(self.eef_pos, self.eef_rot, self.gripper_qpos)
    }
}

/// A simulated robot in the bins scene.
pub struct Env {
    robot: Robot,
    config: WorldConfig,
    data: MjData<Arc<MjModel>>,
    ids: SceneIds,
    ik: IkSolver,
    camera: Option<Camera>,
    instance: Option<Instance>,
    start_z: f64,
    milestones: Milestones,
    q_target: [f64; 7],
    gripper: f64,
    rest_yaw: f64,
}

impl Env {
    /// Builds the scene for `robot`; `render` opens a headless camera.
    pub fn new(robot: Robot, config: &WorldConfig, render: bool) -> Result<Env> {
        config.validate()?;
        let objects = config.objects.objects();
        let mut model = build_model(robot, config.image, &objects)?;
        model.opt_mut().timestep = config.physics_dt;
        let model = Arc::new(model);
        let ids = SceneIds::resolve(&model, robot, &objects)?;
        let camera = if render { Some(Camera::new(&model, ids.camera, config.image, config.visuals)?) } else { None };
        let mut ik = IkSolver::new(model.clone(), ids.clone(), robot.spec().init_qpos);
        let (_, rest_rot) = ik.forward(&robot.spec().init_qpos);
        let mut data = MjData::new(model);
        data.forward();
        Ok(Env {
            robot,
            config: config.clone(),
            data,
            ids,
            ik,
            camera,
            instance: None,
            start_z: 0.0,
            milestones: Milestones::default(),
            q_target: robot.spec().init_qpos,
            gripper: -1.0,
            rest_yaw: yaw_of(&rest_rot),
        })
    }

    /// Pixel (column, row) of world point `p` in this scene's frames.
    pub fn project(&self, p: [f64; 3]) -> [f64; 2] {
        project(&self.data, self.ids.camera, self.config.image, p)
    }

    /// The settings this scene was built with.
    pub fn config(&self) -> &WorldConfig {
        &self.config
    }

    /// The expert's gripper-yaw rule in this scene.
    pub fn gripper_yaw_rule(&self) -> GripperYaw {
        self.config.gripper_yaw(self.robot)
    }

    /// Yaw of the gripper at the robot's rest posture, in the sense of [`downward`].
    pub fn rest_yaw(&self) -> f64 {
        self.rest_yaw
    }

    /// The gripper pointing down at the rest yaw, as the action's (angle / pi, axis): the orientation a
    /// fixed-yaw expert holds.
    pub fn rest_orientation(&self) -> (f64, [f64; 3]) {
        to_angle_axis(&downward(self.rest_yaw))
    }

    /// The robot in this scene.
    pub fn robot(&self) -> Robot {
        self.robot
    }

    /// The task instance of the current episode.
    pub fn instance(&self) -> Option<&Instance> {
        self.instance.as_ref()
    }

    /// Milestones achieved so far in this episode.
    pub fn milestones(&self) -> Milestones {
        self.milestones
    }

    /// Starts an episode: robot at its initial pose with the gripper open, the instance's objects laid out and
    /// settled, the scene's other objects held still at their parking places. An error names an object the
    /// scene was not built with.
    pub fn reset(&mut self, instance: &Instance) -> Result<()> {
        self.ids.assign(&instance.kinds)?;
        self.data.reset();
        self.hold_parked_objects(&instance.kinds);
        let spec = self.robot.spec();
        {
            let qpos = self.data.qpos_mut();
            for (i, &a) in self.ids.arm_qpos.iter().enumerate() {
                qpos[a] = spec.init_qpos[i];
            }
            for (i, &a) in self.ids.finger_qpos.iter().enumerate() {
                qpos[a] = spec.open_ctrl[i];
            }
            for (k, pose) in instance.objects.iter().enumerate() {
                let a = self.ids.object_qpos[k];
                let (s, c) = (pose.yaw / 2.0).sin_cos();
                qpos[a..a + 7].copy_from_slice(&[pose.pos[0], pose.pos[1], pose.pos[2], c, 0.0, 0.0, s]);
            }
        }
        self.q_target = spec.init_qpos;
        self.gripper = -1.0;
        self.data.forward();
        // Let the objects settle under gravity while the arm holds its pose.
        for _ in 0..3 {
            self.run_controller();
        }
        self.instance = Some(instance.clone());
        self.start_z = self.object_pos(instance.task.object)[2];
        self.milestones = Milestones::default();
        self.update_stages();
        Ok(())
    }

    /// Cancels gravity on every object of the scene outside `kinds`, so that it floats where the model parks
    /// it, out of sight and touching nothing (the reset zeroed the forces of the previous layout).
    fn hold_parked_objects(&mut self, kinds: &[Object; NUM_OBJECTS]) {
        let gravity = self.data.model().opt().gravity;
        let parked: Vec<usize> =
            self.ids.objects.iter().filter(|(o, _)| !kinds.contains(o)).map(|(_, [body, _, _])| *body).collect();
        for body in parked {
            let weight = self.data.model().body_subtreemass()[body];
            let force = &mut self.data.xfrc_applied_mut()[body];
            for axis in 0..3 {
                force[axis] = -gravity[axis] * weight;
            }
        }
    }

    /// Applies one action for 1 / policy_hz seconds.
    pub fn step(&mut self, action: &Action) {
        let a = action.clipped();
        let rot = from_angle_axis(a.0[3], [a.0[4], a.0[5], a.0[6]]);
        let q_now = self.arm_q();
        let target = Vector3::from(a.pos());
        let mut sol = self.ik.solve(&q_now, &target, &rot);
        if sol.pos_err > 0.005 || sol.rot_err > 0.05 {
            // Stuck in a local minimum (often at a joint limit): try again from the rest posture.
            let fresh = self.ik.solve(&self.robot.spec().init_qpos, &target, &rot);
            if fresh.pos_err + 0.1 * fresh.rot_err < sol.pos_err + 0.1 * sol.rot_err {
                sol = fresh;
            }
        }
        self.q_target = sol.q;
        self.gripper = a.gripper();
        self.run_controller();
        self.update_stages();
    }

    /// Current observation.
    pub fn observe(&self) -> Observation {
        let site = self.ids.ee_site;
        let eef_pos = self.data.site_xpos()[site];
        let (angle, axis) = to_angle_axis(&mat_from_mj(&self.data.site_xmat()[site]));
        let qvel = self.data.qvel();
        let qpos = self.data.qpos();
        Observation {
            eef_pos,
            eef_rot: [angle, axis[0], axis[1], axis[2]],
            eef_pixel: self.project(eef_pos),
            joint_pos: self.arm_q(),
            joint_vel: self.ids.arm_dof.map(|d| qvel[d]),
            gripper_qpos: self.finger_qpos(),
            object_poses: std::array::from_fn(|k| {
                let a = self.ids.object_qpos[k];
                qpos[a..a + 7].try_into().expect("free joint has 7 coordinates")
            }),
            milestones: self.milestones,
        }
    }

    /// A camera for scenes of this robot and settings: one camera can render every env built alike (their models
    /// share a layout), which saves a renderer per env.
    pub fn new_camera(&self) -> Result<Camera> {
        Camera::new(self.data.model(), self.ids.camera, self.config.image, self.config.visuals)
    }

    /// Renders this scene's frame with `camera` (made by [`Env::new_camera`] of an env built alike).
    pub fn render_with(&mut self, camera: &mut Camera) -> Result<Vec<u8>> {
        camera.render(&mut self.data)
    }

    /// Renders the camera frame (`height * width * 3` RGB bytes); errors if the env was built without one.
    pub fn render(&mut self) -> Result<Vec<u8>> {
        match self.camera.as_mut() {
            Some(cam) => cam.render(&mut self.data),
            None => bail!("this environment was built without a camera"),
        }
    }

    /// End-effector position and rotation matrix.
    pub fn eef_pose(&self) -> (Vector3<f64>, nalgebra::Matrix3<f64>) {
        let site = self.ids.ee_site;
        (Vector3::from(self.data.site_xpos()[site]), mat_from_mj(&self.data.site_xmat()[site]))
    }

    /// The gripper's two finger joint positions.
    pub fn finger_qpos(&self) -> [f64; 2] {
        let qpos = self.data.qpos();
        self.ids.finger_qpos.map(|a| qpos[a])
    }

    /// Position of object `k`.
    pub fn object_pos(&self, k: usize) -> [f64; 3] {
        self.data.xpos()[self.ids.object_body[k]]
    }

    /// Position of `object`, wherever it is (laid out or parked); none if the scene was built without it.
    pub fn position_of(&self, object: Object) -> Option<[f64; 3]> {
        let (_, [body, _, _]) = self.ids.objects.iter().find(|(o, _)| *o == object)?;
        Some(self.data.xpos()[*body])
    }

    /// Yaw of object `k` about the vertical.
    pub fn object_yaw(&self, k: usize) -> f64 {
        let m = self.data.xmat()[self.ids.object_body[k]];
        m[3].atan2(m[0])
    }

    /// Arm joint angles.
    pub fn arm_q(&self) -> [f64; 7] {
        let qpos = self.data.qpos();
        self.ids.arm_qpos.map(|a| qpos[a])
    }

    /// The IK solver of this scene (for tests and tools).
    pub fn ik(&mut self) -> &mut IkSolver {
        &mut self.ik
    }

    /// Physics steps per action.
    pub fn physics_steps_per_action(&self) -> usize {
        self.config.control_substeps * self.config.physics_per_substep()
    }

    /// Advances the physics `n` steps with the controls as they are (the benchmarks' bare loop).
    pub fn step_physics_only(&mut self, n: usize) {
        for _ in 0..n {
            self.data.step();
        }
    }

    /// Runs the joint PD loop with gravity compensation for one action period.
    fn run_controller(&mut self) {
        let spec = self.robot.spec();
        let g = (self.gripper.clamp(-1.0, 1.0) + 1.0) / 2.0;
        let finger: [f64; 2] =
            std::array::from_fn(|i| spec.open_ctrl[i] + g * (spec.closed_ctrl[i] - spec.open_ctrl[i]));
        let kp = self.config.pd_omega.powi(2);
        let kd = 2.0 * self.config.pd_omega;
        let nv = self.data.model().ffi().nv as usize;
        let mut full_m = vec![0.0; nv * nv];
        for _ in 0..self.config.control_substeps {
            let q = self.arm_q();
            let qvel = self.data.qvel();
            let acc: [f64; 7] =
                std::array::from_fn(|i| kp * (self.q_target[i] - q[i]) - kd * qvel[self.ids.arm_dof[i]]);
            self.data.full_m(&mut full_m).expect("inertia buffer has nv*nv entries");
            let m = DMatrix::from_row_slice(nv, nv, &full_m);
            let bias = self.data.qfrc_bias();
            let torque: [f64; 7] = std::array::from_fn(|i| {
                let r = self.ids.arm_dof[i];
                let inertial: f64 = (0..7).map(|j| m[(r, self.ids.arm_dof[j])] * acc[j]).sum();
                inertial + bias[r]
            });
            let ctrl = self.data.ctrl_mut();
            for i in 0..7 {
                ctrl[self.ids.arm_actuator[i]] = torque[i];
            }
            for i in 0..2 {
                ctrl[self.ids.finger_actuator[i]] = finger[i];
            }
            for _ in 0..self.config.physics_per_substep() {
                self.data.step();
            }
        }
    }

    /// The task's object in the gripper's frame (x across the fingers, z along them), metres; none before the
    /// first reset.
    pub fn target_in_gripper(&self) -> Option<[f64; 3]> {
        let task = self.instance.as_ref()?.task;
        let p = Vector3::from(self.object_pos(task.object));
        let (ee, r) = self.eef_pose();
        let local = r.transpose() * (p - ee);
        Some([local[0], local[1], local[2]])
    }

    fn update_stages(&mut self) {
        let (Some(inst), Some(object_in_gripper)) = (&self.instance, self.target_in_gripper()) else { return };
        let task = inst.task;
        let p = self.object_pos(task.object);
        self.milestones.update(&MilestoneInputs {
            object_in_gripper,
            object_z: p[2],
            start_z: self.start_z,
            in_target: in_quadrant(task.target, [p[0], p[1]]),
            in_other_quadrant: (0..NUM_TARGETS).any(|q| q != task.target && in_quadrant(q, [p[0], p[1]])),
        });
    }
}
