//! Conversation history: completed exchanges (query and answer), trimmed oldest first, a
//! whole pair at a time, to fit the token budget; and the truncation of long tool outputs
//! with a note saying how to get the rest.
//!
//! Trimming forgets for good and goes down to half the budget at once: dropping one old
//! exchange per turn would change the prompt right after the system prompt every turn,
//! and the model would evaluate the whole history again each time; trimming in chunks
//! keeps the cached prefix valid for many turns. History stays bounded however long the
//! chat runs.

use crate::chat::{ChatMessage, Role};

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Exchange {
    pub query: String,
    pub answer: String,
}

#[derive(Debug, Clone, Default)]
pub(crate) struct History {
    exchanges: Vec<Exchange>,
}

impl History {
    pub fn push(&mut self, query: impl Into<String>, answer: impl Into<String>) {
        self.exchanges.push(Exchange {
            query: query.into(),
            answer: answer.into(),
        });
    }

    /// The operator's past queries, oldest first.
    pub fn queries(&self) -> Vec<&str> {
        self.exchanges.iter().map(|e| e.query.as_str()).collect()
    }

    pub fn clear(&mut self) {
        self.exchanges.clear();
    }

    pub fn len(&self) -> usize {
        self.exchanges.len()
    }

    #[cfg(test)]
    pub fn is_empty(&self) -> bool {
        self.exchanges.is_empty()
    }

    /// Forget the oldest exchanges when all of them cost more than `budget` tokens (by
    /// `cost`): down to half the budget, so the next trims are many turns away. Returns
    /// how many were forgotten.
    pub fn trim(&mut self, budget: usize, cost: impl Fn(&str) -> usize) -> usize {
        let costs: Vec<usize> = self
            .exchanges
            .iter()
            .map(|e| cost(&e.query) + cost(&e.answer) + 10)
            .collect();
        let mut total: usize = costs.iter().sum();
        if total <= budget {
            return 0;
        }
        let mut dropped = 0;
        while dropped < costs.len() && total > budget / 2 {
            total -= costs[dropped];
            dropped += 1;
        }
        self.exchanges.drain(..dropped);
        dropped
    }

    /// The remembered exchanges as user/assistant pairs, oldest first.
    pub fn messages(&self) -> Vec<ChatMessage> {
        self.exchanges
            .iter()
            .flat_map(|e| {
                [
                    ChatMessage::new(Role::User, e.query.clone()),
                    ChatMessage::new(Role::Assistant, e.answer.clone()),
                ]
            })
            .collect()
    }
}

/// `text` cut to `limit` characters (at a char boundary) with a note if anything was cut.
pub(crate) fn truncate_output(text: &str, limit: usize) -> String {
    let total = text.chars().count();
    if total <= limit {
        return text.to_string();
    }
    let cut: String = text.chars().take(limit).collect();
    format!(
        "{cut} … [output truncated: showing {limit} of {total} characters; call the tool again with a narrower filter (pattern, count, lines) to see the rest]"
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trimming_forgets_oldest_whole_pairs_down_to_half_the_budget() {
        let mut m = History::default();
        for i in 0..5 {
            m.push(format!("q{i}"), format!("a{i}"));
        }
        // Each exchange costs 2 + 2 + 10 = 14 with this cost function: 70 in all.
        assert_eq!(m.trim(70, |s| s.len()), 0, "everything fits");
        assert_eq!(m.len(), 5);
        // Over 60: down to 30 or less, so three go and two (28) stay.
        assert_eq!(m.trim(60, |s| s.len()), 3);
        let msgs = m.messages();
        assert_eq!(msgs.len(), 4);
        assert_eq!(msgs[0].content, "q3");
        assert_eq!(msgs[3].content, "a4");
        // Room for the next two exchanges before anything is trimmed again.
        m.push("q5", "a5");
        m.push("q6", "a6");
        assert_eq!(m.trim(60, |s| s.len()), 0);
        assert_eq!(m.trim(0, |s| s.len()), 4);
        assert!(m.is_empty());
    }

    #[test]
    fn long_outputs_are_cut_with_a_note() {
        let out = truncate_output(&"é".repeat(50), 10);
        assert!(out.starts_with(&"é".repeat(10)));
        assert!(out.contains("showing 10 of 50"));
        assert_eq!(truncate_output("short", 10), "short");
    }
}
