//! Composes the bins scene with one robot: robosuite's bins arena, the four objects, the robot arm with its
//! gripper (attached through MuJoCo's model-editing API), lights and the `frontview` camera.
use super::assets::assets_root;
use super::camera::{CAMERA_EULER, CAMERA_POS, ImageSize, Intrinsics};
use super::robot::Robot;
use super::task::{Object, Shape};
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

/// Compiles the scene for `robot`, with the camera set up for frames of `image`.
pub fn build_model(robot: Robot, image: ImageSize) -> Result<MjModel> {
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

    let mut scene =
        MjSpec::from_xml_string(&world_xml(image, spec.base_pos)).map_err(|e| anyhow!("scene template: {e}"))?;
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

/// The scene's own MJCF: physics options, render quality, objects, pedestal, light and camera.
fn world_xml(image: ImageSize, base: [f64; 3]) -> String {
    let mut objects = String::new();
    for (i, obj) in Object::ALL.iter().enumerate() {
        let [r, g, b, a] = obj.rgba();
        let geom = match obj.shape() {
            Shape::Box([x, y, z]) => format!(r#"type="box" size="{x} {y} {z}""#),
            Shape::Cylinder { radius, half_height } => {
                format!(r#"type="cylinder" size="{radius} {half_height}""#)
            }
        };
        // Parked out of the way; `Env::reset` places them.
        let x = 2.0 + i as f64 * 0.2;
        objects.push_str(&format!(
            r#"<body name="{name}" pos="{x} 0 0.1"><freejoint/>
                 <geom name="{name}_g" {geom} rgba="{r} {g} {b} {a}" mass="0.1" condim="4"
                       friction="1.5 0.01 0.001" solref="0.01 1" group="2"/></body>
"#,
            name = object_body_name(*obj)
        ));
    }
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
  <worldbody>
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
