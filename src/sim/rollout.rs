//! Running the scripted expert for whole episodes.
use super::action::Action;
use super::env::{Env, Observation};
use super::expert::Expert;
use super::stages::Stages;
use super::task::Instance;
use anyhow::Result;

/// Steps the expert keeps holding still after releasing, so the object comes to rest.
const SETTLE_STEPS: usize = 3;

/// One recorded step: what was seen, and (except on the last step) the action taken from it.
pub struct Step {
    pub frame: Option<Vec<u8>>,
    pub observation: Observation,
    pub action: Option<Action>,
}

/// An expert episode.
pub struct Episode {
    pub steps: Vec<Step>,
    pub stages: Stages,
}

/// Runs the expert on `instance` for at most `max_actions` actions, recording frames if `render`.
pub fn run_expert(env: &mut Env, instance: &Instance, max_actions: usize, render: bool) -> Result<Episode> {
    env.reset(instance);
    let mut expert = Expert::new(env);
    let mut steps = Vec::with_capacity(max_actions + 1);
    let mut settle = 0;
    loop {
        let frame = if render { Some(env.render()?) } else { None };
        let observation = env.observe();
        let finished = steps.len() >= max_actions || settle >= SETTLE_STEPS;
        if finished {
            steps.push(Step { frame, observation, action: None });
            break;
        }
        let action = expert.act(env);
        env.step(&action);
        if expert.done() {
            settle += 1;
        }
        steps.push(Step { frame, observation, action: Some(action) });
    }
    Ok(Episode { steps, stages: env.stages() })
}
