//! The open-loop grip probe: around the agent expert's lift (its fingers closed on the object, then the first
//! command that rises), what the policy's head gives the next command, read from the expert's own frames with as
//! many of them in the window as a rollout shows (1 to `history` frames). It says whether the most likely action
//! stays at the bottom because the network does not see when to lift, or only once the closed loop has drifted.
use super::holds::LIFT;
use crate::data::loader::Batch;
use crate::data::pairs::{FrameForm, PairDataset, Sample, Split, Windows};
use crate::model::mixture::{MixtureParams, mixture_above, mixture_mode};
use crate::seeds::derive_seed;
use crate::sim::action::ACTION_RANGES;
use crate::train::TrainedPolicy;
use anyhow::{Result, bail};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::collections::BTreeMap;
use tch::{Device, Kind, Tensor};

/// Action dimensions the probe reads: the target's height and the gripper command (+1 closes).
const Z: usize = 2;
const GRIPPER: usize = 7;

/// The expert's close and lift in one trajectory: the first step whose action closes the gripper, and the first
/// step after it whose action targets the gripper more than [`LIFT`] above where it is. None when either is
/// missing.
pub fn close_and_lift(actions: &[[f32; 8]], eef_pos: &[[f32; 3]]) -> Option<(usize, usize)> {
    let close = actions.iter().position(|a| a[GRIPPER] > 0.0)?;
    let lift = (close + 1..actions.len()).find(|&t| lifts(actions[t][Z], eef_pos[t][Z]))?;
    Some((close, lift))
}

fn lifts(target_z: f32, z: f32) -> bool {
    f64::from(target_z) > f64::from(z) + LIFT
}

/// What the head gives the next command at a set of queries (a step seen with some number of frames).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct GripRow {
    /// Queries pooled in the row.
    pub queries: usize,
    /// Share of them at which the expert's own action lifts.
    pub expert_lifts: f64,
    /// Mean probability that a sampled action lifts.
    pub lift_probability: f64,
    /// Share at which the most likely action lifts.
    pub mode_lifts: f64,
    /// Mean probability that a sampled action opens the gripper.
    pub open_probability: f64,
    /// Share at which the most likely action opens it.
    pub mode_opens: f64,
}

/// The probe's rows.
#[derive(Debug, Clone, PartialEq)]
pub struct GripProbe {
    /// Trajectories probed (each with a close, a lift and a demonstration of its task), and those left out for
    /// lacking one.
    pub trajectories: usize,
    pub skipped: usize,
    /// By step relative to the expert's lift (0: the step whose action lifts; the most negative, its close), all
    /// window lengths pooled.
    pub by_step: Vec<(i64, GripRow)>,
    /// The lift step alone, by frames in the window (index 0: one frame).
    pub lift_by_frames: Vec<GripRow>,
    /// The steps between the close and the lift (the expert resting on the object), by frames in the window.
    pub rest_by_frames: Vec<GripRow>,
    /// Trajectories whose most likely action lifts at none, some, or all of their bottom queries (every step after
    /// the close through the lift, every window length): whether the mode's choice is the step's or the scene's.
    pub bottom_mode_lifts: [usize; 3],
}

/// One query's outcome.
struct Reading {
    /// Which probed trajectory (0-based) the step is of.
    trajectory: usize,
    offset: i64,
    /// Whether the step lies between the close and the lift (the expert resting on the object).
    rests: bool,
    frames: usize,
    expert_lifts: bool,
    lift_probability: f64,
    mode_lifts: bool,
    open_probability: f64,
    mode_opens: bool,
}

/// Running sums behind a [`GripRow`].
#[derive(Default, Clone, Copy)]
struct Sums {
    n: usize,
    expert_lifts: usize,
    lift_probability: f64,
    mode_lifts: usize,
    open_probability: f64,
    mode_opens: usize,
}

impl Sums {
    fn add(&mut self, r: &Reading) {
        self.n += 1;
        self.expert_lifts += usize::from(r.expert_lifts);
        self.lift_probability += r.lift_probability;
        self.mode_lifts += usize::from(r.mode_lifts);
        self.open_probability += r.open_probability;
        self.mode_opens += usize::from(r.mode_opens);
    }

    fn row(&self) -> GripRow {
        let n = self.n.max(1) as f64;
        GripRow {
            queries: self.n,
            expert_lifts: self.expert_lifts as f64 / n,
            lift_probability: self.lift_probability / n,
            mode_lifts: self.mode_lifts as f64 / n,
            open_probability: self.open_probability / n,
            mode_opens: self.mode_opens as f64 / n,
        }
    }
}

/// A height in metres in the action's normalised units.
fn normalised_z(z: f64) -> f64 {
    let [lo, hi] = ACTION_RANGES[Z];
    2.0 * (z - lo) / (hi - lo) - 1.0
}

/// One window to run, and the steps read from it.
struct Planned {
    trajectory: usize,
    sample: Sample,
    reads: Vec<Read>,
}

/// A step read from a window: where it lies, and what the expert did there.
#[derive(Clone, Copy)]
struct Read {
    /// Window position showing the step as its last frame.
    position: usize,
    /// Step relative to the lift.
    offset: i64,
    /// Whether the step lies between the close and the lift.
    rests: bool,
    /// The expert's gripper height there (m) and whether its action lifts.
    z: f64,
    expert_lifts: bool,
}

/// Probes the first `trajectories` agent trajectories of `split` that close and lift, each paired with a
/// demonstration of its task: every step from the close to one past the lift, seen with 1 to `history` frames
/// (the window's last), run in batches of `batch` windows; the context frames drawn from `seed`.
pub fn grip_probe(
    policy: &TrainedPolicy,
    data: &PairDataset,
    split: Split,
    trajectories: usize,
    history: usize,
    batch: usize,
    seed: u64,
) -> Result<GripProbe> {
    let model = policy.policy.config();
    data.check_fits(model)?;
    if trajectories == 0 || batch == 0 {
        bail!("the grip probe needs at least one trajectory and a batch of at least one");
    }
    if history == 0 || history + 1 > model.agent_frames {
        bail!(
            "the grip probe reads 1 to {history} frames, but model.agent_frames = {} trains 1 to {}",
            model.agent_frames,
            model.agent_frames - 1
        );
    }
    let (mut probed, mut skipped, mut planned) = (0, 0, Vec::new());
    for agent in data.agents_of(split) {
        if probed == trajectories {
            break;
        }
        let trajectory = data.agent(agent);
        let Some((close, lift)) = close_and_lift(&trajectory.actions, &trajectory.eef_pos) else {
            skipped += 1;
            continue;
        };
        let demos = data.demos_for(split, agent, trajectory.meta.task);
        let Some(&demo) = demos.get(probed % demos.len().max(1)) else {
            skipped += 1;
            continue;
        };
        probed += 1;
        let last_step = (lift + 1).min(trajectory.actions.len() - 1);
        let first_start = close.saturating_sub(history - 1);
        let last_start = last_step.min(trajectory.len() - model.agent_frames);
        for start in first_start..=last_start {
            // Every window of a trajectory shows the same context frames: one draw per trajectory.
            let mut rng = ChaCha8Rng::seed_from_u64(derive_seed("probe-grip", &[seed, agent as u64]));
            let sample =
                data.sample_pair(&mut rng, [demo, agent], model, Windows::At(start), None, FrameForm::Normalised)?;
            let reads: Vec<Read> = (0..history)
                .map(|position| (position, start + position))
                .filter(|&(_, step)| step >= close && step <= last_step)
                .map(|(position, step)| Read {
                    position,
                    offset: step as i64 - lift as i64,
                    rests: step > close && step < lift,
                    z: f64::from(trajectory.eef_pos[step][Z]),
                    expert_lifts: lifts(trajectory.actions[step][Z], trajectory.eef_pos[step][Z]),
                })
                .collect();
            if !reads.is_empty() {
                planned.push(Planned { trajectory: probed - 1, sample, reads });
            }
        }
    }
    if probed == 0 {
        bail!("no {split:?} agent trajectory both closes its gripper and lifts");
    }
    let mut readings = Vec::new();
    while !planned.is_empty() {
        let chunk: Vec<Planned> = planned.drain(..batch.min(planned.len())).collect();
        readings.extend(read_chunk(policy, data, chunk)?);
    }
    let (mut by_step, mut lift_by, mut rest_by) =
        (BTreeMap::<i64, Sums>::new(), vec![Sums::default(); history], vec![Sums::default(); history]);
    for r in &readings {
        by_step.entry(r.offset).or_default().add(r);
        if r.offset == 0 {
            lift_by[r.frames - 1].add(r);
        }
        if r.rests {
            rest_by[r.frames - 1].add(r);
        }
    }
    let mut bottom = vec![(0, 0); probed];
    for r in readings.iter().filter(|r| r.rests || r.offset == 0) {
        bottom[r.trajectory].0 += usize::from(r.mode_lifts);
        bottom[r.trajectory].1 += 1;
    }
    let mut bottom_mode_lifts = [0; 3];
    for (lifted, queries) in bottom.into_iter().filter(|&(_, q)| q > 0) {
        bottom_mode_lifts[if lifted == 0 {
            0
        } else if lifted < queries {
            1
        } else {
            2
        }] += 1;
    }
    Ok(GripProbe {
        bottom_mode_lifts,
        trajectories: probed,
        skipped,
        by_step: by_step.into_iter().map(|(k, s)| (k, s.row())).collect(),
        lift_by_frames: lift_by.iter().map(Sums::row).collect(),
        rest_by_frames: rest_by.iter().map(Sums::row).collect(),
    })
}

/// Runs one batch of planned windows and reads each planned step: the head's output at the window position that
/// shows the step as its last frame.
fn read_chunk(policy: &TrainedPolicy, data: &PairDataset, chunk: Vec<Planned>) -> Result<Vec<Reading>> {
    let model = policy.policy.config();
    let trajectories: Vec<usize> = chunk.iter().map(|p| p.trajectory).collect();
    let (samples, reads): (Vec<Sample>, Vec<Vec<Read>>) = chunk.into_iter().map(|p| (p.sample, p.reads)).unzip();
    let b = Batch::from_samples(samples, model, data.height, data.width, Device::Cpu);
    let b = b.to_device(model, data.height, data.width, policy.vars.device());
    let out = tch::no_grad(|| policy.policy.forward_with_states(&b.context, &b.agent, &b.states, false));
    let steps = (model.agent_frames - 1) as i64;
    let on_cpu = |t: &Tensor| t.narrow(1, 0, steps).to_device(Device::Cpu).to_kind(Kind::Float);
    let params = MixtureParams {
        means: on_cpu(&out.actions.means),
        log_scales: on_cpu(&out.actions.log_scales),
        logits: on_cpu(&out.actions.logits),
    };
    let mode = mixture_mode(&params);
    // The lift threshold of every window position, from the expert's own height there ([B, T]).
    let mut thresholds = vec![1.0f32; reads.len() * steps as usize];
    for (w, window) in reads.iter().enumerate() {
        for r in window {
            thresholds[w * steps as usize + r.position] = normalised_z(r.z + LIFT) as f32;
        }
    }
    let thresholds = Tensor::from_slice(&thresholds).view([reads.len() as i64, steps]);
    let lift = mixture_above(&params, Z as i64, &thresholds);
    let closed =
        mixture_above(&params, GRIPPER as i64, &Tensor::zeros([reads.len() as i64, steps], (Kind::Float, Device::Cpu)));
    let mut readings = Vec::new();
    for (w, window) in reads.iter().enumerate() {
        for r in window {
            let (w, p) = (w as i64, r.position as i64);
            let mode_at = |d: usize| mode.double_value(&[w, p, d as i64]);
            let threshold = thresholds.double_value(&[w, p]);
            readings.push(Reading {
                trajectory: trajectories[w as usize],
                offset: r.offset,
                rests: r.rests,
                frames: r.position + 1,
                expert_lifts: r.expert_lifts,
                lift_probability: lift.double_value(&[w, p]),
                mode_lifts: mode_at(Z) > threshold,
                open_probability: 1.0 - closed.double_value(&[w, p]),
                mode_opens: mode_at(GRIPPER) <= 0.0,
            });
        }
    }
    Ok(readings)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn action(z: f32, gripper: f32) -> [f32; 8] {
        [0.6, 0.0, z, 1.0, 0.0, 1.0, 0.0, gripper]
    }

    #[test]
    fn the_close_is_the_first_closing_command_and_the_lift_the_first_rise_after_it() {
        // Descends open, closes at step 2, rests two steps, then targets 10 cm above: the lift is step 5. A target
        // only 3 cm above (step 1, still open) is no lift, nor is a rise before the close.
        let actions = [
            action(1.0, -1.0),
            action(0.88, -1.0),
            action(0.85, 1.0),
            action(0.85, 1.0),
            action(0.85, 1.0),
            action(0.95, 1.0),
        ];
        let eef = [
            [0.6, 0.0, 0.95],
            [0.6, 0.0, 0.9],
            [0.6, 0.0, 0.85],
            [0.6, 0.0, 0.85],
            [0.6, 0.0, 0.85],
            [0.6, 0.0, 0.85],
            [0.6, 0.0, 0.9],
        ];
        assert_eq!(close_and_lift(&actions, &eef), Some((2, 5)));
        assert_eq!(close_and_lift(&actions[..5], &eef), None, "no rise after the close");
        let never_closes: Vec<[f32; 8]> = actions.iter().map(|a| action(a[2], -1.0)).collect();
        assert_eq!(close_and_lift(&never_closes, &eef), None);
    }

    #[test]
    fn heights_map_into_the_action_range() {
        let [lo, hi] = ACTION_RANGES[Z];
        assert!((normalised_z(lo) + 1.0).abs() < 1e-12 && (normalised_z(hi) - 1.0).abs() < 1e-12);
        assert!(normalised_z((lo + hi) / 2.0).abs() < 1e-12);
    }
}
