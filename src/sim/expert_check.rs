//! The scripted expert's staged success over instances of every task (`expert-check`).
use super::env::{Env, GripperYaw, WorldConfig};
use super::milestones::Milestones;
use super::object::{Object, Split, split_objects};
use super::robot::Robot;
use super::rollout::{run_expert, run_expert_aimed_off};
use super::task::{Instance, NUM_OBJECTS, NUM_TARGETS, NUM_TASKS, Task};
use anyhow::{Result, bail};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

/// Success counts per task, in task order.
pub struct ExpertReport {
    pub robot: Robot,
    pub per_task: Vec<[usize; 3]>,
    pub instances_per_task: usize,
}

impl ExpertReport {
    /// Counts [reached, picked, placed] per object of the base world (its four tasks pooled), in task order.
    pub fn per_base_object(&self) -> [[usize; 3]; NUM_OBJECTS] {
        let mut out = [[0; 3]; NUM_OBJECTS];
        for (t, c) in self.per_task.iter().enumerate() {
            for s in 0..3 {
                out[t / NUM_TARGETS][s] += c[s];
            }
        }
        out
    }

    /// Fraction of all episodes that reached each stage [reached, picked, placed].
    pub fn overall(&self) -> [f64; 3] {
        let n = (self.per_task.len() * self.instances_per_task) as f64;
        std::array::from_fn(|s| self.per_task.iter().map(|t| t[s]).sum::<usize>() as f64 / n)
    }
}

/// Seed of the `i`-th check instance of `task`: mixed so that it does not
/// coincide with the plain small seeds other commands use.
fn check_seed(seed: u64, task: usize, i: usize) -> u64 {
    seed.wrapping_mul(1_000_003) ^ ((task as u64) << 32) ^ (i as u64) ^ 0x00c0_ffee_0000_0000
}

/// How the checked expert aims its grasp.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Aim {
    /// At the object, starting over after a miss (the expert that collects the data).
    Privileged,
    /// This far off the object (metres, across the fingers and sideways along their faces, in the gripper's
    /// frame), once: what a policy's aim error of that size costs (needs the robot's `fixed` yaw rule). It hovers
    /// above its grasp point rather than above the object, so `Off([0.0, 0.0])` is the expert without restarts.
    Off([f64; 2]),
}

/// Runs the expert on `per_task` instances of each of the 16 tasks in `world`, without rendering.
pub fn expert_check(
    robot: Robot,
    world: &WorldConfig,
    per_task: usize,
    seed: u64,
    max_actions: usize,
    aim: Aim,
) -> Result<ExpertReport> {
    check_counts(per_task, max_actions)?;
    check_aim(robot, world, aim)?;
    let mut env = Env::new(robot, world, false)?;
    let mut counts = Vec::with_capacity(NUM_TASKS);
    for t in 0..NUM_TASKS {
        let task = Task::from_id(t)?;
        let instances = (0..per_task).map(|i| Instance::sample(task, check_seed(seed, t, i)));
        counts.push(tally(&mut env, instances, max_actions, aim)?);
    }
    Ok(ExpertReport { robot, per_task: counts, instances_per_task: per_task })
}

/// Refuses a check of no episodes.
fn check_counts(per_task: usize, max_actions: usize) -> Result<()> {
    if per_task == 0 || max_actions == 0 {
        bail!("--per-task ({per_task}) and --max-actions ({max_actions}) must be at least 1");
    }
    Ok(())
}

/// Refuses an aim off the object for a robot whose gripper turns: the aimed-off expert holds the rest yaw, so it
/// would check another expert than the robot's.
fn check_aim(robot: Robot, world: &WorldConfig, aim: Aim) -> Result<()> {
    if matches!(aim, Aim::Off(_)) && world.gripper_yaw(robot) != GripperYaw::Fixed {
        bail!(
            "--aim-offset holds the gripper's rest yaw, and the {robot}'s expert turns its gripper here: add \
             --gripper-yaw fixed"
        );
    }
    Ok(())
}

/// Runs the expert on each of `instances`, counting the episodes that [reached, picked, placed].
fn tally(env: &mut Env, instances: impl Iterator<Item = Instance>, max_actions: usize, aim: Aim) -> Result<[usize; 3]> {
    let mut c = [0usize; 3];
    for instance in instances {
        let episode = match aim {
            Aim::Privileged => run_expert(env, &instance, max_actions, false)?,
            Aim::Off(offset) => run_expert_aimed_off(env, &instance, max_actions, offset)?,
        };
        let Milestones { reached, picked, placed, .. } = episode.milestones;
        for (k, hit) in [reached, picked, placed].into_iter().enumerate() {
            c[k] += hit as usize;
        }
    }
    Ok(c)
}

/// Success counts [reached, picked, placed] of the expert moving each library object, in catalogue order.
pub struct LibraryReport {
    pub robot: Robot,
    pub per_object: Vec<(Object, [usize; 3])>,
    pub instances_per_object: usize,
}

/// The `i`-th check environment of library object `object`: it sits in slot `i % 4` beside three other objects
/// of its own split, and the task is to carry it to quadrant `(i + i / 4) % 4`.
pub fn library_instance(object: Object, i: usize, seed: u64) -> Instance {
    let split = if object.held_out() { Split::HeldOut } else { Split::Train };
    let mut others: Vec<Object> = split_objects(split).into_iter().filter(|o| *o != object).collect();
    let layout_seed = check_seed(seed, 0x100 + object_index(object), i);
    others.shuffle(&mut ChaCha8Rng::seed_from_u64(layout_seed));
    let slot = i % NUM_OBJECTS;
    let mut others = others.into_iter();
    let kinds = std::array::from_fn(|k| if k == slot { object } else { others.next().expect("three others") });
    let task = Task { object: slot, target: (i + i / NUM_OBJECTS) % NUM_TARGETS };
    Instance::sample_with(task, layout_seed, kinds)
}

/// Position of `object` in the library.
fn object_index(object: Object) -> usize {
    Object::library().position(|o| o == object).expect("a library object")
}

/// Runs the expert on `per_object` environments of each of the 30 library objects (`world.objects` must be
/// `library`), without rendering.
pub fn library_check(
    robot: Robot,
    world: &WorldConfig,
    per_object: usize,
    seed: u64,
    max_actions: usize,
    aim: Aim,
) -> Result<LibraryReport> {
    check_counts(per_object, max_actions)?;
    check_aim(robot, world, aim)?;
    let mut env = Env::new(robot, world, false)?;
    let mut per_object_counts = Vec::new();
    for object in Object::library() {
        let instances = (0..per_object).map(|i| library_instance(object, i, seed));
        per_object_counts.push((object, tally(&mut env, instances, max_actions, aim)?));
    }
    Ok(LibraryReport { robot, per_object: per_object_counts, instances_per_object: per_object })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn per_base_object_pools_each_objects_four_target_quadrants() {
        let per_task = (0..NUM_TASKS).map(|t| [t, t % NUM_TARGETS, 1]).collect();
        let report = ExpertReport { robot: Robot::Panda, per_task, instances_per_task: 1 };
        assert_eq!(report.per_base_object(), [[6, 6, 4], [22, 6, 4], [38, 6, 4], [54, 6, 4]]);
    }
}
