//! The shipped experiment files: every one loads at paper scale and under its `cpu` profile, and the paper's
//! tables have their models.
use oneshot_lab::config::Experiment;
use oneshot_lab::eval::config::Control;
use std::path::Path;

#[test]
fn every_shipped_experiment_loads_with_and_without_its_profile() {
    let mut files: Vec<_> = std::fs::read_dir("experiments")
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml") && !p.ends_with("paper_base.toml"))
        .collect();
    files.sort();
    assert!(files.len() >= 5, "{files:?}");
    for file in &files {
        let e = Experiment::load(file, None).unwrap_or_else(|err| panic!("{}: {err:#}", file.display()));
        assert!(!e.cells.is_empty(), "{}", file.display());
        if std::fs::read_to_string(file).unwrap().contains("[profiles.cpu]") {
            Experiment::load(file, Some("cpu"))
                .unwrap_or_else(|err| panic!("{} --profile cpu: {err:#}", file.display()));
        }
    }
}

#[test]
fn the_baselines_file_has_every_table_1_model() {
    for profile in [None, Some("cpu")] {
        let e = Experiment::load(Path::new("experiments/baselines.toml"), profile).unwrap();
        let models: Vec<(String, Control)> =
            e.cells.iter().map(|c| (c.config.model.architecture.0.clone(), c.config.eval.control)).collect();
        for wanted in [
            ("transformer", Control::Policy),
            ("contextual_lstm", Control::Policy),
            ("daml", Control::Policy),
            ("daml", Control::ScriptedPoses),
        ] {
            assert!(models.iter().any(|(a, c)| a == wanted.0 && *c == wanted.1), "{wanted:?} missing: {models:?}");
        }
    }
}

#[test]
fn the_ablations_grid_collects_once_per_robot() {
    use oneshot_lab::pipeline::stages::{collection_totals, plan};
    let e = Experiment::load(Path::new("experiments/ablations.toml"), None).unwrap();
    assert_eq!(e.grid.sizes, [480, 800, 1600]);
    assert_eq!(collection_totals(&plan(&e)), (2, 2 * 1600), "the 480 and 800 sets are slots of the 1600 collection");
}
