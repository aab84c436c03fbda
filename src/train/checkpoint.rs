//! Checkpoints: the var store as safetensors (parameter names as in the network, loadable from Python), written
//! to a temporary name and renamed, and loaded only after every name and shape is checked.
use anyhow::{Context, Result, bail};
use std::path::{Path, PathBuf};
use tch::{Tensor, nn};

/// Saves all variables of `vs` to `path` atomically.
pub fn save(vs: &nn::VarStore, path: &Path) -> Result<()> {
    crate::fsio::write_with(path, |tmp| Ok(vs.save(tmp)?))
}

/// Loads `path` into `vs`; errors name the file and the first parameter that does not fit.
pub fn load(vs: &mut nn::VarStore, path: &Path) -> Result<()> {
    let mut stored =
        Tensor::read_safetensors(path).with_context(|| format!("reading checkpoint {}", path.display()))?;
    stored.sort_by(|a, b| a.0.cmp(&b.0));
    let mut expected = vs.variables();
    for (name, tensor) in &stored {
        let Some(var) = expected.remove(name) else {
            bail!("checkpoint {} has parameter `{name}`, which this architecture lacks", path.display());
        };
        if var.size() != tensor.size() {
            bail!(
                "checkpoint {} does not fit this architecture: `{name}` is {:?}, the model expects {:?}",
                path.display(),
                tensor.size(),
                var.size()
            );
        }
    }
    if let Some(name) = expected.keys().min() {
        bail!("checkpoint {} lacks parameter `{name}` of this architecture", path.display());
    }
    let mut vars = vs.variables();
    tch::no_grad(|| {
        for (name, tensor) in &stored {
            vars.get_mut(name).expect("checked above").copy_(tensor);
        }
    });
    Ok(())
}

/// Copies matching `backbone.*` parameters from a torchvision-named safetensors file: ResNet-18's, or VGG-16's
/// first block for DAML.
pub fn load_backbone(vs: &mut nn::VarStore, path: &Path) -> Result<usize> {
    let copied = load_under(vs, path, "backbone.")?;
    if copied == 0 {
        bail!(
            "{} holds no parameter of this backbone (expected torchvision names like `layer1.0.conv1.weight` for \
             ResNet-18, `features.0.weight` for DAML's VGG-16 block)",
            path.display()
        );
    }
    Ok(copied)
}

/// Copies the weights of `path` into the variables of `vs` named `prefix` + their stored name; returns how many
/// it copied (an error if one's shape differs).
pub fn load_under(vs: &mut nn::VarStore, path: &Path, prefix: &str) -> Result<usize> {
    let stored =
        Tensor::read_safetensors(path).with_context(|| format!("reading pretrained weights {}", path.display()))?;
    let mut vars = vs.variables();
    let mut copied = 0;
    tch::no_grad(|| -> Result<()> {
        for (name, tensor) in &stored {
            if let Some(var) = vars.get_mut(&format!("{prefix}{name}")) {
                if var.size() != tensor.size() {
                    bail!("{}: `{name}` is {:?}, the network expects {:?}", path.display(), tensor.size(), var.size());
                }
                var.copy_(tensor);
                copied += 1;
            }
        }
        Ok(())
    })?;
    Ok(copied)
}

/// The checkpoint file of `step` in `dir`.
pub fn path_for(dir: &Path, step: u64) -> PathBuf {
    dir.join(format!("step_{step:08}.safetensors"))
}

/// The optimiser state saved beside the weights at `weights` (written first, so a checkpoint whose weights exist
/// has its state).
pub fn optimizer_path(weights: &Path) -> PathBuf {
    weights.with_extension("adam.safetensors")
}

/// The latest complete checkpoint in `dir` and its step.
pub fn latest(dir: &Path) -> Result<Option<(u64, PathBuf)>> {
    if !dir.exists() {
        return Ok(None);
    }
    let mut best = None;
    for entry in std::fs::read_dir(dir).with_context(|| format!("listing {}", dir.display()))? {
        let path = entry?.path();
        if let Some(step) = step_of(&path)
            && best.as_ref().is_none_or(|(b, _)| step > *b)
        {
            best = Some((step, path));
        }
    }
    Ok(best)
}

/// The step of the checkpoint file at `path` ([`path_for`]'s name), or none for any other file.
pub fn step_of(path: &Path) -> Option<u64> {
    let name = path.file_name()?.to_str()?;
    name.strip_prefix("step_")?.strip_suffix(".safetensors")?.parse().ok()
}
