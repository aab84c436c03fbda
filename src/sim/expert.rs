//! Scripted expert with privileged state, timed like the authors' `PickPlaceController` (`expert_pick_place.py`):
//! approach a point 0.2 above the object until within 5 cm of it (or until step 14); 7 steps towards the grasp
//! point; close the gripper; rise back towards the hover point (2 steps); carry to 0.3 above the target quadrant's
//! centre until within reach of it; open. Every position target lies at most 0.15 from the gripper. Departures,
//! both for this world's physics: the authors close the gripper while already rising, which here loses most
//! objects, so the gripper closes in place for 3 steps first (or, with `world.rise_on_grip`, until its fingers
//! have stopped); and they rise towards the point above the object, which here feeds a swing of the arm back into
//! the target, so the gripper rises straight up from where it closed. Unlike the authors', whose failed episodes
//! were discarded and re-run, the expert starts over from the approach when the object is not in the gripper as it
//! carries, so that demonstrations also show recoveries. How the gripper turns about the vertical is a world
//! setting per robot ([`GripperYaw`]).
use super::action::Action;
use super::env::{Env, GripperYaw};
use super::robot::Robot;
use super::rotation::{downward, to_angle_axis};
use super::task::{BIN_FLOOR_TOP, Object, Shape};
use nalgebra::Vector3;
use std::f64::consts::{FRAC_PI_2, PI};

/// Height above the object of the point the gripper approaches first.
const HOVER: f64 = 0.2;
/// Distance to the hover point at which the descent starts (the authors' `g_tol` of a first try).
const APPROACH_TOLERANCE: f64 = 0.05;
/// The descent starts at this step at the latest.
const LAST_APPROACH_STEP: usize = 14;
/// Steps from the start of the descent to closing the gripper (at the latest, with `close_on_arrival`).
const CLOSE_AFTER: usize = 8;
/// Distance to the grasp point at which `close_on_arrival` closes the gripper.
const ARRIVAL_TOLERANCE: f64 = 0.01;
/// Steps from closing the gripper to rising (at the latest, with `rise_on_grip`).
const RISE_AFTER: usize = 3;
/// With `rise_on_grip`, the fewest steps from closing the gripper to rising: a closing step, then a still one.
const RISE_ON_GRIP_AFTER: usize = 2;
/// Steps of rising straight up before the carry.
const RISING_STEPS: usize = 2;
/// With `rise_on_grip`, the fingers have stopped once no finger joint moved more than this in a step (metres).
const FINGERS_STILL: f64 = 0.001;
/// Height of the carry point: 0.3 above the bin floor, kept inside the action's z range.
const CARRY_Z: f64 = 1.1;
/// Largest distance of a position target from the gripper (the authors' `max_step`).
const MAX_DELTA: f64 = 0.15;
/// Lowest height of the grip site, keeping the fingertips off the bin floor.
const MIN_GRASP_Z: f64 = BIN_FLOOR_TOP + 0.022;
/// The object counts as lost from the gripper once it is this far below the grip site.
const LOST_BELOW: f64 = 0.12;
/// Steps over which a turning demonstrator reaches its grasp yaw (the authors slerp over 5 steps).
const TURN_STEPS: usize = 5;
/// Extra turn for the cereal box under the heading rule (the authors': pi/3).
const CEREAL_TURN: f64 = std::f64::consts::FRAC_PI_3;

/// Distance from the carry point within which the gripper opens (the authors': 6 cm for the Panda, 1 cm for the
/// Sawyer).
fn release_distance(robot: Robot) -> f64 {
    match robot {
        Robot::Panda => 0.06,
        Robot::Sawyer => 0.01,
    }
}

/// Where the expert takes the grasp point and the drop point from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Guidance {
    /// The simulator's object position and the target quadrant (privileged state).
    Privileged,
    /// Given positions (metres): where to close the gripper and where to open it, as DAML-Auxiliary executes its
    /// network's predictions (the paper's Sec. 5). Nothing tells this expert that the object slipped, so it never
    /// starts over; it cannot see the object's yaw either, so an `object_yaw` rule holds the rest yaw.
    Given { grasp: [f64; 3], drop: [f64; 3] },
}

impl Guidance {
    /// The privileged expert's grasp and drop points for the episode `env` was just reset to, as given positions,
    /// the grasp point moved so that the task's object lies `offset` (metres: across the fingers, then sideways
    /// along their faces) from the end-effector point in the gripper's frame at reset. An expert that aims off by
    /// a known amount: how much aim error an object tolerates. Like every given guidance it does not start over
    /// after a miss. The offset is taken in the frame of the gripper held at its rest yaw, which is where it
    /// stays under the `fixed` yaw rule only: under another rule the offset lands elsewhere.
    pub fn aimed_off(env: &Env, offset: [f64; 2]) -> Guidance {
        let privileged = Expert::new(env);
        let shift = downward(env.rest_yaw()) * Vector3::new(offset[0], offset[1], 0.0);
        let grasp = privileged.grasp_point(env) - Vector3::new(shift[0], shift[1], 0.0);
        Guidance::Given { grasp: grasp.into(), drop: privileged.drop_point(env).into() }
    }
}

/// The expert's state for one episode.
pub struct Expert {
    guidance: Guidance,
    /// Yaw the gripper starts at (the robot's rest yaw) and the yaw it turns to.
    start_yaw: f64,
    yaw: f64,
    /// Actions taken so far.
    t: usize,
    /// Step at which the descent began.
    descent: Option<usize>,
    /// Step at which the gripper began to close.
    closed_at: Option<usize>,
    /// Close as soon as the grasp point is reached (see [`super::env::WorldConfig::close_on_arrival`]).
    close_on_arrival: bool,
    /// Rise as soon as the fingers have stopped (see [`super::env::WorldConfig::rise_on_grip`]).
    rise_on_grip: bool,
    /// The finger joints when the last action was chosen.
    fingers: Option<[f64; 2]>,
    /// Step at which the gripper began to rise from where it closed.
    rose_at: Option<usize>,
    /// Where the gripper closed.
    grasp: Option<Vector3<f64>>,
    released: bool,
}

impl Expert {
    /// A fresh expert for the episode `env` was just reset to, with privileged state.
    pub fn new(env: &Env) -> Expert {
        Expert::guided(env, Guidance::Privileged)
    }

    /// A fresh expert for the episode `env` was just reset to, taking its positions from `guidance`.
    pub fn guided(env: &Env, guidance: Guidance) -> Expert {
        let instance = env.instance().expect("expert needs a reset environment");
        let (task, obj) = (instance.task, instance.kinds[instance.task.object]);
        let p = match guidance {
            Guidance::Privileged => env.object_pos(task.object),
            Guidance::Given { grasp, .. } => grasp,
        };
        let start_yaw = env.rest_yaw();
        let yaw = match (env.gripper_yaw_rule(), guidance) {
            (GripperYaw::Fixed, _) | (GripperYaw::ObjectYaw, Guidance::Given { .. }) => start_yaw,
            (GripperYaw::ObjectYaw, Guidance::Privileged) => grasp_yaw(obj, env.object_yaw(task.object)),
            (GripperYaw::Heading, _) => {
                let (ee, _) = env.eef_pose();
                let turn = if obj == Object::CEREAL { CEREAL_TURN } else { 0.0 };
                wrap_angle(start_yaw + (p[1] - ee[1]).atan2(p[0] - ee[0]) + turn)
            }
        };
        let (close_on_arrival, rise_on_grip) = (env.config().close_on_arrival, env.config().rise_on_grip);
        Expert {
            guidance,
            start_yaw,
            yaw,
            t: 0,
            descent: None,
            closed_at: None,
            close_on_arrival,
            rise_on_grip,
            fingers: None,
            rose_at: None,
            grasp: None,
            released: false,
        }
    }

    /// Where the gripper closes: above the object's centre by its grasp offset (guided: the given point), kept
    /// off the bin floor.
    fn grasp_point(&self, env: &Env) -> Vector3<f64> {
        let p = match self.guidance {
            Guidance::Privileged => {
                let instance = env.instance().expect("expert needs a reset environment");
                let obj = Vector3::from(env.object_pos(instance.task.object));
                obj + Vector3::new(0.0, 0.0, grasp_offset(instance.kinds[instance.task.object]))
            }
            Guidance::Given { grasp, .. } => Vector3::from(grasp),
        };
        Vector3::new(p[0], p[1], p[2].max(MIN_GRASP_Z))
    }

    /// Where the gripper carries the object and opens: above the target quadrant's centre (guided: the given
    /// point).
    fn drop_point(&self, env: &Env) -> Vector3<f64> {
        match self.guidance {
            Guidance::Privileged => {
                let c = env.instance().expect("expert needs a reset environment").task.target_centre();
                Vector3::new(c[0], c[1], CARRY_Z)
            }
            Guidance::Given { drop, .. } => Vector3::from(drop),
        }
    }

    /// Whether the expert has opened the gripper above the target and is only holding still.
    pub fn done(&self) -> bool {
        self.released
    }

    /// The next action.
    pub fn act(&mut self, env: &Env) -> Action {
        let task = env.instance().expect("expert needs a reset environment").task;
        let obj = Vector3::from(env.object_pos(task.object));
        let (ee, _) = env.eef_pose();
        let t = self.t;
        self.t += 1;
        let grasp_point = self.grasp_point(env);
        let hover = match self.guidance {
            Guidance::Privileged => obj + Vector3::new(0.0, 0.0, HOVER),
            Guidance::Given { .. } => grasp_point + Vector3::new(0.0, 0.0, HOVER),
        };
        let carry = self.drop_point(env);
        let privileged = self.guidance == Guidance::Privileged;
        if let (Some(s), None) = (self.descent, self.closed_at) {
            let arrived = self.close_on_arrival && (grasp_point - ee).norm() < ARRIVAL_TOLERANCE;
            if arrived || t >= s + CLOSE_AFTER {
                self.closed_at = Some(t);
            }
        }
        let fingers = env.finger_qpos();
        let moved = self.fingers.map(|f| (0..2).map(|i| (fingers[i] - f[i]).abs()).fold(0.0, f64::max));
        self.fingers = Some(fingers);
        if let (Some(c), None) = (self.closed_at, self.rose_at) {
            let gripped = self.rise_on_grip && t >= c + RISE_ON_GRIP_AFTER && moved.is_some_and(|m| m < FINGERS_STILL);
            if gripped || t >= c + RISE_AFTER {
                self.rose_at = Some(t);
            }
        }
        let (target, gripper) = match (self.descent, self.closed_at) {
            (None, _) => {
                if (hover - ee).norm() < APPROACH_TOLERANCE || t >= LAST_APPROACH_STEP {
                    self.descent = Some(t);
                }
                (hover, -1.0)
            }
            (Some(_), None) => (grasp_point, -1.0),
            (_, Some(_)) if self.rose_at.is_none() => (*self.grasp.get_or_insert(ee), 1.0),
            (_, Some(_)) if self.rose_at.is_some_and(|r| t < r + RISING_STEPS) => {
                let g = self.grasp.unwrap_or(ee);
                (Vector3::new(g[0], g[1], g[2] + HOVER), 1.0)
            }
            _ if privileged && !self.released && ee[2] - obj[2] > LOST_BELOW => {
                // The grasp failed or the object slipped out: start over from above it.
                (self.t, self.descent, self.closed_at, self.grasp, self.rose_at) = (1, None, None, None, None);
                (hover, -1.0)
            }
            _ if !self.released && (carry - ee).norm() > release_distance(env.robot()) => (carry, 1.0),
            _ => {
                self.released = true;
                (ee, -1.0)
            }
        };
        let step = target - ee;
        let clipped = if step.norm() > MAX_DELTA { ee + step * (MAX_DELTA / step.norm()) } else { target };
        let turned = (self.t as f64 / TURN_STEPS as f64).min(1.0);
        let yaw = self.start_yaw + turned * wrap_angle(self.yaw - self.start_yaw);
        let (angle, axis) = to_angle_axis(&downward(yaw));
        Action::new([clipped[0], clipped[1], clipped[2]], angle, axis, gripper).clipped()
    }
}

/// `a` wrapped into (-pi, pi].
fn wrap_angle(a: f64) -> f64 {
    let w = a.rem_euclid(2.0 * PI);
    if w > PI { w - 2.0 * PI } else { w }
}

/// Height of the grasp point relative to the object's centre.
fn grasp_offset(obj: Object) -> f64 {
    match obj.shape() {
        // Round shapes narrow above their middle: closed on their widest section.
        Shape::Sphere(_) | Shape::Ellipsoid(_) => 0.0,
        shape => (shape.half_extents()[2] - 0.025).max(0.0),
    }
}

/// Gripper yaw that closes the fingers (the gripper's x axis) across the object's narrow side (its y axis),
/// chosen in (-pi/2, pi/2] to keep the wrist near its rest pose.
fn grasp_yaw(obj: Object, object_yaw: f64) -> f64 {
    let period = match obj.shape() {
        Shape::Cylinder { .. } | Shape::Sphere(_) => return 0.0,
        Shape::Box([x, y, _]) if (x - y).abs() < 1e-9 => FRAC_PI_2,
        Shape::Box(_) | Shape::Ellipsoid(_) => PI,
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
            let g = grasp_yaw(Object::BREAD, yaw);
            assert!(g > -FRAC_PI_2 - 1e-9 && g <= FRAC_PI_2 + 1e-9);
            let closing = downward(g) * Vector3::x();
            let narrow = Vector3::new(-yaw.sin(), yaw.cos(), 0.0);
            assert!((closing.dot(&narrow).abs() - 1.0).abs() < 1e-9, "yaw {yaw}");
        }
        assert_eq!(grasp_yaw(Object::CAN, 1.0), 0.0);
        assert!(grasp_yaw(Object::MILK, 1.0).abs() <= PI / 4.0 + 1e-9);
    }
}
