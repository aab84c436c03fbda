//! End to end: the main job, `experiments/smoke.toml`, run for real into a scratch store.
use rusqlite::Connection;
use std::process::Command;

#[test]
fn the_smoke_experiment_runs_the_whole_chain_and_reports() {
    let store = std::env::temp_dir().join(format!("oneshot-test-smoke-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&store);
    let out = Command::new(env!("CARGO_BIN_EXE_oneshot-lab"))
        .args(["run", "experiments/smoke.toml", "--store", store.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("smoke: 8 stages run, 0 cached, 0 failed, 0 skipped"), "{stdout}");

    let db = Connection::open(store.join("oneshot.sqlite")).unwrap();
    let placed = |cell: &str| -> (i64, i64) {
        db.query_row(
            "SELECT COUNT(*), SUM(placed) FROM episodes WHERE eval_key = (SELECT eval_key FROM cells WHERE cell = ?1)",
            [cell],
            |r| Ok((r.get(0)?, r.get(1)?)),
        )
        .unwrap()
    };
    let (n, expert) = placed("expert");
    assert!(n == 16 && expert >= 15, "expert placed {expert} of {n}");
    assert_eq!(placed("random"), (16, 0));
    assert_eq!(placed("n32-full-s0").0, 16);
    let (first, last): (f64, f64) = db
        .query_row(
            "SELECT (SELECT bc FROM loss_curves WHERE train_key = c.train_key AND split = 'val' ORDER BY step LIMIT 1),
                    (SELECT bc FROM loss_curves WHERE train_key = c.train_key AND split = 'val' ORDER BY step DESC LIMIT 1)
             FROM cells c WHERE c.cell = 'n32-full-s0'",
            [],
            |r| Ok((r.get(0)?, r.get(1)?)),
        )
        .unwrap();
    assert!(last < first - 0.3, "validation BC {first} -> {last}");

    let report = store.join("reports/smoke");
    for f in ["index.md", "table1.md", "table1.csv", "table1.tex", "context.md"] {
        assert!(report.join(f).exists(), "{f}");
    }
    for fig in ["success_by_configuration", "success_vs_size", "loss_curves"] {
        let png = image::open(report.join(format!("{fig}.png"))).unwrap().to_rgb8();
        assert_eq!((png.width(), png.height()), (900, 560));
        let inked = png.pixels().filter(|p| p.0.iter().any(|&c| c < 128)).count();
        assert!(inked > 2000, "{fig}.png is almost blank");
        assert!(std::fs::read_to_string(report.join(format!("{fig}.svg"))).unwrap().contains("<text"));
    }
    let index = std::fs::read_to_string(report.join("index.md")).unwrap();
    assert!(index.contains("| expert | 1/1 |") && index.contains("code version"));
    // Every evaluated policy recorded episode 0 (task 0) as a video, copied beside the report and linked.
    let videos: Vec<String> = std::fs::read_dir(report.join("videos"))
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    assert_eq!(videos.len(), 4, "{videos:?}");
    for v in &videos {
        assert!(v.contains("episode_0000_task00") && index.contains(&format!("(videos/{v})")), "{v}");
        let gif = std::fs::File::open(report.join("videos").join(v)).unwrap();
        let decoder = image::codecs::gif::GifDecoder::new(std::io::BufReader::new(gif)).unwrap();
        let frames: Vec<_> = image::AnimationDecoder::into_frames(decoder).collect::<Result<_, _>>().unwrap();
        assert!(frames.len() > 20, "{v} has {} frames", frames.len());
        // Rendered 320 wide (eval.video_width) beside the demonstration, though the policy sees 64x80.
        assert_eq!(frames[0].buffer().width(), 2 * 320, "{v}");
    }
    // The self-contained page: every figure inlined as SVG, every video embedded, no link into the folder but the
    // table files.
    let html = std::fs::read_to_string(report.join("index.html")).unwrap();
    assert_eq!(html.matches("<figure><svg").count(), 3, "three figures inlined");
    assert_eq!(html.matches("src=\"data:image/gif;base64,").count(), 4, "four videos embedded");
    assert!(!html.contains(".png\"") && !html.contains("videos/"), "no reference to files beside the page");

    // A report of one training seed goes beside the pooled one, says so, and keeps the references; a seed the
    // experiment has not got is an error naming it.
    let report_seed = |seed: &str| {
        Command::new(env!("CARGO_BIN_EXE_oneshot-lab"))
            .args(["report", "experiments/smoke.toml", "--seed", seed, "--store", store.to_str().unwrap()])
            .output()
            .unwrap()
    };
    let out = report_seed("0");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let seed0 = std::fs::read_to_string(store.join("reports/smoke@seed-0/index.md")).unwrap();
    assert!(seed0.contains("from the cells of training seed 0 only") && seed0.contains("| expert | 1/1 |"), "{seed0}");
    assert!(seed0.contains("| full @ 32 | 1/1 |"), "{seed0}");
    assert_eq!(std::fs::read_to_string(report.join("index.md")).unwrap(), index, "the pooled report is untouched");
    let out = report_seed("7");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--seed 7") && err.contains("its seeds: 0"), "{err}");
    assert!(!store.join("reports/smoke@seed-7").exists());
    std::fs::remove_dir_all(&store).unwrap();
}
