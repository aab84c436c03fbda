//! Embeds run-time search paths for libtorch and libmujoco so the binary runs without LD_LIBRARY_PATH.
use std::path::Path;

fn main() {
    for var in ["LIBTORCH", "MUJOCO_DYNAMIC_LINK_DIR"] {
        println!("cargo:rerun-if-env-changed={var}");
        let Ok(dir) = std::env::var(var) else {
            continue;
        };
        let dir = Path::new(&dir);
        let lib = if var == "LIBTORCH" { dir.join("lib") } else { dir.to_path_buf() };
        let lib = lib.canonicalize().unwrap_or(lib);
        println!("cargo:rustc-link-arg=-Wl,-rpath,{}", lib.display());
    }
    println!("cargo:rerun-if-env-changed=ONESHOT_ASSETS_DEFAULT");
    // The commit a binary was built from, stamped on reports.
    println!("cargo:rerun-if-changed=.git/HEAD");
    println!("cargo:rerun-if-changed=.git/refs/heads");
    let commit = std::process::Command::new("git")
        .args(["rev-parse", "--short=10", "HEAD"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .unwrap_or_else(|| "unknown".into());
    println!("cargo:rustc-env=ONESHOT_GIT_COMMIT={commit}");
}
