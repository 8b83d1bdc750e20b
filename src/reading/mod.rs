//! Reading a request without a model: what the operator asks for and in which language,
//! which tools it points at, which names it may mean, and how a tool's result is said in
//! one line. The agent reads a request here before the model sees it (to offer tools,
//! split a request into parts, hold names to real ones, weigh the first tool choice) and
//! after (to ground an answer in the results). Its knowledge comes from the tools (their
//! specs and examples), the robot's names, and word data per language (`data/`), never
//! from an evaluation suite's requests.
//!
//! Layout:
//! - `concepts`: what a request asks for, forbids or asks about (acts, negation, mood),
//!   in six languages
//! - `language`: the language a request is written in and an answer is written in
//! - `intent`: whether a request asks for an actuating call, and the names it targets
//! - `plan`: a request of several parts, split into the steps it asks for
//! - `meaning`: how near a request is to each tool's examples, by the sentence encoder
//! - `meant`: the robot's names a request asks to act on, by the sentence encoder
//! - `select`: which tools a request is offered, and the prior of its first tool choice
//! - `bound`: name arguments held to the names the robot has and the operator wrote
//! - `amount`: number arguments held to the request's amounts, in the argument's unit
//! - `arithmetic`: an expression said in words ("12 times 7"), for a computing tool
//! - `facts`: a result in one line, and whether an answer states it
//! - `small_talk`: the reply to a request no tool was called for

pub mod amount;
pub(crate) mod arithmetic;
pub mod bound;
pub mod concepts;
pub mod facts;
pub mod intent;
pub mod language;
pub mod meaning;
pub(crate) mod meant;
pub mod plan;
pub mod select;
pub mod small_talk;
