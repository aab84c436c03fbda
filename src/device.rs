//! Which torch device a network runs on.
use anyhow::{Result, bail};
use tch::Device;

/// Parses `auto` (CUDA when present), `cpu`, `cuda` or `cuda:N`.
pub fn parse_device(name: &str) -> Result<Device> {
    Ok(match name {
        "auto" => Device::cuda_if_available(),
        "cpu" => Device::Cpu,
        "cuda" => Device::Cuda(0),
        _ => match name.strip_prefix("cuda:").and_then(|n| n.parse().ok()) {
            Some(n) => Device::Cuda(n),
            None => bail!("device = {name:?}: expected auto, cpu, cuda or cuda:N"),
        },
    })
}
