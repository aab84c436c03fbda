//! Lockstep rollouts: simulation workers step their scenes while the network (if any) runs batched, with the
//! authors' evaluation protocol applied to the network's actions.
use super::actor::Actor;
use super::config::{ActionChoice, Control, EvalConfig};
use super::history::AgentHistory;
use super::workers::{EpisodeSpec, WorkerPool, WorkerSpec};
use super::{EpisodeResult, EpisodeTrace, EvalOutput, GripperClose, TraceStep, strip, video};
use crate::data::augment::AugmentDraw;
use crate::data::pairs::context_indices;
use crate::data::trajectory::jpeg_round_trip;
use crate::model::mixture::{MixtureParams, mixture_component_mean, mixture_mode, mixture_sample};
use crate::seeds::derive_seed;
use crate::sim::action::{ACTION_DIM, Action};
use crate::sim::env::{STATE_DIM, WorldConfig};
use crate::sim::expert::Guidance;
use crate::sim::milestones::Milestones;
use crate::train::TrainedPolicy;
use anyhow::{Context, Result, bail};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use tch::{Device, Tensor};

/// A policy as it runs: the loaded network, or a reference policy.
pub type LoadedActor<'a> = Actor<&'a TrainedPolicy>;

/// Runs the episodes `specs` of `policy` in waves of `config.batch`, with `workers` simulation threads; with
/// `config.traces`, also every episode's steps (else the traces are empty).
pub fn rollouts(
    policy: &LoadedActor,
    world: &WorldConfig,
    config: &EvalConfig,
    specs: &[EpisodeSpec],
    workers: usize,
    output: &EvalOutput,
) -> Result<(Vec<EpisodeResult>, Vec<EpisodeTrace>)> {
    config.validate()?;
    let device = crate::device::parse_device(&config.device)?;
    if let Actor::Network(p) = policy {
        let differences = world_differences(&p.summary.world, world);
        if !differences.is_empty() {
            bail!("the policy was trained in another world than the evaluation's: {}", differences.join("; "));
        }
        config.check_policy(p.policy.config(), world)?;
    }
    tch::manual_seed(derive_seed("eval-sampling", &[config.seed]) as i64);
    let spec = WorkerSpec {
        world: world.clone(),
        chooser: policy.as_ref().map(|_| ()),
        demo_max_actions: config.demo_max_actions,
        demo_attempts: config.demo_attempts,
        seed: config.seed,
    };
    let pool = WorkerPool::new(workers.clamp(1, config.batch), &spec)?;
    let (mut results, mut traces) = (Vec::with_capacity(specs.len()), Vec::new());
    for wave in specs.chunks(config.batch) {
        let (r, t) = run_wave(policy, &pool, wave, world, config, device, output)?;
        results.extend(r);
        traces.extend(t);
    }
    Ok((results, traces))
}

/// `world.key: trained vs evaluated` for every setting in which `trained` and `evaluated` differ.
pub fn world_differences(trained: &WorldConfig, evaluated: &WorldConfig) -> Vec<String> {
    let (a, b) = (serde_json::to_value(trained), serde_json::to_value(evaluated));
    let (Ok(serde_json::Value::Object(a)), Ok(serde_json::Value::Object(b))) = (a, b) else {
        return vec!["the worlds do not serialise".into()];
    };
    a.iter()
        .filter(|(k, v)| b.get(*k) != Some(v))
        .map(|(k, v)| format!("world.{k}: trained {v}, evaluated {}", b.get(k).cloned().unwrap_or_default()))
        .collect()
}

/// A frame as the network sees it during evaluation: through the JPEG encoding of the training data, then
/// normalised, exactly as training reads a stored frame.
pub fn network_frame(rgb: &[u8], world: &WorldConfig, jpeg_quality: u8) -> Result<Vec<f32>> {
    let (h, w) = (world.image.height, world.image.width);
    let decoded = jpeg_round_trip(rgb, h, w, jpeg_quality)?;
    let mut out = vec![0.0; 3 * h * w];
    AugmentDraw::identity(h, w).apply(&decoded, h, w, &mut out);
    Ok(out)
}

/// Turns the network's normalised action into the command sent at `step`: the rotation replaced by the agent's
/// fixed orientation and the gripper binarised, where the configuration says so.
fn command(normalised: &[f32], step: usize, config: &EvalConfig, rest: (f64, [f64; 3])) -> Action {
    let mut a = Action::from_normalized(normalised);
    if config.fixed_rotation {
        let (angle, axis) = rest;
        a.0[3..7].copy_from_slice(&[angle, axis[0], axis[1], axis[2]]);
    }
    if config.binarize_gripper {
        a.0[ACTION_DIM - 1] = if a.0[ACTION_DIM - 1] > 0.0 && step + 1 < config.horizon { 1.0 } else { -1.0 };
    }
    a
}

/// What the network needs of one episode: its context frames and the window of its own recent frames, each with
/// the robot's state when it was seen.
struct NetworkInputs {
    context: Vec<f32>,
    history: AgentHistory<(Vec<f32>, [f32; STATE_DIM])>,
}

/// Runs one lockstep wave of episodes.
fn run_wave(
    policy: &LoadedActor,
    pool: &WorkerPool,
    wave: &[EpisodeSpec],
    world: &WorldConfig,
    config: &EvalConfig,
    device: Device,
    output: &EvalOutput,
) -> Result<(Vec<EpisodeResult>, Vec<EpisodeTrace>)> {
    let started = pool.start(wave)?;
    let n = wave.len();
    let mut inputs: Vec<NetworkInputs> = Vec::new();
    if let Actor::Network(p) = policy {
        let q = p.summary.jpeg_quality;
        for (e, s) in wave.iter().zip(&started) {
            let mut rng = ChaCha8Rng::seed_from_u64(derive_seed("eval-context", &[config.seed, e.index as u64]));
            let mut context = Vec::new();
            for t in context_indices(&mut rng, s.demo_frames.len(), p.policy.config()) {
                context.extend(network_frame(&s.demo_frames[t], world, q)?);
            }
            let mut history = AgentHistory::new(config.history, config.history_frames);
            history.push((network_frame(&s.frame, world, q)?, s.state));
            inputs.push(NetworkInputs { context, history });
        }
    }
    let scripted = matches!(policy, Actor::Network(_)) && config.control == Control::ScriptedPoses;
    if let (Actor::Network(p), true) = (policy, scripted) {
        pool.guide(&predicted_guidance(p, &inputs, world, device)?)?;
    }
    // Frames of the episodes drawn as strips, each with the stages that held when it was seen; the executed
    // actions of those recorded as videos, replayed at the video's size once the wave is done.
    let recorded: Vec<bool> = wave.iter().map(|e| config.strips.contains(&e.index)).collect();
    let filmed: Vec<bool> = wave.iter().map(|e| config.videos.contains(&e.index)).collect();
    let mut executed: Vec<Vec<Action>> = vec![Vec::new(); n];
    let mut frames: Vec<Vec<(Vec<u8>, Milestones)>> = started
        .iter()
        .zip(&recorded)
        .map(|(s, &want)| if want { vec![(s.frame.clone(), Milestones::default())] } else { Vec::new() })
        .collect();
    let mut results: Vec<EpisodeResult> = wave
        .iter()
        .zip(&started)
        .map(|(e, s)| EpisodeResult {
            index: e.index,
            task: e.task,
            agent_seed: e.agent_seed,
            demo_seed: s.demo_seed,
            reached: false,
            picked: false,
            placed: false,
            wrong_bin: false,
            steps: 0,
            first_reached: None,
            first_picked: None,
            first_placed: None,
            first_close: None,
        })
        .collect();
    let mut traces: Vec<EpisodeTrace> = match config.traces {
        true => wave.iter().map(|e| EpisodeTrace { index: e.index, steps: Vec::new() }).collect(),
        false => Vec::new(),
    };

    for t in 0..config.horizon {
        let active: Vec<usize> = (0..n).filter(|&j| !results[j].placed).collect();
        if active.is_empty() {
            break;
        }
        let mut commands: Vec<Option<Option<Action>>> = vec![None; n];
        match policy {
            Actor::Network(p) if !scripted => {
                let sampled = network_actions(p, &active, &inputs, world, config.action, device)?;
                for (&j, a) in active.iter().zip(sampled.chunks(ACTION_DIM)) {
                    commands[j] = Some(Some(command(a, t, config, started[j].rest_orientation)));
                }
            }
            _ => active.iter().for_each(|&j| commands[j] = Some(None)),
        }
        let stepped = pool.step(&commands)?;
        for &j in &active {
            let s = &stepped[j];
            let r = &mut results[j];
            r.steps = t + 1;
            let hit = |flag: bool, first: &mut Option<usize>| {
                if flag && first.is_none() {
                    *first = Some(t + 1);
                }
            };
            hit(s.milestones.reached, &mut r.first_reached);
            hit(s.milestones.picked, &mut r.first_picked);
            hit(s.milestones.placed, &mut r.first_placed);
            (r.reached, r.picked, r.placed) = (s.milestones.reached, s.milestones.picked, s.milestones.placed);
            r.wrong_bin = s.milestones.wrong_bin;
            if let (None, Some(action), Some(offset)) = (r.first_close, s.action, s.target_in_gripper)
                && action.gripper() > 0.0
            {
                r.first_close = Some(GripperClose { step: t + 1, object_in_gripper: offset });
            }
            if let (Actor::Network(p), false, Some(observed)) = (policy, scripted, &s.observed) {
                let frame = network_frame(&s.frame, world, p.summary.jpeg_quality)?;
                inputs[j].history.push((frame, observed.robot_state()));
            }
            if recorded[j] {
                frames[j].push((s.frame.clone(), s.milestones));
            }
            if let (true, Some(action)) = (filmed[j], s.action) {
                executed[j].push(action);
            }
            if let (Some(trace), Some(action), Some(object_in_gripper), Some(observed)) =
                (traces.get_mut(j), s.action, s.target_in_gripper, &s.observed)
            {
                let m = s.milestones;
                trace.steps.push(TraceStep {
                    step: t + 1,
                    action: action.0,
                    gripper_pos: observed.eef_pos,
                    fingers: observed.gripper_qpos,
                    object_in_gripper,
                    reached: m.reached,
                    picked: m.picked,
                    placed: m.placed,
                });
            }
        }
    }
    if let Some(dir) = &output.strips_dir {
        for j in (0..n).filter(|&j| config.strips.contains(&wave[j].index)) {
            let path = dir.join(format!("episode_{:04}_task{:02}.png", wave[j].index, wave[j].task));
            let agent: Vec<Vec<u8>> = frames[j].iter().map(|(f, _)| f.clone()).collect();
            strip::write_strip(&path, &started[j].demo_frames, &agent, world.image, &results[j])
                .with_context(|| format!("writing strip {}", path.display()))?;
        }
    }
    if let Some(dir) = &output.videos_dir {
        let size = video::video_size(world.image, config.video_width);
        for j in (0..n).filter(|&j| filmed[j]) {
            let (demo, agent) =
                video::replay(world, size, &results[j], wave[j].objects, &executed[j], config.demo_max_actions)?;
            video::write_video(dir, &demo, &agent, size, world.policy_hz, &results[j])
                .with_context(|| format!("writing the video of episode {}", wave[j].index))?;
        }
    }
    Ok((results, traces))
}

/// The grasp and drop positions the network predicts for each episode of a wave from its context and first
/// agent frame, as guidance for the scripted expert.
fn predicted_guidance(
    p: &TrainedPolicy,
    inputs: &[NetworkInputs],
    world: &WorldConfig,
    device: Device,
) -> Result<Vec<Guidance>> {
    let (h, w) = (world.image.height as i64, world.image.width as i64);
    let b = inputs.len() as i64;
    let tc = p.policy.config().context_len() as i64;
    let ctx: Vec<f32> = inputs.iter().flat_map(|i| i.context.iter().copied()).collect();
    let first: Vec<f32> =
        inputs.iter().flat_map(|i| i.history.frames().next().into_iter().flat_map(|(f, _)| f).copied()).collect();
    let ctx = Tensor::from_slice(&ctx).view([b, tc, 3, h, w]).to_device(device);
    let agent = Tensor::from_slice(&first).view([b, 1, 3, h, w]).to_device(device);
    let poses = tch::no_grad(|| p.policy.predict_poses(&ctx, &agent))
        .context("eval.control = \"scripted_poses\": the architecture predicts no positions")?;
    let poses: Vec<f64> = Vec::try_from(poses.to_device(Device::Cpu).to_kind(tch::Kind::Double).flatten(0, -1))?;
    Ok(poses.chunks(6).map(|q| Guidance::Given { grasp: [q[0], q[1], q[2]], drop: [q[3], q[4], q[5]] }).collect())
}

/// One batched forward pass: a normalised action (8 values) for each active episode, read at the last position of
/// its window.
fn network_actions(
    p: &TrainedPolicy,
    active: &[usize],
    inputs: &[NetworkInputs],
    world: &WorldConfig,
    choice: ActionChoice,
    device: Device,
) -> Result<Vec<f32>> {
    let (h, w) = (world.image.height as i64, world.image.width as i64);
    let b = active.len() as i64;
    let tc = p.policy.config().context_len() as i64;
    let ta = inputs[active[0]].history.len() as i64;
    let ctx: Vec<f32> = active.iter().flat_map(|&j| inputs[j].context.iter().copied()).collect();
    let agent: Vec<f32> =
        active.iter().flat_map(|&j| inputs[j].history.frames().flat_map(|(f, _)| f).copied()).collect();
    let states: Vec<f32> =
        active.iter().flat_map(|&j| inputs[j].history.frames().flat_map(|(_, s)| s).copied()).collect();
    let ctx = Tensor::from_slice(&ctx).view([b, tc, 3, h, w]).to_device(device);
    let agent = Tensor::from_slice(&agent).view([b, ta, 3, h, w]).to_device(device);
    let states = Tensor::from_slice(&states).view([b, ta, STATE_DIM as i64]).to_device(device);
    let sample = tch::no_grad(|| {
        let out = p.policy.forward_with_states(&ctx, &agent, &states, false);
        let last = |t: &Tensor| t.select(1, ta - 1);
        let params = MixtureParams {
            means: last(&out.actions.means),
            log_scales: last(&out.actions.log_scales),
            logits: last(&out.actions.logits),
        };
        match choice {
            ActionChoice::Sample => mixture_sample(&params),
            ActionChoice::Mode => mixture_mode(&params),
            ActionChoice::Component => mixture_component_mean(&params),
        }
        .to_device(Device::Cpu)
    });
    Ok(Vec::try_from(sample.flatten(0, -1))?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn commands_take_the_fixed_rotation_and_a_binary_gripper_opened_at_the_end() {
        let config = EvalConfig { horizon: 10, ..EvalConfig::default() };
        let rest = (1.0, [0.0, 1.0, 0.0]);
        let wild = [0.1f32, -0.2, 0.3, -0.9, 0.7, -0.6, 0.5, 0.2];
        let a = command(&wild, 3, &config, rest);
        assert_eq!(&a.0[3..7], &[1.0, 0.0, 1.0, 0.0]);
        assert_eq!(a.gripper(), 1.0, "a positive command closes");
        assert_eq!(command(&wild, 9, &config, rest).gripper(), -1.0, "the last step opens");
        let open = [0.0f32, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -0.01];
        assert_eq!(command(&open, 0, &config, rest).gripper(), -1.0);
        let raw = EvalConfig { fixed_rotation: false, binarize_gripper: false, ..config };
        let b = command(&wild, 9, &raw, rest);
        assert_eq!(b, Action::from_normalized(&wild), "both switches off: the network's action as it is");
    }

    #[test]
    fn world_differences_name_each_setting() {
        let a = WorldConfig::default();
        let b = WorldConfig { policy_hz: 20.0, agent_yaw: crate::sim::env::GripperYaw::ObjectYaw, ..a.clone() };
        let d = world_differences(&a, &b);
        assert_eq!(d.len(), 2, "{d:?}");
        assert!(d.iter().any(|s| s.starts_with("world.policy_hz: trained 10.0, evaluated 20.0")), "{d:?}");
        assert!(world_differences(&a, &a).is_empty());
    }
}
