//! Embeds run-time search paths for libtorch and libmujoco so the binary runs without LD_LIBRARY_PATH, the
//! commit the binary was built from, and a digest of every source file (which code built a stage).
use std::path::{Path, PathBuf};

/// Every `.rs` file under `dir`, as paths relative to `root` with `/` separators, sorted.
fn rust_files(root: &Path, dir: &Path, out: &mut Vec<(String, PathBuf)>) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            rust_files(root, &path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            let relative = path.strip_prefix(root).expect("under root").to_string_lossy().replace('\\', "/");
            out.push((relative, path));
        }
    }
}

/// Writes `sources.rs` into `OUT_DIR`: `SOURCES`, each file under `src/` with the blake3 digest of its text.
fn source_digests() {
    println!("cargo:rerun-if-changed=src");
    let mut files = Vec::new();
    rust_files(Path::new("src"), Path::new("src"), &mut files);
    files.sort();
    let mut table = String::from("/// Each source file under `src/` and the blake3 digest of its text.\n");
    table.push_str("pub const SOURCES: &[(&str, &str)] = &[\n");
    for (relative, path) in files {
        let text = std::fs::read(&path).expect("reading a source file");
        table.push_str(&format!("    ({relative:?}, {:?}),\n", blake3::hash(&text).to_hex().as_str()));
    }
    table.push_str("];\n");
    let out = PathBuf::from(std::env::var("OUT_DIR").expect("cargo sets OUT_DIR")).join("sources.rs");
    std::fs::write(out, table).expect("writing sources.rs");
}

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
    source_digests();
}
