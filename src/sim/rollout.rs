//! Running the scripted expert for whole episodes.
use super::action::Action;
use super::env::{Env, Observation};
use super::expert::{Expert, Guidance};
use super::milestones::{Milestones, PLACED_Z};
use super::task::Instance;
use crate::seeds::derive_seed;
use anyhow::Result;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Steps the expert holds still after releasing before the episode may end.
const SETTLE_STEPS: usize = 3;
/// Steps after releasing by which the episode ends even if the object has not come to rest in its quadrant (a
/// slow fall or an object caught on the bin's divider).
const MAX_SETTLE_STEPS: usize = 20;

/// One recorded step: what was seen, and (except on the last step) the action taken from it.
pub struct Step {
    pub frame: Option<Vec<u8>>,
    pub observation: Observation,
    pub action: Option<Action>,
}

/// An expert episode.
pub struct Episode {
    pub steps: Vec<Step>,
    pub milestones: Milestones,
}

/// Runs the expert on `instance` for at most `max_actions` actions, recording frames if `render`. After the
/// release the expert holds still until the object rests in its quadrant (at least 3 steps, at most 20).
pub fn run_expert(env: &mut Env, instance: &Instance, max_actions: usize, render: bool) -> Result<Episode> {
    run_expert_perturbed(env, instance, max_actions, render, 0.0)
}

/// Like [`run_expert`], but each action is executed with Gaussian noise of standard deviation `noise` (metres)
/// added to its position target, while the expert's own action is what is recorded: the states a learner's errors
/// lead to, labelled with the expert's correction (DART, Laskey et al., CoRL 2017). The noise is drawn from the
/// instance's seed, so an episode is reproducible.
pub fn run_expert_perturbed(
    env: &mut Env,
    instance: &Instance,
    max_actions: usize,
    render: bool,
    noise: f64,
) -> Result<Episode> {
    run(env, instance, max_actions, render, noise, |_| Guidance::Privileged)
}

/// Runs the expert on `instance` without rendering, aiming its grasp `offset` off the object (metres, in the
/// gripper's frame: see [`Guidance::aimed_off`]); it does not start over after a miss.
pub fn run_expert_aimed_off(
    env: &mut Env,
    instance: &Instance,
    max_actions: usize,
    offset: [f64; 2],
) -> Result<Episode> {
    run(env, instance, max_actions, false, 0.0, |env| Guidance::aimed_off(env, offset))
}

/// The expert's episode loop, its guidance made from the environment once reset.
fn run(
    env: &mut Env,
    instance: &Instance,
    max_actions: usize,
    render: bool,
    noise: f64,
    guidance: impl FnOnce(&Env) -> Guidance,
) -> Result<Episode> {
    let mut rng = ChaCha8Rng::seed_from_u64(derive_seed("expert-noise", &[instance.seed]));
    env.reset(instance)?;
    let mut expert = Expert::guided(env, guidance(env));
    let mut steps = Vec::with_capacity(max_actions + 1);
    let mut settle = 0;
    loop {
        let frame = if render { Some(env.render()?) } else { None };
        let observation = env.observe();
        // Placed (a latched stage) and low now: at rest in the quadrant, not lifted out of it again.
        let object_z = observation.object_poses[instance.task.object][2];
        let resting = env.milestones().placed && object_z < PLACED_Z.1;
        let settled = settle >= SETTLE_STEPS && (resting || settle >= MAX_SETTLE_STEPS);
        let finished = steps.len() >= max_actions || settled;
        if finished {
            steps.push(Step { frame, observation, action: None });
            break;
        }
        let action = expert.act(env);
        if noise > 0.0 {
            let mut executed = action;
            for d in 0..3 {
                executed.0[d] += noise * gaussian(&mut rng);
            }
            env.step(&executed);
        } else {
            env.step(&action);
        }
        if expert.done() {
            settle += 1;
        }
        steps.push(Step { frame, observation, action: Some(action) });
    }
    Ok(Episode { steps, milestones: env.milestones() })
}

/// A standard normal draw (Box-Muller).
fn gaussian<R: Rng>(rng: &mut R) -> f64 {
    let u: f64 = rng.random_range(f64::EPSILON..1.0);
    let v: f64 = rng.random();
    (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
}
