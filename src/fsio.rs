//! Writing files and folders so that an interrupted write never leaves something that looks complete: everything
//! is written under a temporary name first and renamed into place.
use anyhow::{Context, Result};
use std::path::{Path, PathBuf};

/// The temporary sibling a file is written to before its rename: `name.partial.ext` (the extension kept, since
/// some writers choose the format by it).
pub fn temporary_path(path: &Path) -> PathBuf {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    match path.extension() {
        Some(ext) => path.with_file_name(format!("{stem}.partial.{}", ext.to_string_lossy())),
        None => path.with_file_name(format!("{stem}.partial")),
    }
}

/// Writes `path` through `write`, which is handed the temporary path to fill; renamed into place once it
/// returns.
pub fn write_with(path: &Path, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    let tmp = temporary_path(path);
    write(&tmp).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))
}

/// Writes `bytes` to `path` atomically.
pub fn write_atomic(path: &Path, bytes: impl AsRef<[u8]>) -> Result<()> {
    write_with(path, |tmp| Ok(std::fs::write(tmp, bytes)?))
}

/// Writes `records` to `path` as JSON lines, one record a line, atomically.
pub fn write_json_lines<T: serde::Serialize>(path: &Path, records: &[T]) -> Result<()> {
    let mut text = String::new();
    for record in records {
        text += &serde_json::to_string(record)?;
        text.push('\n');
    }
    write_atomic(path, text)
}

/// The records of the JSON-lines file `path`, in order (blank lines skipped); an error names the file and line.
pub fn read_json_lines<T: serde::de::DeserializeOwned>(path: &Path) -> Result<Vec<T>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let records = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty());
    records
        .map(|(i, l)| serde_json::from_str(l).with_context(|| format!("parsing {} line {}", path.display(), i + 1)))
        .collect()
}

/// The hidden sibling folder `.name.partial` that a folder is built in before it is published.
pub fn staging_sibling(dest: &Path) -> Result<PathBuf> {
    let name = dest.file_name().with_context(|| format!("{} has no folder name", dest.display()))?;
    let parent = dest.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    Ok(parent.join(format!(".{}.partial", name.to_string_lossy())))
}

/// Moves the finished folder `staging` to `dest`, replacing a stale `dest` left by an attempt that was never
/// recorded as complete.
pub fn publish_dir(staging: &Path, dest: &Path) -> Result<()> {
    if dest.exists() {
        std::fs::remove_dir_all(dest).with_context(|| format!("removing stale {}", dest.display()))?;
    }
    if let Some(parent) = dest.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).with_context(|| format!("creating {}", parent.display()))?;
    }
    std::fs::rename(staging, dest).with_context(|| format!("moving {} to {}", staging.display(), dest.display()))
}

/// Checks that `name`, which becomes a file or folder name, is a plain one: letters, digits, `.`, `_` and `-`
/// only, not empty, `.` or `..`, so that no name from a file or a flag reaches outside its folder; the error
/// names `what` and the name.
pub fn check_plain_name(what: &str, name: &str) -> Result<()> {
    let plain = name.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-'));
    if name.is_empty() || name == "." || name == ".." || !plain {
        anyhow::bail!("{what} = {name:?} is not a plain name (letters, digits, '.', '_' and '-'; not '.' or '..')");
    }
    Ok(())
}

/// Removes the folder `dir` if it exists.
pub fn remove_dir_if_present(dir: &Path) -> Result<()> {
    if dir.exists() {
        std::fs::remove_dir_all(dir).with_context(|| format!("removing {}", dir.display()))?;
    }
    Ok(())
}

/// Removes the file `path` if it exists.
pub fn remove_file_if_present(path: &Path) -> Result<()> {
    match std::fs::remove_file(path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            Err(e).with_context(|| format!("removing {}", path.display()))
        }
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_plain_names_pass() {
        for ok in ["smoke", "learn_cpu16", "n480-full-s0", "v1.2"] {
            check_plain_name("name", ok).unwrap();
        }
        for bad in ["", ".", "..", "../artifacts", "/tmp/x", "a/b", "a b", "r\\x"] {
            let err = check_plain_name("name", bad).unwrap_err().to_string();
            assert!(err.contains("name = ") && err.contains("not a plain name"), "{bad}: {err}");
        }
    }

    #[test]
    fn temporary_names_keep_the_extension() {
        assert_eq!(temporary_path(Path::new("a/model.safetensors")), Path::new("a/model.partial.safetensors"));
        assert_eq!(temporary_path(Path::new("notes")), Path::new("notes.partial"));
        assert_eq!(staging_sibling(Path::new("runs/set")).unwrap(), Path::new("runs/.set.partial"));
    }

    #[test]
    fn a_failed_write_leaves_no_file_and_publishing_replaces_a_stale_folder() {
        let dir = std::env::temp_dir().join(format!("oneshot-fsio-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("x.json");
        assert!(write_with(&path, |_| anyhow::bail!("interrupted")).is_err());
        assert!(!path.exists());
        write_atomic(&path, "{}").unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "{}");
        let (staging, dest) = (dir.join("staging"), dir.join("dest"));
        std::fs::create_dir_all(&staging).unwrap();
        std::fs::write(staging.join("new"), "").unwrap();
        std::fs::create_dir_all(&dest).unwrap();
        std::fs::write(dest.join("stale"), "").unwrap();
        publish_dir(&staging, &dest).unwrap();
        assert!(dest.join("new").exists() && !dest.join("stale").exists() && !staging.exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
