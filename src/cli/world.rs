//! `expert-check`, `collect` and `contact-sheet`: the world and its scripted expert.
use super::default_workers;
use super::options::{FrameArgs, parse_robot};
use anyhow::{Context, Result, bail};
use oneshot_lab::data::collect;
use oneshot_lab::data::collect_config::{CollectConfig, LayoutSharing};
use oneshot_lab::sim::env::{Env, GripperYaw, WorldConfig};
use oneshot_lab::sim::expert_check::{ExpertReport, expert_check as check};
use oneshot_lab::sim::robot::Robot;
use oneshot_lab::sim::task::{Instance, NUM_TASKS, Task};
use std::path::{Path, PathBuf};

/// Arguments of the `expert-check` command.
#[derive(clap::Args)]
pub struct ExpertCheckArgs {
    /// `sawyer` (the demonstrator) or `panda` (the agent).
    #[arg(long, value_parser = parse_robot)]
    pub robot: Robot,
    /// Instances of each of the 16 tasks.
    #[arg(long, default_value_t = 10)]
    pub per_task: usize,
    /// Root seed of the layouts.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Action budget per episode (default: collect.max_actions).
    #[arg(long)]
    pub max_actions: Option<usize>,
    /// The expert's gripper yaw rule (default: the robot's in the default world).
    #[arg(long, value_enum)]
    pub gripper_yaw: Option<YawRule>,
    /// The expert closes the gripper on reaching the grasp point (world.close_on_arrival).
    #[arg(long)]
    pub close_on_arrival: bool,
}

/// How the scripted expert turns its gripper about the vertical (`world.demo_yaw`, `world.agent_yaw`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum YawRule {
    /// One orientation for the whole episode, the robot's rest yaw.
    Fixed,
    /// Turned towards the object's bearing from the gripper at the start.
    Heading,
    /// Turned so that the fingers close across the object's narrow side.
    #[value(name = "object_yaw")]
    ObjectYaw,
}

/// Arguments of the `collect` command.
#[derive(clap::Args)]
pub struct CollectArgs {
    /// `sawyer` (the demonstrator) or `panda` (the agent).
    #[arg(long, value_parser = parse_robot)]
    pub robot: Robot,
    /// Output folder (must not exist; it appears only when complete).
    #[arg(long)]
    pub out: PathBuf,
    /// Task ids, comma separated (default: all 16).
    #[arg(long, value_delimiter = ',')]
    pub tasks: Option<Vec<usize>>,
    /// Trajectories per task (default: the paper's 100).
    #[arg(long)]
    pub per_task: Option<usize>,
    /// Root seed of the layouts (default: collect.seed).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Parallel workers (default: CPU cores).
    #[arg(long)]
    pub workers: Option<usize>,
    /// JPEG quality of stored frames (default: collect.jpeg_quality).
    #[arg(long)]
    pub jpeg_quality: Option<u8>,
    /// Noise (m) on the executed position targets; the expert's own actions are recorded (default:
    /// collect.action_noise).
    #[arg(long)]
    pub action_noise: Option<f64>,
    /// The expert closes the gripper on reaching the grasp point (world.close_on_arrival).
    #[arg(long)]
    pub close_on_arrival: bool,
    /// Whether layouts recur under several tasks (default: collect.layouts, the authors' `shared`).
    #[arg(long, value_enum)]
    pub layouts: Option<Layouts>,
    /// Environments in the pool of shared layouts (default: collect.layout_pool, half the trajectories).
    #[arg(long)]
    pub layout_pool: Option<usize>,
    #[command(flatten)]
    pub frames: FrameArgs,
}

/// How a collection's layouts are drawn (`collect.layouts`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Layouts {
    /// Each slot draws an environment from a pool with replacement (the authors').
    Shared,
    /// Every slot has a layout of its own.
    Unique,
}

/// Arguments of the `contact-sheet` command.
#[derive(clap::Args)]
pub struct ContactSheetArgs {
    /// The PNG file written.
    #[arg(long, default_value = "contact_sheet.png")]
    pub out: PathBuf,
    /// Instances (columns) per robot.
    #[arg(long, default_value_t = 4)]
    pub instances: usize,
    /// Root seed of the layouts.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    #[command(flatten)]
    pub frames: FrameArgs,
}

/// `expert-check`: the expert's staged success per task.
pub fn expert_check(a: ExpertCheckArgs) -> Result<()> {
    let mut world = WorldConfig { close_on_arrival: a.close_on_arrival, ..WorldConfig::default() };
    if let Some(rule) = a.gripper_yaw {
        let rule = match rule {
            YawRule::Fixed => GripperYaw::Fixed,
            YawRule::Heading => GripperYaw::Heading,
            YawRule::ObjectYaw => GripperYaw::ObjectYaw,
        };
        match a.robot {
            Robot::Sawyer => world.demo_yaw = rule,
            Robot::Panda => world.agent_yaw = rule,
        }
    }
    let max_actions = a.max_actions.unwrap_or(CollectConfig::paper(a.robot).settings.max_actions);
    let report = check(a.robot, &world, a.per_task, a.seed, max_actions)?;
    print_report(&report);
    Ok(())
}

/// `collect`: expert trajectories into a new dataset folder.
pub fn collect(a: CollectArgs) -> Result<()> {
    let world = WorldConfig { close_on_arrival: a.close_on_arrival, ..a.frames.world() };
    let mut config = CollectConfig { world, ..CollectConfig::paper(a.robot) };
    config.per_task = a.per_task.unwrap_or(config.per_task);
    let s = &mut config.settings;
    s.seed = a.seed.unwrap_or(s.seed);
    s.tasks = a.tasks.unwrap_or(s.tasks.clone());
    s.jpeg_quality = a.jpeg_quality.unwrap_or(s.jpeg_quality);
    s.action_noise = a.action_noise.unwrap_or(s.action_noise);
    if let Some(layouts) = a.layouts {
        s.layouts = match layouts {
            Layouts::Shared => LayoutSharing::Shared,
            Layouts::Unique => LayoutSharing::Unique,
        };
    }
    s.layout_pool = a.layout_pool.or(s.layout_pool);
    let manifest = collect::collect(&config, &a.out, a.workers.unwrap_or_else(default_workers), true)?;
    let retries: usize = manifest.trajectories.iter().map(|e| e.attempts - 1).sum();
    println!(
        "wrote {} trajectories ({} frames, {} expert retries) to {}",
        manifest.trajectories.len(),
        manifest.total_steps(),
        retries,
        a.out.display()
    );
    Ok(())
}

/// `contact-sheet`: first frames of several instances for both robots in one PNG.
pub fn contact_sheet(a: ContactSheetArgs) -> Result<()> {
    render_sheet(&a.out, a.instances, a.seed, &a.frames.world())?;
    println!("wrote {}", a.out.display());
    Ok(())
}

/// Prints the report as a table.
fn print_report(r: &ExpertReport) {
    let n = r.instances_per_task;
    println!("expert on {} ({} instances per task)", r.robot, n);
    println!("{:>4} {:>8} {:>8} {:>8}", "task", "reached", "picked", "placed");
    for (t, c) in r.per_task.iter().enumerate() {
        println!("{t:>4} {:>8} {:>8} {:>8}", format!("{}/{n}", c[0]), format!("{}/{n}", c[1]), format!("{}/{n}", c[2]));
    }
    let o = r.overall();
    println!("all  {:>7.1}% {:>7.1}% {:>7.1}%", o[0] * 100.0, o[1] * 100.0, o[2] * 100.0);
}

/// Renders `instances` first frames per robot (rows: robots, columns: instances) into `out`.
fn render_sheet(out: &Path, instances: usize, seed: u64, world: &WorldConfig) -> Result<()> {
    if instances == 0 {
        bail!("--instances must be at least 1");
    }
    let (h, w) = (world.image.height, world.image.width);
    let mut sheet = image::RgbImage::new((w * instances) as u32, (h * Robot::ALL.len()) as u32);
    for (row, robot) in Robot::ALL.iter().enumerate() {
        let mut env = Env::new(*robot, world, true)?;
        for col in 0..instances {
            let task = Task::from_id((col * 5) % NUM_TASKS)?;
            env.reset(&Instance::sample(task, seed + col as u64));
            let frame = env.render()?;
            let img = image::RgbImage::from_raw(w as u32, h as u32, frame).context("frame size")?;
            image::imageops::overlay(&mut sheet, &img, (col * w) as i64, (row * h) as i64);
        }
    }
    sheet.save(out).with_context(|| format!("writing {}", out.display()))?;
    Ok(())
}
