//! Tasks (object x target quadrant) and their random instances.
use anyhow::{Result, bail};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

pub use super::object::{Object, Shape};

/// Number of objects in the source bin.
pub const NUM_OBJECTS: usize = 4;
/// Number of target quadrants in the target bin.
pub const NUM_TARGETS: usize = 4;
/// Number of tasks: every object to every quadrant.
pub const NUM_TASKS: usize = NUM_OBJECTS * NUM_TARGETS;

/// Centre of the source bin's floor (world frame).
pub const SOURCE_BIN: [f64; 3] = [0.6, -0.15, 0.8];
/// Centre of the target bin's floor (world frame).
pub const TARGET_BIN: [f64; 3] = [0.6, 0.38, 0.8];
/// Full size (x, y) of one target quadrant.
pub const QUADRANT_SIZE: [f64; 2] = [0.195, 0.245];
/// Height of the bins' floor top surface.
pub const BIN_FLOOR_TOP: f64 = 0.82;

/// One of the 16 tasks: carry `object` into target quadrant `target`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Task {
    pub object: usize,
    pub target: usize,
}

impl Task {
    /// Task from its id in 0..16 (object = id / 4, target = id % 4, as in the paper's code).
    pub fn from_id(id: usize) -> Result<Task> {
        if id >= NUM_TASKS {
            bail!("task id {id} out of range: tasks are 0..{}", NUM_TASKS - 1);
        }
        Ok(Task { object: id / NUM_TARGETS, target: id % NUM_TARGETS })
    }

    /// Task id in 0..16.
    pub fn id(self) -> usize {
        self.object * NUM_TARGETS + self.target
    }

    /// Centre (x, y) of the target quadrant: 0 near-right, 1 near-left, 2 far-right, 3 far-left
    /// as seen from the robot (near = smaller x, right = smaller y).
    pub fn target_centre(self) -> [f64; 2] {
        quadrant_centre(self.target)
    }
}

/// Centre (x, y) of target quadrant `q`.
pub fn quadrant_centre(q: usize) -> [f64; 2] {
    let dx = if q / 2 == 0 { -0.5 } else { 0.5 } * QUADRANT_SIZE[0];
    let dy = if q.is_multiple_of(2) { -0.5 } else { 0.5 } * QUADRANT_SIZE[1];
    [TARGET_BIN[0] + dx, TARGET_BIN[1] + dy]
}

/// Whether (x, y) lies inside target quadrant `q`.
pub fn in_quadrant(q: usize, xy: [f64; 2]) -> bool {
    let c = quadrant_centre(q);
    (xy[0] - c[0]).abs() < QUADRANT_SIZE[0] / 2.0 && (xy[1] - c[1]).abs() < QUADRANT_SIZE[1] / 2.0
}

/// Starting pose of one object: position and yaw.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ObjectPose {
    pub pos: [f64; 3],
    pub yaw: f64,
}

/// A task instance: a task plus a random layout of the environment's four objects in the source bin.
#[derive(Debug, Clone, PartialEq)]
pub struct Instance {
    pub task: Task,
    pub seed: u64,
    /// The environment's objects, by slot (the base world's: milk, bread, cereal, can).
    pub kinds: [Object; NUM_OBJECTS],
    pub objects: [ObjectPose; NUM_OBJECTS],
}

/// Half extent (x, y) of the region of the source bin that object centres are drawn from.
const PLACEMENT_HALF: [f64; 2] = [0.13, 0.17];
/// Extra gap kept between object footprints.
const CLEARANCE: f64 = 0.025;

impl Instance {
    /// Samples a layout of the base world's objects by rejection: objects inside the source bin, apart by a
    /// clearance margin, yaw uniform in [0, pi/4] or [3pi/4, 2pi] (the paper's code). Same seed, same layout.
    pub fn sample(task: Task, seed: u64) -> Instance {
        Instance::sample_with(task, seed, Object::ALL)
    }

    /// Samples a layout of the objects `kinds` (by slot) as [`Instance::sample`] does.
    pub fn sample_with(task: Task, seed: u64, kinds: [Object; NUM_OBJECTS]) -> Instance {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut placed: Vec<ObjectPose> = Vec::with_capacity(NUM_OBJECTS);
        for obj in kinds {
            let pose = loop {
                let x = SOURCE_BIN[0] + rng.random_range(-PLACEMENT_HALF[0]..PLACEMENT_HALF[0]);
                let y = SOURCE_BIN[1] + rng.random_range(-PLACEMENT_HALF[1]..PLACEMENT_HALF[1]);
                let free = placed.iter().zip(kinds).all(|(p, other)| {
                    let d = (p.pos[0] - x).hypot(p.pos[1] - y);
                    d > obj.footprint_radius() + other.footprint_radius() + CLEARANCE
                });
                if free {
                    // [0, pi/4] has length pi/4, [3pi/4, 2pi] has length 5pi/4: draw over their union.
                    let u = rng.random_range(0.0..1.5 * PI);
                    let yaw = if u < PI / 4.0 { u } else { u + PI / 2.0 };
                    break ObjectPose { pos: [x, y, BIN_FLOOR_TOP + obj.half_height()], yaw };
                }
            };
            placed.push(pose);
        }
        Instance { task, seed, kinds, objects: placed.try_into().expect("four objects") }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn task_ids_round_trip_and_reject_out_of_range() {
        for id in 0..NUM_TASKS {
            assert_eq!(Task::from_id(id).unwrap().id(), id);
        }
        assert_eq!(Task::from_id(6).unwrap(), Task { object: 1, target: 2 });
        let err = Task::from_id(16).unwrap_err().to_string();
        assert!(err.contains("16"), "{err}");
    }

    #[test]
    fn quadrants_tile_the_target_bin() {
        for q in 0..NUM_TARGETS {
            assert!(in_quadrant(q, quadrant_centre(q)));
            for other in (0..NUM_TARGETS).filter(|&o| o != q) {
                assert!(!in_quadrant(other, quadrant_centre(q)));
            }
        }
    }

    #[test]
    fn layouts_are_seeded_separated_and_inside_the_bin() {
        let task = Task::from_id(5).unwrap();
        assert_eq!(Instance::sample(task, 7), Instance::sample(task, 7));
        assert_ne!(Instance::sample(task, 7), Instance::sample(task, 8));
        for seed in 0..200 {
            let inst = Instance::sample(task, seed);
            for (i, a) in inst.objects.iter().enumerate() {
                assert!((a.pos[0] - SOURCE_BIN[0]).abs() <= PLACEMENT_HALF[0]);
                assert!((a.pos[1] - SOURCE_BIN[1]).abs() <= PLACEMENT_HALF[1]);
                let yaw_ok = (0.0..=PI / 4.0).contains(&a.yaw) || (0.75 * PI..=2.0 * PI).contains(&a.yaw);
                assert!(yaw_ok, "yaw {}", a.yaw);
                for b in &inst.objects[i + 1..] {
                    assert!((a.pos[0] - b.pos[0]).hypot(a.pos[1] - b.pos[1]) > 0.05);
                }
            }
        }
    }
}
