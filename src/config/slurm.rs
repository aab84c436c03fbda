//! The `[slurm.KIND]` sections of an experiment file: what each stage kind asks of the cluster when `run --slurm`
//! submits it. They shape jobs, not results, so no stage key includes them.
use anyhow::{Result, bail};
use serde::{Deserialize, Serialize};

/// The resources one stage kind's jobs request; each given field becomes an `sbatch` option.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct SlurmResources {
    /// Partition (`--partition`).
    pub partition: Option<String>,
    /// Time limit in Slurm's spelling, e.g. `"24:00:00"` or `"2-00:00:00"` (`--time`).
    pub time: Option<String>,
    /// Generic resources, e.g. `"gpu:1"` (`--gres`).
    pub gres: Option<String>,
    /// CPUs per task (`--cpus-per-task`).
    pub cpus: Option<u32>,
    /// Memory per node, e.g. `"32G"` (`--mem`).
    pub memory: Option<String>,
    /// Any further `sbatch` options, each one argument, e.g. `["--qos=long"]`.
    pub args: Vec<String>,
}

impl SlurmResources {
    /// The `sbatch` arguments these resources stand for.
    pub fn sbatch_args(&self) -> Vec<String> {
        let mut out = Vec::new();
        let named = [("--partition", &self.partition), ("--time", &self.time), ("--gres", &self.gres)];
        out.extend(named.iter().filter_map(|(flag, v)| v.as_ref().map(|v| format!("{flag}={v}"))));
        out.extend(self.cpus.map(|c| format!("--cpus-per-task={c}")));
        out.extend(self.memory.as_ref().map(|m| format!("--mem={m}")));
        out.extend(self.args.iter().cloned());
        out
    }

    fn validate(&self, kind: &str) -> Result<()> {
        let fields =
            [("partition", &self.partition), ("time", &self.time), ("gres", &self.gres), ("memory", &self.memory)];
        for (key, v) in fields {
            if let Some(v) = v.as_ref().filter(|v| v.is_empty() || v.chars().any(|c| c.is_whitespace() || c == '=')) {
                bail!("slurm.{kind}.{key} = {v:?} must be one word without spaces or '='");
            }
        }
        if self.cpus == Some(0) {
            bail!("slurm.{kind}.cpus = 0 must be at least 1");
        }
        if let Some(a) = self.args.iter().find(|a| !a.starts_with('-')) {
            bail!("slurm.{kind}.args contains {a:?}: each entry is one sbatch option, starting with '-'");
        }
        Ok(())
    }
}

/// Per stage kind, the resources its jobs request (after `run --slurm-arg`, which every job gets first).
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields, default)]
pub struct SlurmSection {
    /// Collection jobs.
    pub collect: SlurmResources,
    /// Trunk pretraining jobs.
    pub pretrain: SlurmResources,
    /// Training jobs.
    pub train: SlurmResources,
    /// Evaluation jobs.
    pub eval: SlurmResources,
}

impl SlurmSection {
    /// The resources of stage kind `kind` (`collect`, `pretrain`, `train` or `eval`).
    pub fn of(&self, kind: &str) -> Option<&SlurmResources> {
        match kind {
            "collect" => Some(&self.collect),
            "pretrain" => Some(&self.pretrain),
            "train" => Some(&self.train),
            "eval" => Some(&self.eval),
            _ => None,
        }
    }

    /// Checks every kind's resources; errors name the key.
    pub fn validate(&self) -> Result<()> {
        for kind in ["collect", "pretrain", "train", "eval"] {
            self.of(kind).expect("a kind").validate(kind)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resources_become_sbatch_options_and_bad_values_name_their_key() {
        let train = SlurmResources {
            partition: Some("gpu".into()),
            time: Some("24:00:00".into()),
            gres: Some("gpu:1".into()),
            cpus: Some(8),
            memory: Some("32G".into()),
            args: vec!["--qos=long".into()],
        };
        let want =
            ["--partition=gpu", "--time=24:00:00", "--gres=gpu:1", "--cpus-per-task=8", "--mem=32G", "--qos=long"];
        assert_eq!(train.sbatch_args(), want);
        assert!(SlurmResources::default().sbatch_args().is_empty());
        let section = SlurmSection { train, ..Default::default() };
        section.validate().unwrap();
        assert_eq!(section.of("train").unwrap().cpus, Some(8));
        let spaced =
            SlurmSection { eval: SlurmResources { time: Some("1 day".into()), ..Default::default() }, ..section };
        let err = spaced.validate().unwrap_err().to_string();
        assert!(err.contains("slurm.eval.time") && err.contains("1 day"), "{err}");
    }
}
