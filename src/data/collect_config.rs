//! What a collection is: the robot, trajectories per task, the world, and how layouts are drawn (the `[collect]`
//! section of an experiment file); the seeds of every slot's layout, and in the multi-object world the
//! environment (four library objects) each slot belongs to.
use crate::seeds::derive_seed;
use crate::sim::env::{ObjectSet, WorldConfig};
use crate::sim::object::{Object, Split};
use crate::sim::robot::Robot;
use crate::sim::task::{Instance, NUM_OBJECTS, NUM_TASKS, Task};
use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};

/// Whether a collection's layouts recur under several tasks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum LayoutSharing {
    /// Each slot draws an environment from a pool with replacement; the layout depends on the environment and
    /// the robot only, so about half the layouts recur under two or more tasks (the authors'
    /// `collect_demonstrations.py`).
    Shared,
    /// Every slot has a layout of its own, derived from its task and slot.
    Unique,
}

/// How trajectories are collected: the `[collect]` section of an experiment file (the robot and the trajectories
/// per task come from the grid).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct CollectSettings {
    /// Root seed; instance seeds derive from it, the robot, the task and the slot.
    pub seed: u64,
    /// Whether layouts recur under several tasks (`shared`, the authors': each slot draws its environment from a
    /// pool with replacement) or each slot has its own (`unique`).
    pub layouts: LayoutSharing,
    /// Size of the environment pool of `layouts = "shared"` (none: half the collection's trajectories, the
    /// authors' `--n_env 800` for N = 1600).
    pub layout_pool: Option<usize>,
    /// Task ids (0..16).
    pub tasks: Vec<usize>,
    /// Action budget of one expert episode.
    pub max_actions: usize,
    /// Expert attempts (each on a fresh layout) before a trajectory slot fails the collection.
    pub max_attempts: usize,
    /// JPEG quality of stored frames (1..=100).
    pub jpeg_quality: u8,
    /// Standard deviation (m) of noise added to the executed position targets, the recorded actions staying the
    /// expert's (0: the authors' noise-free data).
    pub action_noise: f64,
    /// In the multi-object world (`world.objects = "library"`): trajectories of each task per environment. Slot
    /// `i` of every task lies in environment `i / environment_instances`, whose four training objects and
    /// layouts all sixteen tasks share (the authors' `--per_task_group 2 --give_env_seed`: 2,400 instances of
    /// 1,200 tasks in 75 environments at 150 per task).
    pub environment_instances: usize,
}

impl Default for CollectSettings {
    fn default() -> Self {
        CollectSettings {
            seed: 0,
            layouts: LayoutSharing::Shared,
            layout_pool: None,
            tasks: (0..NUM_TASKS).collect(),
            max_actions: 100,
            max_attempts: 10,
            jpeg_quality: 90,
            action_noise: 0.0,
            environment_instances: 2,
        }
    }
}

impl CollectSettings {
    /// Checks ranges; errors name the key.
    pub fn validate(&self) -> Result<()> {
        if self.tasks.is_empty() {
            bail!("collect.tasks is empty");
        }
        for (i, &t) in self.tasks.iter().enumerate() {
            Task::from_id(t).with_context(|| format!("collect.tasks contains {t}"))?;
            if self.tasks[..i].contains(&t) {
                bail!("collect.tasks lists task {t} twice");
            }
        }
        if self.max_actions == 0 || self.max_attempts == 0 {
            bail!("collect.max_actions and collect.max_attempts must be at least 1");
        }
        if !(0.0..=0.1).contains(&self.action_noise) {
            bail!("collect.action_noise = {} out of range [0, 0.1] (metres)", self.action_noise);
        }
        if self.layout_pool == Some(0) {
            bail!("collect.layout_pool = 0: the pool needs at least one environment");
        }
        if self.layout_pool.is_some() && self.layouts == LayoutSharing::Unique {
            bail!("collect.layout_pool is set but collect.layouts = \"unique\" draws no pool");
        }
        if self.environment_instances == 0 {
            bail!("collect.environment_instances = 0: an environment needs at least one trajectory per task");
        }
        if !(1..=100).contains(&self.jpeg_quality) {
            bail!("collect.jpeg_quality = {} out of range 1..=100", self.jpeg_quality);
        }
        Ok(())
    }
}

/// Refuses the layout keys that do not apply in the multi-object world, whose layouts follow its environments.
pub fn check_layouts_in(world: &WorldConfig, settings: &CollectSettings) -> Result<()> {
    let pooled = settings.layouts == LayoutSharing::Unique || settings.layout_pool.is_some();
    if world.objects == ObjectSet::Library && pooled {
        bail!(
            "collect.layouts and collect.layout_pool do not apply with world.objects = \"library\": its layouts \
             follow its environments (collect.environment_instances)"
        );
    }
    Ok(())
}

/// One collection: `per_task` trajectories of each task by `robot` in `world`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CollectConfig {
    pub robot: Robot,
    /// Trajectories per task.
    pub per_task: usize,
    pub world: WorldConfig,
    pub settings: CollectSettings,
}

impl CollectConfig {
    /// The defaults of the paper's code for `robot`: all tasks, 100 per task, the default world.
    pub fn paper(robot: Robot) -> CollectConfig {
        CollectConfig { robot, per_task: 100, world: WorldConfig::default(), settings: CollectSettings::default() }
    }

    /// Checks ranges; errors name the key.
    pub fn validate(&self) -> Result<()> {
        self.world.validate()?;
        if self.per_task == 0 {
            bail!("collect.per_task must be at least 1");
        }
        check_layouts_in(&self.world, &self.settings)?;
        self.settings.validate()
    }

    /// Whether the collection lies in the multi-object world (environments of library objects).
    pub fn library(&self) -> bool {
        self.world.objects == ObjectSet::Library
    }

    /// Number of environments the slots draw from: the pool of shared layouts, or in the multi-object world the
    /// environments the slots are grouped into (none when every slot has its own layout).
    pub fn pool_size(&self) -> Option<usize> {
        if self.library() {
            return Some(self.per_task.div_ceil(self.settings.environment_instances));
        }
        match self.settings.layouts {
            LayoutSharing::Unique => None,
            LayoutSharing::Shared => Some(
                self.settings.layout_pool.unwrap_or_else(|| (self.per_task * self.settings.tasks.len() / 2).max(1)),
            ),
        }
    }

    /// The environment of slot `index` of `task` (the same for both robots, so a demonstration and the agent
    /// trajectory of its slot fall in the same split): drawn from the pool when layouts are shared, or in the
    /// multi-object world the slot's group, `index / environment_instances`, whatever the task.
    pub fn environment(&self, task: usize, index: usize) -> Option<u64> {
        if self.library() {
            return Some((index / self.settings.environment_instances) as u64);
        }
        let pool = self.pool_size()? as u64;
        Some(derive_seed("layout-pool", &[self.settings.seed, task as u64, index as u64]) % pool)
    }

    /// The four objects, by slot, of `environment` (the base world's four outside the multi-object world): the
    /// same for both robots, drawn from the library's training objects only.
    pub fn objects(&self, environment: Option<u64>) -> [Object; NUM_OBJECTS] {
        let seed = derive_seed("library-environment", &[self.settings.seed, environment.unwrap_or(0)]);
        self.world.objects.environment(Split::Train, seed)
    }

    /// Seed of the layout of `attempt` for slot `index` of `task`. With shared layouts the first attempt's layout
    /// depends on the slot's environment and the robot only; in the multi-object world, on the environment, the
    /// slot's place in it and the robot, so that all sixteen tasks of an environment share its layouts (the
    /// authors'). A retry draws a layout of the slot's own (the authors change the layout after failed tries too).
    pub fn instance_seed(&self, task: usize, index: usize, attempt: usize) -> u64 {
        let (seed, robot) = (self.settings.seed, self.robot as u64);
        match self.environment(task, index) {
            Some(env) if attempt == 0 && self.library() => {
                let place = (index % self.settings.environment_instances) as u64;
                derive_seed("collect-library", &[seed, robot, env, place])
            }
            Some(env) if attempt == 0 => derive_seed("collect-env", &[seed, robot, env]),
            _ => derive_seed("collect", &[seed, robot, task as u64, index as u64, attempt as u64]),
        }
    }

    /// The instance of `attempt` for slot `index` of `task`: its layout of its environment's objects.
    pub fn instance(&self, task: usize, index: usize, attempt: usize) -> Result<Instance> {
        let objects = self.objects(self.environment(task, index));
        Ok(Instance::sample_with(Task::from_id(task)?, self.instance_seed(task, index, attempt), objects))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::{HashMap, HashSet};

    /// First-attempt layout seeds of every slot of `config`, with the tasks each recurs under.
    fn layouts(config: &CollectConfig) -> HashMap<u64, HashSet<usize>> {
        let mut tasks: HashMap<u64, HashSet<usize>> = HashMap::new();
        for &task in &config.settings.tasks {
            for index in 0..config.per_task {
                tasks.entry(config.instance_seed(task, index, 0)).or_default().insert(task);
            }
        }
        tasks
    }

    #[test]
    fn shared_layouts_recur_under_several_tasks() {
        // The authors' N = 1600 from a pool of 800 environments, drawn with replacement.
        let config = CollectConfig::paper(Robot::Panda);
        assert_eq!(config.pool_size(), Some(800));
        let shared = layouts(&config);
        let recurring = shared.values().filter(|t| t.len() >= 2).count();
        // 800 (1 - e^-2) = 692 distinct environments expected.
        assert!(shared.len() > 650 && shared.len() < 740, "{} distinct layouts", shared.len());
        assert!(recurring > 300, "{recurring} layouts under two or more tasks");
        // Both robots draw the same environment per slot, each with a layout of its own.
        let demos = CollectConfig::paper(Robot::Sawyer);
        assert_eq!(demos.environment(5, 17), config.environment(5, 17));
        assert_ne!(demos.instance_seed(5, 17, 0), config.instance_seed(5, 17, 0));
        // A retry leaves the pool.
        assert!(!shared.contains_key(&config.instance_seed(5, 17, 1)));

        let unique = CollectConfig {
            settings: CollectSettings { layouts: LayoutSharing::Unique, ..CollectSettings::default() },
            ..config
        };
        assert_eq!(unique.pool_size(), None);
        assert!(layouts(&unique).values().all(|t| t.len() == 1));
        assert_eq!(layouts(&unique).len(), 1600);
    }

    #[test]
    fn library_slots_group_into_environments_of_training_objects_shared_by_both_robots_and_all_tasks() {
        use crate::sim::env::ObjectSet;
        let library = |robot| {
            let mut c = CollectConfig::paper(robot);
            c.world.objects = ObjectSet::Library;
            c.per_task = 150;
            c
        };
        let (panda, sawyer) = (library(Robot::Panda), library(Robot::Sawyer));
        panda.validate().unwrap();
        // The authors' multi-object data: 2,400 instances of 1,200 tasks in 75 environments.
        assert_eq!(panda.pool_size(), Some(75));
        let mut environments = HashSet::new();
        for index in 0..panda.per_task {
            let env = panda.environment(0, index).unwrap();
            assert_eq!(env, (index / 2) as u64);
            let objects = panda.objects(Some(env));
            assert!(objects.iter().all(|o| !o.held_out()), "environment {env} holds {objects:?}");
            environments.insert(objects);
            for task in 0..NUM_TASKS {
                // Every task of the environment: the same objects for both robots and the same layout per robot.
                assert_eq!(panda.environment(task, index), Some(env));
                assert_eq!(sawyer.instance(task, index, 0).unwrap().kinds, objects);
                assert_eq!(panda.instance_seed(task, index, 0), panda.instance_seed(0, index, 0));
            }
            assert_ne!(panda.instance_seed(0, index, 0), sawyer.instance_seed(0, index, 0));
        }
        assert!(environments.len() > 70, "{} distinct object sets in 75 environments", environments.len());
        assert_ne!(panda.instance_seed(0, 0, 0), panda.instance_seed(0, 1, 0), "two instances per environment");
        assert_eq!(CollectConfig::paper(Robot::Panda).objects(Some(3)), crate::sim::object::Object::ALL);

        let mut unique = library(Robot::Panda);
        unique.settings.layouts = LayoutSharing::Unique;
        assert!(unique.validate().unwrap_err().to_string().contains("collect.layouts"));
        unique.settings = CollectSettings { environment_instances: 0, ..CollectSettings::default() };
        assert!(unique.validate().unwrap_err().to_string().contains("collect.environment_instances = 0"));
    }

    #[test]
    fn a_pool_setting_without_a_pool_is_refused_by_name() {
        let mut settings =
            CollectSettings { layouts: LayoutSharing::Unique, layout_pool: Some(10), ..Default::default() };
        assert!(settings.validate().unwrap_err().to_string().contains("collect.layout_pool"));
        settings.layouts = LayoutSharing::Shared;
        settings.layout_pool = Some(0);
        assert!(settings.validate().unwrap_err().to_string().contains("collect.layout_pool = 0"));
    }
}
