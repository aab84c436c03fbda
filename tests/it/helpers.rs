//! What the test modules share: the binary under test, scratch folders, and the lock on libtorch's global
//! random generator.
use std::path::PathBuf;
use std::process::Command;
use std::sync::{Mutex, MutexGuard};

/// The `oneshot-lab` binary built for these tests.
pub fn oneshot() -> Command {
    Command::new(env!("CARGO_BIN_EXE_oneshot-lab"))
}

/// An empty folder for one test, under the system's temporary folder (names are unique across the modules).
pub fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("oneshot-test-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// libtorch's random generator is global to the process: every test that seeds it, draws from it, or trains or
/// evaluates a network in-process holds this lock, so that its draws do not depend on what other tests draw
/// meanwhile.
static TORCH_RNG: Mutex<()> = Mutex::new(());

/// Holds the generator (see [`TORCH_RNG`]).
pub fn torch_rng() -> MutexGuard<'static, ()> {
    TORCH_RNG.lock().unwrap_or_else(|e| e.into_inner())
}

/// Holds the generator and seeds it.
pub fn seeded(seed: i64) -> MutexGuard<'static, ()> {
    let guard = torch_rng();
    tch::manual_seed(seed);
    guard
}
