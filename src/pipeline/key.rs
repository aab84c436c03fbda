//! Content keys of stages: blake3 over the kind, the kind's implementation version, the resolved configuration
//! in canonical JSON (object keys sorted, no whitespace) and the keys of the upstream stages.
use serde::Serialize;

/// Canonical JSON of `value`: serde_json's map is ordered by key, so equal values give equal text.
pub fn canonical_json<T: Serialize>(value: &T) -> String {
    let v = serde_json::to_value(value).expect("configurations serialise to JSON");
    serde_json::to_string(&v).expect("JSON values serialise")
}

/// The key of a stage.
pub fn stage_key(kind: &str, version: u32, config_json: &str, upstream: &[String]) -> String {
    let mut h = blake3::Hasher::new();
    for part in [kind, &version.to_string(), config_json] {
        h.update(&(part.len() as u64).to_le_bytes());
        h.update(part.as_bytes());
    }
    for u in upstream {
        h.update(&(u.len() as u64).to_le_bytes());
        h.update(u.as_bytes());
    }
    h.finalize().to_hex().to_string()
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn canonical_json_ignores_key_order() {
        let a = json!({"b": 1, "a": {"y": 2, "x": 3}});
        let b = json!({"a": {"x": 3, "y": 2}, "b": 1});
        assert_eq!(canonical_json(&a), canonical_json(&b));
    }

    #[test]
    fn keys_change_with_every_input() {
        let k = stage_key("train", 1, "{}", &["u".into()]);
        assert_eq!(k, stage_key("train", 1, "{}", &["u".into()]));
        assert_ne!(k, stage_key("eval", 1, "{}", &["u".into()]));
        assert_ne!(k, stage_key("train", 2, "{}", &["u".into()]));
        assert_ne!(k, stage_key("train", 1, "{\"a\":1}", &["u".into()]));
        assert_ne!(k, stage_key("train", 1, "{}", &["v".into()]));
    }
}
