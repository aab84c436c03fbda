//! Scripted expert with privileged state (design.md): hover above the object with the gripper open,
//! descend, close and lift, carry above the target quadrant, open. Re-tries a grasp that failed.
use super::action::Action;
use super::env::Env;
use super::rotation::{downward, to_angle_axis};
use super::task::{BIN_FLOOR_TOP, Object, Shape};
use nalgebra::Vector3;
use std::f64::consts::{FRAC_PI_2, PI};

/// Height above the object at which the gripper hovers before descending.
const HOVER: f64 = 0.2;
/// Number of policy steps of the descent.
const DESCEND_STEPS: usize = 8;
/// Steps spent closing and opening the gripper.
const GRIP_STEPS: usize = 4;
/// Height the object is lifted to before carrying.
const LIFT_Z: f64 = 1.05;
/// Carry height above the target bin (bin floor + 0.3, design.md).
const CARRY_Z: f64 = 1.1;
/// Largest change of the position target per step (design.md).
const MAX_DELTA: f64 = 0.15;
/// Lowest height of the grip site, keeping the fingertips off the bin floor.
const MIN_GRASP_Z: f64 = BIN_FLOOR_TOP + 0.022;

#[derive(Debug, Clone, Copy, PartialEq)]
enum Phase {
    Approach,
    Descend(usize),
    Grasp(usize),
    Lift,
    Carry,
    Release(usize),
    Done,
}

/// The expert's state for one episode.
pub struct Expert {
    phase: Phase,
    yaw: f64,
    hover_z: f64,
    grasp_z: f64,
}

impl Expert {
    /// A fresh expert for the episode `env` was just reset to.
    pub fn new(env: &Env) -> Expert {
        let task = env.instance().expect("expert needs a reset environment").task;
        let obj = task.object_kind();
        let p = env.object_pos(task.object);
        let grasp_z = (p[2] + grasp_offset(obj)).max(MIN_GRASP_Z);
        Expert {
            phase: Phase::Approach,
            yaw: grasp_yaw(obj, env.object_yaw(task.object)),
            hover_z: p[2] + HOVER,
            grasp_z,
        }
    }

    /// Whether the expert has released the object and is only holding still.
    pub fn done(&self) -> bool {
        self.phase == Phase::Done
    }

    /// The next action.
    pub fn act(&mut self, env: &Env) -> Action {
        let task = env.instance().expect("expert needs a reset environment").task;
        let obj = Vector3::from(env.object_pos(task.object));
        let (ee, _) = env.eef_pose();
        let (target, gripper) = match self.phase {
            Phase::Approach => {
                let goal = Vector3::new(obj[0], obj[1], self.hover_z);
                if (ee.xy() - goal.xy()).norm() < 0.01 && (ee[2] - goal[2]).abs() < 0.03 {
                    self.phase = Phase::Descend(0);
                }
                (goal, -1.0)
            }
            Phase::Descend(k) => {
                let f = ((k + 1) as f64 / DESCEND_STEPS as f64).min(1.0);
                let z = self.hover_z + f * (self.grasp_z - self.hover_z);
                let settled = k + 1 >= DESCEND_STEPS && (ee[2] - self.grasp_z).abs() < 0.01;
                self.phase = if settled || k > DESCEND_STEPS + 6 { Phase::Grasp(0) } else { Phase::Descend(k + 1) };
                (Vector3::new(obj[0], obj[1], z), -1.0)
            }
            Phase::Grasp(k) => {
                self.phase = if k + 1 >= GRIP_STEPS { Phase::Lift } else { Phase::Grasp(k + 1) };
                (Vector3::new(ee[0], ee[1], self.grasp_z), 1.0)
            }
            Phase::Lift => {
                if obj[2] < self.grasp_z - 0.05 + (ee[2] - self.grasp_z).max(0.0) && ee[2] > self.grasp_z + 0.08 {
                    // The object stayed behind: start over from above it.
                    self.restart(env);
                    (Vector3::new(ee[0], ee[1], LIFT_Z), -1.0)
                } else {
                    if ee[2] > LIFT_Z - 0.03 {
                        self.phase = Phase::Carry;
                    }
                    (Vector3::new(ee[0], ee[1], LIFT_Z), 1.0)
                }
            }
            Phase::Carry => {
                let c = task.target_centre();
                let goal = Vector3::new(c[0], c[1], CARRY_Z);
                if (ee.xy() - goal.xy()).norm() < 0.02 {
                    self.phase = Phase::Release(0);
                }
                if ee[2] - obj[2] > 0.12 {
                    self.restart(env);
                }
                (goal, 1.0)
            }
            Phase::Release(k) => {
                self.phase = if k + 1 >= GRIP_STEPS { Phase::Done } else { Phase::Release(k + 1) };
                (ee, -1.0)
            }
            Phase::Done => (ee, -1.0),
        };
        let step = target - ee;
        let clipped = if step.norm() > MAX_DELTA { ee + step * (MAX_DELTA / step.norm()) } else { target };
        let (angle, axis) = to_angle_axis(&downward(self.yaw));
        Action::new([clipped[0], clipped[1], clipped[2]], angle, axis, gripper).clipped()
    }

    fn restart(&mut self, env: &Env) {
        let task = env.instance().expect("reset environment").task;
        let p = env.object_pos(task.object);
        self.yaw = grasp_yaw(task.object_kind(), env.object_yaw(task.object));
        self.hover_z = p[2] + HOVER;
        self.grasp_z = (p[2] + grasp_offset(task.object_kind())).max(MIN_GRASP_Z);
        self.phase = Phase::Approach;
    }
}

/// Height of the grasp point relative to the object's centre.
fn grasp_offset(obj: Object) -> f64 {
    match obj.shape() {
        Shape::Box([_, _, h]) => (h - 0.025).max(0.0),
        Shape::Cylinder { half_height, .. } => (half_height - 0.025).max(0.0),
    }
}

/// Gripper yaw that closes the fingers (the gripper's x axis) across the object's narrow side (its y axis),
/// chosen in (-pi/2, pi/2] to keep the wrist near its rest pose.
fn grasp_yaw(obj: Object, object_yaw: f64) -> f64 {
    let period = match obj.shape() {
        Shape::Cylinder { .. } => return 0.0,
        Shape::Box([x, y, _]) if (x - y).abs() < 1e-9 => FRAC_PI_2,
        Shape::Box(_) => PI,
    };
    // downward(yaw) maps the gripper x axis to (-cos yaw, -sin yaw, 0): align with the object's y axis.
    let mut yaw = object_yaw + FRAC_PI_2;
    yaw = yaw.rem_euclid(period);
    if yaw > period / 2.0 {
        yaw -= period;
    }
    yaw
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grasp_yaw_closes_across_the_narrow_side() {
        for yaw in [0.0, 0.3, 2.5, 4.0, 6.0] {
            let g = grasp_yaw(Object::Bread, yaw);
            assert!(g > -FRAC_PI_2 - 1e-9 && g <= FRAC_PI_2 + 1e-9);
            let closing = downward(g) * Vector3::x();
            let narrow = Vector3::new(-yaw.sin(), yaw.cos(), 0.0);
            assert!((closing.dot(&narrow).abs() - 1.0).abs() < 1e-9, "yaw {yaw}");
        }
        assert_eq!(grasp_yaw(Object::Can, 1.0), 0.0);
        assert!(grasp_yaw(Object::Milk, 1.0).abs() <= PI / 4.0 + 1e-9);
    }
}
