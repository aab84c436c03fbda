//! The policy behind a configuration: the paper's transformer (or its temporal-conv ablation) or the
//! Contextual-LSTM baseline, with one forward interface for training and evaluation.
use super::config::{Architecture, ModelConfig};
use super::lstm::ContextualLstm;
use super::transformer::{PolicyOutput, TransformerPolicy};
use tch::{Tensor, nn};

#[derive(Debug)]
enum Net {
    Transformer(Box<TransformerPolicy>),
    ContextualLstm(Box<ContextualLstm>),
}

/// A policy network and the configuration it was built from.
#[derive(Debug)]
pub struct Policy {
    config: ModelConfig,
    net: Net,
}

impl Policy {
    /// Builds the network of `config` under `vs` (call `config.validate()` first).
    pub fn new(vs: &nn::Path, config: &ModelConfig) -> Policy {
        let net = match config.architecture {
            Architecture::ContextualLstm => Net::ContextualLstm(Box::new(ContextualLstm::new(vs, config))),
            Architecture::Transformer | Architecture::TemporalConv => {
                Net::Transformer(Box::new(TransformerPolicy::new(vs, config)))
            }
        };
        Policy { config: config.clone(), net }
    }

    /// Runs the trunk on channels-last tensors (see [`super::resnet::ResNet18::set_channels_last`]).
    pub fn set_channels_last(&mut self, on: bool) {
        match &mut self.net {
            Net::Transformer(t) => t.trunk_mut().set_channels_last(on),
            Net::ContextualLstm(l) => l.trunk_mut().set_channels_last(on),
        }
    }

    /// The settings this network was built with.
    pub fn config(&self) -> &ModelConfig {
        &self.config
    }

    /// Predictions for `context` `[B, Tc, 3, H, W]` and agent frames `[B, Ta, 3, H, W]`; agent frame t's outputs
    /// depend only on the context and agent frames 0..=t.
    pub fn forward_t(&self, context: &Tensor, agent: &Tensor, train: bool) -> PolicyOutput {
        match &self.net {
            Net::Transformer(t) => t.forward_t(context, agent, train),
            Net::ContextualLstm(l) => {
                PolicyOutput { actions: l.forward_t(context, agent, train), inverse: None, point: None }
            }
        }
    }
}
