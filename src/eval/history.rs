//! The agent's recent frames that the network sees during a rollout (its agent window).
//!
//! Behaviour cloning trains the actions at window positions 0..agent_frames-2 only (the last frame of a training
//! window has no action), so the window must never grow past `agent_frames - 1` frames. The authors' test script
//! clears the history once it holds 5 frames: the network is queried with 1 to 5 frames.
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

/// How the window is kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum HistoryMode {
    /// Cleared once it holds `history_frames` frames (the authors').
    #[default]
    Reset,
    /// The latest `history_frames` frames.
    Sliding,
}

/// The frames of one episode's window, oldest first.
#[derive(Debug, Clone)]
pub struct AgentHistory<T> {
    mode: HistoryMode,
    capacity: usize,
    frames: VecDeque<T>,
}

impl<T> AgentHistory<T> {
    /// An empty window holding at most `capacity` frames.
    pub fn new(mode: HistoryMode, capacity: usize) -> AgentHistory<T> {
        AgentHistory { mode, capacity: capacity.max(1), frames: VecDeque::with_capacity(capacity) }
    }

    /// Adds the newest frame, first making room as the mode says.
    pub fn push(&mut self, frame: T) {
        if self.frames.len() >= self.capacity {
            match self.mode {
                HistoryMode::Reset => self.frames.clear(),
                HistoryMode::Sliding => {
                    self.frames.pop_front();
                }
            }
        }
        self.frames.push_back(frame);
    }

    /// Frames in the window, oldest first.
    pub fn frames(&self) -> impl Iterator<Item = &T> {
        self.frames.iter()
    }

    /// Frames in the window; the network's action is read at position `len() - 1`.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether no frame has been pushed.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reset_mode_cycles_through_one_to_capacity_frames() {
        let mut h = AgentHistory::new(HistoryMode::Reset, 5);
        let lens: Vec<usize> = (0..12)
            .map(|t| {
                h.push(t);
                h.len()
            })
            .collect();
        assert_eq!(lens, [1, 2, 3, 4, 5, 1, 2, 3, 4, 5, 1, 2]);
        assert_eq!(h.frames().copied().collect::<Vec<_>>(), [10, 11]);
    }

    #[test]
    fn sliding_mode_keeps_the_latest_frames() {
        let mut h = AgentHistory::new(HistoryMode::Sliding, 3);
        for t in 0..7 {
            h.push(t);
            assert!(h.len() <= 3);
        }
        assert_eq!(h.frames().copied().collect::<Vec<_>>(), [4, 5, 6]);
    }
}
