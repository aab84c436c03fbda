//! Composes the bins scene with one robot: robosuite's bins arena, the four objects, the robot arm with its
//! gripper (attached through MuJoCo's model-editing API), lights and the `frontview` camera.
use super::assets::assets_root;
use super::camera::{CAMERA_EULER, CAMERA_POS, ImageSize, Intrinsics};
use super::object::{Object, Pattern};
use super::robot::Robot;
use anyhow::{Context, Result, anyhow};
use mujoco_rs::prelude::*;
use mujoco_rs::wrappers::mj_editing::Attach;

/// Offset applied to robosuite's bins arena so its bins land where the authors' arena has them: source bin
/// centred at (0.6, -0.15, 0.8), target bin at (0.6, 0.38, 0.8).
const ARENA_OFFSET: [f64; 3] = [0.5, 0.1, 0.0];
/// Prefix of every element of the attached robot.
pub const ROBOT_PREFIX: &str = "robot0_";
/// Prefix of every element of the gripper inside the robot.
pub const GRIPPER_PREFIX: &str = "gripper0_";

/// Name of the free body holding object `i`.
pub fn object_body_name(obj: Object) -> String {
    format!("obj_{}", obj.name())
}

/// Compiles the scene for `robot` with `objects` (parked until a reset lays some of them out), with the camera
/// set up for frames of `image`.
pub fn build_model(robot: Robot, image: ImageSize, objects: &[Object]) -> Result<MjModel> {
    let root = assets_root()?;
    let spec = robot.spec();
    let robot_xml = root.join("robots").join(spec.robot_dir).join("robot.xml");
    let gripper_xml = root.join("grippers").join(spec.gripper_file);
    let arena_xml = root.join("arenas/bins_arena.xml");

    let load = |path: &std::path::Path| MjSpec::from_xml(path).map_err(|e| anyhow!("loading {}: {e}", path.display()));
    let mut arm = load(&robot_xml)?;
    let mut gripper = load(&gripper_xml)?;
    let mut arena = load(&arena_xml)?;

    arm.body_mut(spec.hand_body)
        .with_context(|| format!("{} has no body {}", robot_xml.display(), spec.hand_body))?
        .add_frame()
        .attach_by_deep_copy(&mut gripper, GRIPPER_PREFIX, "")
        .map_err(|e| anyhow!("attaching the gripper: {e}"))?;

    let mut scene = MjSpec::from_xml_string(&world_xml(image, spec.base_pos, objects))
        .map_err(|e| anyhow!("scene template: {e}"))?;
    let world = scene.world_body_mut();
    world
        .add_frame()
        .with_pos(ARENA_OFFSET)
        .attach_by_deep_copy(&mut arena, "arena_", "")
        .map_err(|e| anyhow!("attaching the arena: {e}"))?;
    world
        .add_frame()
        .with_pos(spec.base_pos)
        .attach_by_deep_copy(&mut arm, ROBOT_PREFIX, "")
        .map_err(|e| anyhow!("attaching the robot: {e}"))?;
    let mut model = scene.compile().map_err(|e| anyhow!("compiling the {robot} scene: {e}"))?;
    disable_self_collision(&mut model);
    Ok(model)
}

/// Moves the robot's colliding geoms to contact type 2 (affinity stays 1): they still touch the objects and
/// bins but not each other. robosuite's arms otherwise collide with their own static base links, since MuJoCo
/// only filters parent-child contacts below a moving parent.
fn disable_self_collision(model: &mut MjModel) {
    let robot_geoms: Vec<usize> = (0..model.ffi().ngeom as usize)
        .filter(|&g| {
            let body = model.geom_bodyid()[g] as usize;
            model.id_to_name(MjtObjBase::mjOBJ_BODY, body).is_some_and(|name| name.starts_with(ROBOT_PREFIX))
        })
        .collect();
    let contype = model.geom_contype_mut();
    for g in robot_geoms {
        if contype[g] & 1 != 0 {
            contype[g] = 2;
        }
    }
}

/// Where object `i` of a scene waits while no layout uses it: in a row far outside the camera's view.
pub fn parking_position(i: usize) -> [f64; 3] {
    [2.0 + i as f64 * 0.2, 0.0, 0.1]
}

/// The MJCF of `objects`' bodies (parked) and, for the patterned ones, their textures and materials.
fn objects_xml(objects: &[Object]) -> (String, String) {
    let (mut bodies, mut assets) = (String::new(), String::new());
    for (i, obj) in objects.iter().enumerate() {
        let name = object_body_name(*obj);
        let [r, g, b, a] = obj.rgba();
        let look = match obj.pattern() {
            Pattern::Plain => format!(r#"rgba="{r} {g} {b} {a}""#),
            Pattern::Checker([r2, g2, b2]) | Pattern::Stripes([r2, g2, b2]) => {
                let (builtin, mark) = match obj.pattern() {
                    Pattern::Checker(_) => ("checker", ""),
                    _ => ("gradient", r#" mark="edge" markrgb="0 0 0""#),
                };
                assets.push_str(&format!(
                    r#"<texture name="{name}_t" type="cube" builtin="{builtin}" rgb1="{r} {g} {b}" rgb2="{r2} {g2} {b2}"
                 width="32" height="32"{mark}/>
    <material name="{name}_m" texture="{name}_t" texrepeat="2 2"/>
"#
                ));
                format!(r#"material="{name}_m""#)
            }
        };
        // The library's objects (round ones among them) also resist rolling, equally for all: the base objects keep
        // the contacts their collections were made with.
        let contact = if Object::ALL.contains(obj) {
            r#"condim="4" friction="1.5 0.01 0.001""#
        } else {
            r#"condim="6" friction="1.5 0.01 0.02""#
        };
        let top = obj.top().map_or_else(String::new, |top| {
            let z = obj.half_height() + top.half_extents()[2];
            format!(
                r#"<geom name="{name}_top" {} pos="0 0 {z}" {look} mass="0.01" {contact}
                       solref="0.01 1" group="2"/>"#,
                top.mjcf()
            )
        });
        // Parked out of the way; `Env::reset` places them.
        let [x, y, z] = parking_position(i);
        bodies.push_str(&format!(
            r#"<body name="{name}" pos="{x} {y} {z}"><freejoint/>
                 <geom name="{name}_g" {geom} {look} mass="0.1" {contact}
                       solref="0.01 1" group="2"/>{top}</body>
"#,
            geom = obj.shape().mjcf()
        ));
    }
    (bodies, assets)
}

/// The scene's own MJCF: physics options, render quality, objects, pedestal, light and camera.
fn world_xml(image: ImageSize, base: [f64; 3], objects: &[Object]) -> String {
    let (objects, assets) = objects_xml(objects);
    let assets = if assets.is_empty() { assets } else { format!("<asset>\n    {assets}  </asset>\n  ") };
    let [cx, cy, cz] = CAMERA_POS;
    let [ex, ey, ez] = CAMERA_EULER;
    let intrinsics = Intrinsics::for_size(image).mjcf_attributes(image);
    let (offwidth, offheight) = (image.width.max(64), image.height.max(64));
    let base_top = base[2];
    format!(
        r#"<mujoco model="oneshot_bins">
  <compiler angle="radian"/>
  <option timestep="0.002" cone="elliptic" impratio="10"/>
  <visual>
    <global offwidth="{offwidth}" offheight="{offheight}"/>
    <quality shadowsize="0" offsamples="0"/>
    <headlight ambient="0.35 0.35 0.35" diffuse="0.5 0.5 0.5" specular="0.1 0.1 0.1"/>
  </visual>
  {assets}<worldbody>
    <geom name="pedestal" type="cylinder" size="0.12 {ph}" pos="{px} {py} {ph}" rgba="0.2 0.2 0.22 1"
          contype="0" conaffinity="0" group="1"/>
    <camera name="frontview" mode="fixed" pos="{cx} {cy} {cz}" euler="{ex} {ey} {ez}" {intrinsics}/>
    {objects}
  </worldbody>
</mujoco>"#,
        ph = base_top / 2.0,
        px = base[0] - 0.05,
        py = base[1],
    )
}
