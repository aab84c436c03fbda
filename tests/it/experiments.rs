//! The shipped experiment files: every one loads at paper scale and under its `cpu` profile, and the paper's
//! tables have their models.
use oneshot_lab::config::{Experiment, Resolution};
use oneshot_lab::eval::config::Control;
use oneshot_lab::pipeline::graph::PlannedCell;
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
        let e =
            Experiment::load(file, &Resolution::default()).unwrap_or_else(|err| panic!("{}: {err:#}", file.display()));
        assert!(!e.cells.is_empty(), "{}", file.display());
        if std::fs::read_to_string(file).unwrap().contains("[profiles.cpu]") {
            Experiment::load(file, &Resolution::profile(Some("cpu")))
                .unwrap_or_else(|err| panic!("{} --profile cpu: {err:#}", file.display()));
        }
    }
}

#[test]
fn the_baselines_file_has_every_table_1_model() {
    for profile in [None, Some("cpu")] {
        let e = Experiment::load(Path::new("experiments/baselines.toml"), &Resolution::profile(profile)).unwrap();
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
    let e = Experiment::load(Path::new("experiments/ablations.toml"), &Resolution::default()).unwrap();
    assert_eq!(e.grid.sizes, [480, 800, 1600]);
    assert_eq!(collection_totals(&plan(&e)), (2, 2 * 1600), "the 480 and 800 sets are slots of the 1600 collection");
}

#[test]
fn a_pretrained_trunk_file_keys_training_by_its_content_and_must_exist() {
    use oneshot_lab::pipeline::stages::plan;
    let dir = std::env::temp_dir().join(format!("oneshot-pretrained-key-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (weights, file) = (dir.join("trunk.safetensors"), dir.join("exp.toml"));
    let text = format!(
        "[world]\nimage = {{ height = 32, width = 40 }}\n[model]\npretrained_backbone = {:?}\n[grid]\nsizes = [16]\n",
        weights.to_string_lossy()
    );
    std::fs::write(&file, text).unwrap();
    let err = format!("{:#}", Experiment::load(&file, &Resolution::default()).unwrap_err());
    assert!(err.contains("model.pretrained_backbone") && err.contains("no such file"), "{err}");

    let frozen = dir.join("frozen.toml");
    std::fs::write(&frozen, "[model]\nfreeze_backbone = true\n[grid]\nsizes = [16]\n").unwrap();
    let err = format!("{:#}", Experiment::load(&frozen, &Resolution::default()).unwrap_err());
    assert!(err.contains("frozen.toml") && err.contains("model.freeze_backbone"), "{err}");
    let copy = "[model]\nobject_attention = true\nobject_attention_input = \"frozen_trunk\"\n[grid]\nsizes = [16]\n";
    std::fs::write(&frozen, copy).unwrap();
    let err = format!("{:#}", Experiment::load(&frozen, &Resolution::default()).unwrap_err());
    assert!(err.contains("frozen.toml") && err.contains("frozen_trunk") && err.contains("[pretrain]"), "{err}");

    let train_and_eval = |bytes: &[u8]| {
        std::fs::write(&weights, bytes).unwrap();
        let p = plan(&Experiment::load(&file, &Resolution::default()).unwrap());
        let cell = &p.cells[0];
        (cell.train.clone().unwrap(), cell.eval.clone(), cell.collect_agent.clone().unwrap())
    };
    let first = train_and_eval(b"one");
    let same = train_and_eval(b"one");
    let changed = train_and_eval(b"two");
    assert_eq!(first, same, "the same file content, the same keys");
    assert_ne!(first.0, changed.0, "new weights retrain");
    assert_ne!(first.1, changed.1, "and re-evaluate");
    assert_eq!(first.2, changed.2, "collections do not depend on them");

    // A relative path is read from the experiment file's folder (not the working directory, the repository
    // here), and where the weights lie does not enter the key: a copy elsewhere, named relatively, keys the same.
    std::fs::write(&weights, b"one").unwrap();
    let sub = dir.join("sub");
    std::fs::create_dir_all(&sub).unwrap();
    std::fs::write(sub.join("copy.safetensors"), b"one").unwrap();
    let train_key = |file: &std::path::Path, path: &str| {
        let text = format!(
            "[world]\nimage = {{ height = 32, width = 40 }}\n[model]\npretrained_backbone = {path:?}\n[grid]\nsizes = [16]\n"
        );
        std::fs::write(file, text).unwrap();
        plan(&Experiment::load(file, &Resolution::default()).unwrap()).cells[0].train.clone().unwrap()
    };
    assert_eq!(train_key(&dir.join("relative.toml"), "trunk.safetensors"), first.0);
    assert_eq!(train_key(&sub.join("copy.toml"), "copy.safetensors"), first.0);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn every_shipped_train_config_loads() {
    let files: Vec<_> = std::fs::read_dir("experiments/train").unwrap().map(|e| e.unwrap().path()).collect();
    assert!(files.len() >= 2, "{files:?}");
    for file in files {
        oneshot_lab::config::CellConfig::load(&file).unwrap_or_else(|err| panic!("{}: {err:#}", file.display()));
    }
}

#[test]
fn window_start_is_checked_and_the_authors_value_leaves_keys_unchanged() {
    use oneshot_lab::config::CellConfig;
    let dir = std::env::temp_dir().join(format!("oneshot-window-start-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let load = |text: &str| {
        let file = dir.join("train.toml");
        std::fs::write(&file, text).unwrap();
        CellConfig::load(&file)
    };
    let err = format!("{:#}", load("[train]\nwindow_start = 0.9\n").unwrap_err());
    assert!(err.contains("train.window_start") && err.contains("0.9"), "{err}");
    assert!(load("[train]\nwindow_start = 0.5\n").is_ok());
    std::fs::remove_dir_all(&dir).unwrap();
    let train = |extra: &str| stage_inputs(extra, |c| c.train.clone())["train"].clone();
    assert!(train("[train]\nwindow_start = 0.2\n").get("window_start").is_none(), "the authors' value");
    assert_eq!(train("[train]\nwindow_start = 0.5\n")["window_start"], 0.5);
}

/// The key inputs of one stage of a one-cell experiment with `extra` sections (`which` picks the stage key).
fn stage_inputs(extra: &str, which: impl Fn(&PlannedCell) -> Option<String>) -> serde_json::Value {
    use oneshot_lab::pipeline::stages::plan;
    let dir = crate::helpers::scratch(&format!("experiments-keys-{}", blake3::hash(extra.as_bytes())));
    let file = dir.join("exp.toml");
    std::fs::write(&file, format!("{extra}[collect]\ntasks = [0]\n[grid]\nsizes = [16]\n")).unwrap();
    let p = plan(&Experiment::load(&file, &Resolution::default()).unwrap());
    let key = which(&p.cells[0]).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    p.stages[&key].inputs.clone()
}

#[test]
fn settings_added_after_keys_existed_stay_out_of_them_at_their_first_value() {
    let eval = |extra: &str| stage_inputs(extra, |c| Some(c.eval.clone()))["eval"].clone();
    assert!(eval("").get("control").is_none(), "the default is left out of stage keys");
    let scripted = "[model]\narchitecture = \"daml\"\n[train.loss]\ninverse = 0.0\npoint = 0.0\n\
                    [eval]\ncontrol = \"scripted_poses\"\n";
    assert_eq!(eval(scripted)["control"], "scripted_poses");
    assert!(eval("").get("videos").is_none());
    let model = |extra: &str| stage_inputs(extra, |c| c.train.clone())["model"].clone();
    assert!(model("").get("pose_head").is_none() && model("").get("freeze_backbone").is_none());
    assert_eq!(model("[model]\npose_head = true\n")["pose_head"], true);
    assert!(model("").get("object_attention").is_none());
    // The authors' action quantisation is the default and in the key; the exact actions of earlier keys are not.
    let train = |extra: &str| stage_inputs(extra, |c| c.train.clone())["train"].clone();
    assert_eq!(train("")["action_resolution"], 128);
    assert!(train("[train]\naction_resolution = 0\n").get("action_resolution").is_none());
    assert_eq!(model("[model]\nobject_attention = true\n")["object_attention"], true);
    // Trainings that read the robot's state are keyed by its encoding; the others are not.
    let inputs = |extra: &str| stage_inputs(extra, |c| c.train.clone());
    assert!(inputs("").get("state_version").is_none());
    assert_eq!(inputs("[model]\nconcat_state = true\n")["state_version"], oneshot_lab::sim::env::STATE_VERSION);
    let world = |extra: &str| stage_inputs(extra, |c| c.collect_agent.clone())["world"].clone();
    assert!(world("").get("close_on_arrival").is_none());
    assert_eq!(world("[world]\nclose_on_arrival = true\n")["close_on_arrival"], true);
    let eval_world = |extra: &str| stage_inputs(extra, |c| Some(c.eval.clone()))["world"].clone();
    for w in [world, eval_world] {
        assert!(w("").get("rise_on_grip").is_none(), "left out of collect and eval keys at its default");
        assert_eq!(w("[world]\nrise_on_grip = true\n")["rise_on_grip"], true);
    }
}

#[test]
fn a_smaller_nested_size_pretrains_its_trunk_on_its_own_layouts() {
    use oneshot_lab::pipeline::stages::plan;
    let dir = std::env::temp_dir().join(format!("oneshot-pretrain-nested-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("exp.toml");
    let text =
        "[collect]\ntasks = [0]\n[model]\nbackbone_width = 8\n[pretrain]\nsteps = 10\n[grid]\nsizes = [16, 32]\n";
    std::fs::write(&file, text).unwrap();
    let p = plan(&Experiment::load(&file, &Resolution::default()).unwrap());
    let (small, large) = (&p.cells[0], &p.cells[1]);
    assert_eq!(small.collect_agent, large.collect_agent, "one nested collection");
    let (small_key, large_key) = (small.pretrain.clone().unwrap(), large.pretrain.clone().unwrap());
    assert_ne!(small_key, large_key);
    assert_eq!(p.stages[&small_key].inputs["per_task"], 16);
    assert!(p.stages[&large_key].inputs.get("per_task").is_none(), "the largest size uses the whole collection");
    assert!(p.stages[&small.train.clone().unwrap()].upstream.contains(&small_key));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_sweep_crosses_its_values_with_the_variants_and_seeds_and_changes_only_the_keys_it_touches() {
    use oneshot_lab::pipeline::stages::plan;
    let dir = crate::helpers::scratch("experiments-sweep");
    let file = dir.join("exp.toml");
    let write = |sweep: &str| {
        std::fs::write(
            &file,
            format!(
                "[collect]\ntasks = [0]\n[variants.no_inverse]\ntrain.loss.inverse = 0.0\n[grid]\nsizes = [16]\n\
                 variants = [\"full\", \"no_inverse\"]\nseeds = [0, 1]\n[grid.sweep]\n{sweep}"
            ),
        )
        .unwrap();
    };
    write("\"train.lr\" = [0.001, 0.003]\n\"model.context\" = [\"spread\", \"final\"]\n");
    let e = Experiment::load(&file, &Resolution::default()).unwrap();
    assert_eq!(e.cells.len(), 2 * 2 * 2 * 2, "variants x lr x context x seeds");
    let cell = e.cells.iter().find(|c| c.name == "n16-no_inverse-context-final-lr-0.003-s1").unwrap();
    assert_eq!(cell.config.train.lr, 0.003);
    assert_eq!(cell.config.train.loss.inverse, 0.0, "the variant's own change stays");
    assert_eq!(cell.config.model.context, oneshot_lab::model::config::ContextMode::Final);
    assert_eq!(cell.config.train.seed, 1);
    let p = plan(&e);
    let of = |name: &str| p.cells.iter().find(|c| c.name == name).unwrap();
    let (a, b) = (of("n16-full-context-spread-lr-0.001-s0"), of("n16-full-context-spread-lr-0.003-s0"));
    assert_eq!(a.collect_agent, b.collect_agent, "the learning rate does not touch the collection");
    assert_ne!(a.train, b.train);

    for (sweep, named) in [
        ("\"train.lrr\" = [0.1]\n", "grid.sweep train.lrr=0.1"),
        ("\"train.lr\" = [\"fast\"]\n", "train.lr"),
        ("\"train.lr\" = [-1.0]\n", "train.lr = -1"),
        ("\"train.lr\" = []\n", "`train.lr` has no values"),
        ("\"name\" = [\"x\"]\n", "`name` is not a key of a section"),
        ("\"model.context\" = [\"final\", \"final\"]\n", "name the same variant"),
    ] {
        write(sweep);
        let err = format!("{:#}", Experiment::load(&file, &Resolution::default()).unwrap_err());
        assert!(err.contains(named) && err.contains("exp.toml"), "{sweep}: {err}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn paper_base_spells_out_the_papers_values_and_they_are_the_defaults() {
    use oneshot_lab::config::CellConfig;
    let e = Experiment::load(Path::new("experiments/paper_base.toml"), &Resolution::default()).unwrap();
    let b = &e.base;
    // The paper and the authors' `base.yaml` (../shared/design.md): 240x320 frames at 10 Hz, ResNet-18 features
    // into two attention layers of inner width 128, 40-wide embeddings, 2 logistic mixtures over 256 bins,
    // Adam at 5e-4 with batch 30 for 60k steps, BC + inverse + 0.1 point, 160 test episodes of 60 actions.
    assert_eq!((b.world.image.height, b.world.image.width, b.world.policy_hz), (240, 320, 10.0));
    assert_eq!((b.model.backbone_width, b.model.attention_layers, b.model.attention_inner), (64, 2, 128));
    assert_eq!((b.model.latent, b.model.mixtures, b.model.bins, b.model.dropout), (40, 2, 256, 0.2));
    assert_eq!((b.model.context_frames, b.model.agent_frames), (4, 7));
    assert_eq!((b.train.steps, b.train.batch_size, b.train.lr), (60_000, 30, 5e-4));
    assert_eq!((b.train.loss.bc, b.train.loss.inverse, b.train.loss.point), (1.0, 1.0, 0.1));
    assert_eq!((b.eval.episodes, b.eval.horizon), (160, 60));
    // Every value it spells out is the built-in default: a change of a default shows up here.
    assert_eq!(b, &CellConfig::default());
}
