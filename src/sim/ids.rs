//! Indices into the compiled scene that control, sensing and success need, resolved once by name.
use super::object::Object;
use super::robot::Robot;
use super::scene::{GRIPPER_PREFIX, ROBOT_PREFIX, object_body_name};
use super::task::NUM_OBJECTS;
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
    /// Body, qpos and dof addresses of the objects in the current layout's slots ([`SceneIds::assign`]).
    pub object_body: [usize; NUM_OBJECTS],
    pub object_qpos: [usize; NUM_OBJECTS],
    pub object_dof: [usize; NUM_OBJECTS],
    /// Every object of the scene with its body, qpos and dof addresses, in the order it was built with.
    pub objects: Vec<(Object, [usize; 3])>,
    pub camera: usize,
}

impl SceneIds {
    /// Looks every element up in `model`, built for `robot` with `objects` (the first four fill the slots).
    pub fn resolve(model: &MjModel, robot: Robot, objects: &[Object]) -> Result<SceneIds> {
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
        let mut resolved = Vec::with_capacity(objects.len());
        for obj in objects {
            let b = id(MjtObjBase::mjOBJ_BODY, &object_body_name(*obj))?;
            let j = model.body_jntadr()[b] as usize;
            resolved.push((*obj, [b, model.jnt_qposadr()[j] as usize, model.jnt_dofadr()[j] as usize]));
        }
        let mut ids = SceneIds {
            arm_joint,
            arm_qpos: arm_joint.map(|j| model.jnt_qposadr()[j] as usize),
            arm_dof: arm_joint.map(|j| model.jnt_dofadr()[j] as usize),
            arm_actuator,
            finger_qpos,
            finger_actuator,
            ee_site: id(MjtObjBase::mjOBJ_SITE, &format!("{ROBOT_PREFIX}{GRIPPER_PREFIX}grip_site"))?,
            object_body: [0; NUM_OBJECTS],
            object_qpos: [0; NUM_OBJECTS],
            object_dof: [0; NUM_OBJECTS],
            objects: resolved,
            camera: id(MjtObjBase::mjOBJ_CAMERA, "frontview")?,
        };
        let first: Vec<Object> = objects.iter().take(NUM_OBJECTS).copied().collect();
        ids.assign(&first.try_into().map_err(|_| anyhow::anyhow!("a scene needs at least four objects"))?)?;
        Ok(ids)
    }

    /// Points the slots at the objects `kinds`; an error names an object the scene was not built with.
    pub fn assign(&mut self, kinds: &[Object; NUM_OBJECTS]) -> Result<()> {
        for (slot, kind) in kinds.iter().enumerate() {
            let [b, q, d] = self
                .objects
                .iter()
                .find(|(o, _)| o == kind)
                .map(|(_, a)| *a)
                .with_context(|| format!("this scene has no object {}", kind.name()))?;
            (self.object_body[slot], self.object_qpos[slot], self.object_dof[slot]) = (b, q, d);
        }
        Ok(())
    }
}
