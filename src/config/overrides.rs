//! `--set KEY=VALUE`: one key of an experiment file given on the command line, merged after the chosen profile
//! and validated exactly like the file.
use anyhow::{Result, bail};
use std::fmt;
use std::str::FromStr;

/// One dotted key and its value, e.g. `train.lr=1e-3` or `variants.final_frame.eval.episodes=8`.
#[derive(Debug, Clone, PartialEq)]
pub struct Override {
    /// The key's path of tables, e.g. `["train", "lr"]`.
    pub path: Vec<String>,
    pub value: toml::Value,
}

impl FromStr for Override {
    type Err = anyhow::Error;

    /// The value is read as TOML (`3`, `1e-3`, `true`, `[0, 1]`, `"text"`); anything that does not read as TOML
    /// is taken as a bare string, so `model.context=final` needs no quotes.
    fn from_str(s: &str) -> Result<Override> {
        let Some((key, value)) = s.split_once('=') else {
            bail!("--set {s}: expected KEY=VALUE, e.g. train.lr=1e-3");
        };
        let path: Vec<String> = key.trim().split('.').map(str::to_string).collect();
        let plain = |p: &String| !p.is_empty() && p.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
        if !path.iter().all(plain) {
            bail!("--set {s}: `{key}` is not a dotted key of the experiment file (e.g. train.lr)");
        }
        let value = value.trim();
        let value = match toml::from_str::<toml::Table>(&format!("v = {value}")) {
            Ok(mut t) if t.len() == 1 => t.remove("v").expect("the one key read"),
            _ => toml::Value::String(value.to_string()),
        };
        Ok(Override { path, value })
    }
}

impl fmt::Display for Override {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let value = match &self.value {
            toml::Value::String(s)
                if !s.is_empty() && s.chars().all(|c| c.is_ascii_alphanumeric() || "._-".contains(c)) =>
            {
                s.clone()
            }
            v => v.to_string(),
        };
        write!(f, "{}={value}", self.path.join("."))
    }
}

impl Override {
    /// Sets the key in `table`, creating the tables on its path; a value on the path that is not a table is an
    /// error naming the key.
    pub fn apply(&self, table: &mut toml::Table) -> Result<()> {
        let (last, tables) = self.path.split_last().expect("a parsed key has at least one part");
        let mut at = table;
        for (i, part) in tables.iter().enumerate() {
            let entry = at.entry(part.clone()).or_insert_with(|| toml::Value::Table(toml::Table::new()));
            let toml::Value::Table(next) = entry else {
                bail!("--set {self}: `{}` is a value, not a table of keys", self.path[..=i].join("."));
            };
            at = next;
        }
        at.insert(last.clone(), self.value.clone());
        Ok(())
    }
}

/// The overrides as the command line spells them, space separated (empty when none).
pub fn spelled(overrides: &[Override]) -> String {
    overrides.iter().map(|o| format!("--set {o}")).collect::<Vec<_>>().join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn values_read_as_toml_else_as_bare_strings() {
        let o: Override = "train.lr=1e-3".parse().unwrap();
        assert_eq!((o.path.join("."), o.value.as_float()), ("train.lr".into(), Some(1e-3)));
        let o: Override = "grid.seeds=[0, 1]".parse().unwrap();
        assert_eq!(o.value.as_array().map(Vec::len), Some(2));
        let o: Override = "model.context=final".parse().unwrap();
        assert_eq!(o.value.as_str(), Some("final"));
        assert_eq!(o.to_string(), "model.context=final");
        let o: Override = "description=two words".parse().unwrap();
        assert_eq!(o.to_string(), "description=\"two words\"");
        for bad in ["train.lr", "=3", "train..lr=3", "../x=1"] {
            assert!(bad.parse::<Override>().is_err(), "{bad}");
        }
    }

    #[test]
    fn apply_sets_nested_keys_and_refuses_a_value_on_the_path() {
        let mut t: toml::Table = toml::from_str("[train]\nlr = 0.1\nsteps = 5\n").unwrap();
        "train.lr=0.2".parse::<Override>().unwrap().apply(&mut t).unwrap();
        "variants.x.eval.episodes=4".parse::<Override>().unwrap().apply(&mut t).unwrap();
        assert_eq!(t["train"]["lr"].as_float(), Some(0.2));
        assert_eq!(t["train"]["steps"].as_integer(), Some(5));
        assert_eq!(t["variants"]["x"]["eval"]["episodes"].as_integer(), Some(4));
        let e = "train.lr.x=1".parse::<Override>().unwrap().apply(&mut t).unwrap_err();
        assert!(e.to_string().contains("`train.lr` is a value"), "{e}");
    }
}
