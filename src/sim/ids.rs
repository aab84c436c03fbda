//! Indices into the compiled scene that control, sensing and success need, resolved once by name.
use super::robot::Robot;
use super::scene::{GRIPPER_PREFIX, ROBOT_PREFIX, object_body_name};
use super::task::{NUM_OBJECTS, Object};
use anyhow::{Context, Result};
use mujoco_rs::prelude::*;

/// Resolved ids and addresses of the robot, its gripper, the objects and the camera.
#[derive(Debug, Clone)]
pub struct SceneIds {
    pub arm_joint: [usize; 7],
    pub arm_qpos: [usize; 7],
    pub arm_dof: [usize; 7],
    pub arm_actuator: [usize; 7],
    pub finger_qpos: [usize; 2],
    pub finger_actuator: [usize; 2],
    /// The gripper's grip site: the end-effector frame (z along the fingers, x across them).
    pub ee_site: usize,
    pub object_body: [usize; NUM_OBJECTS],
    pub object_qpos: [usize; NUM_OBJECTS],
    pub object_dof: [usize; NUM_OBJECTS],
    pub camera: usize,
}

impl SceneIds {
    /// Looks every element up in `model`, built for `robot`.
    pub fn resolve(model: &MjModel, robot: Robot) -> Result<SceneIds> {
        let spec = robot.spec();
        let id = |kind: MjtObjBase, name: &str| {
            model.name_to_id(kind, name).with_context(|| format!("scene has no {kind:?} named {name}"))
        };
        let joint = |name: &str| id(MjtObjBase::mjOBJ_JOINT, &format!("{ROBOT_PREFIX}{name}"));
        let actuator_of = |jnt: usize| {
            model
                .actuator_trnid()
                .iter()
                .position(|t| t[0] as usize == jnt)
                .with_context(|| format!("no actuator drives joint {jnt}"))
        };
        let mut arm_joint = [0; 7];
        let mut arm_actuator = [0; 7];
        for (i, name) in spec.arm_joints.iter().enumerate() {
            arm_joint[i] = joint(name)?;
            arm_actuator[i] = actuator_of(arm_joint[i])?;
        }
        let mut finger_qpos = [0; 2];
        let mut finger_actuator = [0; 2];
        for (i, name) in spec.finger_joints.iter().enumerate() {
            let j = joint(&format!("{GRIPPER_PREFIX}{name}"))?;
            finger_qpos[i] = model.jnt_qposadr()[j] as usize;
            finger_actuator[i] = actuator_of(j)?;
        }
        let mut object_body = [0; NUM_OBJECTS];
        let mut object_qpos = [0; NUM_OBJECTS];
        let mut object_dof = [0; NUM_OBJECTS];
        for (i, obj) in Object::ALL.iter().enumerate() {
            let b = id(MjtObjBase::mjOBJ_BODY, &object_body_name(*obj))?;
            let j = model.body_jntadr()[b] as usize;
            object_body[i] = b;
            object_qpos[i] = model.jnt_qposadr()[j] as usize;
            object_dof[i] = model.jnt_dofadr()[j] as usize;
        }
        Ok(SceneIds {
            arm_joint,
            arm_qpos: arm_joint.map(|j| model.jnt_qposadr()[j] as usize),
            arm_dof: arm_joint.map(|j| model.jnt_dofadr()[j] as usize),
            arm_actuator,
            finger_qpos,
            finger_actuator,
            ee_site: id(MjtObjBase::mjOBJ_SITE, &format!("{ROBOT_PREFIX}{GRIPPER_PREFIX}grip_site"))?,
            object_body,
            object_qpos,
            object_dof,
            camera: id(MjtObjBase::mjOBJ_CAMERA, "frontview")?,
        })
    }
}
