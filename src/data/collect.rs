//! Collection of expert trajectories in parallel, written atomically with a manifest of blake3 digests.
use super::collect_config::CollectConfig;
use super::manifest::{Manifest, ManifestEntry, TRAJECTORY_DIR};
use super::trajectory::{Trajectory, TrajectoryMeta};
use crate::sim::env::Env;
use crate::sim::rollout::run_expert_perturbed;
use anyhow::{Context, Result, bail};
use std::path::Path;
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};

/// One trajectory slot to fill.
#[derive(Clone, Copy)]
struct Slot {
    task: usize,
    index: usize,
}

/// Collects into `out` with `workers` threads. `out` must not exist; it appears only once complete.
pub fn collect(config: &CollectConfig, out: &Path, workers: usize, progress: bool) -> Result<Manifest> {
    config.validate()?;
    if out.exists() {
        bail!("output folder {} already exists", out.display());
    }
    let staging = crate::fsio::staging_sibling(out)?;
    crate::fsio::remove_dir_if_present(&staging)?;
    let manifest = collect_into(config, &staging, workers, progress)?;
    crate::fsio::publish_dir(&staging, out)?;
    Ok(manifest)
}

/// Collects into the folder `dir` (created if needed), which the caller publishes once this returns.
pub fn collect_into(config: &CollectConfig, dir: &Path, workers: usize, progress: bool) -> Result<Manifest> {
    config.validate()?;
    let traj_dir = dir.join(TRAJECTORY_DIR);
    std::fs::create_dir_all(&traj_dir).with_context(|| format!("creating {}", traj_dir.display()))?;

    let slots: Vec<Slot> = config
        .settings
        .tasks
        .iter()
        .flat_map(|&task| (0..config.per_task).map(move |index| Slot { task, index }))
        .collect();
    let bar = crate::progress::progress_bar(slots.len() as u64, progress, &format!("collect {}", config.robot));
    let next = AtomicUsize::new(0);
    let entries: Mutex<Vec<(usize, ManifestEntry)>> = Mutex::new(Vec::with_capacity(slots.len()));
    let workers = workers.clamp(1, slots.len());
    std::thread::scope(|scope| -> Result<()> {
        let handles: Vec<_> = (0..workers)
            .map(|_| {
                scope.spawn(|| -> Result<()> {
                    let mut env = Env::new(config.robot, &config.world, true)?;
                    loop {
                        let k = next.fetch_add(1, Ordering::Relaxed);
                        let Some(&slot) = slots.get(k) else { return Ok(()) };
                        let entry = collect_slot(config, &mut env, slot, &traj_dir)?;
                        entries.lock().expect("no worker panicked holding the lock").push((k, entry));
                        bar.inc(1);
                    }
                })
            })
            .collect();
        for h in handles {
            h.join().expect("collection worker panicked")?;
        }
        Ok(())
    })?;
    bar.finish_and_clear();

    let mut entries = entries.into_inner().expect("workers finished");
    entries.sort_by_key(|(k, _)| *k);
    let manifest = Manifest::new(config.clone(), entries.into_iter().map(|(_, e)| e).collect());
    manifest.save(dir)?;
    Ok(manifest)
}

/// Runs the expert on fresh layouts until it places the object, then writes the trajectory.
fn collect_slot(config: &CollectConfig, env: &mut Env, slot: Slot, dir: &Path) -> Result<ManifestEntry> {
    let c = &config.settings;
    for attempt in 0..c.max_attempts {
        let instance = config.instance(slot.task, slot.index, attempt)?;
        let seed = instance.seed;
        let episode = run_expert_perturbed(env, &instance, c.max_actions, true, c.action_noise)?;
        if !episode.milestones.placed {
            continue;
        }
        let meta = TrajectoryMeta {
            format_version: super::trajectory::FORMAT_VERSION,
            robot: config.robot,
            task: slot.task,
            instance_seed: seed,
            height: config.world.image.height,
            width: config.world.image.width,
            stages: episode.milestones,
        };
        let bytes = Trajectory::from_episode(meta, &episode, c.jpeg_quality)?.to_bytes()?;
        let file = format!("{TRAJECTORY_DIR}/task{:02}_{:04}.safetensors", slot.task, slot.index);
        std::fs::write(dir.parent().expect("trajectory dir has a parent").join(&file), &bytes)
            .with_context(|| format!("writing {file}"))?;
        return Ok(ManifestEntry {
            file,
            task: slot.task,
            index: slot.index,
            environment: config.environment(slot.task, slot.index),
            objects: config.library().then(|| instance.kinds.iter().map(|o| o.name().to_string()).collect()),
            instance_seed: seed,
            attempts: attempt + 1,
            steps: episode.steps.len(),
            bytes: bytes.len() as u64,
            blake3: blake3::hash(&bytes).to_hex().to_string(),
        });
    }
    bail!("expert failed {} attempts on task {} slot {}", c.max_attempts, slot.task, slot.index)
}
