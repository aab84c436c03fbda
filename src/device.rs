//! Which torch device a network runs on.
use anyhow::{Result, bail};
use tch::Device;

/// Checks that `name` is `auto`, `cpu`, `cuda` or `cuda:N` (whether this machine has that GPU is left to
/// [`parse_device`], so that a GPU experiment can be planned anywhere).
pub fn check_device_name(name: &str) -> Result<()> {
    let valid = matches!(name, "auto" | "cpu" | "cuda")
        || name.strip_prefix("cuda:").is_some_and(|n| n.parse::<usize>().is_ok());
    if !valid {
        bail!("device = {name:?}: expected auto, cpu, cuda or cuda:N");
    }
    Ok(())
}

/// Parses `auto` (CUDA when present), `cpu`, `cuda` or `cuda:N`; asking for a GPU this process cannot use is an
/// error that says why.
pub fn parse_device(name: &str) -> Result<Device> {
    check_device_name(name)?;
    let device = match name {
        "auto" => Device::cuda_if_available(),
        "cpu" => Device::Cpu,
        "cuda" => Device::Cuda(0),
        _ => Device::Cuda(name["cuda:".len()..].parse().expect("checked above")),
    };
    if let Device::Cuda(n) = device {
        let count = tch::Cuda::device_count().max(0) as usize;
        if count == 0 {
            bail!(
                "device = {name:?}, but libtorch sees no CUDA device: this machine has no usable GPU, or libtorch's \
                 CUDA backend was not loaded (docs/guide/gpu.md: LD_PRELOAD=libtorch_cuda.so)"
            );
        }
        if n >= count {
            bail!("device = {name:?}, but libtorch sees {count} CUDA device(s): cuda:0 to cuda:{}", count - 1);
        }
    }
    Ok(device)
}

/// Lets cuDNN time its convolution algorithms on the first step and keep the fastest: worth it where every step
/// has the same shapes (training, benchmarks). No effect on CPU.
pub fn autotune_convolutions(device: Device) {
    if device.is_cuda() {
        tch::Cuda::cudnn_set_benchmark(true);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_and_a_missing_gpu_is_a_clear_error() {
        assert_eq!(parse_device("cpu").unwrap(), Device::Cpu);
        for bad in ["gpu", "cuda:x", "cuda:"] {
            let err = parse_device(bad).unwrap_err().to_string();
            assert!(err.contains("expected auto, cpu, cuda or cuda:N"), "{err}");
            assert!(check_device_name(bad).is_err());
        }
        check_device_name("cuda:3").unwrap();
        if tch::Cuda::device_count() == 0 {
            assert_eq!(parse_device("auto").unwrap(), Device::Cpu);
            for name in ["cuda", "cuda:1"] {
                let err = parse_device(name).unwrap_err().to_string();
                assert!(err.contains("no CUDA device"), "{err}");
            }
        } else {
            let err = parse_device("cuda:99").unwrap_err().to_string();
            assert!(err.contains("CUDA device(s)"), "{err}");
        }
    }
}
