//! The orchestrator against real (tiny) stages: caching, selective re-runs, interruption, concurrency, reports.
use crate::helpers::{HANG_GUARD, latest_staged_checkpoint, oneshot, scratch, wait_for};
use rusqlite::Connection;
use std::path::{Path, PathBuf};
use std::process::Output;
use std::time::Duration;

/// A tiny experiment: task 0 only, 32x40 frames of collision geometry (collected about four times faster than with
/// the visual meshes on Mesa: docs/benchmarks.md), a narrow network, a few steps, two short episodes.
fn experiment(seeds: &str, jpeg_quality: u8, steps: u32) -> String {
    format!(
        r#"name = "tiny"
[world]
visuals = "collision"
[world.image]
height = 32
width = 40
[collect]
tasks = [0]
jpeg_quality = {jpeg_quality}
[model]
backbone_width = 8
attention_inner = 16
embed_hidden = 32
[train]
steps = {steps}
batch_size = 2
val_interval = 2
val_batches = 1
checkpoint_interval = 20
[eval]
episodes = 2
horizon = 3
batch = 2
[variants.no_point]
train.loss.point = 0.0
[grid]
sizes = [32]
variants = ["full", "no_point"]
seeds = {seeds}
references = ["random"]
"#
    )
}

fn run(file: &Path, store: &Path) -> Output {
    let out = oneshot()
        .args(["run", file.to_str().unwrap(), "--store", store.to_str().unwrap(), "--workers", "1"])
        .output()
        .unwrap();
    assert!(out.status.success(), "run failed: {}", String::from_utf8_lossy(&out.stderr));
    out
}

/// Stage kinds executed by the run whose stdout is `out`, from its summary line and the attempts table.
fn executed(out: &Output) -> usize {
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text.lines().find(|l| l.contains("stages run")).expect("summary line");
    line.split(':').nth(1).unwrap().split_whitespace().next().unwrap().parse().unwrap()
}

fn db(store: &Path) -> Connection {
    Connection::open(store.join("oneshot.sqlite")).unwrap()
}

/// The running attempts `status --format json` lists for the store at `store`.
fn running_attempts(store: &Path) -> Vec<serde_json::Value> {
    let out = oneshot().args(["status", "--store", store.to_str().unwrap(), "--format", "json"]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let status: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    status["running"].as_array().unwrap().clone()
}

/// The two running trainings of the store at `store` as `status` lists them, once both show their progress.
fn both_trainings(store: &Path) -> Vec<serde_json::Value> {
    wait_for(HANG_GUARD, Duration::from_millis(100), || {
        let running = running_attempts(store);
        let shown = running.iter().filter(|r| r["kind"] == "train" && !r["training"].is_null()).count();
        (shown == 2).then(|| running.clone()).ok_or_else(|| format!("not both trainings shown yet: {running:?}"))
    })
}

fn count(conn: &Connection, sql: &str) -> i64 {
    conn.query_row(sql, [], |r| r.get(0)).unwrap()
}

#[test]
fn reruns_touch_exactly_what_changed_and_reports_match_the_store() {
    let dir = scratch("pipeline-incremental");
    let (file, store) = (dir.join("tiny.toml"), dir.join("runs"));
    std::fs::write(&file, experiment("[0]", 90, 4)).unwrap();
    // collect x2, train x2, eval x2, random eval.
    let first = run(&file, &store);
    assert_eq!(executed(&first), 7);
    let printed = String::from_utf8_lossy(&first.stdout);
    assert!(printed.contains("| random | 1/1 |"), "the run prints its Table 1: {printed}");
    assert_eq!(executed(&run(&file, &store)), 0, "an unchanged file runs nothing");

    // Report numbers equal a direct aggregation, and regenerating gives identical files.
    let report = store.join("reports/tiny");
    let table = std::fs::read_to_string(report.join("table1.csv")).unwrap();
    let conn = db(&store);
    let placed_random: f64 = conn
        .query_row(
            "SELECT AVG(e.placed) FROM episodes e JOIN cells c ON c.eval_key = e.eval_key WHERE c.cell = 'random'",
            [],
            |r| r.get(0),
        )
        .unwrap();
    let reached_full: f64 = conn
        .query_row(
            "SELECT AVG(e.reached) FROM episodes e JOIN cells c ON c.eval_key = e.eval_key WHERE c.cell = 'n32-full-s0'",
            [],
            |r| r.get(0),
        )
        .unwrap();
    let row = |label: &str| {
        table.lines().find(|l| l.starts_with(label)).unwrap().split(',').map(String::from).collect::<Vec<_>>()
    };
    let header: Vec<&str> = table.lines().next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    assert_eq!(row("random")[col("place")].parse::<f64>().unwrap(), placed_random);
    assert_eq!(row("full @ 32")[col("reach")].parse::<f64>().unwrap(), reached_full);
    let before: Vec<(PathBuf, Vec<u8>)> = files(&report);
    let out = oneshot().args(["report", file.to_str().unwrap(), "--store", store.to_str().unwrap()]).output().unwrap();
    assert!(out.status.success());
    assert_eq!(before, files(&report), "a regenerated report is byte-identical");
    // It prints the Table 1 it wrote.
    let table1 = std::fs::read_to_string(report.join("table1.md")).unwrap();
    assert!(String::from_utf8_lossy(&out.stdout).contains(&table1), "report printed no Table 1");
    assert!(before.iter().any(|(p, _)| p.ends_with("loss_curves.png")));
    // Success per task and per object: the store's episodes counted (task 0 only, the milk's).
    let (n, reached, picked, placed): (i64, i64, i64, i64) = conn
        .query_row(
            "SELECT COUNT(*), SUM(e.reached), SUM(e.picked), SUM(e.placed) FROM episodes e
             JOIN cells c ON c.eval_key = e.eval_key WHERE c.cell = 'random' AND e.task = 0",
            [],
            |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?)),
        )
        .unwrap();
    let tasks = std::fs::read_to_string(report.join("tasks.csv")).unwrap();
    assert!(tasks.lines().any(|l| l == format!("random,0,milk,0,{n},{reached},{picked},{placed}")), "{tasks}");
    let objects = std::fs::read_to_string(report.join("objects.md")).unwrap();
    let random = objects.lines().find(|l| l.starts_with("| random |")).expect("the random policy's row");
    assert!(random.ends_with(&format!("({n}) | none | none | none |")), "{objects}");

    // A new seed: only that seed's two train and two eval stages.
    std::fs::write(&file, experiment("[0, 1]", 90, 4)).unwrap();
    assert_eq!(executed(&run(&file, &store)), 4);
    // Replacing seed 1 by seed 2 re-runs exactly those cells' train and eval stages.
    std::fs::write(&file, experiment("[0, 2]", 90, 4)).unwrap();
    assert_eq!(executed(&run(&file, &store)), 4);

    // A collection setting: both collections and everything below them (4 cells x train + eval), not the random
    // reference.
    std::fs::write(&file, experiment("[0, 2]", 80, 4)).unwrap();
    assert_eq!(executed(&run(&file, &store)), 2 + 4 + 4);
    let conn = db(&store);
    assert_eq!(
        count(
            &conn,
            "SELECT COUNT(*) FROM attempts WHERE stage_key IN (SELECT eval_key FROM cells WHERE cell = 'random')"
        ),
        1
    );
    assert_eq!(count(&conn, "SELECT COUNT(*) FROM stages WHERE status = 'done' AND artifact IS NULL"), 0);

    // `why` explains the old collection against the new one.
    // Pretend the two new collections are not cached yet: the nearest cached stage of the new Panda collection is
    // the old Panda collection.
    conn.execute(
        "UPDATE stages SET status = 'planned' WHERE key IN
         (SELECT key FROM stages WHERE kind = 'collect' ORDER BY created_at DESC LIMIT 2)",
        [],
    )
    .unwrap();
    let new_collect: String = conn
        .query_row(
            "SELECT key FROM stages WHERE kind = 'collect' AND status = 'planned' AND inputs LIKE '%panda%'",
            [],
            |r| r.get(0),
        )
        .unwrap();
    let why = oneshot().args(["why", &new_collect[..10], "--store", store.to_str().unwrap()]).output().unwrap();
    let text = String::from_utf8_lossy(&why.stdout);
    assert!(text.contains("jpeg_quality: 90 (cached) -> 80 (this stage)"), "{text}");
    conn.execute("UPDATE stages SET status = 'done' WHERE status = 'planned' AND artifact IS NOT NULL", []).unwrap();

    // plan, status and query read the same store.
    let cli = |args: &[&str]| {
        let out = oneshot().args(args).args(["--store", store.to_str().unwrap()]).output().unwrap();
        assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    assert!(cli(&["plan", file.to_str().unwrap()]).contains("0 stages to run"));
    // plan's estimate of a training scales with its steps (seconds per step of the trainings done).
    let estimate = |steps: u32| -> f64 {
        let text = cli(&["plan", file.to_str().unwrap(), "--set", &format!("train.steps={steps}")]);
        let after = text.split("about ").nth(1).unwrap_or_else(|| panic!("no estimate in {text}"));
        after.split(' ').next().unwrap().parse().unwrap()
    };
    let (short, long) = (estimate(40), estimate(4000));
    assert!(long > 5.0 * short, "4,000 steps estimated at {long} s, 40 at {short} s");
    assert!(cli(&["status"]).contains("done"));
    let cells: serde_json::Value = serde_json::from_str(&cli(&["query", "cells", "--format", "json"])).unwrap();
    assert_eq!(cells.as_array().unwrap().len(), 5, "2 variants x 2 seeds + the random reference");
    let csv = cli(&["query", "SELECT COUNT(*) AS n FROM stages WHERE kind = 'collect'", "--format", "csv"]);
    assert_eq!(csv.trim(), "n\n4");

    // A report of seed 2 alone: the full model's row counts seed 2's episodes only (one seed of one), beside the
    // pooled report, which has both; the reference is in both.
    cli(&["report", file.to_str().unwrap(), "--seed", "2"]);
    let conn = db(&store);
    let reached_of = |cells: &str| -> f64 {
        let sql = format!(
            "SELECT AVG(e.reached) FROM episodes e JOIN cells c ON c.eval_key = e.eval_key WHERE c.cell IN ({cells})"
        );
        conn.query_row(&sql, [], |r| r.get(0)).unwrap()
    };
    for (folder, cells, seeds) in
        [("tiny@seed-2", "'n32-full-s2'", "1,1"), ("tiny", "'n32-full-s0', 'n32-full-s2'", "2,2")]
    {
        let table = std::fs::read_to_string(store.join("reports").join(folder).join("table1.csv")).unwrap();
        let full = table.lines().find(|l| l.starts_with("full @ 32,")).unwrap().split(',').collect::<Vec<_>>();
        assert_eq!(full[col("seeds_done")..=col("seeds_total")].join(","), seeds, "{folder}: {table}");
        let reach: f64 = full[col("reach")].parse().unwrap();
        assert!((reach - reached_of(cells)).abs() < 1e-4, "{folder}: {reach} against {}", reached_of(cells));
        assert!(table.lines().any(|l| l.starts_with("random,")), "{folder}: {table}");
    }

    // gc lists the artifacts of the replaced stages (the old collections and everything trained on them), deletes
    // them only when asked, and the current experiment stays fully cached.
    let listed = cli(&["gc", file.to_str().unwrap()]);
    let unused: Vec<&str> = listed.lines().filter(|l| l.contains("/artifacts/")).collect();
    // Old collections (2); train and eval of seeds 0 and 2 on them and of the dropped seed 1 (3 x 2 x 2).
    assert_eq!(unused.len(), 2 + 12, "{listed}");
    assert!(unused.iter().all(|p| std::path::Path::new(p).exists()), "a dry run deletes nothing");
    cli(&["gc", file.to_str().unwrap(), "--delete"]);
    assert!(unused.iter().all(|p| !std::path::Path::new(p.trim_start_matches("removed ")).exists()));
    assert_eq!(executed(&run(&file, &store)), 0);
    std::fs::remove_dir_all(&dir).unwrap();
}

fn files(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut v: Vec<(PathBuf, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .map(|p| (p.clone(), std::fs::read(&p).unwrap()))
        .collect();
    v.sort();
    v
}

#[test]
fn a_killed_run_leaves_nothing_falsely_complete_and_the_next_run_resumes() {
    let dir = scratch("pipeline-kill");
    let (file, store) = (dir.join("tiny.toml"), dir.join("runs"));
    std::fs::write(&file, experiment("[0]", 90, 400)).unwrap();
    let args =
        ["run", file.to_str().unwrap(), "--store", store.to_str().unwrap(), "--workers", "1", "--only", "n32-full-s0"];
    let mut child =
        oneshot().args(args).stdout(std::process::Stdio::null()).stderr(std::process::Stdio::null()).spawn().unwrap();
    // Wait until training has written a checkpoint, then kill -9.
    wait_for(HANG_GUARD, Duration::from_millis(100), || {
        assert!(child.try_wait().unwrap().is_none(), "run ended before it could be killed");
        (latest_staged_checkpoint(&store) > 0).then_some(()).ok_or_else(|| "training never checkpointed".to_string())
    });
    child.kill().unwrap();
    child.wait().unwrap();
    let conn = db(&store);
    assert_eq!(count(&conn, "SELECT COUNT(*) FROM stages WHERE kind = 'train' AND status = 'done'"), 0);

    let out = oneshot().args(args).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let conn = db(&store);
    let train_key: String =
        conn.query_row("SELECT train_key FROM cells WHERE cell = 'n32-full-s0'", [], |r| r.get(0)).unwrap_or_default();
    let train_key = if train_key.is_empty() {
        conn.query_row("SELECT key FROM stages WHERE kind = 'train' AND status = 'done'", [], |r| r.get(0)).unwrap()
    } else {
        train_key
    };
    let attempts: Vec<(String, Option<String>)> = conn
        .prepare("SELECT status, error FROM attempts WHERE stage_key = ?1 ORDER BY id")
        .unwrap()
        .query_map([&train_key], |r| Ok((r.get(0)?, r.get(1)?)))
        .unwrap()
        .map(Result::unwrap)
        .collect();
    assert_eq!(attempts.len(), 2, "{attempts:?}");
    assert_eq!(attempts[0].0, "failed");
    assert!(attempts[0].1.as_deref().is_some_and(|e| e.contains("interrupted")), "{attempts:?}");
    assert_eq!(attempts[1].0, "done");
    let artifact: String =
        conn.query_row("SELECT artifact FROM stages WHERE key = ?1", [&train_key], |r| r.get(0)).unwrap();
    let info = std::fs::read_to_string(store.join(&artifact).join("model.json")).unwrap();
    let summary: serde_json::Value = serde_json::from_str(&info).unwrap();
    assert!(
        summary["resumed_from"].as_u64().is_some_and(|s| s >= 20),
        "training resumed from its checkpoint: {summary}"
    );
    assert_eq!(count(&conn, "SELECT COUNT(*) FROM stages WHERE status = 'running'"), 0);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Blake3 of every weights file of every finished train stage of the store at `store`, by stage key and file.
fn trained_weights(store: &Path) -> Vec<(String, String, String)> {
    let conn = db(store);
    let stages: Vec<(String, String)> = conn
        .prepare("SELECT key, artifact FROM stages WHERE kind = 'train' AND status = 'done' ORDER BY key")
        .unwrap()
        .query_map([], |r| Ok((r.get(0)?, r.get(1)?)))
        .unwrap()
        .map(Result::unwrap)
        .collect();
    let mut out = Vec::new();
    for (key, artifact) in stages {
        let digests: serde_json::Value =
            serde_json::from_slice(&std::fs::read(store.join(artifact).join("digests.json")).unwrap()).unwrap();
        for f in digests.as_array().expect("a list of files") {
            let path = f["path"].as_str().unwrap();
            if path.ends_with(".safetensors") {
                out.push((key.clone(), path.to_string(), f["blake3"].as_str().unwrap().to_string()));
            }
        }
    }
    out
}

/// Every stored episode of the store at `store`, in order.
fn stored_episodes(store: &Path) -> Vec<(String, i64, i64, i64, i64, Option<f64>)> {
    db(store)
        .prepare("SELECT eval_key, idx, reached, picked, steps, close_x FROM episodes ORDER BY eval_key, idx")
        .unwrap()
        .query_map([], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?, r.get(5)?)))
        .unwrap()
        .map(Result::unwrap)
        .collect()
}

#[test]
fn concurrent_stages_give_the_results_they_give_one_at_a_time() {
    // Stages that shared one process drew dropout masks and sampled actions from one libtorch generator, so two
    // trainings side by side came out different from the same trainings one after the other, under the same keys.
    let dir = scratch("pipeline-concurrent");
    let file = dir.join("tiny.toml");
    std::fs::write(&file, experiment("[0, 1]", 90, 20)).unwrap();
    let (alone, beside) = (dir.join("alone"), dir.join("beside"));
    run(&file, &alone);
    let out = oneshot()
        .args(["run", file.to_str().unwrap(), "--store", beside.to_str().unwrap(), "--workers", "1", "--jobs", "2"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(executed(&out), 11, "2 collections, 4 trainings, 4 evaluations and the random policy's");
    let weights = trained_weights(&alone);
    assert_eq!(weights.len(), 4 * 3, "four trainings, each with its weights, its checkpoint and its optimiser state");
    assert_eq!(weights, trained_weights(&beside));
    let episodes = stored_episodes(&alone);
    assert_eq!(episodes.len(), 5 * 2);
    assert_eq!(episodes, stored_episodes(&beside));
    // A failing stage's process reports its error to the run, which records it.
    let out = oneshot()
        .args(["run", file.to_str().unwrap(), "--store", beside.to_str().unwrap(), "--jobs", "2"])
        .args(["--set", "eval.horizon=4", "--set", "eval.device=\"cuda:99\"", "--only", "n32-full-*"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("cuda"), "{err}");
    let conn = db(&beside);
    let error: String = conn
        .query_row("SELECT error FROM attempts WHERE status = 'failed' ORDER BY id DESC LIMIT 1", [], |r| r.get(0))
        .unwrap();
    assert!(error.contains("cuda"), "{error}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_stopped_or_killed_concurrent_run_stops_its_stage_processes() {
    let dir = scratch("pipeline-kill-concurrent");
    let (file, store) = (dir.join("tiny.toml"), dir.join("runs"));
    std::fs::write(&file, experiment("[0, 1]", 90, 400)).unwrap();
    let args = ["run", file.to_str().unwrap(), "--store", store.to_str().unwrap(), "--workers", "1", "--jobs", "2"];
    // One libtorch thread per stage process, as the guide runs two stages side by side: two processes of two
    // spinning threads each on a 2-core machine took this test's last run from minutes to a quarter of an hour.
    let start = || {
        oneshot()
            .env("OMP_NUM_THREADS", "1")
            .args(args)
            .args(["--only", "n32-full-*"])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap()
    };
    let stage_processes = || -> Vec<u32> {
        std::fs::read_dir("/proc")
            .unwrap()
            .filter_map(|e| e.ok()?.file_name().to_str()?.parse::<u32>().ok())
            .filter(|pid| {
                let line = std::fs::read(format!("/proc/{pid}/cmdline")).unwrap_or_default();
                let line = String::from_utf8_lossy(&line);
                line.contains("run-stage") && line.contains(store.to_str().unwrap())
            })
            .collect()
    };
    let wait_for_training = |child: &mut std::process::Child, after: u64| {
        wait_for(HANG_GUARD, Duration::from_millis(100), || {
            assert!(child.try_wait().unwrap().is_none(), "run ended before it could be stopped");
            let latest = latest_staged_checkpoint(&store);
            (latest > after).then_some(()).ok_or_else(|| format!("the latest checkpoint is at step {latest}"))
        })
    };

    // SIGTERM to the run (what Slurm sends at a time limit): it relays the signal, and both trainings checkpoint
    // and stop, as they do in one process.
    let mut child = start();
    wait_for_training(&mut child, 0);
    assert_eq!(stage_processes().len(), 2, "the trainings run in processes of their own");
    // `status` follows both trainings from their staging folders: fresh starts here.
    for attempt in both_trainings(&store) {
        let progress = &attempt["training"];
        assert_eq!((progress["steps"].as_u64(), progress["resumed_from"].as_u64()), (Some(400), Some(0)), "{attempt}");
    }
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let stopped = child.wait_with_output().unwrap();
    assert!(!stopped.status.success());
    let conn = db(&store);
    let errors: Vec<(String, String)> = conn
        .prepare("SELECT s.key, a.error FROM attempts a JOIN stages s ON s.key = a.stage_key WHERE s.kind = 'train'")
        .unwrap()
        .query_map([], |r| Ok((r.get(0)?, r.get(1)?)))
        .unwrap()
        .map(Result::unwrap)
        .collect();
    assert_eq!(errors.len(), 2, "{errors:?}");
    assert!(errors.iter().all(|(_, e)| e.contains("stopped by SIGTERM at step")), "{errors:?}");
    // The step each training stopped and checkpointed at, by key.
    let stopped_at: std::collections::HashMap<String, u64> = errors
        .iter()
        .map(|(key, e)| {
            let step = e.split("at step ").nth(1).and_then(|s| s.split_whitespace().next()).unwrap();
            (key.clone(), step.parse().unwrap())
        })
        .collect();
    assert!(stage_processes().is_empty());

    // kill -9 of the run: its stage processes notice and end.
    let before = latest_staged_checkpoint(&store);
    let mut child = start();
    wait_for_training(&mut child, before);
    // Resumed, each from the checkpoint its stopped attempt wrote: `status` counts its pace from there.
    for attempt in &both_trainings(&store) {
        let progress = &attempt["training"];
        let (step, resumed) = (progress["step"].as_u64().unwrap(), progress["resumed_from"].as_u64().unwrap());
        let key = attempt["key"].as_str().unwrap();
        assert!(resumed == stopped_at[key] && resumed > 0 && step >= resumed, "{attempt}: {stopped_at:?}");
    }
    child.kill().unwrap();
    child.wait().unwrap();
    wait_for(Duration::from_secs(30), Duration::from_millis(100), || {
        let left = stage_processes();
        left.is_empty().then_some(()).ok_or_else(|| format!("stage processes outlived their run: {left:?}"))
    });

    // The next run resumes both trainings from their checkpoints and finishes.
    let out = oneshot().env("OMP_NUM_THREADS", "1").args(args).args(["--only", "n32-full-*"]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(count(&conn, "SELECT COUNT(*) FROM stages WHERE kind = 'train' AND status = 'done'"), 2);
    assert_eq!(count(&conn, "SELECT COUNT(*) FROM stages WHERE status = 'running'"), 0);
    for artifact in conn
        .prepare("SELECT artifact FROM stages WHERE kind = 'train'")
        .unwrap()
        .query_map([], |r| r.get::<_, String>(0))
        .unwrap()
        .map(Result::unwrap)
    {
        let info = std::fs::read_to_string(store.join(&artifact).join("model.json")).unwrap();
        let summary: serde_json::Value = serde_json::from_str(&info).unwrap();
        assert!(summary["resumed_from"].as_u64().unwrap() >= 20, "resumed from a checkpoint: {summary}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The key and artifact of the store's one finished pretrain stage, checking that it recorded `metric` as a
/// held-out error in metres.
fn finished_pretrain(conn: &Connection, metric: &str) -> (String, String) {
    let (pretrain, artifact): (String, String) = conn
        .query_row("SELECT key, artifact FROM stages WHERE kind = 'pretrain' AND status = 'done'", [], |r| {
            Ok((r.get(0)?, r.get(1)?))
        })
        .unwrap();
    let held_out: f64 = conn
        .query_row("SELECT value FROM metrics WHERE stage_key = ?1 AND name = ?2", [&pretrain, metric], |r| r.get(0))
        .unwrap();
    assert!(held_out > 0.0 && held_out < 1.0, "{metric}: a held-out error in metres: {held_out}");
    (pretrain, artifact)
}

/// The tiny experiment with a `pretrained` variant whose trunk a pretrain stage of `pretrain_steps` trains; the
/// trunk is frozen, so the trained policy's trunk weights must be the pretrained ones.
fn pretrained_experiment(seeds: &str, pretrain_steps: u32) -> String {
    experiment(seeds, 90, 4).replace(r#"variants = ["full", "no_point"]"#, r#"variants = ["full", "pretrained"]"#)
        + &format!(
            "[variants.pretrained]\npretrain = {{ steps = {pretrain_steps}, batch = 4 }}\nmodel.freeze_backbone = true\n"
        )
}

#[test]
fn a_pretrain_section_trains_the_trunk_once_per_seed_and_training_starts_from_it() {
    let dir = scratch("pipeline-pretrain");
    let (file, store) = (dir.join("tiny.toml"), dir.join("runs"));
    std::fs::write(&file, pretrained_experiment("[0]", 6)).unwrap();
    // collect x2, pretrain, train x2, eval x2, random eval.
    assert_eq!(executed(&run(&file, &store)), 8);
    let conn = db(&store);
    let (pretrain, artifact) = finished_pretrain(&conn, "trunk_held_out_error_x");
    let (train, upstream, train_artifact): (String, String, String) = conn
        .query_row(
            "SELECT s.key, s.upstream, s.artifact FROM stages s JOIN cells c ON c.train_key = s.key \
             WHERE c.cell = 'n32-pretrained-s0'",
            [],
            |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?)),
        )
        .unwrap();
    assert!(upstream.contains(&pretrain), "the train stage {train} is downstream of the pretraining: {upstream}");
    // The frozen trunk the policy trained with is, tensor for tensor, the pretrained one (convolutions and
    // batch-norm scales; the running statistics follow the data).
    let read = |p: PathBuf| -> std::collections::HashMap<String, tch::Tensor> {
        tch::Tensor::read_safetensors(&p).unwrap().into_iter().collect()
    };
    let trunk = read(store.join(&artifact).join("trunk.safetensors"));
    let policy = read(store.join(&train_artifact).join("model.safetensors"));
    let learned: Vec<&String> = trunk.keys().filter(|n| n.ends_with("weight") || n.ends_with("bias")).collect();
    assert!(learned.len() > 10 && learned.iter().any(|n| n.as_str() == "conv1.weight"), "{learned:?}");
    for name in learned {
        assert!(trunk[name].equal(&policy[&format!("backbone.{name}")]), "backbone.{name} is not the pretrained one");
    }

    // Another seed pretrains its own trunk; changing the pretraining re-runs that cell's pretrain, train and
    // eval stages only.
    std::fs::write(&file, pretrained_experiment("[0, 1]", 6)).unwrap();
    assert_eq!(executed(&run(&file, &store)), 1 + 2 + 2);
    std::fs::write(&file, pretrained_experiment("[0, 1]", 8)).unwrap();
    assert_eq!(executed(&run(&file, &store)), 2 * 3);
    assert_eq!(count(&db(&store), "SELECT COUNT(*) FROM stages WHERE kind = 'pretrain' AND status = 'done'"), 4);

    // A long pretraining shows its phase, step and held-out error in `status` while it runs.
    std::fs::write(&file, pretrained_experiment("[0]", 1_000_000)).unwrap();
    let mut child = oneshot()
        .args(["run", file.to_str().unwrap(), "--store", store.to_str().unwrap(), "--workers", "1"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let progress = wait_for(HANG_GUARD, Duration::from_millis(200), || {
        assert!(child.try_wait().unwrap().is_none(), "the run ended during a million-step pretraining");
        let running = running_attempts(&store);
        let pretraining = running.iter().map(|r| &r["pretraining"]).find(|p| !p.is_null()).cloned();
        pretraining.ok_or_else(|| format!("no pretraining progress yet: {running:?}"))
    });
    assert_eq!(progress["phase"], "trunk", "{progress}");
    assert_eq!((progress["steps"].as_u64(), progress["total"].as_u64()), (Some(1_000_000), Some(1_000_000)));
    assert!(progress["held_out"].as_array().unwrap().iter().all(|e| e.as_f64().is_some_and(|e| e > 0.0)));
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    child.wait().unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_pretrained_object_attention_is_where_the_policys_attention_starts() {
    let dir = scratch("pipeline-pretrain-attention");
    let (file, store) = (dir.join("tiny.toml"), dir.join("runs"));
    let attending = "[variants.attending]\npretrain = { steps = 4, batch = 4, object_attention_steps = 4 }\n\
        model.object_attention = true\nmodel.object_attention_input = \"trunk\"\n\
        model.object_attention_query = \"task_head\"\nmodel.task_head = true\ntrain.lr = 1e-9\n";
    let body = experiment("[0]", 90, 4).replace(r#"variants = ["full", "no_point"]"#, r#"variants = ["attending"]"#);
    std::fs::write(&file, body.clone() + attending).unwrap();
    run(&file, &store);
    let conn = db(&store);
    let (pretrain, artifact) = finished_pretrain(&conn, "attention_held_out_error_x");
    // Each phase's curve is kept in the artifact, its last point the error the store recorded.
    for (file, metric) in
        [("trunk_curve.jsonl", "trunk_held_out_error_x"), ("attention_curve.jsonl", "attention_held_out_error_x")]
    {
        let curve = oneshot_lab::train::pretrain::read_curve(&store.join(&artifact).join(file)).unwrap();
        let steps: Vec<u64> = curve.iter().map(|p| p.step).collect();
        assert_eq!(steps, [0, 1, 2, 3, 4], "{file}");
        let recorded: f64 = conn
            .query_row("SELECT value FROM metrics WHERE stage_key = ?1 AND name = ?2", [&pretrain, metric], |r| {
                r.get(0)
            })
            .unwrap();
        assert_eq!(curve[4].held_out[0], recorded, "{file}");
    }
    let train_artifact: String = conn
        .query_row("SELECT artifact FROM stages WHERE kind = 'train' AND status = 'done'", [], |r| r.get(0))
        .unwrap();
    let read = |p: PathBuf| -> std::collections::HashMap<String, tch::Tensor> {
        tch::Tensor::read_safetensors(&p).unwrap().into_iter().collect()
    };
    let attention = read(store.join(&artifact).join("object_attention.safetensors"));
    let policy = read(store.join(&train_artifact).join("model.safetensors"));
    // Sixteen task entries feed the query; at a learning rate of 1e-9 the policy's attention is still the
    // pretrained one.
    assert_eq!(attention["object_attention.query.weight"].size()[1], 16);
    assert_eq!(attention.len(), 2, "{:?}", attention.keys());
    for (name, weights) in &attention {
        let drift = (weights - &policy[name]).abs().max().double_value(&[]);
        assert!(drift < 1e-5, "{name} moved {drift} from the pretrained weights");
    }

    // Without an attention queried by task the setting is refused, naming it.
    let plain = attending
        .replace("model.object_attention = true\n", "")
        .replace("model.object_attention_input = \"trunk\"\nmodel.object_attention_query = \"task_head\"\n", "");
    std::fs::write(&file, body + &plain).unwrap();
    let out = oneshot().args(["plan", file.to_str().unwrap(), "--store", store.to_str().unwrap()]).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("pretrain.object_attention_steps"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn two_concurrent_runs_execute_each_stage_once() {
    let dir = scratch("pipeline-concurrent");
    let (file, store) = (dir.join("tiny.toml"), dir.join("runs"));
    std::fs::write(&file, experiment("[0]", 90, 4)).unwrap();
    let spawn = || {
        oneshot()
            .args(["run", file.to_str().unwrap(), "--store", store.to_str().unwrap(), "--workers", "1"])
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap()
    };
    let (a, b) = (spawn(), spawn());
    let (a, b) = (a.wait_with_output().unwrap(), b.wait_with_output().unwrap());
    assert!(a.status.success(), "{}", String::from_utf8_lossy(&a.stderr));
    assert!(b.status.success(), "{}", String::from_utf8_lossy(&b.stderr));
    assert_eq!(executed(&a) + executed(&b), 7);
    let conn = db(&store);
    assert_eq!(count(&conn, "SELECT COUNT(*) FROM attempts"), 7);
    assert_eq!(count(&conn, "SELECT COUNT(*) FROM stages WHERE status = 'done'"), 7);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn malformed_experiment_files_name_file_line_and_key() {
    let dir = scratch("pipeline-malformed");
    let cases = [
        ("[train]\nsteps = 10\n\nlearnin_rate = 0.1\n", &["bad.toml", "line 4", "learnin_rate"][..]),
        ("[grid]\nsizes = [100]\n", &["bad.toml", "grid.sizes", "100"][..]),
        (
            "[collect]\ntasks = [0, 1, 2]\n[grid]\nsizes = [32]\n",
            &["bad.toml", "grid.sizes", "32", "collect.tasks"][..],
        ),
        ("[collect]\ntasks = [3, 5, 3]\n", &["bad.toml", "collect.tasks", "task 3 twice"][..]),
        ("[grid]\nvariants = [\"full\", \"nope\"]\n", &["bad.toml", "nope"][..]),
        ("[variants.x]\ntrain.lr = -1.0\n[grid]\nvariants = [\"x\"]\n", &["bad.toml", "variant `x`", "train.lr"][..]),
        ("[variants.x]\ntrain.los.inverse = 0.0\n[grid]\nvariants = [\"x\"]\n", &["bad.toml", "line 2", "los"][..]),
        ("[eval]\nepisodes = \"many\"\n", &["bad.toml", "line 2", "episodes"][..]),
        (
            "[variants.x]\nmodel.architecture = \"hypernet\"\n[grid]\nvariants = [\"x\"]\n",
            &["bad.toml", "variant `x`", "hypernet", "transformer, temporal_conv"][..],
        ),
        ("[train]\nlr = 0.1\nseed = 3\n", &["bad.toml", "line 3", "train.seed", "grid.seeds"][..]),
        ("[variants.s]\ntrain.seed = 3\n[grid]\nvariants = [\"s\"]\n", &["bad.toml", "variant `s`", "train.seed"][..]),
        ("[eval]\nhistory_frames = 7\n", &["bad.toml", "eval.history_frames = 7", "agent_frames"][..]),
        ("[collect]\ntasks = [0, 1]\n[eval]\ntasks = [3]\n", &["bad.toml", "eval.tasks", "task 3"][..]),
        (
            "[train]\ncheckpoint_interval = 10\n[eval]\ncheckpoints = [15]\n",
            &["bad.toml", "eval.checkpoints", "15"][..],
        ),
        ("[world]\nagent_yaw = \"object_yaw\"\n", &["bad.toml", "eval.fixed_rotation", "agent_yaw"][..]),
        ("[world]\nagent_yaw = \"sideways\"\n", &["bad.toml", "sideways"][..]),
        ("[experiment]\nx = 1\n", &["bad.toml", "line 1", "key `experiment`"][..]),
        ("[grid]\nseeds = [0.5]\n", &["bad.toml", "line 2", "key `grid.seeds`"][..]),
        ("[grid]\nreferences = [\"oracle\"]\n", &["bad.toml", "line 2", "key `grid.references`", "oracle"][..]),
        ("[collect]\naction_noise = nan\n", &["bad.toml", "collect.action_noise", "not a finite number"][..]),
        ("[variants.x]\nmodel.dropout = inf\n", &["bad.toml", "variants.x.model.dropout", "finite"][..]),
        ("[grid]\nsizes = [2000000000000]\n", &["bad.toml", "grid.sizes", "2000000000000", "100000"][..]),
    ];
    for (text, needles) in cases {
        let path = dir.join("bad.toml");
        std::fs::write(&path, text).unwrap();
        let out = oneshot()
            .args(["plan", path.to_str().unwrap(), "--store", dir.join("runs").to_str().unwrap()])
            .output()
            .unwrap();
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        for n in needles {
            assert!(err.contains(n), "{text:?}: missing {n:?} in {err}");
        }
    }
    let store = dir.join("runs");
    let out = oneshot()
        .args(["plan", "experiments/smoke.toml", "--profile", "gpu", "--store", store.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&out.stderr).contains("no profile `gpu`"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_byte_changed_in_any_artifact_is_caught_before_use_and_the_stage_recomputed() {
    let dir = scratch("pipeline-integrity");
    let (file, store) = (dir.join("tiny.toml"), dir.join("runs"));
    std::fs::write(&file, pretrained_experiment("[0]", 4)).unwrap();
    assert_eq!(executed(&run(&file, &store)), 8);
    let conn = db(&store);
    // One stage of each kind, and a file of its artifact that a later stage or the report reads.
    for (kind, name) in [
        ("collect", "manifest.json"),
        ("pretrain", "trunk.safetensors"),
        ("train", "model.safetensors"),
        ("eval", "summary.json"),
    ] {
        let (key, artifact): (String, String) = conn
            .query_row(
                "SELECT key, artifact FROM stages WHERE kind = ?1 AND status = 'done' ORDER BY key LIMIT 1",
                [kind],
                |r| Ok((r.get(0)?, r.get(1)?)),
            )
            .unwrap();
        let artifact = store.join(artifact);
        let target = if kind == "collect" {
            // A trajectory file, changed in place at the same size (only a truncation was caught before).
            let dir = Path::new(&artifact).join("trajectories");
            std::fs::read_dir(&dir).unwrap().next().unwrap().unwrap().path()
        } else {
            Path::new(&artifact).join(name)
        };
        assert!(target.is_file(), "{}", target.display());
        let mut bytes = std::fs::read(&target).unwrap();
        let at = bytes.len() / 2;
        bytes[at] ^= 0x55;
        std::fs::write(&target, &bytes).unwrap();

        // plan and a dry run agree that it is no longer cached, and say why.
        let plan = oneshot().args(["plan", file.to_str().unwrap(), "--store", store.to_str().unwrap()]).output();
        let plan = String::from_utf8_lossy(&plan.unwrap().stdout).into_owned();
        assert!(plan.contains(&format!("failed {}", &key[..12])), "{kind}: {plan}");
        let out = run(&file, &store);
        let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
        assert_eq!(executed(&out), 1, "{kind}: only the damaged stage runs again (its result is the same):\n{text}");
        let status: String = conn.query_row("SELECT status FROM stages WHERE key = ?1", [&key], |r| r.get(0)).unwrap();
        assert_eq!(status, "done", "{kind}");
        let error: String = conn
            .query_row(
                "SELECT error FROM attempts WHERE stage_key = ?1 AND status = 'failed' ORDER BY id DESC LIMIT 1",
                [&key],
                |r| r.get(0),
            )
            .unwrap();
        assert!(error.contains("artifact damaged") && error.contains("differs"), "{kind}: {error}");
    }

    // Artifact paths are recorded relative to the store, so a moved store needs nothing of its old place; paths
    // recorded the old way (relative to where `run` ran) are read as the store's own.
    let recorded: String =
        conn.query_row("SELECT artifact FROM stages WHERE kind = 'train' LIMIT 1", [], |r| r.get(0)).unwrap();
    assert!(recorded.starts_with("artifacts/train/"), "{recorded}");
    // A store of that time: old paths, and no schema version recorded (0).
    conn.execute("UPDATE stages SET artifact = 'elsewhere/runs/' || artifact WHERE kind = 'eval'", []).unwrap();
    conn.pragma_update(None, "user_version", 0).unwrap();
    drop(conn);
    let moved = dir.join("moved");
    std::fs::rename(&store, &moved).unwrap();
    assert_eq!(executed(&run(&file, &moved)), 0, "the moved store is fully cached");
    let recorded: String =
        db(&moved).query_row("SELECT artifact FROM stages WHERE kind = 'eval' LIMIT 1", [], |r| r.get(0)).unwrap();
    assert!(recorded.starts_with("artifacts/eval/"), "{recorded}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_multi_object_experiment_runs_in_library_environments_and_reports_the_wrong_bin() {
    let dir = scratch("pipeline-multi-object");
    let (file, store) = (dir.join("objects.toml"), dir.join("runs"));
    let text = r#"name = "objects"
[world]
image = { height = 32, width = 40 }
visuals = "collision"
objects = "library"
close_on_arrival = true
[collect]
tasks = [0, 5]
[model]
backbone_width = 8
attention_inner = 16
embed_hidden = 32
[train]
steps = 2
batch_size = 2
val_interval = 2
val_batches = 1
[eval]
episodes = 4
horizon = 80
batch = 4
tasks = [0, 5]
traces = true
[grid]
sizes = [8]
references = ["expert"]
"#;
    std::fs::write(&file, text).unwrap();
    run(&file, &store);
    let conn = db(&store);
    // Two environments of two instances per task and robot; every episode recorded whether it ended in the wrong bin.
    assert_eq!(count(&conn, "SELECT COUNT(*) FROM episodes WHERE wrong_bin IS NULL"), 0);
    assert_eq!(count(&conn, "SELECT COUNT(*) FROM episodes"), 8);
    let inputs: String =
        conn.query_row("SELECT inputs FROM stages WHERE kind = 'collect' LIMIT 1", [], |r| r.get(0)).unwrap();
    assert!(inputs.contains("\"environment_instances\":2"), "{inputs}");
    let artifact: String = conn
        .query_row(
            "SELECT s.artifact FROM stages s JOIN cells c ON c.eval_key = s.key WHERE c.cell = 'expert'",
            [],
            |r| r.get(0),
        )
        .unwrap();
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(store.join(artifact).join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["wrong_bin"]["value"], 0.0, "{summary}");
    let table = std::fs::read_to_string(store.join("reports/objects/multi_object.md")).unwrap();
    assert!(table.contains("wrong bin % [95% CI]") && table.contains("paper pick %"), "{table}");
    let expert = table.lines().find(|l| l.starts_with("| expert |")).expect("the expert's row");
    assert!(expert.contains("| 0.0 [0.0,"), "the expert never leaves the object in another quadrant: {expert}");
    assert!(table.lines().any(|l| l.starts_with("| full @ 8 |") && l.contains("50.0 ± 9.9")), "{table}");
    let index = std::fs::read_to_string(store.join("reports/objects/index.md")).unwrap();
    assert!(index.contains("## Multi-object environments: held-out objects"));
    // Every episode recorded whether and where the gripper first closed; the report tabulates it from the store.
    assert_eq!(count(&conn, "SELECT COUNT(*) FROM episodes WHERE closed IS NULL"), 0);
    let closed = count(
        &conn,
        "SELECT COUNT(*) FROM episodes e JOIN cells c ON c.eval_key = e.eval_key \
         WHERE c.cell = 'expert' AND e.closed = 1 AND e.close_step > 0",
    );
    assert_eq!(closed, 4, "the expert closes its gripper in every episode");
    let grasps = std::fs::read_to_string(store.join("reports/objects/grasps.md")).unwrap();
    let expert = grasps.lines().find(|l| l.starts_with("| expert |")).expect("the expert's row");
    assert!(expert.starts_with("| expert | 1/1 | 100.0 ["), "{grasps}");
    assert!(index.contains("## Where the gripper first closed") && index.contains(expert), "{index}");
    assert!(!store.join("reports/objects/objects.md").exists(), "library slots are not the base world's objects");
    // The traces' holds: the expert holds the object on the table in every episode, lifts and never loses it; the
    // report's row is the stage summary's.
    let holds: serde_json::Value = summary["holds"].clone();
    assert_eq!((holds["episodes"].as_u64(), holds["lost"].as_u64()), (Some(4), Some(0)), "{holds}");
    let table = std::fs::read_to_string(store.join("reports/objects/holds.md")).unwrap();
    let expert = table.lines().find(|l| l.starts_with("| expert |")).expect("the expert's row");
    let lifted = 100.0 * holds["lifted"].as_f64().unwrap();
    assert_eq!(
        expert,
        format!("| expert | 1/1 | 4 | {} | 0% / {lifted:.0}% | 0 / 0 of 0 |", holds["steps"]),
        "{table}"
    );
    assert!(lifted > 0.0 && index.contains("## After the close"), "{index}");
    // After the pick: the expert's picked episodes, split by what followed, add up to the store's counts.
    let expert_episodes = "SELECT COUNT(*) FROM episodes e JOIN cells c ON c.eval_key = e.eval_key \
                           WHERE c.cell = 'expert' AND e.picked = 1";
    let picked = count(&conn, expert_episodes);
    let placed = count(&conn, &format!("{expert_episodes} AND e.placed = 1"));
    let table = std::fs::read_to_string(store.join("reports/objects/carries.md")).unwrap();
    let expert = table.lines().find(|l| l.starts_with("| expert |")).expect("the expert's row");
    let cells: Vec<&str> = expert.split('|').map(str::trim).collect();
    assert!(picked > 0 && cells[3] == picked.to_string(), "{picked} picked: {table}");
    assert!(cells[4].starts_with(&format!("{placed} (")), "{placed} placed: {table}");
    let parts: i64 = cells[4..9].iter().map(|c| c.split(' ').next().unwrap().parse::<i64>().unwrap()).sum();
    assert_eq!(parts, picked, "every picked episode lands in one column: {table}");
    assert!(index.contains("## After the pick") && index.contains(expert), "{index}");
    std::fs::remove_dir_all(&dir).unwrap();
}
