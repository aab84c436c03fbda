//! Artifact integrity: every artifact folder is sealed with a digest manifest (`digests.json`: each file's
//! size and blake3) when it is published, and checked before the store calls it cached, before it is used as an
//! upstream and before a report copies from it. A damaged or missing artifact marks its stage failed with the
//! reason, so `plan`, `status` and `run` agree and the next `run` recomputes it.
use super::child::RESULTS_FILE;
use super::store::{StageState, Store};
use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The manifest's file name inside an artifact folder.
pub const DIGESTS_FILE: &str = "digests.json";

/// One file of an artifact.
#[derive(Debug, Serialize, Deserialize, PartialEq)]
struct Digest {
    path: String,
    bytes: u64,
    blake3: String,
}

/// Every file under `dir` (but the manifest), as sorted paths relative to it.
fn files(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    let mut pending = vec![PathBuf::new()];
    while let Some(rel) = pending.pop() {
        let here = dir.join(&rel);
        for entry in std::fs::read_dir(&here).with_context(|| format!("reading {}", here.display()))? {
            let entry = entry?;
            let path = rel.join(entry.file_name());
            if entry.file_type()?.is_dir() {
                pending.push(path);
            } else if path != Path::new(DIGESTS_FILE) {
                out.push(path);
            }
        }
    }
    out.sort();
    Ok(out)
}

fn digest(dir: &Path, rel: &Path) -> Result<Digest> {
    let path = dir.join(rel);
    let mut hasher = blake3::Hasher::new();
    let mut file = std::fs::File::open(&path).with_context(|| format!("reading {}", path.display()))?;
    let bytes = std::io::copy(&mut file, &mut hasher).with_context(|| format!("reading {}", path.display()))?;
    Ok(Digest { path: rel.to_string_lossy().into_owned(), bytes, blake3: hasher.finalize().to_hex().to_string() })
}

/// Writes the digest manifest of the folder `dir` (call it on the staging folder, before it is published).
pub fn seal(dir: &Path) -> Result<()> {
    let digests = files(dir)?.iter().map(|f| digest(dir, f)).collect::<Result<Vec<_>>>()?;
    crate::fsio::write_atomic(&dir.join(DIGESTS_FILE), serde_json::to_string_pretty(&digests)? + "\n")
}

/// Checks the artifact folder `dir` against its manifest; the error names the first file that is missing, of
/// another size or another digest, a file the manifest does not list (but the stage process's results, written
/// after the seal), or an entry that is not a plain path inside the folder. A folder without a manifest was never
/// sealed, so it is damaged.
pub fn verify(dir: &Path) -> Result<()> {
    if !dir.is_dir() {
        bail!("its artifact folder {} is missing", dir.display());
    }
    let manifest = dir.join(DIGESTS_FILE);
    let text = match std::fs::read_to_string(&manifest) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => bail!("{} is missing: never sealed", manifest.display()),
        Err(e) => return Err(e).with_context(|| format!("reading {}", manifest.display())),
    };
    let digests: Vec<Digest> =
        serde_json::from_str(&text).with_context(|| format!("{} is not a digest manifest", manifest.display()))?;
    let inside = |p: &str| Path::new(p).components().all(|c| matches!(c, std::path::Component::Normal(_)));
    if let Some(d) = digests.iter().find(|d| d.path.is_empty() || !inside(&d.path)) {
        bail!("{} lists {:?}, which is not a path inside the folder", manifest.display(), d.path);
    }
    let listed: std::collections::HashSet<&Path> = digests.iter().map(|d| Path::new(&d.path)).collect();
    if let Some(extra) = files(dir)?.iter().find(|f| !listed.contains(f.as_path()) && **f != Path::new(RESULTS_FILE)) {
        bail!("{} is not in the published manifest", dir.join(extra).display());
    }
    for d in &digests {
        let path = dir.join(&d.path);
        let bytes = std::fs::metadata(&path).map(|m| m.len()).ok();
        match bytes {
            None => bail!("{} is missing", path.display()),
            Some(n) if n != d.bytes => bail!("{} has {n} bytes where {} were published", path.display(), d.bytes),
            Some(_) if digest(dir, Path::new(&d.path))?.blake3 != d.blake3 => {
                bail!("{} differs from the published file (blake3)", path.display())
            }
            Some(_) => {}
        }
    }
    Ok(())
}

/// Whether stage `key` is cached: done in the store with an intact artifact folder (returned). A done stage
/// whose artifact is missing or damaged, or recorded at a path outside the store, is marked failed with the reason (the next `run` recomputes it) and
/// reported as `Err(reason)`.
pub fn cached(store: &mut Store, key: &str) -> Result<Option<std::result::Result<PathBuf, String>>> {
    if store.state(key)? != StageState::Done {
        return Ok(None);
    }
    let checked = match store.artifact(key) {
        Ok(None) => return Ok(None),
        Ok(Some(artifact)) => verify(&artifact).map(|()| artifact),
        Err(e) => Err(e),
    };
    match checked {
        Ok(artifact) => Ok(Some(Ok(artifact))),
        Err(e) => {
            let reason = format!("artifact damaged, to be recomputed: {e:#}");
            store.mark_damaged(key, &reason)?;
            Ok(Some(Err(reason)))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sealed_folder_verifies_until_a_byte_changes_or_a_file_goes() {
        let dir = std::env::temp_dir().join(format!("oneshot-integrity-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("sub")).unwrap();
        std::fs::write(dir.join("a.bin"), [1u8; 100]).unwrap();
        std::fs::write(dir.join("sub/b.json"), "{}").unwrap();
        seal(&dir).unwrap();
        verify(&dir).unwrap();
        std::fs::write(dir.join("a.bin"), [[1u8; 50], [2u8; 50]].concat()).unwrap();
        let e = verify(&dir).unwrap_err().to_string();
        assert!(e.contains("a.bin") && e.contains("blake3"), "{e}");
        std::fs::write(dir.join("a.bin"), [1u8; 100]).unwrap();
        verify(&dir).unwrap();
        std::fs::write(dir.join(RESULTS_FILE), "{}").unwrap();
        verify(&dir).unwrap();
        std::fs::write(dir.join("sub/extra"), "x").unwrap();
        assert!(verify(&dir).unwrap_err().to_string().contains("extra is not in the published manifest"));
        std::fs::remove_file(dir.join("sub/extra")).unwrap();
        std::fs::remove_file(dir.join("sub/b.json")).unwrap();
        assert!(verify(&dir).unwrap_err().to_string().contains("b.json is missing"));
        let outside = r#"[{"path": "../elsewhere", "bytes": 1, "blake3": "00"}]"#;
        std::fs::write(dir.join(DIGESTS_FILE), outside).unwrap();
        assert!(verify(&dir).unwrap_err().to_string().contains("not a path inside the folder"));
        std::fs::remove_file(dir.join(DIGESTS_FILE)).unwrap();
        assert!(verify(&dir).unwrap_err().to_string().contains("never sealed"), "an unsealed folder is damaged");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
