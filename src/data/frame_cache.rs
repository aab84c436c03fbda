//! How many bytes of decoded frames a training holds in memory: half of what the machine has available when the
//! dataset opens (two trainings side by side then leave the system room), or what `ONESHOT_FRAME_CACHE_GIB` says.
//! Frames beyond the budget are decoded from JPEG on every use.
use anyhow::{Context, Result, bail};

/// The environment variable that fixes the budget, in GiB (0 decodes every frame on use).
pub const BUDGET_VARIABLE: &str = "ONESHOT_FRAME_CACHE_GIB";

/// The budget when the machine's available memory cannot be read.
const FALLBACK_BYTES: usize = 4 << 30;

/// The budget in bytes for this machine now.
pub fn budget() -> Result<usize> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok();
    budget_from(std::env::var(BUDGET_VARIABLE).ok().as_deref(), meminfo.as_deref())
}

/// The budget from the variable's value, if set, else from `/proc/meminfo`'s text, if readable.
pub fn budget_from(variable: Option<&str>, meminfo: Option<&str>) -> Result<usize> {
    if let Some(v) = variable {
        let gib: f64 = v.trim().parse().with_context(|| format!("{BUDGET_VARIABLE} = {v:?} is not a number of GiB"))?;
        if !(gib >= 0.0 && gib.is_finite()) {
            bail!("{BUDGET_VARIABLE} = {v:?} must be a non-negative number of GiB");
        }
        return Ok((gib * (1u64 << 30) as f64) as usize);
    }
    Ok(meminfo.and_then(available_bytes).map_or(FALLBACK_BYTES, |bytes| bytes / 2))
}

/// `MemAvailable` of a `/proc/meminfo` text, in bytes.
fn available_bytes(meminfo: &str) -> Option<usize> {
    let line = meminfo.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: usize = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

#[cfg(test)]
mod tests {
    use super::*;

    const MEMINFO: &str = "MemTotal:       24000000 kB\nMemFree:         1000000 kB\nMemAvailable:   16000000 kB\n";

    #[test]
    fn the_budget_is_half_the_available_memory_unless_the_variable_sets_it() {
        assert_eq!(budget_from(None, Some(MEMINFO)).unwrap(), 8_000_000 * 1024);
        assert_eq!(budget_from(Some("1.5"), Some(MEMINFO)).unwrap(), 3 << 29);
        assert_eq!(budget_from(Some("0"), None).unwrap(), 0);
        assert_eq!(budget_from(None, Some("MemTotal: 1 kB\n")).unwrap(), FALLBACK_BYTES);
        assert_eq!(budget_from(None, None).unwrap(), FALLBACK_BYTES);
        for bad in ["lots", "-1", "inf"] {
            let err = budget_from(Some(bad), None).unwrap_err().to_string();
            assert!(err.contains(BUDGET_VARIABLE) && err.contains(bad), "{err}");
        }
    }
}
