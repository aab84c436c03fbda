//! The paper's published numbers (Table 1 and section 5.3), matched to our rows where the configuration is the same.
use super::data::ResultRow;

/// Table 1, "ours": (reach, pick, place) in % with the paper's +- half-widths, at N = 1600 with the full model.
pub const OURS_TABLE1: [(f64, f64); 3] = [(99.4, 1.2), (92.5, 4.1), (88.8, 5.0)];
/// Table 1, Contextual-LSTM.
pub const LSTM_TABLE1: [(f64, f64); 3] = [(38.8, 7.6), (26.3, 6.9), (23.8, 6.7)];
/// Table 1, DAML.
pub const DAML_TABLE1: [(f64, f64); 3] = [(36.9, 7.6), (10.6, 4.8), (6.9, 4.0)];
/// Table 1, DAML-Auxiliary.
pub const DAML_AUXILIARY_TABLE1: [(f64, f64); 3] = [(47.8, 7.4), (17.8, 5.6), (13.3, 5.0)];
/// Final-frame-only context at N = 1600: overall success in %.
pub const FINAL_FRAME_PLACED: (f64, f64) = (61.0, 9.7);

/// The paper's (reach, pick, place) for a row, when the paper reports that configuration.
pub fn paper_stages(row: &ResultRow) -> Option<[Option<(f64, f64)>; 3]> {
    if row.policy != "model" || row.size != Some(1600) {
        return None;
    }
    // The paper does not say which of DAML's two trunks its rows used: both are compared with them.
    if matches!(row.architecture.as_deref(), Some("daml" | "daml_resnet")) {
        let scripted = row.control.as_deref() == Some("scripted_poses");
        return Some(if scripted { DAML_AUXILIARY_TABLE1 } else { DAML_TABLE1 }.map(Some));
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

#[cfg(test)]
mod tests {
    use super::*;

    fn row(architecture: &str, control: Option<&str>, size: usize) -> ResultRow {
        ResultRow { control: control.map(String::from), ..ResultRow::model_for_test("x", size, architecture, "spread") }
    }

    #[test]
    fn each_table_1_row_is_matched_by_architecture_and_control() {
        assert_eq!(paper_placed(&row("daml", None, 1600)), Some(6.9));
        assert_eq!(paper_placed(&row("daml", Some("scripted_poses"), 1600)), Some(13.3));
        assert_eq!(paper_placed(&row("contextual_lstm", None, 1600)), Some(23.8));
        assert_eq!(paper_placed(&row("daml_resnet", None, 1600)), Some(6.9));
        assert_eq!(paper_placed(&row("daml", None, 160)), None, "the paper reports N = 1600 only");
    }
}
