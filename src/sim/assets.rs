//! Locating robosuite's robot, gripper, arena and texture assets on disk.
use anyhow::{Result, bail};
use std::path::{Path, PathBuf};

/// Environment variable that overrides where the robosuite assets folder lives.
pub const ASSETS_ENV: &str = "ONESHOT_ASSETS";

/// Root of robosuite's `models/assets` folder: `ONESHOT_ASSETS` if set, else the `.venv` made by set-up.
pub fn assets_root() -> Result<PathBuf> {
    let root = match std::env::var_os(ASSETS_ENV) {
        Some(dir) => PathBuf::from(dir),
        None => match option_env!("ONESHOT_ASSETS_DEFAULT") {
            Some(dir) => PathBuf::from(dir),
            None => {
                bail!("robosuite assets not configured: set {ASSETS_ENV} or run scripts/setup.sh")
            }
        },
    };
    check_assets(&root)?;
    Ok(root)
}

fn check_assets(root: &Path) -> Result<()> {
    for rel in [
        "robots/sawyer/robot.xml",
        "robots/panda/robot.xml",
        "grippers/rethink_gripper.xml",
        "grippers/panda_gripper.xml",
        "arenas/bins_arena.xml",
    ] {
        if !root.join(rel).is_file() {
            bail!(
                "missing asset {} (assets root {}): run scripts/setup.sh or point {ASSETS_ENV} at robosuite's models/assets",
                root.join(rel).display(),
                root.display()
            );
        }
    }
    Ok(())
}
