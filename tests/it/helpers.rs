//! What the test modules share: the binary under test, scratch folders, the lock on libtorch's global random
//! generator, and waiting on what a run in another process does.
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

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

/// How long a test waits for a stage before calling it a hang: a guard, not a timing (on 2 cores shared with
/// other work, or with a hypervisor taking most of them, stages take many times their usual time).
pub const HANG_GUARD: Duration = Duration::from_secs(1800);

/// Calls `poll` every `every` until it returns `Ok`, and returns that; panics with its last `Err`, which says where
/// things stand, once `limit` has passed.
pub fn wait_for<T>(limit: Duration, every: Duration, mut poll: impl FnMut() -> Result<T, String>) -> T {
    let start = Instant::now();
    loop {
        match poll() {
            Ok(value) => return value,
            Err(state) => assert!(start.elapsed() < limit, "after {:?}: {state}", start.elapsed()),
        }
        std::thread::sleep(every);
    }
}

/// Checkpoint files the trainings under way in a store have written to their staging folders.
pub fn staged_checkpoints(store: &Path) -> usize {
    std::fs::read_dir(store.join("artifacts/.staging"))
        .into_iter()
        .flatten()
        .map(|e| std::fs::read_dir(e.unwrap().path().join("checkpoints")).map_or(0, |d| d.count()))
        .sum()
}
