//! Stopping trainings cleanly on SIGTERM or SIGUSR1, the signals a cluster sends before it preempts a job or its
//! time runs out (Slurm: SIGTERM at the limit, or any signal `--signal` asks for, ahead of it): a training that
//! receives one writes a checkpoint at its current step and stops with an error naming the signal, so the stage
//! fails without losing work and the next run resumes from that step. A run waiting on a stage process holds the
//! same guard and relays the signal to it (`pipeline::child`). Otherwise the signals keep their default effect:
//! the process ends at once.
use std::sync::Once;
use std::sync::atomic::{AtomicI32, AtomicUsize, Ordering};

/// The signal received while a training ran (0: none).
static RECEIVED: AtomicI32 = AtomicI32::new(0);
/// Trainings running in this process.
static ACTIVE: AtomicUsize = AtomicUsize::new(0);
static INSTALL: Once = Once::new();

extern "C" fn on_signal(signal: libc::c_int) {
    if ACTIVE.load(Ordering::SeqCst) == 0 {
        // As the default disposition would: end now (only async-signal-safe calls here).
        unsafe { libc::_exit(128 + signal) };
    }
    RECEIVED.store(signal, Ordering::SeqCst);
}

/// Held while a training runs (or a run waits on a stage process): the signals then ask it to checkpoint and stop.
pub struct StopGuard(());

impl StopGuard {
    /// Marks a training, or a wait on a stage process, as running (installing the handlers on first use).
    pub fn new() -> StopGuard {
        INSTALL.call_once(|| {
            for signal in [libc::SIGTERM, libc::SIGUSR1] {
                let handler = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
                unsafe { libc::signal(signal, handler) };
            }
        });
        ACTIVE.fetch_add(1, Ordering::SeqCst);
        StopGuard(())
    }
}

impl Default for StopGuard {
    fn default() -> Self {
        StopGuard::new()
    }
}

impl Drop for StopGuard {
    fn drop(&mut self) {
        ACTIVE.fetch_sub(1, Ordering::SeqCst);
    }
}

/// The signal that asked this process to stop, if one did: trainings checkpoint and stop, and no new stage starts.
pub fn requested() -> Option<&'static str> {
    match RECEIVED.load(Ordering::SeqCst) {
        0 => None,
        s if s == libc::SIGTERM => Some("SIGTERM"),
        s if s == libc::SIGUSR1 => Some("SIGUSR1"),
        _ => Some("a signal"),
    }
}
