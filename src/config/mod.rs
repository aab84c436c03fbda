//! Experiment files: TOML with defaults for every stage, named variants (overrides), a grid of dataset sizes,
//! variants and seeds, an optional `include` of a base file and named scale `profiles`.
//!
//! Resolution order (later wins): included file, this file, the chosen profile, `--set` overrides, then a cell's
//! variant.
use crate::eval::EvalConfig;
use crate::model::config::ModelConfig;
use crate::sim::env::WorldConfig;
use crate::train::config::TrainConfig;
use crate::train::pretrain::PretrainConfig;
use anyhow::{Context, Result, bail};
use file::{FileShape, line_of, located, merge, read_table, shape_error};
use rules::{reject_train_seed, resolve, validate_grid};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

pub use crate::data::collect_config::CollectSettings;
pub use overrides::Override;

mod file;
pub mod overrides;
mod rules;
pub mod slurm;

/// How an experiment file is resolved: an optional scale profile, then `--set` overrides, in that order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Resolution {
    pub profile: Option<String>,
    pub overrides: Vec<Override>,
}

impl Resolution {
    /// The file as written, with only a profile (or none).
    pub fn profile(profile: Option<&str>) -> Resolution {
        Resolution { profile: profile.map(str::to_string), overrides: Vec::new() }
    }
}

/// Reference policies that are evaluated once per experiment through the same path as the models.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum Reference {
    Expert,
    Random,
}

impl<N> From<Reference> for crate::eval::Actor<N> {
    fn from(r: Reference) -> Self {
        match r {
            Reference::Expert => crate::eval::Actor::Expert,
            Reference::Random => crate::eval::Actor::Random,
        }
    }
}

impl Reference {
    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Reference::Expert => "expert",
            Reference::Random => "random",
        }
    }
}

/// The grid of cells.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct Grid {
    /// Training trajectories per robot, spread evenly over the collected tasks (`collect.tasks`; a multiple of
    /// their number): the paper's N = 1600 over 16 tasks is 100 per task.
    pub sizes: Vec<usize>,
    /// Variant names; `full` is the unmodified configuration.
    pub variants: Vec<String>,
    /// Training seeds.
    pub seeds: Vec<u64>,
    /// Reference policies evaluated once per experiment beside the models (`expert`, `random`).
    pub references: Vec<Reference>,
    /// Smaller sizes train on the first slots of each task of the largest size's collection (collected once per
    /// robot and collection settings), and share its pool of layouts; `false` collects every size separately (the
    /// authors' protocol), each with a pool of its own size under `collect.layouts = "shared"`. With
    /// `collect.layouts = "unique"` a size's trajectories are the same either way.
    pub nested: bool,
    /// Sweeps of any section key, e.g. `"train.lr" = [1e-3, 3e-3]`: each value makes a variant of every variant
    /// in `variants` (named from it, the key's last part and the value: `full-lr-0.001`), crossed with the
    /// sizes and seeds; several keys cross with each other.
    #[schemars(with = "BTreeMap<String, Vec<serde_json::Value>>")]
    pub sweep: BTreeMap<String, Vec<toml::Value>>,
}

impl Default for Grid {
    fn default() -> Self {
        Grid {
            sizes: vec![1600],
            variants: vec![FULL.into()],
            seeds: vec![0],
            references: Vec::new(),
            nested: true,
            sweep: BTreeMap::new(),
        }
    }
}

/// The variant without overrides.
pub const FULL: &str = "full";

/// Everything one cell's stages need.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct CellConfig {
    pub world: WorldConfig,
    pub collect: CollectSettings,
    pub model: ModelConfig,
    /// A stage that trains the image trunk before the policy (absent: the authors' start).
    pub pretrain: Option<PretrainConfig>,
    pub train: TrainConfig,
    pub eval: EvalConfig,
}

/// A cell of the grid.
#[derive(Debug, Clone, PartialEq)]
pub struct Cell {
    /// `size-variant-seed`, e.g. `n480-no_inverse-s1`.
    pub name: String,
    pub size: usize,
    pub variant: String,
    pub seed: u64,
    pub config: CellConfig,
}

impl Cell {
    /// Training trajectories per task and robot: the size spread over the collected tasks.
    pub fn per_task(&self) -> usize {
        self.size / self.config.collect.tasks.len()
    }
}

/// A loaded, validated experiment.
#[derive(Debug, Clone)]
pub struct Experiment {
    pub name: String,
    pub description: String,
    pub grid: Grid,
    pub base: CellConfig,
    pub cells: Vec<Cell>,
    /// What each stage kind's Slurm jobs request (`[slurm.KIND]`).
    pub slurm: slurm::SlurmSection,
    /// The profile and overrides it was resolved with.
    pub resolution: Resolution,
}

impl Experiment {
    /// Loads `path` with an optional scale profile and overrides; every error names the file and the key (and a
    /// line), or the override.
    pub fn load(path: &Path, resolution: &Resolution) -> Result<Experiment> {
        let (mut table, text) = read_table(path, 0)?;
        let file = path.display().to_string();
        let profile = resolution.profile.as_deref();
        if let Some(p) = profile {
            let profiles = table.get("profiles").and_then(|v| v.as_table());
            let Some(over) = profiles.and_then(|t| t.get(p)).and_then(|v| v.as_table()).cloned() else {
                let known: Vec<String> = profiles.map(|t| t.keys().cloned().collect()).unwrap_or_default();
                bail!(
                    "{file}: no profile `{p}` (profiles: {})",
                    if known.is_empty() { "none".into() } else { known.join(", ") }
                );
            };
            merge(&mut table, &over);
        }
        if let Some(key) = non_finite(&table, "") {
            bail!(
                "{file}{}: {key} is not a finite number",
                line_of(&text, key.rsplit('.').next().unwrap_or(""))
                    .map(|l| format!(" (line {l})"))
                    .unwrap_or_default()
            );
        }
        for o in &resolution.overrides {
            check_alone(o, "--set")?;
            o.apply(&mut table)?;
            if let Some(key) = non_finite(&table, "") {
                bail!("--set {o}: {key} is not a finite number");
            }
        }
        let mut what = match profile {
            Some(p) => format!("the file with profile `{p}`"),
            None => "the file".to_string(),
        };
        if !resolution.overrides.is_empty() {
            what = format!("{what} and {}", overrides::spelled(&resolution.overrides));
        }
        let shape: FileShape = toml::Value::Table(table).try_into().map_err(|e| shape_error(e, &file, &what, &text))?;
        let name = shape
            .name
            .clone()
            .unwrap_or_else(|| path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default());
        crate::fsio::check_plain_name("name", &name).with_context(|| {
            format!(
                "{file}{}: the experiment's name names its report folder",
                line_of(&text, "name").map(|l| format!(" (line {l})")).unwrap_or_default()
            )
        })?;
        let description = shape.description.clone().unwrap_or_default();
        let base_table = shape.sections();
        let (grid, variants) = (shape.grid, shape.variants);
        // A value out of range may come from a `--set`, so the base configuration's label names them.
        let base_label = match resolution.overrides.is_empty() {
            true => "the base configuration".to_string(),
            false => format!("the base configuration with {}", overrides::spelled(&resolution.overrides)),
        };
        reject_train_seed(&base_table, &file, &base_label, &text)?;
        for (name, over) in &variants {
            reject_train_seed(over, &file, &format!("variant `{name}`"), &text)?;
        }
        let base = resolve(&base_table, &file, &base_label, &text)?;
        validate_grid(&grid, &variants, &file, &text)?;
        for (variant, over) in &variants {
            crate::fsio::check_plain_name("variant", variant)
                .with_context(|| format!("{file}: variant names become cell and folder names"))?;
            // A variant the grid does not list is typed too (its keys and their types), so a typo waits for no
            // one; the listed ones are resolved in full below.
            let mut t = base_table.clone();
            merge(&mut t, over);
            toml::Value::Table(t)
                .try_into::<CellConfig>()
                .map_err(|e| located(e, &file, &format!("variant `{variant}`"), &text))?;
        }

        let sweep = sweep_points(&grid.sweep).with_context(|| format!("{file}: grid.sweep"))?;
        let mut cells = Vec::new();
        for (variant, swept) in grid.variants.iter().flat_map(|v| sweep.iter().map(move |p| (v, p))) {
            let mut t = base_table.clone();
            if variant != FULL {
                merge(&mut t, &variants[variant]);
            }
            for o in &swept.overrides {
                o.apply(&mut t)?;
            }
            let variant = &format!("{variant}{}", swept.suffix);
            let resolved = resolve(&t, &file, &format!("variant `{variant}`"), &text)?;
            let tasks = resolved.collect.tasks.len();
            for &size in &grid.sizes {
                if size % tasks != 0 {
                    bail!(
                        "{file}{}: grid.sizes contains {size}: variant `{variant}` collects {tasks} tasks \
                         (collect.tasks), so sizes must be multiples of {tasks}",
                        line_of(&text, "sizes").map(|l| format!(" (line {l})")).unwrap_or_default()
                    );
                }
                for &seed in &grid.seeds {
                    let mut config = resolved.clone();
                    config.train.seed = seed;
                    cells.push(Cell {
                        name: format!("n{size}-{variant}-s{seed}"),
                        size,
                        variant: variant.clone(),
                        seed,
                        config,
                    });
                }
            }
        }
        let slurm = shape.slurm.clone();
        slurm.validate().with_context(|| format!("{file}: in {what}"))?;
        Ok(Experiment { name, description, grid, base, cells, slurm, resolution: resolution.clone() })
    }
}

/// The dotted key of the first float in `table` that is NaN or infinite (no setting takes one).
fn non_finite(table: &toml::Table, prefix: &str) -> Option<String> {
    table.iter().find_map(|(k, v)| {
        let key = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
        match v {
            toml::Value::Float(f) if !f.is_finite() => Some(key),
            toml::Value::Table(t) => non_finite(t, &key),
            toml::Value::Array(items) => items.iter().find_map(|i| match i {
                toml::Value::Float(f) if !f.is_finite() => Some(key.clone()),
                toml::Value::Table(t) => non_finite(t, &key),
                _ => None,
            }),
            _ => None,
        }
    })
}

/// One point of a grid's sweep: the keys it sets and the suffix it adds to a variant's name.
struct SweepPoint {
    overrides: Vec<Override>,
    suffix: String,
}

/// Every combination of the sweep's values (one point with nothing set when there is no sweep); each key is
/// typed like a `--set`, and two values that would name the same variant are refused.
fn sweep_points(sweep: &BTreeMap<String, Vec<toml::Value>>) -> Result<Vec<SweepPoint>> {
    let mut points = vec![SweepPoint { overrides: Vec::new(), suffix: String::new() }];
    for (key, values) in sweep {
        if values.is_empty() {
            bail!("`{key}` has no values");
        }
        let path: Vec<String> = key.split('.').map(str::to_string).collect();
        let leaf = path.last().cloned().unwrap_or_default();
        let mut named = std::collections::BTreeSet::new();
        let mut next = Vec::new();
        for value in values {
            let o = Override { path: path.clone(), value: value.clone() };
            if !matches!(
                path.first().map(String::as_str),
                Some("world" | "collect" | "model" | "pretrain" | "train" | "eval")
            ) {
                bail!("`{key}` is not a key of a section (world, collect, model, pretrain, train or eval)");
            }
            check_alone(&o, "grid.sweep")?;
            let shown = match value {
                toml::Value::String(s) => s.clone(),
                v => v.to_string(),
            };
            let shown: String =
                shown.chars().map(|c| if c.is_ascii_alphanumeric() || "._-".contains(c) { c } else { '_' }).collect();
            if !named.insert(shown.clone()) {
                bail!("`{key}` has two values that name the same variant (`{leaf}-{shown}`)");
            }
            for p in &points {
                let mut overrides = p.overrides.clone();
                overrides.push(o.clone());
                next.push(SweepPoint { overrides, suffix: format!("{}-{leaf}-{shown}", p.suffix) });
            }
        }
        points = next;
    }
    Ok(points)
}

/// Types one override (`label`: where it comes from, `--set` or `grid.sweep`) on its own (a section key against its section, a variant's key against the sections, a
/// top-level key against the file's shape), so that an unknown key or a wrong type is reported against the
/// override itself rather than a line of the file.
fn check_alone(o: &Override, label: &str) -> Result<()> {
    const SECTIONS: [&str; 6] = ["world", "collect", "model", "pretrain", "train", "eval"];
    if o.path.first().is_some_and(|p| p == "profiles") {
        bail!("{label} {o}: a profile applies before the overrides; pick it with --profile and set its keys directly");
    }
    let in_cell = match o.path.as_slice() {
        [variants, _, rest @ ..] if variants == "variants" && !rest.is_empty() => Some(rest),
        [section, ..] if SECTIONS.contains(&section.as_str()) => Some(o.path.as_slice()),
        _ => None,
    };
    let typed = match in_cell {
        Some(path) => {
            if !SECTIONS.contains(&path[0].as_str()) {
                bail!("{label} {o}: `{}` is not a section (sections: {})", path[0], SECTIONS.join(", "));
            }
            // Set onto the defaults, so that a key of a nested table (`world.image.height`) is typed beside
            // its siblings.
            let mut table = toml::Table::try_from(CellConfig::default()).context("the default configuration")?;
            Override { path: path.to_vec(), value: o.value.clone() }.apply(&mut table)?;
            toml::Value::Table(table).try_into::<CellConfig>().map(drop)
        }
        None => {
            let mut table = toml::Table::new();
            o.apply(&mut table)?;
            toml::Value::Table(table).try_into::<FileShape>().map(drop)
        }
    };
    typed.map_err(|e| anyhow::anyhow!("{label} {o}: {}", e.message()))
}

impl CellConfig {
    /// Reads a file of sections (`[world]`, `[collect]`, `[model]`, `[train]`, `[eval]`; all optional, the
    /// paper's values by default), e.g. for `train --config`; errors name the file, the line and the key.
    pub fn load(path: &Path) -> Result<CellConfig> {
        let file = path.display().to_string();
        let text = file::read_text(path)?;
        let table: toml::Table = toml::from_str(&text).with_context(|| format!("in {file}"))?;
        // Typed straight from the text first: its errors carry their position in the file.
        toml::from_str::<CellConfig>(&text).map_err(|e| located(e, &file, "the file", &text))?;
        resolve(&table, &file, "the file", &text)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::pretrain::LocaliseTarget;

    fn load(text: &str) -> Result<Experiment> {
        let dir = std::env::temp_dir().join(format!(
            "oneshot-config-{}-{}",
            std::process::id(),
            blake3::hash(text.as_bytes())
        ));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("e.toml");
        std::fs::write(&path, text).unwrap();
        let e = Experiment::load(&path, &Resolution::default());
        std::fs::remove_dir_all(&dir).unwrap();
        e
    }

    #[test]
    fn evaluation_covers_the_collected_tasks_and_the_grid_sets_training_seeds() {
        let e = load("[collect]\ntasks = [0, 5]\n[grid]\nsizes = [32]\nseeds = [4, 7]\n").unwrap();
        assert!(e.cells.iter().all(|c| c.config.eval.tasks == [0, 5]));
        assert_eq!(e.cells.iter().map(|c| c.config.train.seed).collect::<Vec<_>>(), [4, 7]);
        let own = load("[collect]\ntasks = [0, 5]\n[eval]\ntasks = [5]\n[grid]\nsizes = [32]\n").unwrap();
        assert_eq!(own.cells[0].config.eval.tasks, [5]);
    }

    #[test]
    fn slurm_sections_give_each_kind_its_resources_and_unknown_names_are_refused() {
        let grid = "[grid]\nsizes = [16]\n";
        let e = load(&format!("[slurm.train]\npartition = \"gpu\"\ncpus = 4\n{grid}")).unwrap();
        assert_eq!((e.slurm.train.partition.as_deref(), e.slurm.train.cpus), (Some("gpu"), Some(4)));
        assert_eq!(e.slurm.collect, Default::default());
        let err = |text: &str| format!("{:#}", load(text).unwrap_err());
        assert!(err(&format!("[slurm.trian]\ncpus = 4\n{grid}")).contains("trian"));
        assert!(err(&format!("[slurm.train]\nwalltime = \"1:00:00\"\n{grid}")).contains("walltime"));
        assert!(err(&format!("[slurm.eval]\ncpus = 0\n{grid}")).contains("slurm.eval.cpus"));
    }

    #[test]
    fn a_pretrain_section_must_be_the_only_start_of_a_resnet_trunk() {
        let grid = "[grid]\nsizes = [16]\n";
        let e = load(&format!("[pretrain]\nsteps = 50\n{grid}")).unwrap();
        let p = e.cells[0].config.pretrain.as_ref().unwrap();
        assert_eq!((p.steps, p.target, p.augmentation.as_ref()), (50, LocaliseTarget::Objects, None));
        assert_eq!(load(grid).unwrap().cells[0].config.pretrain, None, "absent: the authors' start");
        let err = |text: &str| format!("{:#}", load(text).unwrap_err());
        let weights = concat!(env!("CARGO_MANIFEST_DIR"), "/Cargo.toml");
        let both = err(&format!("[pretrain]\n[model]\npretrained_backbone = {weights:?}\n{grid}"));
        assert!(both.contains("[pretrain] and model.pretrained_backbone"), "{both}");
        let vgg = err(&format!(
            "[pretrain]\n[model]\narchitecture = \"daml\"\n[train.loss]\ninverse = 0.0\npoint = 0.0\n{grid}"
        ));
        assert!(vgg.contains("[pretrain]") && vgg.contains("no ResNet-18 trunk"), "{vgg}");
        let zero = err(&format!("[pretrain]\nsteps = 0\n{grid}"));
        assert!(zero.contains("pretrain.steps"), "{zero}");
        let frozen = err(&format!("[model]\nfreeze_backbone = true\n{grid}"));
        assert!(frozen.contains("needs model.pretrained_backbone or [pretrain]"), "{frozen}");
        let library = err(&format!("[world]\nobjects = \"library\"\n[collect]\nlayouts = \"unique\"\n{grid}"));
        assert!(library.contains("collect.layouts") && library.contains("environment_instances"), "{library}");
        load(&format!("[world]\nobjects = \"library\"\n{grid}")).unwrap();
    }

    #[test]
    fn overrides_are_typed_beside_their_siblings_and_named_when_wrong() {
        let dir = std::env::temp_dir().join(format!("oneshot-config-overrides-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("e.toml");
        std::fs::write(&path, "[world.image]\nheight = 32\nwidth = 40\n[grid]\nsizes = [16]\n").unwrap();
        let with = |sets: &[&str]| {
            let overrides = sets.iter().map(|s| s.parse().unwrap()).collect();
            Experiment::load(&path, &Resolution { profile: None, overrides })
        };
        let e = with(&["world.image.height=48"]).unwrap();
        assert_eq!((e.cells[0].config.world.image.height, e.cells[0].config.world.image.width), (48, 40));
        let err = |sets: &[&str]| format!("{:#}", with(sets).unwrap_err());
        assert!(err(&["world.image.height=tall"]).contains("--set world.image.height"));
        let nan = err(&["train.lr=nan"]);
        assert!(nan.starts_with("--set train.lr=nan: train.lr is not a finite number"), "{nan}");
        let small = err(&["world.image.height=7"]);
        assert!(small.contains("with --set world.image.height=7") && small.contains("out of range"), "{small}");
        assert!(err(&["profiles.cpu.train.steps=5"]).contains("--profile"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn every_variant_is_checked_and_no_grid_list_repeats_a_value() {
        let err = |text: &str| format!("{:#}", load(text).unwrap_err());
        let grid = "[grid]\nsizes = [16]\n";
        assert!(err(&format!("[variants.x]\ntrain.lrr = 0.1\n{grid}")).contains("lrr"), "unlisted, still checked");
        assert!(err(&format!("[variants.full]\ntrain.steps = 7\n{grid}")).contains("[variants.full]"));
        assert!(err("[grid]\nsizes = [16, 16]\n").contains("grid.sizes lists 16 twice"));
        assert!(err("[grid]\nsizes = [16]\nseeds = [0, 0]\n").contains("grid.seeds lists 0 twice"));
        assert!(err("[grid]\nsizes = [16]\nvariants = [\"full\", \"full\"]\n").contains("grid.variants"));
    }

    #[test]
    fn a_configuration_file_is_a_regular_file_of_bounded_size() {
        let err = |path: &str| format!("{:#}", Experiment::load(Path::new(path), &Resolution::default()).unwrap_err());
        assert!(err("/dev/zero").contains("not a regular file"));
        assert!(err("/").contains("not a regular file"));
        let dir = std::env::temp_dir().join(format!("oneshot-config-big-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("big.toml");
        std::fs::write(&path, "#".repeat(2 << 20)).unwrap();
        assert!(err(path.to_str().unwrap()).contains("at most"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn merge_is_deep_and_later_wins() {
        let mut a: toml::Table = toml::from_str("[train]\nlr = 1.0\nsteps = 5\n[train.loss]\nbc = 1.0\n").unwrap();
        let b: toml::Table = toml::from_str("[train]\nlr = 2.0\n[train.loss]\npoint = 0.0\n").unwrap();
        merge(&mut a, &b);
        let t = a["train"].as_table().unwrap();
        assert_eq!((t["lr"].as_float(), t["steps"].as_integer()), (Some(2.0), Some(5)));
        let loss = t["loss"].as_table().unwrap();
        assert_eq!((loss["bc"].as_float(), loss["point"].as_float()), (Some(1.0), Some(0.0)));
    }
}
