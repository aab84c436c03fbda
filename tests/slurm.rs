//! The Slurm executor against a real (one-node) Slurm: `scripts/slurm-one-node.sh` starts one; CI sets
//! ONESHOT_REQUIRE_SLURM=1 so that a missing Slurm fails the test instead of skipping it.
use rusqlite::Connection;
use std::process::Command;

const EXPERIMENT: &str = r#"name = "tiny_slurm"
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

#[test]
fn stages_run_as_slurm_jobs_and_failed_jobs_are_recorded() {
    if !slurm_up() {
        assert!(std::env::var_os("ONESHOT_REQUIRE_SLURM").is_none(), "Slurm is required here but `sinfo` fails");
        eprintln!("skipped: no Slurm on this machine (start one with scripts/slurm-one-node.sh)");
        return;
    }
    let dir = std::env::temp_dir().join(format!("oneshot-test-slurm-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("tiny.toml");
    std::fs::write(&file, EXPERIMENT).unwrap();
    let store = dir.join("runs");
    let run = |extra: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_oneshot-lab"))
            .args(["run", file.to_str().unwrap(), "--store", store.to_str().unwrap(), "--workers", "1"])
            .args(extra)
            .output()
            .unwrap()
    };
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
    assert!(text.contains("Slurm job") && text.contains("nowhere"), "{text}");
    let failed: i64 = db.query_row("SELECT COUNT(*) FROM stages WHERE status = 'failed'", [], |r| r.get(0)).unwrap();
    assert_eq!(failed, 1);
    std::fs::remove_dir_all(&dir).unwrap();
}
