//! Which code built a stage: the commit the binary was built from and a digest of the source files of the stage
//! kind's modules ([`Kind::sources`]), recorded with every attempt. Keys change only through a kind's version;
//! this lets `plan`, `why` and `run --rerun-code-changed` tell a cached stage that other code built.
use super::stages::Kind;

mod sources {
    include!(concat!(env!("OUT_DIR"), "/sources.rs"));
}

/// The commit this binary was built from (`unknown` outside a git checkout).
pub const COMMIT: &str = env!("ONESHOT_GIT_COMMIT");

/// The code an attempt ran: the commit and the digest of its kind's sources.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CodeVersion {
    pub commit: String,
    pub digest: String,
}

/// This binary's code for stages of `kind`.
pub fn current(kind: Kind) -> CodeVersion {
    CodeVersion { commit: COMMIT.to_string(), digest: digest(kind, sources::SOURCES) }
}

/// Digest (16 hex digits) of the files of `sources` (path, file digest) that `kind`'s source prefixes cover.
fn digest(kind: Kind, sources: &[(&str, &str)]) -> String {
    let mut hasher = blake3::Hasher::new();
    for (path, file) in sources.iter().filter(|(path, _)| kind.sources().iter().any(|p| path.starts_with(p))) {
        hasher.update(path.as_bytes());
        hasher.update(file.as_bytes());
    }
    hasher.finalize().to_hex()[..16].to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_kind_covers_its_own_stage_module_and_only_its_files_move_its_digest() {
        for kind in Kind::ALL {
            let own = format!("pipeline/stages/{}.rs", kind.name());
            assert!(sources::SOURCES.iter().any(|(path, _)| *path == own), "{own} is not a source file");
            assert!(kind.sources().iter().any(|p| own.starts_with(p)), "{kind:?} does not cover {own}");
        }
        let files = [("sim/world.rs", "a"), ("model/heads.rs", "b"), ("report/table.rs", "c")];
        let edited_model = [("sim/world.rs", "a"), ("model/heads.rs", "B"), ("report/table.rs", "c")];
        let edited_report = [("sim/world.rs", "a"), ("model/heads.rs", "b"), ("report/table.rs", "C")];
        assert_ne!(digest(Kind::Train, &files), digest(Kind::Train, &edited_model));
        assert_eq!(digest(Kind::Collect, &files), digest(Kind::Collect, &edited_model));
        for kind in Kind::ALL {
            assert_eq!(digest(kind, &files), digest(kind, &edited_report), "reports build no stage");
        }
    }
}
