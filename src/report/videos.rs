//! The report's rollout videos: the GIFs that evaluations recorded (`eval.videos`), copied beside the report and
//! listed per configuration.
use super::data::ResultRow;
use crate::eval::run::VIDEOS_DIR;
use crate::pipeline::graph::short;
use crate::pipeline::store::Store;
use anyhow::{Context, Result};
use std::fmt::Write as _;
use std::path::Path;

/// Copies every recorded video of `rows` into `staging/videos/` and returns the Markdown section that links them
/// (empty when no evaluation recorded one).
pub fn copy_and_list(store: &Store, rows: &[ResultRow], staging: &Path) -> Result<String> {
    let mut lines = Vec::new();
    for row in rows {
        for (key, artifact) in super::data::eval_artifacts(store, row)? {
            let dir = artifact.join(VIDEOS_DIR);
            let Ok(entries) = std::fs::read_dir(&dir) else { continue };
            let mut names: Vec<String> = entries
                .filter_map(|e| e.ok()?.file_name().into_string().ok())
                .filter(|n| n.ends_with(".gif"))
                .collect();
            names.sort();
            for name in names {
                let copied = format!("{}_{name}", short(key));
                let target = staging.join(VIDEOS_DIR).join(&copied);
                std::fs::create_dir_all(staging.join(VIDEOS_DIR))?;
                std::fs::copy(dir.join(&name), &target)
                    .with_context(|| format!("copying {} into the report", dir.join(&name).display()))?;
                let shown = name.trim_end_matches(".gif").replace('_', " ");
                lines.push(format!("| {} | `{}` | [{shown}]({VIDEOS_DIR}/{copied}) |", row.label, short(key)));
            }
        }
    }
    if lines.is_empty() {
        return Ok(String::new());
    }
    let mut section = String::from(
        "\n## Rollout videos\n\nEach GIF plays the demonstration (left) beside the agent's rollout (right) at the \
         policy's rate; the squares under the rollout light up as it reaches (yellow), picks (orange) and places \
         (green).\n\n| model | eval stage | episode |\n| --- | --- | --- |\n",
    );
    for l in lines {
        let _ = writeln!(section, "{l}");
    }
    Ok(section)
}
