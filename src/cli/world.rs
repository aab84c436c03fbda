//! `expert-check`, `collect` and `contact-sheet`: the world and its scripted expert.
use super::default_workers;
use super::options::{FrameArgs, parse_robot};
use anyhow::{Context, Result, bail};
use oneshot_lab::data::collect;
use oneshot_lab::data::collect_config::{CollectConfig, LayoutSharing};
use oneshot_lab::sim::env::{Env, GripperYaw, ObjectSet, WorldConfig};
use oneshot_lab::sim::expert_check::{
    Aim, ExpertReport, LibraryReport, expert_check as check, library_check, library_instance,
};
use oneshot_lab::sim::object::{Object, Split, environment_objects};
use oneshot_lab::sim::robot::Robot;
use oneshot_lab::sim::task::{Instance, NUM_OBJECTS, NUM_TASKS, ObjectPose, SOURCE_BIN, Task};
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
    /// The expert rises as soon as its fingers have stopped after closing (world.rise_on_grip).
    #[arg(long)]
    pub rise_on_grip: bool,
    /// `base`: the 16 tasks of the four base objects; `library`: each of the 30 library objects in turn
    /// (`--per-task` environments each), among three others of its split.
    #[arg(long, value_enum, default_value_t = Objects::Base)]
    pub objects: Objects,
    /// Aim every grasp off the object, once, without starting over: `ACROSS,SIDEWAYS` in cm (each within 10),
    /// where the object's centre is to lie in the gripper's frame at the close (across the fingers, along their
    /// faces; the signs of the report's `grasps.md`). What a policy's aim error of that size costs each object.
    /// Needs the fixed gripper yaw.
    #[arg(long, value_parser = parse_aim_offset, allow_hyphen_values = true)]
    pub aim_offset: Option<[f64; 2]>,
}

/// The largest aim offset `expert-check` takes along either axis (cm): beyond it the fingers close on nothing.
const MAX_AIM_OFFSET_CM: f64 = 10.0;

/// `ACROSS,SIDEWAYS` in cm, each finite and within 10 cm.
fn parse_aim_offset(s: &str) -> Result<[f64; 2], String> {
    let parts: Vec<&str> = s.split(',').collect();
    let [across, sideways] = parts[..] else {
        return Err(format!("`{s}` is not ACROSS,SIDEWAYS (two numbers in cm, e.g. `0,2`)"));
    };
    let number = |p: &str| -> Result<f64, String> {
        match p.trim().parse::<f64>() {
            Ok(v) if v.is_finite() && v.abs() <= MAX_AIM_OFFSET_CM => Ok(v),
            _ => Err(format!("`{p}` in `{s}` is not a number of cm within +-{MAX_AIM_OFFSET_CM}")),
        }
    };
    Ok([number(across)?, number(sideways)?])
}

/// Which objects a world holds (`world.objects`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Objects {
    /// Milk, bread, cereal and can.
    Base,
    /// The 30 procedural library objects (26 training, 4 held out), four per environment.
    Library,
}

impl Objects {
    /// The `world.objects` setting it names.
    pub fn set(self) -> ObjectSet {
        match self {
            Objects::Base => ObjectSet::Base,
            Objects::Library => ObjectSet::Library,
        }
    }
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
    #[arg(long, value_parser = super::options::at_least_one)]
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
    /// The expert rises as soon as its fingers have stopped after closing (world.rise_on_grip).
    #[arg(long)]
    pub rise_on_grip: bool,
    /// Whether layouts recur under several tasks (default: collect.layouts, the authors' `shared`).
    #[arg(long, value_enum)]
    pub layouts: Option<Layouts>,
    /// Environments in the pool of shared layouts (default: collect.layout_pool, half the trajectories).
    #[arg(long)]
    pub layout_pool: Option<usize>,
    /// `base` (the four base objects) or `library` (the multi-object world: each environment four of the 26
    /// training objects).
    #[arg(long, value_enum, default_value_t = Objects::Base)]
    pub objects: Objects,
    /// With `--objects library`: trajectories of each task per environment (default:
    /// collect.environment_instances, the authors' 2).
    #[arg(long, requires = "objects")]
    pub environment_instances: Option<usize>,
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
    /// `library`: layouts of library environments (odd columns held-out ones, framed in red).
    #[arg(long, value_enum, default_value_t = Objects::Base)]
    pub objects: Objects,
    /// With `--objects library`: each of the 30 library objects alone in the bin, `--instances` to a row,
    /// held-out ones framed in red.
    #[arg(long, requires = "objects")]
    pub each_object: bool,
    /// A sheet rendered elsewhere with the same options (e.g. by Mesa on a CPU machine): the new one is compared
    /// with it pixel by pixel, and the command fails if they differ by more than `--tolerance` on average.
    #[arg(long)]
    pub compare: Option<PathBuf>,
    /// The largest mean absolute difference per channel (0-255) `--compare` accepts.
    #[arg(long, default_value_t = 4.0, requires = "compare")]
    pub tolerance: f64,
    #[command(flatten)]
    pub frames: FrameArgs,
}

/// `expert-check`: the expert's staged success per task.
pub fn expert_check(a: ExpertCheckArgs) -> Result<()> {
    let mut world = WorldConfig {
        close_on_arrival: a.close_on_arrival,
        rise_on_grip: a.rise_on_grip,
        objects: a.objects.set(),
        ..WorldConfig::default()
    };
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
    let aim = match a.aim_offset {
        Some([across, sideways]) => {
            println!("aimed {across} cm across and {sideways} cm sideways off the object, once (no starting over)");
            Aim::Off([across / 100.0, sideways / 100.0])
        }
        None => Aim::Privileged,
    };
    if a.objects == Objects::Library {
        print_library_report(&library_check(a.robot, &world, a.per_task, a.seed, max_actions, aim)?);
        return Ok(());
    }
    let report = check(a.robot, &world, a.per_task, a.seed, max_actions, aim)?;
    print_report(&report);
    Ok(())
}

/// `collect`: expert trajectories into a new dataset folder.
pub fn collect(a: CollectArgs) -> Result<()> {
    let world = WorldConfig {
        close_on_arrival: a.close_on_arrival,
        rise_on_grip: a.rise_on_grip,
        objects: a.objects.set(),
        ..a.frames.world()
    };
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
    s.environment_instances = a.environment_instances.unwrap_or(s.environment_instances);
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

/// `contact-sheet`: first frames of several instances for both robots in one PNG (or the library's objects).
pub fn contact_sheet(a: ContactSheetArgs) -> Result<()> {
    let world = WorldConfig { objects: a.objects.set(), ..a.frames.world() };
    match (a.objects, a.each_object) {
        (Objects::Library, true) => render_library_sheet(&a.out, a.instances, a.seed, &world)?,
        (Objects::Base, true) => bail!("--each-object shows the library's objects: add --objects library"),
        _ => render_sheet(&a.out, a.instances, a.seed, &world)?,
    }
    println!("wrote {}", a.out.display());
    if let Some(reference) = &a.compare {
        let (mean, share) = sheet_difference(&a.out, reference)?;
        println!(
            "against {}: mean absolute difference {mean:.3} per channel (0-255), {:.2}% of pixels off by more \
             than 32",
            reference.display(),
            100.0 * share
        );
        if mean > a.tolerance {
            bail!(
                "{} differs from {} by {mean:.3} on average, above --tolerance {}",
                a.out.display(),
                reference.display(),
                a.tolerance
            );
        }
    }
    Ok(())
}

/// The mean absolute difference per channel of two PNGs of one size, and the share of pixels whose largest
/// channel difference exceeds 32.
fn sheet_difference(a: &Path, b: &Path) -> Result<(f64, f64)> {
    let open = |p: &Path| -> Result<image::RgbImage> {
        Ok(image::open(p).with_context(|| format!("reading {}", p.display()))?.to_rgb8())
    };
    let (x, y) = (open(a)?, open(b)?);
    if x.dimensions() != y.dimensions() {
        bail!(
            "{} is {:?} pixels, {} {:?}: render both with the same options",
            a.display(),
            x.dimensions(),
            b.display(),
            y.dimensions()
        );
    }
    let (mut total, mut off) = (0u64, 0usize);
    for (p, q) in x.pixels().zip(y.pixels()) {
        let d = p.0.iter().zip(q.0).map(|(u, v)| u.abs_diff(v) as u64);
        total += d.clone().sum::<u64>();
        off += usize::from(d.max().unwrap_or(0) > 32);
    }
    let pixels = x.pixels().len();
    Ok((total as f64 / (3 * pixels) as f64, off as f64 / pixels as f64))
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
    println!("\n{:<6} {:>7} {:>8} {:>8}", "object", "reached", "picked", "placed");
    let per = (NUM_TASKS / NUM_OBJECTS) * n;
    for (object, c) in Object::ALL.iter().zip(r.per_base_object()) {
        let [a, b, p] = c.map(|k| format!("{k}/{per}"));
        println!("{:<6} {a:>7} {b:>8} {p:>8}", object.name());
    }
}

/// Prints the per-object report as a table.
fn print_library_report(r: &LibraryReport) {
    let n = r.instances_per_object;
    println!("expert on {} with each library object ({} environments per object)", r.robot, n);
    println!("{:<14} {:>9} {:>8} {:>8} {:>8}", "object", "split", "reached", "picked", "placed");
    for (object, c) in &r.per_object {
        let split = if object.held_out() { "held-out" } else { "training" };
        let [a, b, p] = c.map(|k| format!("{k}/{n}"));
        println!("{:<14} {split:>9} {a:>8} {b:>8} {p:>8}", object.name());
    }
    let total = (r.per_object.len() * n) as f64;
    let share = |s: usize| 100.0 * r.per_object.iter().map(|(_, c)| c[s]).sum::<usize>() as f64 / total;
    println!("{:<14} {:>9} {:>7.1}% {:>7.1}% {:>7.1}%", "all", "", share(0), share(1), share(2));
    let worst = r.per_object.iter().map(|(_, c)| c[2]).min().unwrap_or(0);
    println!("fewest placed for one object: {worst}/{n}");
}

/// Renders each library object alone in the source bin, seen by both robots' camera (rows of six), and frames
/// the held-out ones in red: the library and its split at a glance. `seed` picks each object's place and yaw.
fn render_library_sheet(out: &Path, columns: usize, seed: u64, world: &WorldConfig) -> Result<()> {
    let columns = columns.max(1);
    let objects: Vec<_> = Object::library().collect();
    let (h, w) = (world.image.height, world.image.width);
    let rows = objects.len().div_ceil(columns);
    let mut sheet = image::RgbImage::new((w * columns) as u32, (h * rows * Robot::ALL.len()) as u32);
    for (r, robot) in Robot::ALL.iter().enumerate() {
        let mut env = Env::new(*robot, world, true)?;
        for (i, object) in objects.iter().enumerate() {
            let instance = library_instance(*object, 0, seed + i as u64);
            let alone = Instance { objects: lone_layout(&instance), ..instance };
            env.reset(&alone)?;
            let frame = env.render()?;
            let mut img = image::RgbImage::from_raw(w as u32, h as u32, frame).context("frame size")?;
            if object.held_out() {
                frame_red(&mut img);
            }
            let (col, row) = (i % columns, r * rows + i / columns);
            image::imageops::overlay(&mut sheet, &img, (col * w) as i64, (row * h) as i64);
        }
    }
    sheet.save(out).with_context(|| format!("writing {}", out.display()))?;
    Ok(())
}

/// The layout of `instance` with only its task's object in the bin, at the bin's centre; the other three lie
/// outside the camera's view, beyond the robot's base.
fn lone_layout(instance: &Instance) -> [ObjectPose; NUM_OBJECTS] {
    std::array::from_fn(|k| {
        let pose = instance.objects[k];
        if k == instance.task.object {
            ObjectPose { pos: [SOURCE_BIN[0], SOURCE_BIN[1], pose.pos[2]], ..pose }
        } else {
            ObjectPose { pos: [-1.0 - k as f64 * 0.2, 0.0, pose.pos[2]], ..pose }
        }
    })
}

/// Frames an image in red: a held-out environment or object.
fn frame_red(img: &mut image::RgbImage) {
    let (w, h) = img.dimensions();
    for (x, y, px) in img.enumerate_pixels_mut() {
        if x < 2 || y < 2 || x + 2 >= w || y + 2 >= h {
            *px = image::Rgb([230, 20, 20]);
        }
    }
}

/// Renders `instances` first frames per robot (rows: robots, columns: instances) into `out`; in the library
/// world, column `c` is the environment of seed `seed + c`, of the training objects in even columns and the
/// held-out ones (framed in red) in odd columns.
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
            let held_out = world.objects == ObjectSet::Library && col % 2 == 1;
            let kinds = match world.objects {
                ObjectSet::Base => Object::ALL,
                ObjectSet::Library => {
                    environment_objects(if held_out { Split::HeldOut } else { Split::Train }, seed + col as u64)
                }
            };
            env.reset(&Instance::sample_with(task, seed + col as u64, kinds))?;
            let frame = env.render()?;
            let mut img = image::RgbImage::from_raw(w as u32, h as u32, frame).context("frame size")?;
            if held_out {
                frame_red(&mut img);
            }
            image::imageops::overlay(&mut sheet, &img, (col * w) as i64, (row * h) as i64);
        }
    }
    sheet.save(out).with_context(|| format!("writing {}", out.display()))?;
    Ok(())
}
