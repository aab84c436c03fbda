//! Which stages of a plan a run considers: `--only` (the matching cells' stages and all they depend on) and
//! `--force` (the matching stages and all below them), by glob patterns over the stages' `cell/kind` labels, and
//! `--rerun-code-changed` (cached stages of the named kinds that other code built, and all below them).
use super::graph::{Plan, Stage, short};
use super::stages::Kind;
use super::store::Store;
use anyhow::{Context, Result, bail};
use globset::{Glob, GlobMatcher};
use std::collections::{BTreeMap, HashSet};

/// A `--only` or `--force` pattern: a glob (`*` any run of characters, `?` one, `[..]` a class, `{a,b}`
/// either) over the whole label; a pattern without a wildcard matches any label containing it.
#[derive(Debug, Clone)]
pub struct Pattern(GlobMatcher, String);

impl Pattern {
    /// Parses `pattern`; the error names it.
    pub fn new(pattern: &str) -> Result<Pattern> {
        if pattern.trim().is_empty() {
            bail!("stage pattern {pattern:?} is empty: name the cells or stages to select (a glob such as 'n1600-*')");
        }
        let wild = pattern.contains(['*', '?', '[', '{']);
        let glob = if wild { pattern.to_string() } else { format!("*{pattern}*") };
        let glob = Glob::new(&glob).with_context(|| format!("stage pattern {pattern:?}"))?;
        Ok(Pattern(glob.compile_matcher(), pattern.to_string()))
    }

    /// Whether `label` matches.
    pub fn matches(&self, label: &str) -> bool {
        self.0.is_match(label)
    }
}

/// Labels of every stage of a plan, by key.
pub type Labels = BTreeMap<String, Vec<String>>;

/// A readable name of a stage: its first label, the job's detail and the short key.
pub fn display_name(stage: &Stage, labels: &Labels) -> String {
    let label = labels.get(&stage.key).and_then(|l| l.first()).cloned().unwrap_or_else(|| stage.kind().name().into());
    let detail = stage.job.detail();
    let detail = if detail.is_empty() { detail } else { format!(" {detail}") };
    format!("{label}{detail} [{}]", short(&stage.key))
}

fn labelled(labels: &Labels, key: &str, pattern: &Pattern) -> bool {
    labels.get(key).is_some_and(|ls| ls.iter().any(|l| pattern.matches(l)))
}

/// An error unless `pattern` matches one of `keys`' labels (a pattern that selects nothing is a typo).
fn check_matches(flag: &str, pattern: &Pattern, keys: &[String], labels: &Labels) -> Result<()> {
    if keys.iter().any(|k| labelled(labels, k, pattern)) {
        return Ok(());
    }
    let example = labels.values().flatten().next().map(String::as_str).unwrap_or("none");
    bail!("{flag} {:?} matches no stage of the plan (labels read like {example:?})", pattern.1)
}

/// The keys to consider: the matching cells' stages and all they depend on, in plan order; an error if the
/// pattern matches no stage.
pub fn selected(plan: &Plan, only: Option<&Pattern>, labels: &Labels) -> Result<Vec<String>> {
    let Some(p) = only else { return Ok(plan.order.clone()) };
    check_matches("--only", p, &plan.order, labels)?;
    let mut want: HashSet<String> = plan.order.iter().filter(|k| labelled(labels, k, p)).cloned().collect();
    for k in plan.order.iter().rev() {
        if want.contains(k) {
            want.extend(plan.stages[k].upstream.iter().cloned());
        }
    }
    Ok(plan.order.iter().filter(|k| want.contains(*k)).cloned().collect())
}

/// The stages `--force` re-runs: the matching ones and everything below them; an error if the pattern matches
/// none of `keys`.
pub fn forced(plan: &Plan, keys: &[String], force: Option<&Pattern>, labels: &Labels) -> Result<HashSet<String>> {
    let Some(p) = force else { return Ok(HashSet::new()) };
    check_matches("--force", p, keys, labels)?;
    Ok(keys.iter().filter(|k| labelled(labels, k, p)).flat_map(|k| plan.downstream(k)).collect())
}

/// The cached stages among `keys` of the `kinds` that code other than this binary's built, and everything below
/// them: what `--rerun-code-changed` re-runs.
pub fn built_by_other_code(plan: &Plan, keys: &[String], kinds: &[Kind], store: &Store) -> Result<HashSet<String>> {
    let mut rerun = HashSet::new();
    for k in keys {
        let kind = plan.stages[k].kind();
        if kinds.contains(&kind) && store.built_by_other_code(k, kind)?.is_some() {
            rerun.extend(plan.downstream(k));
        }
    }
    Ok(rerun)
}

#[cfg(test)]
mod tests {
    use super::Pattern;

    fn matches(pattern: &str, label: &str) -> bool {
        Pattern::new(pattern).unwrap().matches(label)
    }

    #[test]
    fn patterns_match_substrings_and_globs() {
        assert!(matches("n480", "n480-full-s0/train"));
        assert!(matches("n480-*-s1/eval", "n480-no_point-s1/eval"));
        assert!(!matches("n480-*-s1/eval", "n480-no_point-s0/eval"));
        assert!(matches("*/eval", "expert/eval"));
        assert!(!matches("*/train", "expert/eval"));
    }

    #[test]
    fn a_malformed_pattern_is_an_error_naming_it() {
        let err = Pattern::new("n480-[full").unwrap_err().to_string();
        assert!(err.contains("n480-[full"), "{err}");
    }
}
