//! The paper's published numbers (Table 1 and section 5.3), matched to our rows where the configuration is the same.
use super::data::ResultRow;

/// Table 1, "ours": (reach, pick, place) in % with the paper's +- half-widths, at N = 1600 with the full model.
pub const OURS_TABLE1: [(f64, f64); 3] = [(99.4, 1.2), (92.5, 4.1), (88.8, 5.0)];
/// Table 1, Contextual-LSTM.
pub const LSTM_TABLE1: [(f64, f64); 3] = [(38.8, 7.6), (26.3, 6.9), (23.8, 6.7)];
/// Final-frame-only context at N = 1600: overall success in %.
pub const FINAL_FRAME_PLACED: (f64, f64) = (61.0, 9.7);

/// The paper's (reach, pick, place) for a row, when the paper reports that configuration.
pub fn paper_stages(row: &ResultRow) -> Option<[Option<(f64, f64)>; 3]> {
    if row.policy != "model" || row.size != Some(1600) {
        return None;
    }
    match (row.architecture.as_deref(), row.variant.as_deref(), row.context.as_deref()) {
        (Some("contextual_lstm"), _, _) => Some(LSTM_TABLE1.map(Some)),
        (Some("transformer"), Some("full"), Some("spread")) => Some(OURS_TABLE1.map(Some)),
        (Some("transformer"), _, Some("final")) => Some([None, None, Some(FINAL_FRAME_PLACED)]),
        _ => None,
    }
}

/// The paper's placed % for a row, if reported.
pub fn paper_placed(row: &ResultRow) -> Option<f64> {
    paper_stages(row).and_then(|s| s[2]).map(|(v, _)| v)
}
