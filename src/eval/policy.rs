//! What an evaluation measures: a trained network or a reference policy. The network is referred to differently
//! at each layer (a train stage key while planning, a training folder when a stage runs, the loaded network during
//! rollouts), so the type is generic over that reference.
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// A policy to evaluate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Policy<N> {
    /// A trained network.
    Network(N),
    /// The scripted expert with privileged state (the upper bound).
    Expert,
    /// Uniformly random normalised actions (the floor).
    Random,
}

impl<N> Policy<N> {
    /// A short name for reports: `network`, `expert` or `random`.
    pub fn name(&self) -> &'static str {
        match self {
            Policy::Network(_) => "network",
            Policy::Expert => "expert",
            Policy::Random => "random",
        }
    }

    /// The same policy with the network referred to through `f`.
    pub fn map<M>(self, f: impl FnOnce(N) -> M) -> Policy<M> {
        match self {
            Policy::Network(n) => Policy::Network(f(n)),
            Policy::Expert => Policy::Expert,
            Policy::Random => Policy::Random,
        }
    }

    /// The same policy, borrowing the network reference.
    pub fn as_ref(&self) -> Policy<&N> {
        match self {
            Policy::Network(n) => Policy::Network(n),
            Policy::Expert => Policy::Expert,
            Policy::Random => Policy::Random,
        }
    }

    /// The same policy with the network referred to through the fallible `f`.
    pub fn try_map<M, E>(self, f: impl FnOnce(N) -> Result<M, E>) -> Result<Policy<M>, E> {
        Ok(match self {
            Policy::Network(n) => Policy::Network(f(n)?),
            Policy::Expert => Policy::Expert,
            Policy::Random => Policy::Random,
        })
    }

    /// Parses `expert`, `random`, or anything else as a network reference through `network`.
    pub fn parse(s: &str, network: impl FnOnce(&str) -> N) -> Policy<N> {
        match s {
            "expert" => Policy::Expert,
            "random" => Policy::Random,
            other => Policy::Network(network(other)),
        }
    }
}

/// Weights of a training run: `at` locates the run (a stage key, a folder), `step` picks an intermediate
/// checkpoint instead of the final weights.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Weights<L> {
    pub at: L,
    pub step: Option<u64>,
}

/// A policy whose network is a training folder.
pub type PolicyFiles = Policy<Weights<PathBuf>>;
