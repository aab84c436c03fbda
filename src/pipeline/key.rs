//! Content keys of stages: blake3 over the kind, the kind's implementation version, the resolved configuration
//! in canonical JSON (object keys sorted, no whitespace) and the keys of the upstream stages.
use serde::Serialize;
use serde_json::Value;

/// Canonical JSON of `value`: serde_json's map is ordered by key, so equal values give equal text.
pub fn canonical_json<T: Serialize>(value: &T) -> String {
    let v = serde_json::to_value(value).expect("configurations serialise to JSON");
    serde_json::to_string(&v).expect("JSON values serialise")
}

/// Leaves out of a stage's key inputs each `section.key` path whose value is the one given: settings a kind
/// added after keys existed (at their value before), so that adding them kept every earlier key.
pub fn omit_when(inputs: &mut Value, neutral: &[(&str, Value)]) {
    for (path, value) in neutral {
        let mut parts: Vec<&str> = path.split('.').collect();
        let last = parts.pop().expect("paths are not empty");
        let parent = parts.iter().try_fold(&mut *inputs, |v, p| v.get_mut(*p));
        if let Some(Value::Object(map)) = parent
            && map.get(last) == Some(value)
        {
            map.remove(last);
        }
    }
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
    fn a_neutral_setting_is_left_out_only_at_its_value() {
        let mut v = json!({"train": {"precision": "fp32", "lr": 1.0}, "world": {"close_on_arrival": true}});
        let neutral = [("train.precision", json!("fp32")), ("world.close_on_arrival", json!(false))];
        omit_when(&mut v, &neutral);
        assert_eq!(v, json!({"train": {"lr": 1.0}, "world": {"close_on_arrival": true}}));
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
