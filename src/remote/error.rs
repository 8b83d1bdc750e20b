//! What can go wrong with a model on a server, each case with what to do about it.

use std::time::Duration;

use crate::backend::TokenId;
use crate::decode::DecodeError;

/// Why the remote engine could not give a turn.
#[derive(Debug, thiserror::Error)]
pub enum RemoteError {
    #[error("bad model server address '{url}': {reason}")]
    Url { url: String, reason: String },
    #[error(
        "cannot reach the model server at {url}: {reason} (is it running and listening there?)"
    )]
    Connect { url: String, reason: String },
    #[error("the model server at {url} did not answer within {} s (waiting for {waiting}); if it is only slow, raise --remote-timeout", after.as_secs())]
    Timeout {
        url: String,
        after: Duration,
        waiting: &'static str,
    },
    #[error("the model server refused {path} (HTTP {status}): {message}{}", if matches!(status, 401 | 403) { " (it wants an API key: --api-key-env VAR names the variable that holds it)" } else { "" })]
    Status {
        path: String,
        status: u16,
        message: String,
    },
    #[error("the model server's answer to {path} is not what the API promises: {reason}")]
    BadAnswer { path: String, reason: String },
    #[error("the model server did not hold its turn to the grammar ferrosa sent ({reason}); nothing it wrote was used. Its text: {text}")]
    IgnoredGrammar { reason: String, text: String },
    #[error("the model server runs another model than {local}: it tokenizes {probe:?} as {theirs:?}, {local} as {ours:?}; start it with the same model file, or pass that file with --model")]
    OtherModel {
        local: String,
        probe: String,
        ours: Vec<TokenId>,
        theirs: Vec<TokenId>,
    },
    #[error("the model server does not enforce Lark grammars (llguidance): {message}. Use --grammar json-schema, or auto to let ferrosa choose")]
    NoLark { message: String },
    #[error("{var} is not set; it should hold the model server's API key (--api-key-env {var})")]
    NoKey { var: String },
}

impl From<RemoteError> for DecodeError {
    fn from(e: RemoteError) -> DecodeError {
        DecodeError::Engine(Box::new(e))
    }
}
