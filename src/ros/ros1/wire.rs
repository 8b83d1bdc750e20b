//! TCPROS as ROS 1 nodes speak it: connection headers, length-prefixed frames, and the
//! type identity a connection is checked by (the md5sum of a definition, computed as
//! genmsg does) with the full definition text a publisher or subscriber sends with it.
//!
//! Everything here reads what a peer sends, so it is bounded: a connection header at
//! most `MAX_HEADER` bytes and `MAX_HEADER_FIELDS` fields, a frame at most `MAX_FRAME`,
//! each refused on its declared length before anything is allocated, then read as its
//! bytes arrive (a peer's word alone buys at most `FIRST_READ` bytes), all of them within
//! `FRAME_LIMIT`. A definition is learnt (`learn`) only when it hashes to the md5sum sent
//! with it, within `msg`'s bounds, and never in place of a type ferrosa knows (shipped,
//! or learnt before): a peer that disagrees is refused, not obeyed.
//!
//! Message bodies are ROS 1's serialisation of the JSON the tools use (`cdr::Wire::Ros1`,
//! the same definition-driven walk as ROS 2's CDR).

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};

use crate::ros::msg::{
    check_extent, normalize_type, parse_message, recursion, BaseType, Interfaces, MessageDef,
    MsgError, Shape, MAX_DEFINITION_BYTES, MAX_DEPTH, MAX_TYPES,
};

/// Largest message frame read from a peer (a point cloud or a camera image fits).
pub(crate) const MAX_FRAME: usize = 64 << 20;

/// Largest connection header read from a peer (its `message_definition` included).
pub const MAX_HEADER: usize = 1 << 20;

/// Most fields one connection header may carry (ROS sends about eight).
pub const MAX_HEADER_FIELDS: usize = 256;

/// What a frame's declared length alone may make ferrosa allocate; the rest grows as
/// the bytes arrive.
pub const FIRST_READ: usize = 64 << 10;

/// How long a frame's bytes may take to arrive once its length has.
pub(crate) const FRAME_LIMIT: Duration = Duration::from_secs(30);

/// ROS 1's two time types, which its definitions use as primitives.
pub(crate) const TIME_TYPES: [(&str, &str); 2] = [
    ("rostime/msg/Time", "uint32 secs\nuint32 nsecs\n"),
    ("rostime/msg/Duration", "int32 secs\nint32 nsecs\n"),
];

/// ROS 1's `std_msgs/Header` (ROS 2's has no `seq`, and ROS 2's time).
pub(crate) const HEADER: &str = "uint32 seq\ntime stamp\nstring frame_id\n";

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WireError {
    #[error("a {what} of {len} bytes declared, more than {limit}: refused before reading it")]
    TooLong {
        what: &'static str,
        len: usize,
        limit: usize,
    },
    #[error("reading a {what}: {reason}")]
    Io { what: &'static str, reason: String },
    #[error("a {what} of {len} bytes did not all arrive within {limit:?}")]
    Slow {
        what: &'static str,
        len: usize,
        limit: Duration,
    },
    #[error("a malformed connection header: {0}")]
    Header(String),
    #[error("{type_name}: the peer sent md5sum `*` with its definition, so it cannot be checked; a definition is learnt only with the md5sum it hashes to")]
    NoMd5 { type_name: String },
    #[error("{type_name}: the peer's md5sum is {theirs}, ferrosa's {type_name} has {ours}; a peer cannot redefine a type ferrosa knows, so this connection is refused")]
    Mismatch {
        type_name: String,
        theirs: String,
        ours: String,
    },
    #[error("{type_name}: the definition sent hashes to {computed}, not to the md5sum {sent} sent with it; it is not learnt")]
    HashMismatch {
        type_name: String,
        computed: String,
        sent: String,
    },
    #[error("{type_name}: a definition section named {section:?}, not `MSG: pkg/Name`")]
    BadSection { type_name: String, section: String },
    #[error("{type_name}: more than {MAX_TYPES} types in one definition")]
    TooManyTypes { type_name: String },
    #[error(transparent)]
    Definition(#[from] MsgError),
}

/// A table holding only ROS 1's time types, for definitions learnt from peers.
pub fn table() -> Interfaces {
    // The two constants above parse (the unit tests read them).
    Interfaces::of(&TIME_TYPES).expect("the time types parse")
}

/// `pkg/msg/Name` (any spelling) as ROS 1 writes it: `pkg/Name`.
pub(crate) fn ros1_type(type_name: &str) -> String {
    let full = normalize_type(type_name);
    let parts: Vec<&str> = full.split('/').collect();
    match parts.as_slice() {
        [pkg, "msg" | "srv", name] => format!("{pkg}/{name}"),
        _ => full,
    }
}

/// Whether `ty` (normalised) is `pkg/kind/Name` in ROS names' letters.
pub(crate) fn valid_type(ty: &str) -> bool {
    let parts: Vec<&str> = ty.split('/').collect();
    parts.len() == 3
        && parts.iter().all(|p| {
            p.chars().next().is_some_and(|c| c.is_ascii_alphabetic())
                && p.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
        })
}

/// A connection header: `key=value` fields, each length-prefixed, the whole too.
pub fn encode_header(fields: &[(&str, &str)]) -> Vec<u8> {
    let mut body = Vec::new();
    for (k, v) in fields {
        let field = format!("{k}={v}");
        body.extend_from_slice(&(field.len() as u32).to_le_bytes());
        body.extend_from_slice(field.as_bytes());
    }
    let mut out = (body.len() as u32).to_le_bytes().to_vec();
    out.extend(body);
    out
}

/// A connection header's fields (the body after its length): at most
/// `MAX_HEADER_FIELDS`, each within the body.
pub fn decode_header(body: &[u8]) -> Result<BTreeMap<String, String>, WireError> {
    let mut out = BTreeMap::new();
    let mut at = 0;
    let mut count = 0;
    while at < body.len() {
        count += 1;
        if count > MAX_HEADER_FIELDS {
            return Err(WireError::Header(format!(
                "more than {MAX_HEADER_FIELDS} fields"
            )));
        }
        let len_bytes: [u8; 4] = body
            .get(at..at + 4)
            .and_then(|b| b.try_into().ok())
            .ok_or_else(|| WireError::Header("a field without its length".into()))?;
        let n = u32::from_le_bytes(len_bytes) as usize;
        let field = (at + 4)
            .checked_add(n)
            .and_then(|end| body.get(at + 4..end))
            .ok_or_else(|| {
                WireError::Header(format!("a field of {n} bytes, past the header's end"))
            })?;
        let text = String::from_utf8_lossy(field);
        let (k, v) = text.split_once('=').ok_or_else(|| {
            let shown: String = text.chars().take(40).collect();
            WireError::Header(format!("a field without '=': {shown:?}"))
        })?;
        out.insert(k.to_string(), v.to_string());
        at += 4 + n;
    }
    Ok(out)
}

/// One length-prefixed block of at most `limit` bytes: refused on its length, then read
/// as it arrives.
async fn read_bounded<R: AsyncRead + Unpin>(
    r: &mut R,
    limit: usize,
    what: &'static str,
) -> Result<Vec<u8>, WireError> {
    let io = |e: std::io::Error| WireError::Io {
        what,
        reason: e.to_string(),
    };
    let n = r.read_u32_le().await.map_err(io)? as usize;
    if n > limit {
        return Err(WireError::TooLong {
            what,
            len: n,
            limit,
        });
    }
    let mut buf = Vec::with_capacity(n.min(FIRST_READ));
    let mut body = (&mut *r).take(n as u64);
    let got = tokio::time::timeout(FRAME_LIMIT, body.read_to_end(&mut buf))
        .await
        .map_err(|_| WireError::Slow {
            what,
            len: n,
            limit: FRAME_LIMIT,
        })?
        .map_err(io)?;
    if got < n {
        return Err(WireError::Io {
            what,
            reason: format!("the connection closed after {got} of {n} bytes"),
        });
    }
    Ok(buf)
}

/// One length-prefixed message frame (at most `MAX_FRAME`).
pub(crate) async fn read_frame<R: AsyncRead + Unpin>(r: &mut R) -> Result<Vec<u8>, WireError> {
    read_bounded(r, MAX_FRAME, "frame").await
}

pub(crate) async fn write_frame<W: AsyncWrite + Unpin>(
    w: &mut W,
    body: &[u8],
) -> std::io::Result<()> {
    let mut out = (body.len() as u32).to_le_bytes().to_vec();
    out.extend_from_slice(body);
    w.write_all(&out).await
}

/// One connection header (at most `MAX_HEADER` bytes and `MAX_HEADER_FIELDS` fields).
pub async fn read_header<R: AsyncRead + Unpin>(
    r: &mut R,
) -> Result<BTreeMap<String, String>, WireError> {
    let body = read_bounded(r, MAX_HEADER, "connection header").await?;
    decode_header(&body)
}

/// Where the md5sum walk finds a definition by name.
type Lookup<'a> = &'a dyn Fn(&str) -> Result<Arc<MessageDef>, MsgError>;

/// The md5sum of `name`, nested types by their own (each computed once), at most
/// `MAX_DEPTH` deep; a type that contains itself is an error, not an endless walk.
fn md5_in(
    lookup: Lookup,
    name: &str,
    memo: &mut BTreeMap<String, String>,
    path: &mut Vec<String>,
) -> Result<String, WireError> {
    if let Some(sum) = memo.get(name) {
        return Ok(sum.clone());
    }
    if let Some(e) = recursion(name, path) {
        return Err(e.into());
    }
    if path.len() >= MAX_DEPTH {
        return Err(MsgError::TooLarge {
            type_name: path.first().cloned().unwrap_or_else(|| name.to_string()),
            reason: format!("nested more than {MAX_DEPTH} deep"),
        }
        .into());
    }
    let def = lookup(name)?;
    path.push(name.to_string());
    let text = md5_text(lookup, &def, memo, path)?;
    path.pop();
    let sum = format!("{:x}", md5::compute(text));
    memo.insert(name.to_string(), sum.clone());
    Ok(sum)
}

/// The text genmsg hashes for one message: constants, then fields, nested types by
/// their md5sum (built-in types as written, without array brackets for nested ones).
fn md5_text(
    lookup: Lookup,
    def: &MessageDef,
    memo: &mut BTreeMap<String, String>,
    path: &mut Vec<String>,
) -> Result<String, WireError> {
    let mut lines = Vec::new();
    for c in &def.constants {
        lines.push(format!("{} {}={}", c.type_name, c.name, c.value.trim()));
    }
    for f in &def.fields {
        let suffix = match f.shape {
            Shape::Single => String::new(),
            Shape::Array(n) => format!("[{n}]"),
            Shape::Sequence { .. } => "[]".to_string(),
        };
        let ty = match &f.base {
            BaseType::Primitive(p) => format!("{}{suffix}", p.name()),
            BaseType::Message(m) if m == "rostime/msg/Time" => format!("time{suffix}"),
            BaseType::Message(m) if m == "rostime/msg/Duration" => format!("duration{suffix}"),
            BaseType::Message(m) => md5_in(lookup, m, memo, path)?,
        };
        lines.push(format!("{ty} {}", f.name));
    }
    Ok(lines.join("\n"))
}

fn in_table(ifaces: &Interfaces) -> impl Fn(&str) -> Result<Arc<MessageDef>, MsgError> + '_ {
    move |name: &str| ifaces.message(name)
}

/// The md5sum ROS 1 identifies a message type by.
pub fn md5sum(ifaces: &Interfaces, type_name: &str) -> Result<String, WireError> {
    let name = normalize_type(type_name);
    md5_in(
        &in_table(ifaces),
        &name,
        &mut BTreeMap::new(),
        &mut Vec::new(),
    )
}

/// The md5sum of a service (`pkg/srv/Name`): its request's text and its response's.
pub(crate) fn service_md5sum(ifaces: &Interfaces, service_type: &str) -> Result<String, WireError> {
    let ty = normalize_type(service_type);
    let lookup = in_table(ifaces);
    let mut memo = BTreeMap::new();
    let mut text = String::new();
    for part in ["_Request", "_Response"] {
        let def = ifaces.message(&format!("{ty}{part}"))?;
        text.push_str(&md5_text(&lookup, &def, &mut memo, &mut Vec::new())?);
    }
    Ok(format!("{:x}", md5::compute(text)))
}

/// The full definition a connection carries: the type's text, then each nested type
/// once under `MSG: pkg/Name`.
pub(crate) fn full_text(ifaces: &Interfaces, type_name: &str) -> Result<String, WireError> {
    let def = ifaces.message(type_name)?;
    let mut out = def.text.clone();
    let mut seen = BTreeSet::new();
    // Depth first, in field order (a stack: pushed reversed).
    let mut queue: Vec<String> = nested(&def).rev().collect();
    while let Some(name) = queue.pop() {
        if name.starts_with("rostime/") || !seen.insert(name.clone()) {
            continue;
        }
        if seen.len() > MAX_TYPES {
            return Err(WireError::TooManyTypes {
                type_name: type_name.to_string(),
            });
        }
        let d = ifaces.message(&name)?;
        out.push_str(&format!(
            "{}\nMSG: {}\n{}",
            "=".repeat(80),
            ros1_type(&name),
            d.text
        ));
        queue.extend(nested(&d).rev());
    }
    Ok(out)
}

fn nested(def: &MessageDef) -> impl DoubleEndedIterator<Item = String> + '_ {
    def.fields.iter().filter_map(|f| match &f.base {
        BaseType::Message(m) => Some(m.clone()),
        BaseType::Primitive(_) => None,
    })
}

/// A connection's `message_definition` split into its types: the first named
/// `type_name`, the others by their `MSG: pkg/Name` lines; at most `MAX_TYPES`.
fn sections(type_name: &str, text: &str) -> Result<Vec<(String, String)>, WireError> {
    let mut name = type_name.to_string();
    let mut body = String::new();
    let mut out = Vec::new();
    let push = |name: String, body: String, out: &mut Vec<(String, String)>| {
        if out.len() >= MAX_TYPES {
            return Err(WireError::TooManyTypes {
                type_name: type_name.to_string(),
            });
        }
        if !valid_type(&name) || name.split('/').nth(1) != Some("msg") {
            return Err(WireError::BadSection {
                type_name: type_name.to_string(),
                section: name.chars().take(80).collect(),
            });
        }
        out.push((name, body));
        Ok(())
    };
    let mut named = true;
    for line in text.lines() {
        if line.len() >= 3 && line.chars().all(|c| c == '=') {
            push(
                std::mem::take(&mut name),
                std::mem::take(&mut body),
                &mut out,
            )?;
            named = false;
            continue;
        }
        if !named {
            if let Some(n) = line.trim().strip_prefix("MSG:") {
                name = normalize_type(n.trim());
                named = true;
                continue;
            }
        }
        body.push_str(line);
        body.push('\n');
    }
    push(name, body, &mut out)?;
    Ok(out)
}

/// Learn `type_name` from a peer's connection header: its `message_definition` (`text`)
/// and `md5`. `ours(name)` makes ferrosa's own definition of `name` present in `ifaces`
/// when it has one (shipped, or learnt before) and says whether it did.
///
/// A known type is never replaced: the peer's md5sum must be ferrosa's, else
/// `Mismatch`. An unknown one is learnt only when the definition sent, read with
/// ferrosa's own definitions of the types it nests, is within `msg`'s bounds and hashes
/// to `md5` (never `*`); nothing is added otherwise.
pub fn learn(
    ifaces: &Interfaces,
    type_name: &str,
    text: &str,
    md5: &str,
    ours: &dyn Fn(&str) -> bool,
) -> Result<(), WireError> {
    let type_name = normalize_type(type_name);
    if md5.trim().is_empty() || md5 == "*" {
        return Err(WireError::NoMd5 { type_name });
    }
    let known = |ours_now: String| {
        if ours_now == md5 {
            Ok(())
        } else {
            Err(WireError::Mismatch {
                type_name: type_name.clone(),
                theirs: md5.to_string(),
                ours: ours_now,
            })
        }
    };
    if ours(&type_name) {
        return known(md5sum(ifaces, &type_name)?);
    }
    if text.len() > MAX_DEFINITION_BYTES {
        return Err(MsgError::TooLarge {
            type_name,
            reason: format!(
                "{} bytes of definition, more than {MAX_DEFINITION_BYTES}",
                text.len()
            ),
        }
        .into());
    }
    let mut new: BTreeMap<String, Arc<MessageDef>> = BTreeMap::new();
    for (name, body) in sections(&type_name, text)? {
        if new.contains_key(&name) || ours(&name) {
            continue;
        }
        let def = parse_message(&name, &body)?;
        new.insert(name, Arc::new(def));
    }
    let overlay = |name: &str| -> Result<Arc<MessageDef>, MsgError> {
        let name = normalize_type(name);
        match new.get(&name) {
            Some(d) => Ok(d.clone()),
            None => ifaces.message(&name),
        }
    };
    check_extent(&type_name, &|n: &str| overlay(n).ok())?;
    let computed = md5_in(&overlay, &type_name, &mut BTreeMap::new(), &mut Vec::new())?;
    if computed != md5 {
        return Err(WireError::HashMismatch {
            type_name,
            computed,
            sent: md5.to_string(),
        });
    }
    ifaces.learn(new.into_values().map(|d| (*d).clone()).collect());
    // Another connection may have taught one of these names meanwhile: what the table
    // holds now is what must hash to `md5`.
    known(md5sum(ifaces, &type_name)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn ros1_table() -> Interfaces {
        let t = table();
        for (name, text) in [
            ("std_msgs/msg/Header", HEADER),
            ("geometry_msgs/msg/Vector3", "float64 x\nfloat64 y\nfloat64 z\n"),
            ("geometry_msgs/msg/Twist", "Vector3 linear\nVector3 angular\n"),
            ("turtlesim/msg/Pose", "float32 x\nfloat32 y\nfloat32 theta\n\nfloat32 linear_velocity\nfloat32 angular_velocity\n"),
            ("std_msgs/msg/String", "string data\n"),
            ("rosgraph_msgs/msg/Log", "byte DEBUG=1 #debug level\nbyte INFO=2\nbyte WARN=4\nbyte ERROR=8\nbyte FATAL=16\nHeader header\nbyte level\nstring name\nstring msg\nstring file\nstring function\nuint32 line\nstring[] topics\n"),
            ("std_srvs/srv/SetBool", "bool data\n---\nbool success\nstring message\n"),
            ("std_srvs/srv/Empty", "---\n"),
        ] {
            t.add(name, text).unwrap();
        }
        t
    }

    #[test]
    fn md5sums_match_the_ones_ros1_publishes() {
        // The md5sums rospy and roscpp send for these types (from their generated code).
        let t = ros1_table();
        assert_eq!(
            md5sum(&t, "std_msgs/String").unwrap(),
            "992ce8a1687cec8c8bd883ec73ca41d1"
        );
        assert_eq!(
            md5sum(&t, "geometry_msgs/Twist").unwrap(),
            "9f195f881246fdfa2798d1d3eebca84a"
        );
        assert_eq!(
            md5sum(&t, "turtlesim/Pose").unwrap(),
            "863b248d5016ca62ea2e895ae5265cf9"
        );
        assert_eq!(
            md5sum(&t, "std_msgs/Header").unwrap(),
            "2176decaecbce78abc3b96ef049fabed"
        );
        assert_eq!(
            md5sum(&t, "rosgraph_msgs/Log").unwrap(),
            "acffd30cd6b6de30f120938c17c593fb"
        );
        assert_eq!(
            service_md5sum(&t, "std_srvs/srv/SetBool").unwrap(),
            "09fb03525b03e7ea1fd3992bafd87e16"
        );
        assert_eq!(
            service_md5sum(&t, "std_srvs/srv/Empty").unwrap(),
            "d41d8cd98f00b204e9800998ecf8427e"
        );
    }

    #[test]
    fn a_full_definition_is_learnt_and_checked_by_its_md5sum() {
        let sender = ros1_table();
        let text = full_text(&sender, "rosgraph_msgs/Log").unwrap();
        assert!(text.contains("MSG: std_msgs/Header"));
        let md5 = md5sum(&sender, "rosgraph_msgs/Log").unwrap();
        let t = table();
        learn(&t, "rosgraph_msgs/Log", &text, &md5, &|n| t.has(n)).unwrap();
        assert_eq!(md5sum(&t, "rosgraph_msgs/Log").unwrap(), md5);
        let other = table();
        let e = learn(&other, "rosgraph_msgs/Log", &text, "0123", &|n| {
            other.has(n)
        })
        .unwrap_err();
        assert!(matches!(e, WireError::HashMismatch { .. }), "{e}");
        assert!(!other.has("rosgraph_msgs/Log") && !other.has("std_msgs/Header"));
        let e = learn(&other, "rosgraph_msgs/Log", &text, "*", &|n| other.has(n)).unwrap_err();
        assert!(matches!(e, WireError::NoMd5 { .. }), "{e}");
    }

    /// md5sum of `Vector3 lin / Vector3 ang` as genmsg computes it: a Twist renamed.
    fn renamed_twist() -> (String, String) {
        let text = format!(
            "Vector3 lin\nVector3 ang\n{}\nMSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n",
            "=".repeat(80)
        );
        let v3 = "4a842b65f413084dc2b10fb484ea7f17";
        let md5 = format!("{:x}", md5::compute(format!("{v3} lin\n{v3} ang")));
        (text, md5)
    }

    #[test]
    fn a_known_type_is_never_redefined_whatever_md5sum_comes_with_it() {
        let t = ros1_table();
        let twist = md5sum(&t, "geometry_msgs/Twist").unwrap();
        let (text, md5) = renamed_twist();
        let e = learn(&t, "geometry_msgs/Twist", &text, &md5, &|n| t.has(n)).unwrap_err();
        assert!(
            matches!(&e, WireError::Mismatch { ours, .. } if *ours == twist),
            "{e}"
        );
        let e = learn(&t, "geometry_msgs/Twist", &text, "*", &|n| t.has(n)).unwrap_err();
        assert!(matches!(e, WireError::NoMd5 { .. }), "{e}");
        assert_eq!(md5sum(&t, "geometry_msgs/Twist").unwrap(), twist);
        let fields: Vec<String> = t
            .message("geometry_msgs/Twist")
            .unwrap()
            .fields
            .iter()
            .map(|f| f.name.clone())
            .collect();
        assert_eq!(fields, ["linear", "angular"]);
        // A new type nesting a known one is read with ferrosa's definition of it: a
        // renamed Vector3 inside makes the md5sum another, and the type is refused.
        let nested = format!(
            "Twist cmd\n{}\nMSG: geometry_msgs/Twist\nVector3 lin\nVector3 ang\n",
            "=".repeat(80)
        );
        let e = learn(&t, "geometry_msgs/Cmd", &nested, &md5, &|n| t.has(n)).unwrap_err();
        assert!(matches!(e, WireError::HashMismatch { .. }), "{e}");
        assert!(!t.has("geometry_msgs/Cmd"));
    }

    #[test]
    fn recursive_deep_and_malformed_definitions_are_errors() {
        let t = table();
        let md5 = "0123456789abcdef0123456789abcdef";
        for (name, text) in [
            ("evil/Loop", "Loop next\n".to_string()),
            ("evil/Loop", "Loop[] next\n".to_string()),
            (
                "evil/A",
                format!("B b\n{}\nMSG: evil/B\nA a\n", "=".repeat(80)),
            ),
        ] {
            let e = learn(&t, name, &text, md5, &|n| t.has(n)).unwrap_err();
            assert!(
                matches!(e, WireError::Definition(MsgError::Recursive { .. })),
                "{name}: {e}"
            );
        }
        // A chain of types each nesting the next, deeper than MAX_DEPTH.
        let mut chain = String::from("T1 next\n");
        for k in 1..200 {
            chain.push_str(&format!(
                "{}\nMSG: evil/T{k}\nT{} next\n",
                "=".repeat(80),
                k + 1
            ));
        }
        let e = learn(&t, "evil/T0", &chain, md5, &|n| t.has(n)).unwrap_err();
        assert!(
            matches!(e, WireError::Definition(MsgError::TooLarge { .. })),
            "{e}"
        );
        let e = learn(&t, "evil/X", "int32 a\n===\nint32 b\n", md5, &|n| t.has(n)).unwrap_err();
        assert!(matches!(e, WireError::BadSection { .. }), "{e}");
        assert_eq!(t.names().len(), TIME_TYPES.len());
    }

    #[test]
    fn declared_lengths_are_refused_before_anything_is_read() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .build()
            .unwrap();
        let mut huge: &[u8] = &[0, 0, 0, 0x80, b'a'];
        let e = rt.block_on(read_header(&mut huge)).unwrap_err();
        assert!(
            matches!(e, WireError::TooLong { len, .. } if len == 1 << 31),
            "{e}"
        );
        let mut short: &[u8] = &[10, 0, 0, 0, 5, 0, 0, 0, b'a'];
        let e = rt.block_on(read_frame(&mut short)).unwrap_err();
        assert!(matches!(e, WireError::Io { .. }), "{e}");
    }

    #[test]
    fn ros1_bodies_are_packed_with_unterminated_strings() {
        let t = ros1_table();
        let log = json!({"header": {"seq": 7, "stamp": {"secs": 1, "nsecs": 2}, "frame_id": ""},
                         "level": 4, "name": "/n", "msg": "hi", "file": "", "function": "",
                         "line": 3, "topics": ["/a"]});
        let bytes = crate::ros::cdr::encode_ros1(&t, "rosgraph_msgs/Log", &log).unwrap();
        // seq, secs, nsecs, "" , level, "/n", "hi", "", "", line, [ "/a" ]
        assert_eq!(bytes.len(), 4 + 8 + 4 + 1 + 6 + 6 + 4 + 4 + 4 + 4 + 6);
        assert_eq!(&bytes[17..23], &[2, 0, 0, 0, b'/', b'n']);
        assert_eq!(
            crate::ros::cdr::decode_ros1(&t, "rosgraph_msgs/Log", &bytes).unwrap(),
            log
        );
        let empty =
            crate::ros::cdr::encode_ros1(&t, "std_srvs/srv/Empty_Request", &json!({})).unwrap();
        assert!(empty.is_empty());
    }

    #[test]
    fn headers_round_trip_and_malformed_ones_are_errors() {
        let h = encode_header(&[("callerid", "/ferrosa"), ("md5sum", "*"), ("topic", "/a=b")]);
        let fields = decode_header(&h[4..]).unwrap();
        assert_eq!(fields["topic"], "/a=b");
        assert_eq!(fields["md5sum"], "*");
        assert!(decode_header(&[9, 0, 0, 0, b'a']).is_err());
        assert!(decode_header(&[1, 0, 0, 0, b'a']).is_err());
    }
}
