//! Prompt-lookup drafting: a guess at the next tokens of a turn, copied from the context.
//!
//! A tool call repeats much of what the model has read (a topic's name from the tool
//! list, a value the operator said, a field of a result), and an answer repeats the
//! results. When the turn's last few tokens occurred earlier in the context, the tokens
//! that followed them there are a likely continuation. The generation loop evaluates the
//! guess in one batch with the tokens it must evaluate anyway, and keeps the guessed
//! tokens only as far as the normal choice (sampler, grammar, hook) picks them, one by
//! one from the batch's logits: the text is the one the undrafted loop writes, the model
//! is asked fewer times. No model of its own, no statistics: the lookup is a scan of the
//! context, allocating nothing.

use crate::backend::TokenId;

/// How far to guess. `max_tokens` 0 turns drafting off.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Draft {
    /// Most tokens guessed at once.
    pub max_tokens: usize,
    /// The longest run of the turn's last tokens looked up; longer runs are tried first.
    pub longest_match: usize,
    /// The shortest run looked up (a single token matches too often to guess from).
    pub shortest_match: usize,
}

impl Draft {
    pub const OFF: Draft = Draft {
        max_tokens: 0,
        longest_match: 0,
        shortest_match: 0,
    };

    /// Guesses of up to `max_tokens` tokens, from runs of 6 down to 3 tokens (runs of 2
    /// matched often by chance: on the agent's tool calls 23% of their guessed tokens
    /// were kept, against 75% with 3).
    pub const fn up_to(max_tokens: usize) -> Draft {
        Draft {
            max_tokens,
            longest_match: 6,
            shortest_match: 3,
        }
    }

    /// The most tokens a guess should hold when drafting is wanted.
    pub const SUGGESTED_TOKENS: usize = 8;

    pub fn is_on(&self) -> bool {
        self.max_tokens > 0 && self.shortest_match > 0
    }

    /// Fill `out` with a guess at what follows `head` then `tail` (the context, in two
    /// parts so the caller need not join them): the tokens that followed the latest
    /// earlier occurrence of the context's last `n` tokens, for the longest `n` that
    /// occurs, at most `limit` (and `max_tokens`) of them. Empty when nothing matches.
    pub fn guess(&self, head: &[TokenId], tail: &[TokenId], limit: usize, out: &mut Vec<TokenId>) {
        out.clear();
        let limit = limit.min(self.max_tokens);
        let ctx = Joined { head, tail };
        let len = ctx.len();
        if !self.is_on() || limit == 0 {
            return;
        }
        for n in (self.shortest_match..=self.longest_match).rev() {
            if n >= len {
                continue;
            }
            let Some(at) = ctx.latest_earlier(n) else {
                continue;
            };
            let end = (at + n + limit).min(len);
            out.extend((at + n..end).map(|i| ctx.at(i)));
            return;
        }
    }
}

/// Off: on the agent's tool calls on 2 cores it measured no faster (the grammar already
/// writes a call's structure and names; a wrong guess costs a batch row, on Gemma 3 its
/// 262k-token output layer). `docs/performance.md` has the figures.
impl Default for Draft {
    fn default() -> Draft {
        Draft::OFF
    }
}

/// Two slices read as one.
struct Joined<'a> {
    head: &'a [TokenId],
    tail: &'a [TokenId],
}

impl Joined<'_> {
    fn len(&self) -> usize {
        self.head.len() + self.tail.len()
    }

    fn at(&self, i: usize) -> TokenId {
        match i.checked_sub(self.head.len()) {
            Some(j) => self.tail[j],
            None => self.head[i],
        }
    }

    /// Where the last `n` tokens last occurred before, ending before the last token (so
    /// at least one token follows the occurrence).
    fn latest_earlier(&self, n: usize) -> Option<usize> {
        let len = self.len();
        let last = self.at(len - 1);
        // Occurrence [at, at + n) with at + n < len.
        (0..len - n).rev().find(|&at| {
            self.at(at + n - 1) == last
                && (0..n - 1).all(|k| self.at(at + k) == self.at(len - n + k))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs of 4 down to 2 tokens, as the tests' small contexts need.
    fn short(max_tokens: usize) -> Draft {
        Draft {
            max_tokens,
            longest_match: 4,
            shortest_match: 2,
        }
    }

    fn guess(draft: Draft, head: &[TokenId], tail: &[TokenId], limit: usize) -> Vec<TokenId> {
        let mut out = Vec::new();
        draft.guess(head, tail, limit, &mut out);
        out
    }

    #[test]
    fn copies_what_followed_the_latest_match() {
        // "5 6" occurs twice before the end; the later occurrence is followed by 9.
        let ctx = [1, 5, 6, 7, 8, 2, 5, 6, 9, 3, 5, 6];
        assert_eq!(guess(short(3), &ctx, &[], 10), vec![9, 3, 5]);
    }

    #[test]
    fn the_longest_run_wins_over_a_later_shorter_one() {
        // "4 5 6" occurs once (followed by 7); "5 6" alone later (followed by 0).
        let ctx = [4, 5, 6, 7, 1, 5, 6, 0, 2, 4, 5, 6];
        assert_eq!(guess(short(2), &ctx, &[], 10), vec![7, 1]);
    }

    #[test]
    fn the_context_may_come_in_two_parts() {
        let head = [1, 2, 3, 4, 9];
        assert_eq!(guess(short(8), &head, &[2, 3], 8), vec![4, 9, 2, 3]);
    }

    #[test]
    fn no_guess_without_a_match_of_two_tokens_or_when_off() {
        assert!(guess(short(4), &[1, 2, 3, 1], &[], 8).is_empty());
        assert!(guess(Draft::OFF, &[1, 2, 1, 2], &[], 8).is_empty());
        assert!(guess(short(4), &[1, 2, 1, 2], &[], 0).is_empty());
        assert!(guess(short(4), &[], &[], 8).is_empty());
    }

    #[test]
    fn a_guess_stops_at_the_limit_and_the_context_end() {
        let ctx = [7, 8, 1, 2, 3, 7, 8];
        assert_eq!(guess(short(8), &ctx, &[], 2), vec![1, 2]);
        // The match right before the end is followed by the end's own tokens.
        assert_eq!(guess(short(8), &ctx, &[], 9), vec![1, 2, 3, 7, 8]);
    }
}
