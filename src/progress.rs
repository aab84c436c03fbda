//! Progress bars on stderr for long-running work.
use indicatif::{ProgressBar, ProgressStyle};

/// A bar of `len` steps labelled `label`, hidden when `show` is false.
pub fn progress_bar(len: u64, show: bool, label: &str) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} {per_sec} eta {eta}")
            .expect("static template")
            .progress_chars("=> "),
    );
    bar.set_message(label.to_string());
    bar
}
