//! The command line's handling of bad input: one clear error line and a non-zero exit.
use crate::helpers::{oneshot, scratch, torch_rng};
use oneshot_lab::config::{Experiment, Resolution};
use oneshot_lab::train::build_policy;
use std::path::Path;

/// 32x40 frames of collision geometry: collected about four times faster than with the visual meshes on Mesa.
const SMALL_FRAMES: [&str; 6] = ["--height", "32", "--width", "40", "--visuals", "collision"];

#[test]
fn unknown_robot_is_an_error_naming_it() {
    let out = oneshot().args(["expert-check", "--robot", "ur5"]).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("ur5"), "{err}");
}

#[test]
fn missing_assets_are_an_error_naming_the_path() {
    let out = oneshot()
        .args(["expert-check", "--robot", "panda", "--per-task", "1"])
        .env("ONESHOT_ASSETS", "/nonexistent/assets")
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("/nonexistent/assets") && err.starts_with("error:"), "{err}");
}

#[test]
fn unwritable_contact_sheet_path_is_an_error_naming_it() {
    let out =
        oneshot().args(["contact-sheet", "--instances", "1", "--out", "/nonexistent/dir/sheet.png"]).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("/nonexistent/dir/sheet.png"), "{err}");
}

#[test]
fn zero_instances_per_task_is_an_error_naming_the_flag() {
    let out = oneshot().args(["expert-check", "--robot", "panda", "--per-task", "0"]).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--per-task (0)"), "{err}");
}

#[test]
fn a_reference_policy_with_a_checkpoint_or_an_unrenderable_frame_is_refused_before_any_episode() {
    for (args, named) in [
        (&["--policy", "expert", "--checkpoint", "500"][..], "--checkpoint 500"),
        (&["--policy", "random", "--height", "0"][..], "world.image = 0x"),
    ] {
        let out = oneshot().arg("eval").args(args).args(["--episodes", "1"]).output().unwrap();
        assert!(!out.status.success(), "{args:?} succeeded");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(named), "{args:?}: {err}");
    }
}

#[test]
fn probing_zero_windows_is_an_error_naming_the_flag() {
    for extra in [&[][..], &["--at-grip"][..]] {
        let out = oneshot()
            .args(["probe", "--policy", "p", "--demos", "d", "--agents", "a", "--windows", "0"])
            .args(extra)
            .output()
            .unwrap();
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("--windows (0)"), "{err}");
    }
}

#[test]
fn a_malformed_aim_offset_is_an_error_naming_the_value() {
    for (value, named) in [("2", "`2` is not ACROSS,SIDEWAYS"), ("1,x", "`x` in `1,x`"), ("0,11", "`11` in `0,11`")] {
        let out = oneshot().args(["expert-check", "--robot", "panda", "--aim-offset", value]).output().unwrap();
        assert!(!out.status.success(), "{value} was taken");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("--aim-offset") && err.contains(named), "{value}: {err}");
    }
}

#[test]
fn an_aim_offset_takes_negative_centimetres() {
    let out = oneshot()
        .args(["expert-check", "--robot", "panda", "--per-task", "1", "--aim-offset", "-1,-2"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(text.contains("aimed -1 cm across and -2 cm sideways"), "{text}");
    assert!(text.lines().any(|l| l.starts_with("can ") && l.ends_with("/4")), "a line per object: {text}");
}

#[test]
fn collect_with_a_task_out_of_range_is_an_error_naming_it() {
    let out = oneshot()
        .args(["collect", "--robot", "panda", "--tasks", "2,17", "--per-task", "1", "--out", "/tmp/never-written"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("17") && err.lines().count() == 1, "{err}");
    assert!(!std::path::Path::new("/tmp/never-written").exists());
}

#[test]
fn collect_draws_its_layouts_as_told_and_refuses_a_pool_without_sharing() {
    let dir = scratch("cli-collect-layouts");
    let args = |out: &str, layouts: &str, pool: &str| {
        let out = dir.join(out);
        let base = ["collect", "--robot", "panda", "--tasks", "0,5", "--per-task", "2"];
        let mut cmd = oneshot();
        cmd.args(base)
            .args(SMALL_FRAMES)
            .args(["--layouts", layouts, "--layout-pool", pool, "--workers", "1", "--out"])
            .arg(out);
        cmd.output().unwrap()
    };
    // A pool of one environment: all four slots of both tasks draw it.
    let out = args("shared", "shared", "1");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("shared").join("manifest.json")).unwrap()).unwrap();
    let environments: Vec<_> = manifest["trajectories"].as_array().unwrap().iter().map(|e| &e["environment"]).collect();
    assert_eq!(environments.len(), 4);
    assert!(environments.iter().all(|e| e.as_u64() == Some(0)), "{environments:?}");
    let out = args("unique", "unique", "3");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("collect.layout_pool"));
    assert!(!dir.join("unique").exists());
}

#[test]
fn collect_groups_library_slots_into_environments_and_refuses_a_pool_there() {
    let dir = scratch("cli-collect-library");
    let base = ["collect", "--robot", "sawyer", "--tasks", "3", "--per-task", "3"];
    let library = ["--objects", "library", "--close-on-arrival", "--environment-instances", "2", "--workers", "1"];
    let out =
        oneshot().args(base).args(SMALL_FRAMES).args(library).arg("--out").arg(dir.join("library")).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let manifest: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("library").join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest["config"]["world"]["objects"], "library");
    let environments: Vec<_> =
        manifest["trajectories"].as_array().unwrap().iter().map(|e| e["environment"].as_u64()).collect();
    assert_eq!(environments, [Some(0), Some(0), Some(1)]);
    let out = oneshot()
        .args(base)
        .args(SMALL_FRAMES)
        .args(library)
        .args(["--layout-pool", "4", "--out"])
        .arg(dir.join("pool"))
        .output();
    let out = out.unwrap();
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("collect.layout_pool"));
    assert!(!dir.join("pool").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn commands_that_read_a_store_refuse_a_folder_without_one() {
    let dir = std::env::temp_dir().join(format!("oneshot-test-cli-nostore-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let store = dir.to_str().unwrap();
    let commands: [&[&str]; 5] = [
        &["status", "--store", store],
        &["why", "abc123", "--store", store],
        &["report", "experiments/smoke.toml", "--store", store],
        &["query", "cells", "--store", store],
        &["gc", "experiments/smoke.toml", "--store", store],
    ];
    for args in commands {
        let out = oneshot().args(args).output().unwrap();
        assert!(!out.status.success(), "{args:?} succeeded");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("no results store at") && err.contains(store), "{args:?}: {err}");
    }
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0, "nothing is created in the folder");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_unknown_architecture_to_benchmark_is_an_error_naming_it() {
    let out = oneshot().args(["bench", "train", "--architectures", "transfomer", "--device", "cpu"]).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--architectures") && err.contains("transfomer"), "{err}");
}

#[test]
fn the_training_benchmark_times_an_experiment_cell_as_its_file_configures_it() {
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("experiments/learn_cpu16_motion_96.toml");
    let cell = "n1600-state_16k_motion_bf16-s1";
    let bench = |extra: &[&str]| {
        let mut args = vec!["bench", "train", "--experiment", file.to_str().unwrap(), "--cell", cell];
        args.extend(["--steps", "1", "--batch", "2", "--device", "cpu"]);
        args.extend(extra);
        let out = oneshot().env("OMP_NUM_THREADS", "1").args(&args).output().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let text = bench(&[]);
    let header = text.lines().next().unwrap();
    assert!(header.contains(&format!("cell {cell}")), "{header}");
    // The cell's frame size, the batch given, and the cell's bf16 and channels-last (the flags' defaults are fp32
    // and contiguous).
    assert!(header.contains("96x128 frames, batch 2 (22 frames per step)"), "{header}");
    assert!(header.ends_with("Bf16, ChannelsLast"), "{header}");
    assert!(text.contains("16000 steps: hours for the cell's 16000 training steps"), "{text}");
    let row = text.lines().find(|l| l.trim_start().starts_with("transformer ")).expect("a transformer row");
    let column = |i: usize| row.split_whitespace().nth(i).unwrap().to_string();
    assert!(column(3).parse::<f64>().unwrap() > 0.0, "{row}");
    // The cell's network (its state, pose head and object attention), not the `small` configuration's.
    let experiment = Experiment::load(&file, &Resolution::default()).unwrap();
    let model = &experiment.cells.iter().find(|c| c.name == cell).unwrap().config.model;
    let (vs, _) = {
        let _rng = torch_rng();
        build_policy(model, tch::Device::Cpu).unwrap()
    };
    let parameters: i64 = vs.trainable_variables().iter().map(|t| t.numel() as i64).sum();
    assert_eq!(column(1), parameters.to_string(), "{row}");
    let fp32 = bench(&["--precision", "fp32", "--memory-format", "contiguous"]);
    assert!(fp32.lines().next().unwrap().ends_with("Fp32, Contiguous"), "{fp32}");
    // An architecture the cell's settings do not fit (no paper heads for its pose head) is skipped, not fatal.
    let both = bench(&["--architectures", "transformer,contextual_lstm"]);
    assert!(both.lines().any(|l| l.trim_start().starts_with("contextual_lstm") && l.contains("skipped")), "{both}");
    assert!(both.lines().any(|l| l.trim_start().starts_with("transformer ")), "{both}");
}

#[test]
fn a_training_benchmark_of_an_unknown_cell_or_a_stray_override_is_an_error_naming_it() {
    let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("experiments/learn_cpu16_motion_96.toml");
    let args = ["bench", "train", "--experiment", file.to_str().unwrap(), "--cell", "n1600-nope-s0", "--device", "cpu"];
    let out = oneshot().args(args).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("learn_cpu16_motion_96.toml") && err.contains("no cell `n1600-nope-s0`"), "{err}");
    let strays: [&[&str]; 3] = [
        &["--set", "train.batch_size=4"],
        &["--cell", "n1600-state_16k_motion-s1"],
        &["--config", "paper", "--experiment", file.to_str().unwrap()],
    ];
    for stray in strays {
        let out = oneshot().args(["bench", "train", "--device", "cpu"]).args(stray).output().unwrap();
        assert!(!out.status.success(), "{stray:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains("--experiment"), "{stray:?}: {err}");
    }
}

#[test]
fn the_orchestrator_benchmark_times_plan_and_run_on_a_grid_that_is_all_cached() {
    let out = oneshot().args(["bench", "plan", "--cells", "20"]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("22 cells, 44 stages, all cached"), "{text}");
    for command in ["plan:", "run :"] {
        let line = text.lines().find(|l| l.trim_start().starts_with(command)).expect(command);
        let seconds: f64 = line.split(':').nth(1).unwrap().split_whitespace().next().unwrap().parse().unwrap();
        assert!(seconds > 0.0, "{line}");
    }
}

#[test]
fn the_world_benchmark_times_collection_in_the_multi_object_world() {
    let args = ["bench", "world", "--objects", "library", "--episodes", "1", "--height", "32", "--width", "40"];
    let out = oneshot().args(args).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("Library objects"), "{text}");
    let rate = |label: &str| -> f64 {
        let line = text.lines().find(|l| l.trim_start().starts_with(label)).expect(label);
        line.split("physics steps/s").nth(1).unwrap().split_whitespace().next().unwrap().parse().unwrap()
    };
    assert!(rate("collection") > 0.0 && rate("bare step+render") > 0.0, "{text}");
}

#[test]
fn a_train_config_with_a_pretrain_section_is_refused_naming_the_file() {
    let dir = std::env::temp_dir().join(format!("oneshot-test-cli-pretrain-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let config = dir.join("with_pretrain.toml");
    std::fs::write(&config, "[pretrain]\nsteps = 10\n[model]\nbackbone_width = 8\n").unwrap();
    let out = oneshot()
        .args(["train", "--demos", "/nonexistent/d", "--agents", "/nonexistent/a", "--out"])
        .arg(dir.join("out"))
        .arg("--config")
        .arg(&config)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("with_pretrain.toml") && err.contains("[pretrain] is a stage of experiment files"), "{err}");
    assert!(!dir.join("out").exists(), "nothing is written");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_experiment_name_that_leaves_the_report_folder_is_refused_and_nothing_outside_changes() {
    let dir = scratch("cli-escape");
    let store = dir.join("store");
    std::fs::create_dir_all(store.join("artifacts").join("collect").join("abc")).unwrap();
    std::fs::write(store.join("artifacts").join("collect").join("abc").join("kept.txt"), "data").unwrap();
    for (name, shown) in [("../artifacts", "\"../artifacts\""), ("", "\"\""), ("/tmp/elsewhere", "\"/tmp/elsewhere\"")]
    {
        let file = dir.join("escape.toml");
        std::fs::write(&file, format!("name = {name:?}\n[grid]\nsizes = []\nreferences = [\"random\"]\n")).unwrap();
        for command in ["run", "plan", "report"] {
            let out =
                oneshot().args([command, file.to_str().unwrap(), "--store", store.to_str().unwrap()]).output().unwrap();
            assert!(!out.status.success(), "{command} with name {name:?} succeeded");
            let err = String::from_utf8_lossy(&out.stderr);
            assert!(err.contains(&format!("name = {shown}")) && err.contains("escape.toml"), "{command}: {err}");
        }
    }
    assert_eq!(std::fs::read_to_string(store.join("artifacts/collect/abc/kept.txt")).unwrap(), "data");
    assert!(!store.join("reports").exists(), "no report folder was written");
    // gc --delete without the experiment files that say what to keep would remove everything: refused.
    let out = oneshot().args(["gc", "--delete", "--store", store.to_str().unwrap()]).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("gc --delete needs the experiment files"));
    assert!(store.join("artifacts/collect/abc/kept.txt").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_stage_pattern_that_matches_nothing_is_an_error_naming_it() {
    let dir = scratch("cli-patterns");
    let store = dir.join("store");
    for (flag, pattern) in [("--only", "n999-*"), ("--force", "*/tarin"), ("--only", "n32-[full")] {
        let args = ["run", "experiments/smoke.toml", "--dry-run", flag, pattern, "--store", store.to_str().unwrap()];
        let out = oneshot().args(args).output().unwrap();
        assert!(!out.status.success(), "{flag} {pattern} succeeded");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(flag) && err.contains(pattern), "{flag} {pattern}: {err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn config_prints_the_resolved_file_with_overrides_and_marks_what_differs_from_the_defaults() {
    let args = ["config", "experiments/smoke.toml", "--set", "train.steps=50", "--set", "eval.episodes=4"];
    let out = oneshot().args(args).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    for line in
        ["# --set train.steps=50", "# --set eval.episodes=4", "steps = 50  # default: ", "episodes = 4  # default: "]
    {
        assert!(text.contains(line), "no `{line}` in:\n{text}");
    }
    // A key left at its default carries no mark.
    assert!(text.lines().any(|l| l == "inverse = 1.0"), "{text}");

    // One cell, as JSON: the variant's own change is listed with its default.
    let args = ["config", "experiments/smoke.toml", "--cell", "n32-no_inverse-s0", "--format", "json"];
    let out = oneshot().args(args).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["config"]["train"]["loss"]["inverse"], serde_json::json!(0.0));
    assert_eq!(json["changed"]["train.loss.inverse"]["default"], serde_json::json!(1.0));
    assert_eq!(json["changed"]["train.steps"]["value"], serde_json::json!(300));

    let out = oneshot().args(["config", "experiments/smoke.toml", "--cell", "n32-nope-s0"]).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no cell `n32-nope-s0`"));
}

#[test]
fn a_bad_override_fails_like_a_bad_file_naming_the_key() {
    let dir = scratch("cli-bad-set");
    let store = dir.join("store");
    for (set, named) in [
        ("train.stepz=5", "stepz"),
        ("train.steps=many", "train.steps"),
        ("train.lr=-1", "train.lr"),
        ("model.dropout=1.5", "model.dropout"),
        ("nosuchsection.x=1", "nosuchsection"),
        ("train.steps.x=1", "train.steps"),
        ("variants.no_inverse.train.lr=nan", "train.lr"),
        ("train.lr", "KEY=VALUE"),
        ("train.lr=nan", "--set train.lr=nan: train.lr is not a finite number"),
        ("train.batch_size=9223372036854775807", "train.batch_size"),
        ("model.backbone_width=99999999999", "model.backbone_width"),
        ("eval.episodes=1000000000000", "eval.episodes"),
        ("profiles.cpu.train.steps=5", "--profile"),
        ("world.image.height=7", "world.image = 7x"),
    ] {
        for command in ["config", "plan", "run"] {
            let mut args = vec![command, "experiments/smoke.toml", "--set", set];
            if command != "config" {
                args.extend(["--dry-run", "--store", store.to_str().unwrap()]);
                if command == "plan" {
                    args.retain(|a| *a != "--dry-run");
                }
            }
            let out = oneshot().args(&args).output().unwrap();
            assert!(!out.status.success(), "{command} --set {set} succeeded");
            let err = String::from_utf8_lossy(&out.stderr);
            assert!(err.contains(named), "{command} --set {set}: {err}");
        }
    }
    assert!(!store.join("artifacts").exists(), "nothing was run");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Writes `refs.toml` in `dir`: the random policy alone, two short episodes at 32x40 (seconds to run).
fn refs_experiment(dir: &std::path::Path) -> std::path::PathBuf {
    let file = dir.join("refs.toml");
    std::fs::write(
        &file,
        "name = \"refs\"\n[world]\nvisuals = \"collision\"\n[world.image]\nheight = 32\nwidth = 40\n[eval]\nepisodes = 2\nhorizon = 3\nbatch = 2\n\
         [grid]\nsizes = []\nreferences = [\"random\"]\n",
    )
    .unwrap();
    file
}

#[test]
fn overrides_change_the_keys_they_touch_and_are_recorded_with_the_experiment() {
    let dir = scratch("cli-set-run");
    let store = dir.join("store");
    let file = refs_experiment(&dir);
    let run = |extra: &[&str]| {
        let mut args = vec!["run", file.to_str().unwrap(), "--store", store.to_str().unwrap(), "--workers", "1"];
        args.extend(extra);
        let out = oneshot().args(&args).output().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    run(&["--set", "eval.horizon=4"]);
    let conn = rusqlite::Connection::open(store.join("oneshot.sqlite")).unwrap();
    let overrides: String =
        conn.query_row("SELECT overrides FROM experiments WHERE name = 'refs'", [], |r| r.get(0)).unwrap();
    assert_eq!(overrides, "--set eval.horizon=4");
    let index = std::fs::read_to_string(store.join("reports/refs/index.md")).unwrap();
    assert!(index.contains("overrides `--set eval.horizon=4`"), "{index}");
    let steps: i64 = conn.query_row("SELECT MAX(steps) FROM episodes", [], |r| r.get(0)).unwrap();
    assert!(steps <= 4, "episodes ran under the overridden horizon: {steps} steps");

    // A report shows the experiment as last run: asked plainly it says which overrides that run had; asked with
    // other overrides it is refused, naming both; with the same ones it is quiet.
    let report = |extra: &[&str]| {
        let mut args = vec!["report", file.to_str().unwrap(), "--store", store.to_str().unwrap()];
        args.extend(extra);
        oneshot().args(&args).output().unwrap()
    };
    let plain = report(&[]);
    assert!(plain.status.success(), "{}", String::from_utf8_lossy(&plain.stderr));
    assert!(String::from_utf8_lossy(&plain.stderr).contains("as last run, with --set eval.horizon=4"));
    let other = report(&["--set", "eval.horizon=5"]);
    let err = String::from_utf8_lossy(&other.stderr);
    assert!(!other.status.success(), "a report under other overrides succeeded");
    assert!(
        err.contains("`refs`") && err.contains("--set eval.horizon=4") && err.contains("--set eval.horizon=5"),
        "{err}"
    );
    let same = report(&["--set", "eval.horizon=4"]);
    assert!(same.status.success() && !String::from_utf8_lossy(&same.stderr).contains("note:"));

    // The same override again is cached; without it the file's own horizon is a new evaluation.
    let plan = |extra: &[&str]| {
        let mut args = vec!["plan", file.to_str().unwrap(), "--store", store.to_str().unwrap()];
        args.extend(extra);
        String::from_utf8_lossy(&oneshot().args(&args).output().unwrap().stdout).into_owned()
    };
    assert!(plan(&["--set", "eval.horizon=4"]).contains("0 stages to run"), "{}", plan(&["--set", "eval.horizon=4"]));
    assert!(plan(&[]).contains("1 stages to run"), "{}", plan(&[]));

    // `plan --format json` names each stage's key and state; `diff` puts the two evaluations side by side.
    let json: serde_json::Value = serde_json::from_str(&plan(&["--format", "json"])).unwrap();
    assert_eq!(json["to_run"], serde_json::json!(1));
    let planned = json["cells"][0]["stages"][0].clone();
    assert_eq!((planned["kind"].as_str(), planned["state"].as_str()), (Some("eval"), Some("to run")));
    run(&[]);
    let keys: Vec<String> = conn
        .prepare("SELECT key FROM stages WHERE kind = 'eval' ORDER BY key")
        .unwrap()
        .query_map([], |r| r.get(0))
        .unwrap()
        .collect::<Result<_, _>>()
        .unwrap();
    assert_eq!(keys.len(), 2);
    let diff = |format: &str| {
        let args = ["diff", &keys[0][..10], &keys[1][..10], "--store", store.to_str().unwrap(), "--format", format];
        let out = oneshot().args(args).output().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let json: serde_json::Value = serde_json::from_str(&diff("json")).unwrap();
    let differences = json[0]["differences"].as_array().unwrap();
    assert_eq!(differences.len(), 1, "{json}");
    assert_eq!(differences[0]["input"], serde_json::json!("eval.horizon"));
    let names: Vec<&str> = json[0]["metrics"].as_array().unwrap().iter().filter_map(|m| m["name"].as_str()).collect();
    assert!(!names.is_empty() && json[0]["metrics"][0]["a"].is_number(), "{json}");
    assert!(diff("text").contains("eval.horizon: "), "{}", diff("text"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn reading_the_store_never_writes_and_status_tells_a_dead_holder_from_a_live_one() {
    let dir = scratch("cli-read-only");
    let store = dir.join("store");
    let out = oneshot().args(["plan", "experiments/smoke.toml", "--store", store.to_str().unwrap()]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let outside = dir.join("outside.db");
    for sql in [
        format!("VACUUM INTO '{}'", outside.display()),
        format!("ATTACH DATABASE '{}' AS x", outside.display()),
        "CREATE TABLE t(a INTEGER)".to_string(),
        "PRAGMA journal_mode = DELETE".to_string(),
        "DELETE FROM stages".to_string(),
    ] {
        let out = oneshot().args(["query", &sql, "--store", store.to_str().unwrap()]).output().unwrap();
        assert!(!out.status.success(), "{sql} succeeded");
    }
    assert!(!outside.exists(), "a query wrote a file outside the store");
    let count = |sql: &str| {
        let out = oneshot().args(["query", sql, "--store", store.to_str().unwrap(), "--format", "json"]).output();
        let rows: serde_json::Value = serde_json::from_slice(&out.unwrap().stdout).unwrap();
        rows[0]["n"].as_i64().unwrap()
    };
    assert!(count("SELECT COUNT(*) AS n FROM stages") > 0);

    // `why` matches key prefixes as text: `%` and `_` are not wildcards.
    for pattern in ["%", "_"] {
        let out = oneshot().args(["why", pattern, "--store", store.to_str().unwrap()]).output().unwrap();
        assert!(!out.status.success());
        assert!(String::from_utf8_lossy(&out.stderr).contains(&format!("no stage key starts with `{pattern}`")));
    }

    // An attempt whose process on this machine is gone shows as stale; a live one as running.
    let conn = rusqlite::Connection::open(store.join("oneshot.sqlite")).unwrap();
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap().trim().to_string();
    let keys: Vec<String> = conn
        .prepare("SELECT key FROM stages LIMIT 2")
        .unwrap()
        .query_map([], |r| r.get(0))
        .unwrap()
        .map(Result::unwrap)
        .collect();
    let mut child = std::process::Command::new("sleep").arg("30").spawn().unwrap();
    for (key, pid) in [(&keys[0], 999_999_999i64), (&keys[1], child.id() as i64)] {
        conn.execute(
            "INSERT INTO attempts (stage_key, status, host, pid, started_at) VALUES (?1, 'running', ?2, ?3, 0)",
            rusqlite::params![key, host, pid],
        )
        .unwrap();
    }
    let out = oneshot().args(["status", "--store", store.to_str().unwrap(), "--format", "json"]).output().unwrap();
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let alive: Vec<(String, bool)> = json["running"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| (r["key"].as_str().unwrap().to_string(), r["process_alive"].as_bool().unwrap()))
        .collect();
    assert_eq!(alive, [(keys[0].clone(), false), (keys[1].clone(), true)]);
    let out = oneshot().args(["status", "--store", store.to_str().unwrap()]).output().unwrap();
    assert!(String::from_utf8_lossy(&out.stdout).contains("stale (its process is gone"));
    child.kill().unwrap();
    let _ = child.wait();
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_reference_pages_are_what_the_code_generates() {
    for (page, file) in [("config", "docs/reference/config.md"), ("cli", "docs/reference/commands.md")] {
        let out = oneshot().args(["reference", page]).output().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let generated = String::from_utf8(out.stdout).unwrap();
        let kept = std::fs::read_to_string(file).unwrap_or_default();
        assert!(
            generated == kept,
            "{file} is stale: regenerate it with `oneshot-lab reference {page} > {file}` (first differing line: {:?})",
            generated.lines().zip(kept.lines()).find(|(a, b)| a != b)
        );
        // Every row says what its key or option does.
        let empty = generated.lines().filter(|l| l.starts_with("| `") && l.ends_with("|  |")).collect::<Vec<_>>();
        assert!(empty.is_empty(), "{file}: rows without a description: {empty:?}");
    }
}

#[test]
fn completion_scripts_list_the_commands_and_their_options() {
    for shell in ["bash", "zsh", "fish"] {
        let out = oneshot().args(["completions", shell]).output().unwrap();
        assert!(out.status.success(), "{shell}");
        let script = String::from_utf8_lossy(&out.stdout);
        for word in ["oneshot-lab", "report", "profile", "only", "channels_last"] {
            assert!(script.contains(word), "{shell}: no `{word}`");
        }
    }
}

/// Every file under `dir` with its bytes.
fn snapshot(dir: &std::path::Path) -> std::collections::BTreeMap<std::path::PathBuf, Vec<u8>> {
    let mut files = std::collections::BTreeMap::new();
    let mut pending = vec![dir.to_path_buf()];
    while let Some(d) = pending.pop() {
        for entry in std::fs::read_dir(&d).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                pending.push(path);
            } else {
                files.insert(path.clone(), std::fs::read(&path).unwrap());
            }
        }
    }
    files
}

#[test]
fn a_store_opened_read_only_serves_every_reading_command_without_changing_a_byte() {
    let dir = scratch("cli-store-read-only");
    let store = dir.join("store");
    let file = refs_experiment(&dir);
    let (file, store_arg) = (file.to_str().unwrap(), store.to_str().unwrap());
    let out = oneshot().args(["run", file, "--store", store_arg, "--workers", "1"]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let conn = rusqlite::Connection::open(store.join("oneshot.sqlite")).unwrap();
    let key: String = conn.query_row("SELECT key FROM stages LIMIT 1", [], |r| r.get(0)).unwrap();
    drop(conn);

    let before = snapshot(&store);
    let elsewhere = dir.join("report");
    let elsewhere = elsewhere.to_str().unwrap();
    for args in [
        vec!["status", "--read-only"],
        vec!["why", &key[..8], "--read-only"],
        vec!["query", "cells", "--read-only"],
        vec!["diff", &key[..8], &key[..8], "--read-only"],
        vec!["report", file, "--read-only", "--out", elsewhere],
    ] {
        let out = oneshot().args(&args).args(["--store", store_arg]).output().unwrap();
        assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
    }
    assert!(std::path::Path::new(elsewhere).join("index.md").is_file());
    let out = oneshot().args(["report", file, "--read-only", "--store", store_arg]).output().unwrap();
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("pass --out"));
    assert!(before == snapshot(&store), "a read-only command changed a file of the store");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_store_newer_than_the_binary_is_refused_and_an_older_one_is_migrated() {
    let dir = scratch("cli-store-schema");
    let store = dir.join("store");
    let store_arg = store.to_str().unwrap();
    let out = oneshot().args(["plan", "experiments/smoke.toml", "--store", store_arg]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let version = || {
        let conn = rusqlite::Connection::open(store.join("oneshot.sqlite")).unwrap();
        conn.query_row("PRAGMA user_version", [], |r| r.get::<_, i64>(0)).unwrap()
    };
    let set_version = |v: i64| {
        let conn = rusqlite::Connection::open(store.join("oneshot.sqlite")).unwrap();
        conn.pragma_update(None, "user_version", v).unwrap();
    };
    assert_eq!(version(), oneshot_lab::pipeline::store::SCHEMA_VERSION);

    set_version(99);
    for args in [vec!["status"], vec!["query", "cells"], vec!["plan", "experiments/smoke.toml"]] {
        let out = oneshot().args(&args).args(["--store", store_arg]).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains("schema version 99, newer"), "{args:?}: {err}");
    }

    // A store from before versions were recorded reads 0: a read-only opening cannot migrate it and says how;
    // a writable one migrates it.
    set_version(0);
    let out = oneshot().args(["status", "--read-only", "--store", store_arg]).output().unwrap();
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("older"));
    assert_eq!(version(), 0);
    let out = oneshot().args(["status", "--store", store_arg]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(version(), oneshot_lab::pipeline::store::SCHEMA_VERSION);

    // A version-1 store has no record of the code that ran each attempt: migrating adds it.
    let columns = || {
        let conn = rusqlite::Connection::open(store.join("oneshot.sqlite")).unwrap();
        let mut stmt = conn.prepare("SELECT name FROM pragma_table_info('attempts')").unwrap();
        stmt.query_map([], |r| r.get::<_, String>(0)).unwrap().collect::<Result<Vec<_>, _>>().unwrap()
    };
    let conn = rusqlite::Connection::open(store.join("oneshot.sqlite")).unwrap();
    conn.execute_batch("ALTER TABLE attempts DROP COLUMN code_commit; ALTER TABLE attempts DROP COLUMN code_digest")
        .unwrap();
    drop(conn);
    set_version(1);
    assert!(!columns().contains(&"code_digest".to_string()));
    let out = oneshot().args(["status", "--store", store_arg]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(version(), oneshot_lab::pipeline::store::SCHEMA_VERSION);
    assert!(columns().contains(&"code_digest".to_string()) && columns().contains(&"code_commit".to_string()));

    // A version-2 store's episodes do not say whether the object ended in another quadrant: migrating adds the
    // column, empty for the episodes already there.
    let conn = rusqlite::Connection::open(store.join("oneshot.sqlite")).unwrap();
    conn.execute_batch("ALTER TABLE episodes DROP COLUMN wrong_bin").unwrap();
    drop(conn);
    set_version(2);
    let out = oneshot().args(["status", "--store", store_arg]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(version(), oneshot_lab::pipeline::store::SCHEMA_VERSION);
    let conn = rusqlite::Connection::open(store.join("oneshot.sqlite")).unwrap();
    assert!(
        conn.prepare("SELECT 1 FROM pragma_table_info('episodes') WHERE name = 'wrong_bin'")
            .unwrap()
            .exists([])
            .unwrap()
    );

    // A version-3 store's episodes do not say where the gripper first closed: migrating adds the columns.
    let close_columns = ["closed", "close_step", "close_x", "close_y", "close_z"];
    for column in close_columns {
        conn.execute_batch(&format!("ALTER TABLE episodes DROP COLUMN {column}")).unwrap();
    }
    drop(conn);
    set_version(3);
    let out = oneshot().args(["status", "--store", store_arg]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(version(), oneshot_lab::pipeline::store::SCHEMA_VERSION);
    let conn = rusqlite::Connection::open(store.join("oneshot.sqlite")).unwrap();
    for column in close_columns {
        let mut stmt = conn.prepare("SELECT 1 FROM pragma_table_info('episodes') WHERE name = ?1").unwrap();
        assert!(stmt.exists([column]).unwrap(), "{column}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_cached_stage_built_by_other_code_is_named_by_plan_and_why_and_rerun_on_request() {
    use oneshot_lab::pipeline::code;
    use oneshot_lab::pipeline::stages::Kind;
    let dir = scratch("cli-code-changed");
    let store = dir.join("store");
    let file = refs_experiment(&dir);
    let (file, store_arg) = (file.to_str().unwrap(), store.to_str().unwrap());
    let run = |extra: &[&str]| {
        let out = oneshot().args(["run", file, "--store", store_arg, "--workers", "1"]).args(extra).output().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        (String::from_utf8_lossy(&out.stdout).into_owned(), String::from_utf8_lossy(&out.stderr).into_owned())
    };
    let text = |args: &[&str]| {
        let out = oneshot().args(args).args(["--store", store_arg]).output().unwrap();
        assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let recorded = || {
        let conn = rusqlite::Connection::open(store.join("oneshot.sqlite")).unwrap();
        conn.query_row(
            "SELECT stage_key, code_commit, code_digest FROM attempts WHERE status = 'done' ORDER BY id DESC LIMIT 1",
            [],
            |r| Ok((r.get::<_, String>(0)?, r.get::<_, String>(1)?, r.get::<_, String>(2)?)),
        )
        .unwrap()
    };
    run(&[]);
    let (key, commit, digest) = recorded();
    assert_eq!((commit.as_str(), digest.clone()), (code::COMMIT, code::current(Kind::Eval).digest));
    assert!(!text(&["plan", file]).contains("cached*"));
    assert!(text(&["why", &key[..10]]).contains("by the same eval code"));

    // As if an older binary, with other evaluation code, had built it.
    let conn = rusqlite::Connection::open(store.join("oneshot.sqlite")).unwrap();
    conn.execute("UPDATE attempts SET code_commit = 'abc1234', code_digest = 'older'", []).unwrap();
    drop(conn);
    let plan = text(&["plan", file]);
    assert!(plan.contains(&format!("cached* {}", &key[..12])), "{plan}");
    assert!(plan.contains("abc1234") && plan.contains("--rerun-code-changed eval"), "{plan}");
    let why = text(&["why", &key[..10]]);
    assert!(why.contains("abc1234") && why.contains("by other code"), "{why}");

    // Only the named kinds re-run; the re-run records this binary's code.
    let (out, err) = run(&["--rerun-code-changed", "collect,train"]);
    assert!(out.contains("0 stages run, 1 cached") && err.contains("no cached stage"), "{out}{err}");
    let (out, _) = run(&["--rerun-code-changed", "eval"]);
    assert!(out.contains("1 stages run"), "{out}");
    assert_eq!(recorded().2, digest);
    assert!(!text(&["plan", file]).contains("cached*"));

    let out = oneshot().args(["run", file, "--store", store_arg, "--rerun-code-changed", "evals"]).output().unwrap();
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("evals"));
    let _ = std::fs::remove_dir_all(&dir);
}
