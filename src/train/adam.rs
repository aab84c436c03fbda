//! Adam (Kingma & Ba, 2015; the update of `torch.optim.Adam` without weight decay) over the trainable variables of
//! a var store. Its moment estimates are saved beside each checkpoint, so a resumed run continues exactly.
use anyhow::{Context, Result, bail};
use std::path::Path;
use tch::{Kind, Tensor, nn};

const BETA1: f64 = 0.9;
const BETA2: f64 = 0.999;
const EPS: f64 = 1e-8;

/// The optimiser and its state.
pub struct Adam {
    lr: f64,
    step: i64,
    /// Trainable variables by name (sorted), with their first and second moment estimates.
    params: Vec<(String, Tensor, Tensor, Tensor)>,
}

impl Adam {
    /// A fresh optimiser for the trainable variables of `vs`.
    pub fn new(vs: &nn::VarStore, lr: f64) -> Adam {
        let mut vars: Vec<(String, Tensor)> = vs.variables().into_iter().filter(|(_, t)| t.requires_grad()).collect();
        vars.sort_by(|a, b| a.0.cmp(&b.0));
        let params = vars
            .into_iter()
            .map(|(name, p)| {
                let (m, v) = (p.zeros_like().detach(), p.zeros_like().detach());
                (name, p, m, v)
            })
            .collect();
        Adam { lr, step: 0, params }
    }

    /// Changes the learning rate.
    pub fn set_lr(&mut self, lr: f64) {
        self.lr = lr;
    }

    /// Back-propagates `loss` and applies one update.
    pub fn backward_step(&mut self, loss: &Tensor) {
        for (_, p, _, _) in &self.params {
            let mut g = p.grad();
            if g.defined() {
                let _ = g.zero_();
            }
        }
        loss.backward();
        self.step += 1;
        let (bc1, bc2) = (1.0 - BETA1.powi(self.step as i32), 1.0 - BETA2.powi(self.step as i32));
        tch::no_grad(|| {
            for (_, p, m, v) in &mut self.params {
                let g = p.grad();
                if !g.defined() {
                    continue;
                }
                let _ = m.lerp_(&g, 1.0 - BETA1);
                let _ = v.lerp_(&g.square(), 1.0 - BETA2);
                let mut denom = v.sqrt();
                let _ = denom.g_div_scalar_(bc2.sqrt());
                let _ = denom.g_add_scalar_(EPS);
                let _ = p.addcdiv_(&(&*m * (-self.lr / bc1)), &denom);
            }
        });
    }

    /// Writes the state (`step`, `m.<name>`, `v.<name>`) as safetensors.
    pub fn save(&self, path: &Path) -> Result<()> {
        let step = Tensor::from_slice(&[self.step]);
        let mut named: Vec<(String, &Tensor)> = vec![("step".into(), &step)];
        for (name, _, m, v) in &self.params {
            named.push((format!("m.{name}"), m));
            named.push((format!("v.{name}"), v));
        }
        crate::fsio::write_with(path, |tmp| Ok(Tensor::write_safetensors(&named, tmp)?))
    }

    /// Restores the state written by [`Adam::save`]; errors name the file and a parameter that does not fit.
    pub fn load(&mut self, path: &Path) -> Result<()> {
        let stored: std::collections::HashMap<String, Tensor> = Tensor::read_safetensors(path)
            .with_context(|| format!("reading {}", path.display()))?
            .into_iter()
            .collect();
        let step = stored.get("step").with_context(|| format!("{} has no `step`", path.display()))?;
        tch::no_grad(|| -> Result<()> {
            for (name, p, m, v) in &mut self.params {
                for (prefix, state) in [("m", &mut *m), ("v", &mut *v)] {
                    let key = format!("{prefix}.{name}");
                    let saved = stored.get(&key).with_context(|| format!("{} lacks `{key}`", path.display()))?;
                    if saved.size() != p.size() {
                        bail!("{}: `{key}` is {:?}, the parameter is {:?}", path.display(), saved.size(), p.size());
                    }
                    state.copy_(saved);
                }
            }
            Ok(())
        })?;
        self.step = step.to_kind(Kind::Int64).int64_value(&[0]);
        Ok(())
    }
}
