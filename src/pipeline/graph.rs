//! The stage graph of an experiment: stages identified by content keys, each after its upstream stages, and the
//! experiment's cells pointing at the stages behind their numbers. Identical stages share one key, within and
//! across experiment files. What the stages are is the stage registry's business ([`super::stages`]).
use super::key::{canonical_json, stage_key};
use super::stages::{Job, Kind};
use serde::Serialize;
use std::collections::BTreeMap;

/// A stage: its key, resolved inputs, upstream keys and what it runs.
#[derive(Debug, Clone)]
pub struct Stage {
    pub key: String,
    /// The resolved inputs that went into the key (without the upstream keys).
    pub inputs: serde_json::Value,
    pub upstream: Vec<String>,
    pub job: Job,
}

impl Stage {
    /// The stage's kind.
    pub fn kind(&self) -> Kind {
        self.job.kind()
    }
}

/// A cell of the experiment with the stages that produce its numbers.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PlannedCell {
    pub name: String,
    /// `model` for a trained cell, otherwise the reference policy's name.
    pub policy: String,
    pub size: Option<usize>,
    pub variant: Option<String>,
    pub seed: Option<u64>,
    pub collect_demo: Option<String>,
    pub collect_agent: Option<String>,
    /// The trunk's pretraining, where the cell has a `[pretrain]` section.
    pub pretrain: Option<String>,
    pub train: Option<String>,
    pub eval: String,
    /// Evaluations of intermediate checkpoints: (training step, eval stage key).
    pub checkpoints: Vec<(u64, String)>,
}

/// The stage graph of an experiment.
#[derive(Debug, Clone, Default)]
pub struct Plan {
    /// Stages by key.
    pub stages: BTreeMap<String, Stage>,
    /// Keys in an order where every stage follows its upstream.
    pub order: Vec<String>,
    pub cells: Vec<PlannedCell>,
}

impl Plan {
    /// Adds a stage (once: an identical stage is already there under the same key); returns its key.
    pub fn add(&mut self, inputs: serde_json::Value, upstream: Vec<String>, job: Job) -> String {
        let kind = job.kind();
        let key = stage_key(kind.name(), kind.version(), &canonical_json(&inputs), &upstream);
        if !self.stages.contains_key(&key) {
            self.order.push(key.clone());
            self.stages.insert(key.clone(), Stage { key: key.clone(), inputs, upstream, job });
        }
        key
    }

    /// Keys of `key` and every stage downstream of it.
    pub fn downstream(&self, key: &str) -> Vec<String> {
        let mut out = vec![key.to_string()];
        for k in &self.order {
            if self.stages[k].upstream.iter().any(|u| out.contains(u)) && !out.contains(k) {
                out.push(k.clone());
            }
        }
        out
    }

    /// `cell/kind` labels of every stage (a shared stage has several); checkpoint evaluations are
    /// `cell/eval@step`.
    pub fn labels(&self) -> BTreeMap<String, Vec<String>> {
        let mut out: BTreeMap<String, Vec<String>> = BTreeMap::new();
        for c in &self.cells {
            let keys = [
                (&c.collect_demo, "collect"),
                (&c.collect_agent, "collect"),
                (&c.pretrain, "pretrain"),
                (&c.train, "train"),
            ];
            for (k, kind) in keys {
                if let Some(k) = k {
                    out.entry(k.clone()).or_default().push(format!("{}/{kind}", c.name));
                }
            }
            out.entry(c.eval.clone()).or_default().push(format!("{}/eval", c.name));
            for (step, k) in &c.checkpoints {
                out.entry(k.clone()).or_default().push(format!("{}/eval@{step}", c.name));
            }
        }
        out
    }
}

/// A short form of a key for folder names and tables.
pub fn short(key: &str) -> &str {
    &key[..key.len().min(12)]
}
