//! Conversation memory: completed exchanges (query and answer), trimmed oldest first, a
//! whole pair at a time, to fit the token budget; and the truncation of long tool outputs
//! with a note saying how to get the rest.

use crate::backend::{ChatMessage, Role};

#[derive(Debug, Clone, PartialEq)]
pub struct Exchange {
    pub query: String,
    pub answer: String,
}

#[derive(Debug, Clone, Default)]
pub struct Memory {
    exchanges: Vec<Exchange>,
}

impl Memory {
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

    pub fn is_empty(&self) -> bool {
        self.exchanges.is_empty()
    }

    /// The newest exchanges whose messages fit in `budget` tokens (by `cost`), as
    /// user/assistant pairs, and how many older exchanges were left out.
    pub fn messages_within(
        &self,
        budget: usize,
        cost: impl Fn(&str) -> usize,
    ) -> (Vec<ChatMessage>, usize) {
        let mut used = 0;
        let mut kept = 0;
        for e in self.exchanges.iter().rev() {
            let c = cost(&e.query) + cost(&e.answer) + 10;
            if used + c > budget {
                break;
            }
            used += c;
            kept += 1;
        }
        let dropped = self.exchanges.len() - kept;
        let msgs = self.exchanges[dropped..]
            .iter()
            .flat_map(|e| {
                [
                    ChatMessage::new(Role::User, e.query.clone()),
                    ChatMessage::new(Role::Assistant, e.answer.clone()),
                ]
            })
            .collect();
        (msgs, dropped)
    }
}

/// `text` cut to `limit` characters (at a char boundary) with a note if anything was cut.
pub fn truncate_output(text: &str, limit: usize) -> String {
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
    fn oldest_pairs_go_first_and_pairs_stay_whole() {
        let mut m = Memory::default();
        for i in 0..5 {
            m.push(format!("q{i}"), format!("a{i}"));
        }
        // Each exchange costs 2 + 2 + 10 = 14 with this cost function.
        let (msgs, dropped) = m.messages_within(30, |s| s.len());
        assert_eq!(dropped, 3);
        assert_eq!(msgs.len(), 4);
        assert_eq!(msgs[0].content, "q3");
        assert_eq!(msgs[3].content, "a4");
        let (msgs, dropped) = m.messages_within(0, |s| s.len());
        assert!(msgs.is_empty());
        assert_eq!(dropped, 5);
    }

    #[test]
    fn long_outputs_are_cut_with_a_note() {
        let out = truncate_output(&"é".repeat(50), 10);
        assert!(out.starts_with(&"é".repeat(10)));
        assert!(out.contains("showing 10 of 50"));
        assert_eq!(truncate_output("short", 10), "short");
    }
}
