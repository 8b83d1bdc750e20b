//! Property tests of every parser that reads what a peer, a file or another process
//! sends (issue 41): generated input, arbitrary and adversarial (counts and lengths that
//! claim much, deep nesting, long runs), asserting no panic, no abort (each test runs in
//! a child process, `super::in_child`), a clear error, and bounded memory: the largest
//! single allocation a parse asks for stays within a small multiple of its input
//! (`crate::alloc::largest_allocation`), never a size taken on the input's word.

use ferrosa::backend::TokenId;
use proptest::prelude::*;
use serde_json::json;

use super::{cache_prompt, cases, gguf_string, in_child, start_with_cache};
use crate::alloc::largest_allocation;

/// Expressions: short arbitrary text over the evaluator's alphabet, any text, and long
/// runs of what recurses (parentheses, unary signs, powers, calls).
fn expression() -> impl Strategy<Value = String> {
    prop_oneof![
        "[0-9a-z.,()+*/%^×÷ -]{0,80}",
        any::<String>(),
        (1usize..200_000, "[-+]").prop_map(|(n, op)| format!("{}1", op.repeat(n))),
        (1usize..100_000).prop_map(|n| format!("{}1{}", "(".repeat(n), ")".repeat(n))),
        (1usize..100_000).prop_map(|n| format!("{}1", "(".repeat(n))),
        (1usize..100_000).prop_map(|n| format!("{}2", "2^".repeat(n))),
        (1usize..100_000).prop_map(|n| format!("{}2", "-2^".repeat(n))),
        (1usize..50_000).prop_map(|n| format!("max(1{})", ",1".repeat(n))),
        (1usize..50_000).prop_map(|n| format!("{}4{}", "sqrt(".repeat(n), ")".repeat(n))),
    ]
}

#[test]
fn property_calc_eval_never_panics_and_errors_say_why() {
    if in_child("parsers::property::property_calc_eval_never_panics_and_errors_say_why") {
        return;
    }
    proptest!(cases(300), |(e in expression())| {
        let (r, largest) = largest_allocation(|| ferrosa::tools::expr::eval(&e));
        match r.map_err(|e| e.to_string()) {
            Ok(v) => prop_assert!(v.is_finite()),
            Err(why) => prop_assert!(!why.is_empty()),
        }
        prop_assert!(largest <= 128 * e.len() + (64 << 10), "{} bytes at once for {} of text", largest, e.len());
    });
}

/// An entry file as an attacker may write it: each header field true or crafted.
#[derive(Debug, Clone)]
struct CraftedEntry {
    /// The header's length field, when not the real one.
    header_len: Option<u32>,
    key_ours: bool,
    /// The stable prefix's tokens, or others.
    tokens_ours: bool,
    tokens: Vec<TokenId>,
    payload_len: Option<u64>,
    sha_right: bool,
    payload: Vec<u8>,
    /// Cut the file to this fraction (in thousandths), when not whole.
    cut: Option<u16>,
    /// Raw bytes after the magic instead of a header.
    raw: Option<Vec<u8>>,
}

fn crafted_entry() -> impl Strategy<Value = CraftedEntry> {
    let len = prop_oneof![
        Just(None),
        any::<u64>().prop_map(Some),
        (0u64..4000).prop_map(Some),
        Just(Some(1u64 << 50)),
        Just(Some(u64::MAX))
    ];
    (
        prop::option::of(any::<u32>()),
        any::<bool>(),
        any::<bool>(),
        prop::collection::vec(0u32..300, 0..300),
        len,
        any::<bool>(),
        prop::collection::vec(any::<u8>(), 0..1200),
        prop::option::weighted(0.2, 0u16..1000),
        prop::option::weighted(0.1, prop::collection::vec(any::<u8>(), 0..64)),
    )
        .prop_map(
            |(
                header_len,
                key_ours,
                tokens_ours,
                tokens,
                payload_len,
                sha_right,
                payload,
                cut,
                raw,
            )| {
                CraftedEntry {
                    header_len,
                    key_ours,
                    tokens_ours,
                    tokens,
                    payload_len,
                    sha_right,
                    payload,
                    cut,
                    raw,
                }
            },
        )
}

impl CraftedEntry {
    fn bytes(&self) -> Vec<u8> {
        use sha2::Digest;
        let (prompt, stable) = cache_prompt();
        let mut out = b"FRSKV01\n".to_vec();
        if let Some(raw) = &self.raw {
            out.extend_from_slice(raw);
            return out;
        }
        // What a real entry of the stable prefix would hold (`Kv::snapshot`).
        let tokens: Vec<TokenId> = if self.tokens_ours {
            prompt[..stable].to_vec()
        } else {
            self.tokens.clone()
        };
        let payload: Vec<u8> = if self.tokens_ours && self.payload.len() % 2 == 0 {
            tokens.iter().flat_map(|t| t.to_le_bytes()).collect()
        } else {
            self.payload.clone()
        };
        let sha: String = if self.sha_right {
            sha2::Sha256::digest(&payload)
                .iter()
                .map(|b| format!("{b:02x}"))
                .collect()
        } else {
            "00".repeat(32)
        };
        let key = if self.key_ours {
            "model sha256 model-sha; kv runtime 1"
        } else {
            "model sha256 other; kv runtime 1"
        };
        let header = json!({
            "key": key,
            "tokens": tokens,
            "payload_len": self.payload_len.unwrap_or(payload.len() as u64),
            "payload_sha256": sha,
        });
        let h = serde_json::to_vec(&header).unwrap();
        out.extend_from_slice(&self.header_len.unwrap_or(h.len() as u32).to_le_bytes());
        out.extend_from_slice(&h);
        out.extend_from_slice(&payload);
        if let Some(cut) = self.cut {
            out.truncate(out.len() * usize::from(cut) / 1000);
        }
        out
    }
}

#[test]
fn property_prompt_cache_files_are_a_hit_or_a_miss_never_a_crash() {
    if in_child("parsers::property::property_prompt_cache_files_are_a_hit_or_a_miss_never_a_crash")
    {
        return;
    }
    proptest!(cases(200), |(entry in crafted_entry())| {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("crafted.kv");
        let bytes = entry.bytes();
        std::fs::write(&path, &bytes).unwrap();
        let (_, stable) = cache_prompt();
        let (restored, largest) = largest_allocation(|| start_with_cache(dir.path()));
        prop_assert!(restored == 0 || restored == stable, "restored {}", restored);
        prop_assert!(largest <= 4 * bytes.len() + (1 << 20), "{} bytes at once for a file of {}", largest, bytes.len());
        // Whatever it was, the start after it restores the prefix.
        prop_assert_eq!(start_with_cache(dir.path()), stable);
    });
}

/// WAV bytes: a RIFF header with each `fmt ` field arbitrary (common values likelier),
/// chunk sizes arbitrary, and arbitrary data; or arbitrary bytes.
fn crafted_wav() -> impl Strategy<Value = Vec<u8>> {
    let format = prop_oneof![Just(1u16), Just(3), Just(0xFFFE), any::<u16>()];
    let channels = prop_oneof![Just(0u16), Just(1), Just(2), any::<u16>()];
    let rate = prop_oneof![
        Just(0u32),
        Just(1),
        Just(16000),
        Just(u32::MAX),
        any::<u32>()
    ];
    let bits = prop_oneof![
        Just(0u16),
        Just(8),
        Just(16),
        Just(24),
        Just(32),
        Just(64),
        any::<u16>()
    ];
    let size = prop_oneof![Just(None), any::<u32>().prop_map(Some)];
    let crafted = (
        format,
        channels,
        rate,
        bits,
        size.clone(),
        size,
        prop::collection::vec(any::<u8>(), 0..2048),
    )
        .prop_map(
            |(format, channels, rate, bits, fmt_size, data_size, data)| {
                let mut b = b"RIFF\0\0\0\0WAVEfmt ".to_vec();
                b.extend_from_slice(&fmt_size.unwrap_or(16).to_le_bytes());
                b.extend_from_slice(&format.to_le_bytes());
                b.extend_from_slice(&channels.to_le_bytes());
                b.extend_from_slice(&rate.to_le_bytes());
                b.extend_from_slice(&rate.wrapping_mul(u32::from(channels)).to_le_bytes());
                b.extend_from_slice(&channels.wrapping_mul(bits / 8).to_le_bytes());
                b.extend_from_slice(&bits.to_le_bytes());
                b.extend_from_slice(b"data");
                b.extend_from_slice(&data_size.unwrap_or(data.len() as u32).to_le_bytes());
                b.extend_from_slice(&data);
                b
            },
        );
    prop_oneof![
        4 => crafted,
        1 => prop::collection::vec(any::<u8>(), 0..256),
        1 => prop::collection::vec(any::<u8>(), 0..256).prop_map(|mut b| {
            let mut h = b"RIFF\0\0\0\0WAVE".to_vec();
            h.append(&mut b);
            h
        }),
    ]
}

#[test]
fn property_wav_reading_and_resampling_never_panic() {
    if in_child("parsers::property::property_wav_reading_and_resampling_never_panic") {
        return;
    }
    use ferrosa::speech::wav;
    proptest!(cases(2000), |(bytes in crafted_wav())| {
        let (read, largest) = largest_allocation(|| {
            // What the recogniser does with a recording first.
            wav::read(&bytes).map(|audio| {
                let pcm = wav::resample(&audio, 16000);
                (audio, pcm)
            })
        });
        match read {
            Ok((audio, pcm)) => {
                prop_assert!(wav::RATES.contains(&audio.rate));
                prop_assert!(!audio.samples.is_empty());
                prop_assert!(audio.samples.len() <= bytes.len());
                prop_assert!(audio.samples.iter().all(|s| (-1.0..=1.0).contains(s)), "samples in [-1, 1]");
                let most = (audio.samples.len() as f64 * 16000.0 / f64::from(audio.rate)).ceil();
                prop_assert!(pcm.samples.len() as f64 <= most + 1.0);
            }
            Err(e) => prop_assert!(!e.to_string().is_empty()),
        }
        prop_assert!(largest <= 128 * bytes.len() + (64 << 10), "{} bytes at once for {} bytes of WAV", largest, bytes.len());
    });
}

/// A metadata value of type `ty`, with lengths arbitrary (small ones likelier) and
/// content shorter than claimed or not.
fn gguf_value() -> impl Strategy<Value = Vec<u8>> {
    let len = prop_oneof![0u64..16, any::<u64>(), Just(16u64 << 20), Just(64u64 << 20)];
    (
        0u32..14,
        len,
        prop::collection::vec(any::<u8>(), 0..64),
        0u32..14,
    )
        .prop_map(|(ty, len, content, item_ty)| {
            let mut b = ty.to_le_bytes().to_vec();
            match ty {
                8 => b.extend_from_slice(&len.to_le_bytes()),
                9 => {
                    b.extend_from_slice(&item_ty.to_le_bytes());
                    b.extend_from_slice(&len.to_le_bytes());
                }
                _ => {}
            }
            b.extend_from_slice(&content);
            b
        })
}

fn crafted_gguf() -> impl Strategy<Value = Vec<u8>> {
    let count = prop_oneof![0u64..4, any::<u64>(), Just(1u64 << 20)];
    let tensor = (
        prop::collection::vec(any::<u8>(), 0..8),
        prop_oneof![0u32..5, any::<u32>()],
        prop::collection::vec(prop_oneof![0u64..64, any::<u64>()], 0..5),
        prop_oneof![0u32..40, any::<u32>()],
        prop_oneof![0u64..64, any::<u64>()],
    )
        .prop_map(|(name, n_dims, dims, ty, offset)| {
            let mut b = (name.len() as u64).to_le_bytes().to_vec();
            b.extend_from_slice(&name);
            b.extend_from_slice(&n_dims.to_le_bytes());
            for d in dims {
                b.extend_from_slice(&d.to_le_bytes());
            }
            b.extend_from_slice(&ty.to_le_bytes());
            b.extend_from_slice(&offset.to_le_bytes());
            b
        });
    let crafted = (
        prop_oneof![Just(3u32), Just(2), any::<u32>()],
        count.clone(),
        count,
        prop::collection::vec(("[a-z.]{0,12}", gguf_value()), 0..4),
        prop::collection::vec(tensor, 0..3),
        prop::collection::vec(any::<u8>(), 0..128),
    )
        .prop_map(|(version, n_tensors, n_kv, kv, tensors, tail)| {
            let mut b = b"GGUF".to_vec();
            b.extend_from_slice(&version.to_le_bytes());
            b.extend_from_slice(&n_tensors.to_le_bytes());
            b.extend_from_slice(&n_kv.to_le_bytes());
            for (key, value) in kv {
                gguf_string(&mut b, &key);
                b.extend_from_slice(&value);
            }
            for t in tensors {
                b.extend_from_slice(&t);
            }
            b.extend_from_slice(&tail);
            b
        });
    prop_oneof![
        4 => crafted,
        1 => prop::collection::vec(any::<u8>(), 0..256),
    ]
}

#[test]
fn property_gguf_headers_never_panic_or_allocate_past_the_file() {
    if in_child("parsers::property::property_gguf_headers_never_panic_or_allocate_past_the_file") {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("crafted.gguf");
    proptest!(cases(1000), |(bytes in crafted_gguf())| {
        std::fs::write(&path, &bytes).unwrap();
        let (opened, largest) = largest_allocation(|| ferrosa::backend::Gguf::open(&path));
        // The reader's buffer, and a small multiple of the file (metadata values).
        prop_assert!(largest <= 64 * bytes.len() + (128 << 10), "{} bytes at once for a file of {}", largest, bytes.len());
        match opened {
            Ok(g) => {
                let _ = (g.n_params(), g.vocab_size(), g.kv_cache_bytes(4096));
                for t in &g.tensors {
                    let _ = t.byte_len();
                }
            }
            Err(e) => prop_assert!(!e.to_string().is_empty()),
        }
    });
}

/// Types whose payloads the property test decodes: strings, sequences, nesting.
const CDR_TYPES: [&str; 6] = [
    "std_msgs/msg/String",
    "std_msgs/msg/Int32MultiArray",
    "diagnostic_msgs/msg/DiagnosticArray",
    "geometry_msgs/msg/Twist",
    "sensor_msgs/msg/JointState",
    "std_srvs/srv/Empty_Request",
];

fn crafted_cdr() -> impl Strategy<Value = Vec<u8>> {
    // Counts and lengths that claim much (u32 little-endian), among arbitrary bytes.
    let word = prop_oneof![
        prop::collection::vec(any::<u8>(), 0..8),
        any::<u32>().prop_map(|n| n.to_le_bytes().to_vec()),
        Just(u32::MAX.to_le_bytes().to_vec()),
        (0u32..8).prop_map(|n| n.to_le_bytes().to_vec()),
    ];
    prop::collection::vec(word, 0..40).prop_map(|words| words.concat())
}

#[test]
fn property_cdr_payloads_never_panic() {
    if in_child("parsers::property::property_cdr_payloads_never_panic") {
        return;
    }
    use ferrosa::ros::cdr;
    let ifaces = ferrosa::ros::msg::Interfaces::bundled();
    proptest!(cases(2000), |(bytes in crafted_cdr(), ty in 0usize..CDR_TYPES.len(), origin in 0usize..8)| {
        let ty = CDR_TYPES[ty];
        let (decoded, largest) = largest_allocation(|| {
            [
                cdr::decode(&ifaces, ty, &bytes, origin),
                cdr::decode_ros1(&ifaces, ty, &bytes),
            ]
        });
        prop_assert!(largest <= 256 * bytes.len() + (64 << 10), "{} bytes at once for {} of payload", largest, bytes.len());
        // Nothing decoded from thin air: the JSON is within a small multiple of the
        // payload (every value took at least a byte, or is one of few).
        for v in decoded.into_iter().flatten() {
            prop_assert!(v.to_string().len() <= 64 * bytes.len() + 4096);
        }
    });
}

/// Text a model or a server writes: JSON-ish fragments, arbitrary bytes, deep nesting.
fn json_text() -> impl Strategy<Value = Vec<u8>> {
    let piece = prop_oneof![
        Just(b"{\"name\": \"f\", \"arguments\": {".to_vec()),
        Just(b"[".to_vec()),
        Just(b"]".to_vec()),
        Just(b"{".to_vec()),
        Just(b"}".to_vec()),
        Just(b"\"".to_vec()),
        Just(b"\\".to_vec()),
        Just(b", ".to_vec()),
        Just(b": ".to_vec()),
        Just(b"\"xs\": [".to_vec()),
        "[0-9.e-]{1,4}".prop_map(String::into_bytes),
        "[a-z ]{1,4}".prop_map(String::into_bytes),
        prop::collection::vec(any::<u8>(), 1..4),
    ];
    prop_oneof![
        3 => prop::collection::vec(piece, 0..200).prop_map(|p| p.concat()),
        1 => (1usize..100_000).prop_map(|n| b"[".repeat(n)),
        1 => (1usize..20_000).prop_map(|n| {
            let mut b = b"{\"name\": \"f\", \"arguments\": {\"xs\": ".to_vec();
            b.extend(b"[\"a\", ".repeat(n));
            b
        }),
    ]
}

#[test]
fn property_the_json_reader_never_panics_and_agrees_with_itself() {
    if in_child("parsers::property::property_the_json_reader_never_panics_and_agrees_with_itself") {
        return;
    }
    use ferrosa::json::{JsonScan, Openness};
    proptest!(cases(300), |(text in json_text(), cut in any::<prop::sample::Index>())| {
        let mut scan = JsonScan::new();
        let ((), largest) = largest_allocation(|| {
            for piece in text.chunks(7) {
                scan.push(piece);
                let _ = (scan.context(), scan.looping(), scan.call_start());
            }
        });
        // The text itself (grown by doubling) and a bounded stack of brackets.
        prop_assert!(largest <= 8 * text.len() + (64 << 10), "{} bytes at once for {} of text", largest, text.len());
        prop_assert_eq!(scan.open_count(), Openness::of(&scan).count());
        let _ = scan.closed_calls().count();
        let at = cut.index(text.len() + 1);
        scan.truncate(at);
        let fresh = JsonScan::over(&text[..at]);
        prop_assert_eq!(scan.open_count(), fresh.open_count());
        prop_assert_eq!(scan.depth(), fresh.depth());
    });
}

/// A model server's stream: well-formed events, comments, `error:` lines, and lines and
/// events that go on (long `data:` lines, many of them without a blank line), cut into
/// arbitrary pieces.
fn sse_body() -> impl Strategy<Value = (Vec<u8>, Vec<usize>)> {
    let line = prop_oneof![
        4 => "[ -~]{0,40}".prop_map(|t| format!("data: {t}\n").into_bytes()),
        2 => Just(b"\n".to_vec()),
        1 => Just(b"\r\n".to_vec()),
        1 => Just(b": keep-alive\n".to_vec()),
        1 => "[ -~]{0,20}".prop_map(|t| format!("error: {t}\n").into_bytes()),
        1 => prop::collection::vec(any::<u8>(), 0..40),
        1 => (1usize..3 << 20).prop_map(|n| {
            let mut l = b"data: ".to_vec();
            l.resize(n, b'x');
            l.push(b'\n');
            l
        }),
        1 => (1usize..60_000).prop_map(|n| b"data: 0123456789012345678901234567890123456789\n".repeat(n)),
    ];
    (
        prop::collection::vec(line, 0..30).prop_map(|l| l.concat()),
        prop::collection::vec(1usize..100_000, 1..8),
    )
}

#[test]
fn property_event_streams_are_cut_into_bounded_events() {
    if in_child("parsers::property::property_event_streams_are_cut_into_bounded_events") {
        return;
    }
    use ferrosa::remote::client::{Events, MAX_EVENT, MAX_LINE};
    proptest!(cases(64), |((body, cuts) in sse_body())| {
        let mut events = Events::default();
        let mut pieces = Vec::new();
        let mut at = 0;
        for cut in cuts.iter().cycle() {
            if at >= body.len() {
                break;
            }
            let end = (at + cut).min(body.len());
            pieces.push(&body[at..end]);
            at = end;
        }
        let (got, largest) = largest_allocation(|| {
            let mut got = Vec::new();
            for piece in &pieces {
                got.extend(events.push(piece)?);
            }
            got.extend(events.finish()?);
            Ok::<_, ferrosa::remote::client::StreamLimit>(got)
        });
        if let Ok(got) = got {
            prop_assert!(got.iter().all(|e| e.len() <= MAX_EVENT));
        }
        // A line and an event at most (each grown by doubling, a line read lossily as
        // text), whatever the stream.
        let most = 3 * MAX_LINE + 2 * MAX_EVENT + 2 * cuts.iter().max().copied().unwrap_or(0);
        prop_assert!(largest <= most, "{} bytes at once", largest);
    });
}
