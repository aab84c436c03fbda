//! The Slurm executor against a real (one-node) Slurm: `scripts/slurm-one-node.sh` starts one; CI sets
//! ONESHOT_REQUIRE_SLURM=1 so that a missing Slurm fails the test instead of skipping it.
use crate::helpers::{HANG_GUARD, latest_staged_checkpoint, wait_for};
use rusqlite::Connection;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::Duration;

const EXPERIMENT: &str = r#"name = "tiny_slurm"
[world]
visuals = "collision"
[world.image]
height = 32
width = 40
[collect]
tasks = [0]
[model]
backbone_width = 8
attention_inner = 16
embed_hidden = 32
[train]
steps = 4
batch_size = 2
val_interval = 2
val_batches = 1
[eval]
episodes = 2
horizon = 3
batch = 2
[grid]
sizes = [32]
seeds = [0]
references = ["random"]
"#;

fn slurm_up() -> bool {
    Command::new("sinfo").arg("-h").output().is_ok_and(|o| o.status.success())
}

/// Whether Slurm answers; where it does not, a test is skipped unless ONESHOT_REQUIRE_SLURM is set.
fn slurm_or_skip() -> bool {
    if slurm_up() {
        return true;
    }
    assert!(std::env::var_os("ONESHOT_REQUIRE_SLURM").is_none(), "Slurm is required here but `sinfo` fails");
    eprintln!("skipped: no Slurm on this machine (start one with scripts/slurm-one-node.sh)");
    false
}

/// A fresh folder holding the tiny experiment file, and its store path.
fn workspace(name: &str) -> (PathBuf, PathBuf, PathBuf) {
    let dir = std::env::temp_dir().join(format!("oneshot-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("tiny.toml");
    std::fs::write(&file, EXPERIMENT).unwrap();
    let store = dir.join("runs");
    (dir, file, store)
}

/// Runs `oneshot-lab COMMAND FILE --store STORE EXTRA...` (FILE left out where `file` is none).
fn oneshot(command: &str, file: Option<&Path>, store: &Path, extra: &[&str]) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_oneshot-lab"));
    cmd.arg(command);
    if let Some(f) = file {
        cmd.arg(f);
    }
    cmd.arg("--store").arg(store).args(extra).output().unwrap()
}

fn stdout(o: &Output) -> String {
    String::from_utf8_lossy(&o.stdout).into_owned()
}

#[test]
fn stages_run_as_slurm_jobs_and_failed_jobs_are_recorded() {
    if !slurm_or_skip() {
        return;
    }
    let (dir, file, store) = workspace("slurm");
    let run = |extra: &[&str]| oneshot("run", Some(&file), &store, &[&["--workers", "1"], extra].concat());
    let out = run(&["--slurm", "--jobs", "2"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stdout).contains("5 stages run"));
    let logs = std::fs::read_dir(store.join("logs")).unwrap().count();
    assert_eq!(logs, 5, "one Slurm log per stage");
    let db = Connection::open(store.join("oneshot.sqlite")).unwrap();
    let episodes: i64 = db.query_row("SELECT COUNT(*) FROM episodes", [], |r| r.get(0)).unwrap();
    assert_eq!(episodes, 4, "two evaluations of two episodes, recorded from the jobs' results");
    let curve: i64 = db.query_row("SELECT COUNT(*) FROM loss_curves", [], |r| r.get(0)).unwrap();
    assert!(curve >= 3);

    // The same store, run locally: everything is cached.
    let local = run(&[]);
    assert!(String::from_utf8_lossy(&local.stdout).contains("0 stages run, 5 cached"));

    // A job Slurm refuses fails its stage with the reason, and the run exits non-zero.
    let bad = run(&["--slurm", "--force", "random/eval", "--slurm-arg=--partition=nowhere"]);
    assert!(!bad.status.success());
    let text = String::from_utf8_lossy(&bad.stdout);
    assert!(text.contains("Slurm refused") && text.contains("nowhere"), "{text}");
    let failed: i64 = db.query_row("SELECT COUNT(*) FROM stages WHERE status = 'failed'", [], |r| r.get(0)).unwrap();
    assert_eq!(failed, 1);

    // The file's `[slurm.eval]` resources reach the evaluation jobs' sbatch, and no stage key: the collections
    // and the training stay cached.
    std::fs::write(&file, format!("{EXPERIMENT}[slurm.eval]\npartition = \"elsewhere\"\ntime = \"00:05:00\"\n"))
        .unwrap();
    let per_kind = run(&["--slurm", "--force", "random/eval"]);
    let text = String::from_utf8_lossy(&per_kind.stdout);
    assert!(!per_kind.status.success() && text.contains("Slurm refused") && text.contains("elsewhere"), "{text}");
    let plan = stdout(&oneshot("plan", Some(&file), &store, &[]));
    assert!(plan.contains("1 stages to run"), "only the failed evaluation is left to run: {plan}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Counts of the store's stages by status, after `status` has caught up with the queue.
fn caught_up(store: &Path) -> (String, i64, i64) {
    let status = oneshot("status", None, store, &[]);
    assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));
    let db = Connection::open(store.join("oneshot.sqlite")).unwrap();
    let count =
        |s: &str| -> i64 { db.query_row("SELECT COUNT(*) FROM stages WHERE status = ?1", [s], |r| r.get(0)).unwrap() };
    (stdout(&status), count("done"), count("failed"))
}

/// Calls `status` until `done` stages are done.
fn wait_until_done(store: &Path, done: i64) -> String {
    wait_for(HANG_GUARD, Duration::from_secs(2), || {
        let (text, n, _) = caught_up(store);
        if n == done { Ok(text) } else { Err(format!("{n} of {done} stages done: {text}")) }
    })
}

/// Calls `status` until `failed` stages have failed; returns its text.
fn wait_until_failed(store: &Path, failed: i64) -> String {
    wait_for(HANG_GUARD, Duration::from_secs(2), || {
        let (text, _, n) = caught_up(store);
        if n == failed { Ok(text) } else { Err(format!("{n} of {failed} stages failed: {text}")) }
    })
}

/// The Slurm job holding the running stage of `kind`.
fn job_of(store: &Path, kind: &str) -> String {
    let db = Connection::open(store.join("oneshot.sqlite")).unwrap();
    db.query_row(
        "SELECT a.pid FROM attempts a JOIN stages s ON s.key = a.stage_key \
         WHERE a.status = 'running' AND a.host = 'slurm' AND s.kind = ?1",
        [kind],
        |r| r.get::<_, i64>(0),
    )
    .unwrap()
    .to_string()
}

/// Waits until a training job has written a checkpoint into its staging folder.
fn wait_for_checkpoint(store: &Path) {
    wait_for(HANG_GUARD, Duration::from_millis(100), || {
        (latest_staged_checkpoint(store) > 0)
            .then_some(())
            .ok_or_else(|| "the training job never checkpointed".to_string())
    });
}

/// Every evaluation episode and collection metric of a store, keyed by stage, for comparing two stores.
fn results(store: &Path) -> Vec<String> {
    let db = Connection::open(store.join("oneshot.sqlite")).unwrap();
    let mut q = db
        .prepare(
            "SELECT eval_key || ' ' || idx || ' ' || task || ' ' || agent_seed || ' ' || demo_seed || ' ' || reached \
             || picked || placed || ' ' || steps FROM episodes \
             UNION ALL SELECT stage_key || ' ' || name || ' ' || value FROM metrics \
             WHERE stage_key IN (SELECT key FROM stages WHERE kind = 'collect') ORDER BY 1",
        )
        .unwrap();
    q.query_map([], |r| r.get(0)).unwrap().map(Result::unwrap).collect()
}

#[test]
fn detached_runs_chain_jobs_survive_a_killed_job_and_cancel_and_equal_a_local_run() {
    if !slurm_or_skip() {
        return;
    }
    let (dir, file, store) = workspace("slurm-detached");
    // Long enough training (100 steps, a checkpoint every 10) for its job to be killed while it runs.
    let longer = EXPERIMENT
        .replace("steps = 4\n", "steps = 100\ncheckpoint_interval = 10\n")
        .replace("val_interval = 2\n", "val_interval = 50\n");
    std::fs::write(&file, longer).unwrap();
    let detach = |extra: &[&str]| {
        let out = oneshot("run", Some(&file), &store, &[&["--workers", "1", "--slurm", "--detach"], extra].concat());
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        stdout(&out)
    };

    // Every stage is submitted at once, chained by dependencies; the command returns while the jobs run.
    let text = detach(&[]);
    assert!(text.contains("5 Slurm jobs submitted"), "{text}");

    // Slurm kills the running training job: its stage fails, and the evaluation waiting on it is cancelled.
    wait_for_checkpoint(&store);
    assert!(Command::new("scancel").arg(job_of(&store, "train")).status().unwrap().success());
    let text = wait_until_failed(&store, 2);
    assert!(text.contains("ended CANCELLED without results"), "{text}");
    assert!(text.contains("a job it depended on failed"), "{text}");

    // The next detached run resubmits exactly those two (training resumes from its checkpoint).
    let before = latest_staged_checkpoint(&store);
    let text = detach(&[]);
    assert!(text.contains("2 Slurm jobs submitted"), "{text}");

    // The cluster's warning before preemption or the time limit (here sent by hand, once the resubmitted training
    // has written a checkpoint of its own, so it is under way): the training writes a checkpoint at the step it is
    // at and its job ends; the next submission resumes from that step.
    wait_for(HANG_GUARD, Duration::from_millis(50), || {
        let latest = latest_staged_checkpoint(&store);
        (latest > before).then_some(()).ok_or_else(|| format!("the resubmitted training is at checkpoint {latest}"))
    });
    let job = job_of(&store, "train");
    let warned = Command::new("scancel").args(["--full", "--signal=USR1", &job]).status().unwrap();
    assert!(warned.success());
    let text = wait_until_failed(&store, 2);
    assert!(text.contains("stopped by SIGUSR1 at step"), "{text}");
    let text = detach(&[]);
    assert!(text.contains("2 Slurm jobs submitted"), "{text}");
    wait_until_done(&store, 5);
    let db = Connection::open(store.join("oneshot.sqlite")).unwrap();
    let train: String = db.query_row("SELECT artifact FROM stages WHERE kind = 'train'", [], |r| r.get(0)).unwrap();
    let info: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(store.join(train).join(oneshot_lab::train::FINAL_INFO)).unwrap())
            .unwrap();
    assert!(info["resumed_from"].as_u64().is_some_and(|s| s > 0), "{info}");

    // `cancel` stops an experiment's queued jobs and fails their stages; a detached run resubmits them.
    let text = detach(&["--force", "random/eval", "--slurm-arg=--begin=now+1hour"]);
    assert!(text.contains("1 Slurm jobs submitted"), "{text}");
    let job = job_of(&store, "eval");
    let out = oneshot("cancel", Some(&file), &store, &[]);
    assert!(stdout(&out).contains("1 Slurm jobs cancelled"), "{}", stdout(&out));
    let queue = Command::new("squeue").args(["--noheader", "--format=%T", "--jobs", &job]).output().unwrap();
    assert!(!stdout(&queue).contains("PENDING"), "job {job} still queued: {}", stdout(&queue));
    let (text, done, failed) = caught_up(&store);
    assert_eq!((done, failed), (4, 1), "{text}");
    assert!(text.contains("cancelled by `oneshot-lab cancel`"), "{text}");
    detach(&[]);
    wait_until_done(&store, 5);

    // A plain run on that store finds everything done and writes the report; the results equal a local run's.
    let out = oneshot("run", Some(&file), &store, &["--workers", "1"]);
    assert!(stdout(&out).contains("0 stages run, 5 cached"), "{}", stdout(&out));
    assert!(store.join("reports/tiny_slurm/index.md").is_file());
    let local = dir.join("local");
    let out = oneshot("run", Some(&file), &local, &["--workers", "1"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(results(&store), results(&local), "the detached store's results differ from a local run's");
    std::fs::remove_dir_all(&dir).unwrap();
}
