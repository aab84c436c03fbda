//! Simulation workers for lockstep evaluation: each thread owns its MuJoCo scenes and renderers, makes the
//! demonstrator videos, and steps its agent scenes with actions chosen centrally (a network, batched) or
//! locally (the scripted expert, the random policy).
use super::actor::Actor;
use crate::seeds::derive_seed;
use crate::sim::action::{ACTION_DIM, Action};
use crate::sim::camera::Camera;
use crate::sim::env::{Env, Observation, STATE_DIM, WorldConfig};
use crate::sim::expert::{Expert, Guidance};
use crate::sim::milestones::Milestones;
use crate::sim::object::Object;
use crate::sim::robot::Robot;
use crate::sim::rollout::run_expert;
use crate::sim::task::{Instance, NUM_OBJECTS, Task};
use anyhow::{Context, Result, bail};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::sync::mpsc::{Receiver, Sender, channel};
use std::thread::JoinHandle;

/// Who chooses the agent's actions: the network (centrally: actions arrive with each step command) or a
/// reference policy inside the worker.
pub type Chooser = Actor<()>;

/// One evaluation episode: a task, the agent's layout and the demonstrator's layout of the environment's objects.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EpisodeSpec {
    pub index: usize,
    pub task: usize,
    pub agent_seed: u64,
    pub demo_seed: u64,
    /// The environment's objects by slot, in both scenes.
    pub objects: [Object; NUM_OBJECTS],
}

/// What a worker reports after starting an episode.
pub struct Started {
    /// The demonstrator's whole video (RGB frames).
    pub demo_frames: Vec<Vec<u8>>,
    /// Seed of the layout the demonstration succeeded on.
    pub demo_seed: u64,
    /// The agent's first frame.
    pub frame: Vec<u8>,
    /// The robot's own state at it.
    pub state: [f32; STATE_DIM],
    /// The agent's gripper pointing down at its rest yaw, as (angle / pi, axis): what a fixed-yaw expert holds.
    pub rest_orientation: (f64, [f64; 3]),
}

/// What a worker reports after a step.
pub struct Stepped {
    pub frame: Vec<u8>,
    pub milestones: Milestones,
    /// The action the agent executed (none where the episode was left alone).
    pub action: Option<Action>,
    /// The task's object in the gripper's frame after it (none where the episode was left alone).
    pub target_in_gripper: Option<[f64; 3]>,
    /// What the robot sensed after it (none where the episode was left alone).
    pub observed: Option<Observation>,
}

enum Command {
    Start(Vec<EpisodeSpec>),
    /// Per slot: `None` to leave it alone, `Some(action)` to step it (`Some(None)`: the local chooser decides).
    Step(Vec<Option<Option<Action>>>),
    /// Per slot: hand the episode to a scripted expert executing these positions.
    Guide(Vec<Guidance>),
}

enum Reply {
    Started(Result<Vec<Started>>),
    Stepped(Result<Vec<Stepped>>),
    /// How many episodes were handed over.
    Guided(usize),
}

/// A pool of simulation threads.
pub struct WorkerPool {
    workers: Vec<(Sender<Command>, Receiver<Reply>, JoinHandle<()>)>,
}

/// Settings every worker shares.
#[derive(Clone)]
pub struct WorkerSpec {
    pub world: WorldConfig,
    pub chooser: Chooser,
    pub demo_max_actions: usize,
    pub demo_attempts: usize,
    /// Root of the random policy's draws.
    pub seed: u64,
}

struct Slot {
    env: Env,
    expert: Option<Expert>,
    rng: ChaCha8Rng,
}

struct Worker {
    spec: WorkerSpec,
    demo_env: Env,
    slots: Vec<Slot>,
    /// One renderer for all agent scenes of this worker.
    camera: Option<Camera>,
}

impl Worker {
    fn start(&mut self, specs: Vec<EpisodeSpec>) -> Result<Vec<Started>> {
        while self.slots.len() < specs.len() {
            let env = Env::new(Robot::Panda, &self.spec.world, false)?;
            if self.camera.is_none() {
                self.camera = Some(env.new_camera()?);
            }
            self.slots.push(Slot { env, expert: None, rng: ChaCha8Rng::seed_from_u64(0) });
        }
        let camera = self.camera.as_mut().expect("made with the first slot");
        let mut out = Vec::with_capacity(specs.len());
        for (slot, spec) in self.slots.iter_mut().zip(&specs) {
            let task = Task::from_id(spec.task)?;
            let (demo_frames, demo_seed) = demonstrate(&mut self.demo_env, task, spec, &self.spec)?;
            slot.env.reset(&Instance::sample_with(task, spec.agent_seed, spec.objects))?;
            slot.expert = (self.spec.chooser == Actor::Expert).then(|| Expert::new(&slot.env));
            slot.rng = ChaCha8Rng::seed_from_u64(derive_seed("random-policy", &[self.spec.seed, spec.index as u64]));
            let frame = slot.env.render_with(camera)?;
            let (state, rest_orientation) = (slot.env.observe().robot_state(), slot.env.rest_orientation());
            out.push(Started { demo_frames, demo_seed, frame, state, rest_orientation });
        }
        Ok(out)
    }

    fn step(&mut self, commands: Vec<Option<Option<Action>>>) -> Result<Vec<Stepped>> {
        let mut out = Vec::with_capacity(commands.len());
        let camera = self.camera.as_mut().context("step before start")?;
        for (slot, command) in self.slots.iter_mut().zip(commands) {
            let Some(given) = command else {
                out.push(Stepped {
                    frame: Vec::new(),
                    milestones: slot.env.milestones(),
                    action: None,
                    target_in_gripper: None,
                    observed: None,
                });
                continue;
            };
            let action = match (given, slot.expert.as_mut(), self.spec.chooser) {
                (Some(a), _, _) => a,
                (None, Some(expert), _) => expert.act(&slot.env),
                (None, None, Actor::Random) => {
                    let n: [f32; ACTION_DIM] = std::array::from_fn(|_| slot.rng.random_range(-1.0..=1.0));
                    Action::from_normalized(&n)
                }
                (None, None, _) => bail!("the network sent no action and no scripted expert runs this episode"),
            };
            slot.env.step(&action);
            let frame = slot.env.render_with(camera)?;
            out.push(Stepped {
                frame,
                milestones: slot.env.milestones(),
                action: Some(action),
                target_in_gripper: slot.env.target_in_gripper(),
                observed: Some(slot.env.observe()),
            });
        }
        Ok(out)
    }
}

/// Runs the demonstrator's expert until it places the object (fresh layouts on failure); returns its frames.
fn demonstrate(env: &mut Env, task: Task, episode: &EpisodeSpec, spec: &WorkerSpec) -> Result<(Vec<Vec<u8>>, u64)> {
    let seed = episode.demo_seed;
    for attempt in 0..spec.demo_attempts {
        let s = if attempt == 0 { seed } else { derive_seed("eval-demo-retry", &[seed, attempt as u64]) };
        let episode = run_expert(env, &Instance::sample_with(task, s, episode.objects), spec.demo_max_actions, true)?;
        if episode.milestones.placed {
            let frames = episode.steps.into_iter().map(|s| s.frame.expect("rendered")).collect();
            return Ok((frames, s));
        }
    }
    bail!("the demonstrator's expert failed {} layouts of task {}", spec.demo_attempts, task.id())
}

impl WorkerPool {
    /// Starts `n` worker threads.
    pub fn new(n: usize, spec: &WorkerSpec) -> Result<WorkerPool> {
        let mut workers = Vec::with_capacity(n);
        for _ in 0..n.max(1) {
            let (to_worker, commands) = channel::<Command>();
            let (replies, from_worker) = channel::<Reply>();
            let spec = spec.clone();
            let handle = std::thread::spawn(move || {
                let demo_env = match Env::new(Robot::Sawyer, &spec.world, true) {
                    Ok(e) => e,
                    Err(e) => {
                        let _ = replies.send(Reply::Started(Err(e)));
                        return;
                    }
                };
                let mut worker = Worker { spec, demo_env, slots: Vec::new(), camera: None };
                for command in commands {
                    let reply = match command {
                        Command::Start(specs) => Reply::Started(worker.start(specs)),
                        Command::Step(actions) => Reply::Stepped(worker.step(actions)),
                        Command::Guide(guides) => {
                            let n = guides.len();
                            for (slot, g) in worker.slots.iter_mut().zip(guides) {
                                slot.expert = Some(Expert::guided(&slot.env, g));
                            }
                            Reply::Guided(n)
                        }
                    };
                    if replies.send(reply).is_err() {
                        return;
                    }
                }
            });
            workers.push((to_worker, from_worker, handle));
        }
        Ok(WorkerPool { workers })
    }

    /// Number of workers.
    pub fn len(&self) -> usize {
        self.workers.len()
    }

    /// Whether the pool has no workers (never, by construction).
    pub fn is_empty(&self) -> bool {
        self.workers.is_empty()
    }

    /// Starts episodes; episode `j` of `specs` goes to worker `j % len`. Results come back in `specs` order.
    pub fn start(&self, specs: &[EpisodeSpec]) -> Result<Vec<Started>> {
        self.round_trip(specs, Command::Start, |reply| match reply {
            Reply::Started(r) => Some(r),
            _ => None,
        })
    }

    /// Steps episodes (same order as `start`); `None` leaves an episode alone (its frame comes back empty).
    pub fn step(&self, commands: &[Option<Option<Action>>]) -> Result<Vec<Stepped>> {
        self.round_trip(commands, Command::Step, |reply| match reply {
            Reply::Stepped(r) => Some(r),
            _ => None,
        })
    }

    /// Hands each started episode (same order as `start`) to a scripted expert executing its positions.
    pub fn guide(&self, guides: &[Guidance]) -> Result<()> {
        self.round_trip(guides, Command::Guide, |reply| match reply {
            Reply::Guided(n) => Some(Ok(vec![(); n])),
            _ => None,
        })
        .map(|_: Vec<()>| ())
    }

    /// Sends item `j` of `items` to worker `j % len` (wrapped by `command`), then gathers the answers in `items`
    /// order; `answer` picks the expected reply kind.
    fn round_trip<I: Copy, O>(
        &self,
        items: &[I],
        command: fn(Vec<I>) -> Command,
        answer: fn(Reply) -> Option<Result<Vec<O>>>,
    ) -> Result<Vec<O>> {
        let n = self.len();
        for (w, (tx, _, _)) in self.workers.iter().enumerate() {
            let mine = items.iter().skip(w).step_by(n).copied().collect();
            tx.send(command(mine)).map_err(|_| anyhow::anyhow!("evaluation worker {w} stopped"))?;
        }
        let mut per_worker = Vec::with_capacity(n);
        for (w, (_, rx, _)) in self.workers.iter().enumerate() {
            match rx.recv().ok().and_then(answer) {
                Some(r) => per_worker.push(r?.into_iter()),
                None => bail!("evaluation worker {w} stopped"),
            }
        }
        Ok(interleave(per_worker, items.len()))
    }
}

/// Undoes the round-robin split: item j comes from worker j % n.
fn interleave<T>(mut per_worker: Vec<std::vec::IntoIter<T>>, total: usize) -> Vec<T> {
    let n = per_worker.len();
    (0..total).map(|j| per_worker[j % n].next().expect("worker answered for each of its episodes")).collect()
}

impl Drop for WorkerPool {
    fn drop(&mut self) {
        for (tx, rx, handle) in self.workers.drain(..) {
            drop(tx);
            drop(rx);
            let _ = handle.join();
        }
    }
}
