//! A backend that replays a transcript: each assistant turn it is asked for, it "writes"
//! the next scripted reply, by giving the highest logit to the longest vocabulary token
//! that continues the reply (and end-of-generation when the reply is done). Everything
//! else runs for real: tokenizer, chat template, grammar, fast-forward, the agent loop.
//!
//! It tracks the reply by bytes, not tokens, so whatever tokens the grammar forces, the
//! reply stays on script; a reply the grammar cannot produce shows up as a divergence.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

use ferrosa::backend::bpe::Bpe;
use ferrosa::backend::template::ChatTemplate;
use ferrosa::backend::vocab::{TokenKind, Vocab};
use ferrosa::backend::{Backend, BackendError, Gguf, TokenId, Tokenize};
use ferrosa::chat::{ChatMessage, Role};

use super::synthetic::Synthetic;

pub struct Scripted {
    vocab: Vocab,
    tokenizer: Arc<dyn Tokenize>,
    template: ChatTemplate,
    /// Tokens that open an assistant turn ("<|im_start|>assistant\n" for ChatML).
    opener: Vec<TokenId>,
    replies: VecDeque<String>,
    current: Option<String>,
    /// The current reply has been written to its end.
    finished: bool,
    history: Vec<TokenId>,
    logits: Vec<f32>,
    context: usize,
    /// Where every prompt the model was shown goes, when a test asks to see them.
    probe: Option<Arc<Mutex<Vec<Vec<TokenId>>>>>,
}

impl Scripted {
    /// A scripted model with the vocabulary, tokenizer and template of a GGUF file
    /// (byte-level BPE, e.g. SmolLM2), replying `replies` in order.
    #[allow(dead_code)]
    pub fn from_gguf(g: &Gguf, replies: &[&str]) -> Result<Scripted, BackendError> {
        let fail = |reason: String| BackendError::Load {
            backend: "scripted",
            path: g.path.clone(),
            reason,
        };
        let vocab = Vocab::from_gguf(g).map_err(fail)?;
        let tokenizer = Arc::new(Bpe::from_gguf(g, &vocab).map_err(fail)?);
        let template = ChatTemplate::for_model(g, None)?;
        Scripted::new(vocab, tokenizer, template, replies)
    }

    /// A scripted model over the synthetic vocabulary (no weights needed).
    pub fn synthetic(replies: &[&str]) -> Scripted {
        let s = Synthetic::chatml();
        Scripted::new(s.vocab, s.tokenizer, s.template, replies).expect("ChatML has an opener")
    }

    fn new(
        vocab: Vocab,
        tokenizer: Arc<dyn Tokenize>,
        template: ChatTemplate,
        replies: &[&str],
    ) -> Result<Scripted, BackendError> {
        let user = [ChatMessage::new(Role::User, "x")];
        let with = template.render(&user, None, true)?;
        let without = template.render(&user, None, false)?;
        let opener_text = with.strip_prefix(&without).unwrap_or("").to_string();
        let opener = tokenizer.tokenize(&opener_text, true);
        if opener.is_empty() {
            return Err(BackendError::Eval {
                backend: "scripted",
                reason: "the chat template has no assistant opener".into(),
            });
        }
        Ok(Scripted {
            logits: vec![0.0; vocab.len()],
            vocab,
            tokenizer,
            template,
            opener,
            replies: replies.iter().map(|r| r.to_string()).collect(),
            current: None,
            finished: false,
            history: Vec::new(),
            context: 8192,
            probe: None,
        })
    }

    pub fn with_context(mut self, tokens: usize) -> Scripted {
        self.context = tokens;
        self
    }

    /// Record the token history at the start of every assistant turn into `probe`.
    #[allow(dead_code)]
    pub fn with_probe(mut self, probe: Arc<Mutex<Vec<Vec<TokenId>>>>) -> Scripted {
        self.probe = Some(probe);
        self
    }

    fn last_opener_end(&self) -> Option<usize> {
        let n = self.opener.len();
        (n..=self.history.len())
            .rev()
            .find(|&end| self.history[end - n..end] == self.opener[..])
    }
}

impl Backend for Scripted {
    fn name(&self) -> &'static str {
        "scripted"
    }

    fn vocab(&self) -> &Vocab {
        &self.vocab
    }

    fn chat_template(&self) -> &ChatTemplate {
        &self.template
    }

    fn context_len(&self) -> usize {
        self.context
    }

    fn tokenize(&self, text: &str, special: bool) -> Result<Vec<TokenId>, BackendError> {
        Ok(self.tokenizer.tokenize(text, special))
    }

    fn tokenizer(&self) -> Arc<dyn Tokenize> {
        self.tokenizer.clone()
    }

    fn forward(&mut self, keep: usize, tokens: &[TokenId]) -> Result<&mut [f32], BackendError> {
        let keep = keep.min(self.history.len());
        // Within a turn every forward extends what came before; going back means a new
        // turn whose prompt shares a prefix with the last one.
        let rewound = keep < self.history.len();
        if keep + tokens.len() > self.context {
            return Err(BackendError::ContextFull {
                needed: keep + tokens.len(),
                limit: self.context,
            });
        }
        if let Some(&bad) = tokens.iter().find(|&&t| t as usize >= self.vocab.len()) {
            return Err(BackendError::BadToken(bad));
        }
        self.history.truncate(keep);
        self.history.extend_from_slice(tokens);
        let Some(start) = self.last_opener_end() else {
            // Not in an assistant turn: nothing to say.
            self.logits.fill(0.0);
            return Ok(&mut self.logits);
        };
        // A turn starts when its opener arrives in this batch, or after the last reply
        // was written to its end (a turn whose prompt repeats the last one's reuses the
        // cache past its opener).
        if start > keep || self.current.is_none() || self.finished || rewound {
            self.current = Some(self.replies.pop_front().unwrap_or_default());
            self.finished = false;
            if let Some(p) = &self.probe {
                p.lock().expect("probe lock").push(self.history.clone());
            }
        }
        let reply = self.current.clone().unwrap_or_default();
        let written: Vec<u8> = self.history[start..]
            .iter()
            .filter(|&&t| self.vocab.kind(t) != TokenKind::Control)
            .flat_map(|&t| self.vocab.piece(t).to_vec())
            .collect();
        let rest =
            reply
                .as_bytes()
                .strip_prefix(&written[..])
                .ok_or_else(|| BackendError::Eval {
                    backend: "scripted",
                    reason: format!(
                        "the decoder left the script: wrote {:?}, script is {reply:?}",
                        String::from_utf8_lossy(&written)
                    ),
                })?;
        // Continuations of the script score by length; everything else far below, but
        // finite, so a grammar mask still leaves the best scripted option on top.
        self.logits.fill(-1e6);
        if rest.is_empty() {
            self.finished = true;
            for &e in self.vocab.eog() {
                self.logits[e as usize] = 1e6;
            }
        } else {
            for id in 0..self.vocab.len() as TokenId {
                let p = self.vocab.piece(id);
                if self.vocab.kind(id) != TokenKind::Control && !p.is_empty() && rest.starts_with(p)
                {
                    self.logits[id as usize] = p.len() as f32;
                }
            }
        }
        Ok(&mut self.logits)
    }
}
