//! Options several commands share: the results store, the frames of rendered scenes, and the parser of names in
//! the configuration's spelling.
use oneshot_lab::config::{Override, Resolution};
use oneshot_lab::pipeline::store::Store;
use oneshot_lab::sim::camera::ImageSize;
use oneshot_lab::sim::camera::Visuals;
use oneshot_lab::sim::env::WorldConfig;
use oneshot_lab::sim::robot::Robot;
use std::path::PathBuf;

/// The results store's folder when `--store` is not given.
pub const DEFAULT_STORE: &str = "runs";

/// The results store.
#[derive(clap::Args)]
pub struct StoreDir {
    /// Store folder (database and artifacts).
    #[arg(long, default_value = DEFAULT_STORE)]
    pub store: PathBuf,
}

/// The results store, for the commands that only read it (`why`, `status`, `query`, `diff`).
#[derive(clap::Args)]
pub struct ReadStoreDir {
    /// Store folder (database and artifacts).
    #[arg(long, default_value = DEFAULT_STORE)]
    pub store: PathBuf,
    /// Open the store without writing anything to it (automatic where this process cannot write its folder,
    /// such as a shared results folder).
    #[arg(long)]
    pub read_only: bool,
}

impl ReadStoreDir {
    /// The store, opened for reading.
    pub fn open(&self) -> anyhow::Result<Store> {
        Store::open_for_reading(&self.store, self.read_only)
    }
}

/// How an experiment file is resolved: its scale profile and `--set` overrides.
#[derive(clap::Args)]
pub struct ResolutionArgs {
    /// Scale profile defined in the experiment file (e.g. `cpu`).
    #[arg(long)]
    pub profile: Option<String>,
    /// Sets one key of the experiment file, after the profile (repeatable), e.g. `--set train.steps=50`; checked
    /// like the file.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<Override>,
}

impl ResolutionArgs {
    /// The profile and overrides to resolve the experiment file with.
    pub fn resolution(&self) -> Resolution {
        Resolution { profile: self.profile.clone(), overrides: self.set.clone() }
    }
}

/// The results store, and how the experiment file is resolved.
#[derive(clap::Args)]
pub struct StoreArgs {
    #[command(flatten)]
    pub dir: StoreDir,
    #[command(flatten)]
    pub file: ResolutionArgs,
}

impl StoreArgs {
    /// The profile and overrides to resolve the experiment file with.
    pub fn resolution(&self) -> Resolution {
        self.file.resolution()
    }
}

/// Frame size and visuals of rendered scenes (each defaults to the `[world]` default).
#[derive(clap::Args)]
pub struct FrameArgs {
    /// Frame height (pixels).
    #[arg(long)]
    pub height: Option<usize>,
    /// Frame width (pixels).
    #[arg(long)]
    pub width: Option<usize>,
    /// `full` visual meshes, or `collision` geometry only.
    #[arg(long, value_parser = parse_visuals)]
    pub visuals: Option<Visuals>,
}

impl FrameArgs {
    /// The default world with these frames.
    pub fn world(&self) -> WorldConfig {
        let d = WorldConfig::default();
        let image =
            ImageSize { height: self.height.unwrap_or(d.image.height), width: self.width.unwrap_or(d.image.width) };
        WorldConfig { image, visuals: self.visuals.unwrap_or(d.visuals), ..d }
    }

    /// Whether any frame option was given.
    pub fn given(&self) -> bool {
        self.height.is_some() || self.width.is_some() || self.visuals.is_some()
    }
}

/// A count that must be at least 1 (jobs, workers).
pub fn at_least_one(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(0) => Err("must be at least 1".into()),
        Ok(n) => Ok(n),
        Err(e) => Err(format!("`{s}`: {e}")),
    }
}

/// A lower-case name in the configuration's spelling, parsed as its type (a robot, visuals, a localisation target).
pub fn parse_named<T: serde::de::DeserializeOwned>(s: &str) -> Result<T, String> {
    serde_json::from_value(serde_json::Value::String(s.to_string())).map_err(|e| format!("`{s}`: {e}"))
}

/// `sawyer` or `panda`.
pub fn parse_robot(s: &str) -> Result<Robot, String> {
    parse_named(s)
}

fn parse_visuals(s: &str) -> Result<Visuals, String> {
    parse_named(s)
}

/// How `plan`, `status` and `why` print.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum OutputFormat {
    /// Lines for people.
    Text,
    /// One JSON document for scripts.
    Json,
}
