//! The llama.cpp runtime on the real weights: generation, KV prefix reuse, batching,
//! tokenization round trips, templates, and the errors a bad input must give.

use ferrosa::backend::{BackendError, BackendKind, Detokenizer};
use ferrosa::chat::{ChatMessage, Role};
use ferrosa::decode::{
    generate, Finish, JsonScan, NoHook, Sampler, SamplerConfig, Session, Steering,
};

use crate::util::{greedy, load};

const SMOL: &str = "smollm2-135m";

fn text_of(model: &dyn ferrosa::backend::Backend, ids: &[u32]) -> String {
    let mut d = Detokenizer::new(false);
    let mut s = String::new();
    for &t in ids {
        d.push(model.vocab(), t, &mut s);
    }
    d.finish(&mut s);
    s
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn smollm2_answers_in_english() {
    let mut m = load(SMOL, BackendKind::Llama, 2048);
    let prompt = m
        .chat_template()
        .render(&[ChatMessage::new(Role::User, "What is ROS?")], None, true)
        .unwrap();
    let ids = greedy(m.as_mut(), &prompt, 48);
    let text = text_of(m.as_ref(), &ids);
    let words: Vec<&str> = text
        .split_whitespace()
        .filter(|w| {
            w.chars()
                .all(|c| c.is_ascii_alphabetic() || ",.'\"()-".contains(c))
        })
        .collect();
    assert!(words.len() >= 20, "not English prose: {text:?}");
    assert!(text.contains("ROS"), "{text:?}");
    assert!(!text.contains('\u{FFFD}'), "{text:?}");
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn kv_prefix_reuse_gives_the_same_logits_as_a_fresh_evaluation() {
    let mut m = load(SMOL, BackendKind::Llama, 1024);
    let prefix = m
        .tokenize("The robot arm moved the red block onto the", false)
        .unwrap();
    let tail_a = m.tokenize(" table and then", false).unwrap();
    let tail_b = m.tokenize(" blue block, so the", false).unwrap();
    let all_a: Vec<u32> = prefix.iter().chain(&tail_a).copied().collect();
    let all_b: Vec<u32> = prefix.iter().chain(&tail_b).copied().collect();
    m.forward(0, &all_a).unwrap();
    // Keep the shared prefix, evaluate only B's tail.
    let reused = m.forward(prefix.len(), &tail_b).unwrap().to_vec();
    let fresh = m.forward(0, &all_b).unwrap().to_vec();
    let diff = reused
        .iter()
        .zip(&fresh)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(diff < 0.05, "max logit difference {diff}");
    assert_eq!(
        ferrosa::decode::sample::argmax(&reused),
        ferrosa::decode::sample::argmax(&fresh)
    );
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn a_second_turn_evaluates_only_its_new_tokens() {
    let mut m = load(SMOL, BackendKind::Llama, 2048);
    let t = m.chat_template();
    let turn1 = vec![ChatMessage::new(Role::User, "Name a colour.")];
    let p1 = m
        .tokenize(&t.render(&turn1, None, true).unwrap(), true)
        .unwrap();
    let mut session = Session::new();
    let mut sampler = Sampler::new(SamplerConfig::default(), m.vocab().len());
    let mut answer = Vec::new();
    generate(
        m.as_mut(),
        &mut session,
        &p1,
        16,
        Steering {
            sampler: &mut sampler,
            constraint: None,
            hook: &mut NoHook,
            scan: &mut JsonScan::new(),
            draft: ferrosa::decode::Draft::OFF,
        },
        |tok, _| {
            answer.push(tok);
            std::ops::ControlFlow::Continue(())
        },
    )
    .unwrap();
    let reply = text_of(m.as_ref(), &answer);
    let turn2 = vec![
        ChatMessage::new(Role::User, "Name a colour."),
        ChatMessage::new(Role::Assistant, reply.trim()),
        ChatMessage::new(Role::User, "Another one?"),
    ];
    let t = m.chat_template();
    let p2 = m
        .tokenize(&t.render(&turn2, None, true).unwrap(), true)
        .unwrap();
    let (_, stats) = generate(
        m.as_mut(),
        &mut session,
        &p2,
        4,
        Steering {
            sampler: &mut sampler,
            constraint: None,
            hook: &mut NoHook,
            scan: &mut JsonScan::new(),
            draft: ferrosa::decode::Draft::OFF,
        },
        |_, _| std::ops::ControlFlow::Continue(()),
    )
    .unwrap();
    assert!(
        stats.reused_tokens >= p1.len(),
        "reused {} of {} (first turn was {})",
        stats.reused_tokens,
        p2.len(),
        p1.len()
    );
}

/// Branches side by side after a shared tail (llama.cpp's sequences sharing their leading
/// tokens, the tail in every one of them and in the main sequence; 18 branches, so two
/// batches) give the tail's last token and each branch's tokens the logits they get
/// evaluated alone after the context (as a prompt's tail is, in one batch), and leave the
/// main sequence holding the context and the tail; on both models (Gemma 3's
/// sliding-window layers too). Equal up to rounding: a row's logits depend on where it
/// falls in the batch (llama.cpp's matrix kernels take rows in tiles), by up to half a
/// logit on SmolLM2 and 2.7 on Gemma 3 (Q4_K_M) here, the likeliest token the same in
/// every row.
#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn branches_side_by_side_score_as_each_alone() {
    let max_diff = |a: &[f32], b: &[f32]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max)
    };
    for (name, bound) in [(SMOL, 1.0), ("gemma3-270m", 4.0)] {
        let mut m = load(name, BackendKind::Llama, 2048);
        let text = "The turtle can list nodes, read topics and move. ".repeat(8);
        let context = m.tokenize(&text, false).unwrap();
        let tail = m
            .tokenize("Which tool lists them? The tool", false)
            .unwrap();
        // More branches than one batch holds side by side (15), so they take two, the
        // tail riding in the first.
        let mut words: Vec<String> = [
            "ros_node_list",
            "ros_node_info",
            "ros_topic_list",
            "turtle_move",
            "reply",
        ]
        .map(String::from)
        .to_vec();
        words.extend((0..13).map(|i| format!("robot_tool_{i}")));
        let branches: Vec<Vec<u32>> = words
            .iter()
            .map(|w| m.tokenize(w, false).unwrap())
            .collect();
        let at = context.len();
        let mut whole = context.clone();
        whole.extend_from_slice(&tail);
        let last = whole.len() - 1;
        // Alone: the tail after the context, then the tail and each leading part of
        // each branch, each as one batch.
        m.forward(0, &context).unwrap();
        let root_alone = m.forward(at, &tail).unwrap().to_vec();
        let mut alone = Vec::new();
        for b in &branches {
            for j in 1..=b.len() {
                let mut input = tail.clone();
                input.extend_from_slice(&b[..j]);
                alone.push(m.forward(at, &input).unwrap().to_vec());
            }
        }
        let before = m.forward(last, &whole[last..]).unwrap().to_vec();
        let refs: Vec<&[u32]> = branches.iter().map(Vec::as_slice).collect();
        let mut together = Vec::new();
        let root = m
            .branches(at, &tail, &refs, &mut |_, _, logits| {
                together.push(logits.to_vec())
            })
            .unwrap();
        let argmax = ferrosa::decode::sample::argmax;
        let diff = max_diff(&root, &root_alone);
        assert!(diff < bound, "{name}: after the tail: {diff}");
        assert_eq!(argmax(&root), argmax(&root_alone), "{name}: after the tail");
        assert_eq!(
            together.len(),
            alone.len(),
            "{name}: a row per branch token"
        );
        for (i, (a, t)) in alone.iter().zip(&together).enumerate() {
            let diff = max_diff(a, t);
            assert!(diff < bound, "{name}: row {i}: max logit difference {diff}");
            assert_eq!(argmax(a), argmax(t), "{name}: row {i}");
        }
        // The main sequence holds the context and the tail: its last token again gives
        // what it gave before, up to the tail's own rounding in the branches' batch.
        let again = m.forward(last, &whole[last..]).unwrap().to_vec();
        let diff = max_diff(&again, &before);
        assert!(
            diff < bound,
            "{name}: the context and tail after the branches: {diff}"
        );
        assert_eq!(
            argmax(&again),
            argmax(&before),
            "{name}: after the branches"
        );
    }
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn small_batches_and_one_big_batch_agree() {
    let text = "Robots in the field run with no network. ".repeat(12);
    let mut big = load(SMOL, BackendKind::Llama, 1024);
    let ids = big.tokenize(&text, false).unwrap();
    let a = big.forward(0, &ids).unwrap().to_vec();
    let path = crate::util::model_path(SMOL);
    let mut opts = ferrosa::backend::LoadOptions::new(path);
    opts.batch = 7;
    opts.max_context = 1024;
    let mut small = ferrosa::backend::load(BackendKind::Llama, &opts).unwrap();
    let b = small.forward(0, &ids).unwrap().to_vec();
    assert_eq!(
        ferrosa::decode::sample::argmax(&a),
        ferrosa::decode::sample::argmax(&b)
    );
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn tokenize_then_detokenize_round_trips_unicode() {
    let m = load(SMOL, BackendKind::Llama, 256);
    for s in [
        "move 2.5 m forward",
        "température: 23 °C — ok",
        "emoji 🤖 and 日本語",
        "  leading and trailing  ",
        "<|im_start|> as plain text",
    ] {
        let ids = m.tokenize(s, false).unwrap();
        assert_eq!(text_of_all(m.as_ref(), &ids), s);
    }
    // With `special`, the marker is one control token.
    let ids = m.tokenize("<|im_start|>user", true).unwrap();
    assert_eq!(m.vocab().piece(ids[0]), b"<|im_start|>");
}

fn text_of_all(model: &dyn ferrosa::backend::Backend, ids: &[u32]) -> String {
    let mut d = Detokenizer::new(true);
    let mut s = String::new();
    for &t in ids {
        d.push(model.vocab(), t, &mut s);
    }
    d.finish(&mut s);
    s
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn smollm2_end_tokens_come_from_the_file() {
    let m = load(SMOL, BackendKind::Llama, 256);
    let im_end = m.vocab().find("<|im_end|>").unwrap();
    assert!(m.vocab().is_eog(im_end));
    assert_eq!(m.vocab().bos(), None, "SmolLM2 adds no BOS");
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn short_answers_stop_at_end_of_turn() {
    let mut m = load(SMOL, BackendKind::Llama, 1024);
    let t = m.chat_template();
    let msgs = vec![ChatMessage::new(
        Role::User,
        "Reply with the single word: yes",
    )];
    let p = m
        .tokenize(&t.render(&msgs, None, true).unwrap(), true)
        .unwrap();
    let mut sampler = Sampler::new(SamplerConfig::default(), m.vocab().len());
    let (finish, _) = generate(
        m.as_mut(),
        &mut Session::new(),
        &p,
        200,
        Steering {
            sampler: &mut sampler,
            constraint: None,
            hook: &mut NoHook,
            scan: &mut JsonScan::new(),
            draft: ferrosa::decode::Draft::OFF,
        },
        |_, _| std::ops::ControlFlow::Continue(()),
    )
    .unwrap();
    assert_eq!(finish, Finish::EndOfGeneration);
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn smollm2_template_golden() {
    let m = load(SMOL, BackendKind::Llama, 256);
    let t = m.chat_template();
    let out = t
        .render(
            &[
                ChatMessage::new(Role::System, "You are a turtle robot."),
                ChatMessage::new(Role::User, "Where are you?"),
                ChatMessage::new(Role::Assistant, "At (5.5, 5.5)."),
                ChatMessage::new(Role::User, "Move."),
            ],
            None,
            true,
        )
        .unwrap();
    assert_eq!(
        out,
        "<|im_start|>system\nYou are a turtle robot.<|im_end|>\n\
         <|im_start|>user\nWhere are you?<|im_end|>\n\
         <|im_start|>assistant\nAt (5.5, 5.5).<|im_end|>\n\
         <|im_start|>user\nMove.<|im_end|>\n\
         <|im_start|>assistant\n"
    );
    // Without a system message the file's template supplies its own.
    let out = t
        .render(&[ChatMessage::new(Role::User, "Hi")], None, false)
        .unwrap();
    assert_eq!(
        out,
        "<|im_start|>system\nYou are a helpful AI assistant named SmolLM, trained by Hugging Face<|im_end|>\n\
         <|im_start|>user\nHi<|im_end|>\n"
    );
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn a_full_context_is_an_error_not_a_crash() {
    let mut m = load(SMOL, BackendKind::Llama, 32);
    let ids = m.tokenize(&"word ".repeat(64), false).unwrap();
    match m.forward(0, &ids) {
        Err(BackendError::ContextFull { limit, .. }) => assert_eq!(limit, 32),
        Err(e) => panic!("wrong error {e}"),
        Ok(_) => panic!("64 tokens fit a 32-token context"),
    }
    // The backend is still usable afterwards.
    m.forward(0, &ids[..8]).unwrap();
    assert!(matches!(
        m.forward(0, &[999_999]),
        Err(BackendError::BadToken(999_999))
    ));
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn gemma3_base_model_continues_text_with_the_fallback_template() {
    let mut m = load("gemma3-270m", BackendKind::Llama, 512);
    assert_eq!(
        m.chat_template().origin(),
        &ferrosa::backend::template::TemplateOrigin::Fallback("gemma3")
    );
    assert!(m.vocab().bos().is_some(), "Gemma adds BOS");
    let ids = greedy(m.as_mut(), "The Eiffel Tower is located in the city of", 8);
    let text = text_of(m.as_ref(), &ids);
    assert!(text.contains("Paris"), "{text:?}");
}

#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn kv_cache_size_follows_the_file_dimensions() {
    // SmolLM2-135M: 30 layers, 3 KV heads of 64 dimensions, f16 K and V. llama.cpp
    // reports the same 180 MiB for an 8192-token context when it creates the cache.
    let path = crate::util::models_dir().join("SmolLM2-135M-Instruct.Q4_1.gguf");
    let g = ferrosa::backend::Gguf::open(&path).unwrap();
    assert_eq!(g.kv_cache_bytes(8192), Some(8192 * 30 * 3 * (64 + 64) * 2));
    assert_eq!(g.kv_cache_bytes(8192).unwrap() / (1 << 20), 180);
}

/// The tool chooser's adapter reads only the chooser's branches: the names'
/// log-probabilities change with it, while the main sequence (the prompt's cache, and
/// so every token a turn writes after its tool's name) stays what the base model gives.
#[test]
#[ignore = "needs the model weights (or a ROS peer): cargo test --release -- --include-ignored"]
fn the_chooser_adapter_reads_the_names_and_leaves_the_cache_alone() {
    let max_diff = |a: &[f32], b: &[f32]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max)
    };
    let resolved = ferrosa::models::resolve(Some(SMOL), &crate::util::models_dir()).unwrap();
    let adapter = ferrosa::models::adapter::resolve(
        "smollm2-135m-tools",
        &resolved.path,
        resolved.entry.as_ref(),
    )
    .unwrap()
    .expect("the built-in adapter is for the default model");
    let mut plain = load(SMOL, BackendKind::Llama, 2048);
    let mut opts = ferrosa::backend::LoadOptions::new(resolved.path.clone());
    opts.max_context = 2048;
    opts.family = Some("smollm2".into());
    opts.adapter = Some(adapter);
    let mut adapted = ferrosa::backend::load(BackendKind::Llama, &opts).unwrap();
    assert!(adapted.has_chooser() && !plain.has_chooser());

    let text = "<|im_start|>user\nhow often does the pose topic publish?<|im_end|>\n<|im_start|>assistant\n<tool_call>[\n{\"name\": \"";
    let context = plain.tokenize(text, true).unwrap();
    let (n, last) = (context.len(), *context.last().unwrap());
    let names: Vec<Vec<u32>> = ["ros_topic_hz\"", "ros_topic_echo\"", "robot_status\""]
        .iter()
        .map(|w| plain.tokenize(w, false).unwrap())
        .collect();
    // The main sequence: the same logits with the adapter loaded as without it.
    let base = plain.forward(0, &context).unwrap().to_vec();
    let before = adapted.forward(0, &context).unwrap().to_vec();
    assert!(
        max_diff(&base, &before) < 1e-3,
        "the adapter read the prompt"
    );

    // The branches: the context's last token read again, then each name, adapter on.
    let rows: Vec<Vec<u32>> = names
        .iter()
        .map(|t| std::iter::once(last).chain(t.iter().copied()).collect())
        .collect();
    let refs: Vec<&[u32]> = rows.iter().map(Vec::as_slice).collect();
    let mut read = Vec::new();
    let took = adapted
        .chooser_branches(n - 1, &refs, &mut |b, j, logits| {
            read.push((b, j, logits.to_vec()))
        })
        .unwrap();
    assert!(took, "the chooser read no branches");
    assert_eq!(
        read.len(),
        rows.iter().map(Vec::len).sum::<usize>(),
        "a row per branch token"
    );
    let first = &read.iter().find(|(_, j, _)| *j == 0).unwrap().2;
    let moved = max_diff(first, &base);
    assert!(moved > 0.5, "the adapter changed nothing: {moved}");

    // Afterwards the cache is the base model's: the next token reads as it does without.
    let next = plain.tokenize("ros", false).unwrap();
    let want = plain.forward(n, &next).unwrap().to_vec();
    let got = adapted.forward(n, &next).unwrap().to_vec();
    let diff = max_diff(&want, &got);
    assert!(diff < 1e-3, "the cache changed under the chooser: {diff}");
}
