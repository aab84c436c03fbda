//! Who acts in an evaluation: a trained network or a reference policy (the network itself is `model::policy::Policy`). The network is referred to differently
//! at each layer (a train stage key while planning, a training folder when a stage runs, the loaded network during
//! rollouts), so the type is generic over that reference.
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// Who acts in an evaluation: a trained network (the model this tool trains) or a reference policy.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Actor<N> {
    /// A trained network.
    Network(N),
    /// The scripted expert with privileged state (the upper bound).
    Expert,
    /// Uniformly random normalised actions (the floor).
    Random,
}

impl<N> Actor<N> {
    /// A short name for reports: `network`, `expert` or `random`.
    pub fn name(&self) -> &'static str {
        match self {
            Actor::Network(_) => "network",
            Actor::Expert => "expert",
            Actor::Random => "random",
        }
    }

    /// The same policy with the network referred to through `f`.
    pub fn map<M>(self, f: impl FnOnce(N) -> M) -> Actor<M> {
        match self {
            Actor::Network(n) => Actor::Network(f(n)),
            Actor::Expert => Actor::Expert,
            Actor::Random => Actor::Random,
        }
    }

    /// The same policy, borrowing the network reference.
    pub fn as_ref(&self) -> Actor<&N> {
        match self {
            Actor::Network(n) => Actor::Network(n),
            Actor::Expert => Actor::Expert,
            Actor::Random => Actor::Random,
        }
    }

    /// The same policy with the network referred to through the fallible `f`.
    pub fn try_map<M, E>(self, f: impl FnOnce(N) -> Result<M, E>) -> Result<Actor<M>, E> {
        Ok(match self {
            Actor::Network(n) => Actor::Network(f(n)?),
            Actor::Expert => Actor::Expert,
            Actor::Random => Actor::Random,
        })
    }

    /// Parses `expert`, `random`, or anything else as a network reference through `network`.
    pub fn parse(s: &str, network: impl FnOnce(&str) -> N) -> Actor<N> {
        match s {
            "expert" => Actor::Expert,
            "random" => Actor::Random,
            other => Actor::Network(network(other)),
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
pub type ActorFiles = Actor<Weights<PathBuf>>;
