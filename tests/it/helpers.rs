//! What the test modules share: the binary under test, scratch folders, the lock on libtorch's global random
//! generator, a random training batch, and waiting on what a run in another process does.
use oneshot_lab::model::batch::DeviceBatch;
use oneshot_lab::sim::env::STATE_DIM;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};
use tch::{Device, Kind, Tensor};

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

/// The latest complete checkpoint's step among the trainings under way in a store's staging folders (0: none
/// yet; a checkpoint whose weights file is still being written does not count).
pub fn latest_staged_checkpoint(store: &Path) -> u64 {
    std::fs::read_dir(store.join("artifacts/.staging"))
        .into_iter()
        .flatten()
        .filter_map(|e| oneshot_lab::train::checkpoint::latest(&e.unwrap().path().join("checkpoints")).ok().flatten())
        .map(|(step, _)| step)
        .max()
        .unwrap_or(0)
}

/// A random training batch of two samples at 32x40 on the CPU (four context frames, seven agent frames, tasks 3
/// and 12), drawn from libtorch's generator.
pub fn random_batch() -> DeviceBatch {
    let opts = (Kind::Float, Device::Cpu);
    DeviceBatch {
        context: Tensor::randn([2, 4, 3, 32, 40], opts),
        agent: Tensor::randn([2, 7, 3, 32, 40], opts),
        actions: Tensor::rand([2, 6, 8], opts) * 2.0 - 1.0,
        points: Tensor::rand([2, 2], opts) * 2.0 - 1.0,
        poses: Tensor::rand([2, 6], opts),
        pose_weights: Tensor::ones([2, 7], opts),
        tasks: Tensor::from_slice(&[3i64, 12]),
        states: Tensor::zeros([2, 7, STATE_DIM as i64], opts),
    }
}
