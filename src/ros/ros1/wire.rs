//! TCPROS as ROS 1 nodes speak it: connection headers, length-prefixed frames, and the
//! type identity a connection is checked by (the md5sum of a definition, computed as
//! genmsg does) with the full definition text a publisher or subscriber sends with it.
//!
//! Message bodies are ROS 1's serialisation of the JSON the tools use (`cdr::Wire::Ros1`,
//! the same definition-driven walk as ROS 2's CDR).

use std::collections::BTreeMap;

use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};

use crate::ros::msg::{normalize_type, BaseType, Interfaces, MessageDef, Shape};

/// Largest header or message frame read from a peer.
pub const MAX_FRAME: usize = 64 << 20;

/// ROS 1's two time types, which its definitions use as primitives.
pub const TIME_TYPES: [(&str, &str); 2] = [
    ("rostime/msg/Time", "uint32 secs\nuint32 nsecs\n"),
    ("rostime/msg/Duration", "int32 secs\nint32 nsecs\n"),
];

/// ROS 1's `std_msgs/Header` (ROS 2's has no `seq`, and ROS 2's time).
pub const HEADER: &str = "uint32 seq\ntime stamp\nstring frame_id\n";

/// A table holding only ROS 1's time types, for definitions learnt from peers.
pub fn table() -> Interfaces {
    Interfaces::of(&TIME_TYPES).expect("the time types parse")
}

/// `pkg/msg/Name` (any spelling) as ROS 1 writes it: `pkg/Name`.
pub fn ros1_type(type_name: &str) -> String {
    let full = normalize_type(type_name);
    let parts: Vec<&str> = full.split('/').collect();
    match parts.as_slice() {
        [pkg, "msg" | "srv", name] => format!("{pkg}/{name}"),
        _ => full,
    }
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

pub fn decode_header(body: &[u8]) -> Result<BTreeMap<String, String>, String> {
    let mut out = BTreeMap::new();
    let mut at = 0;
    while at < body.len() {
        let len_bytes = body
            .get(at..at + 4)
            .ok_or("a connection header field without its length")?;
        let n = u32::from_le_bytes(len_bytes.try_into().expect("4 bytes")) as usize;
        let field = body
            .get(at + 4..at + 4 + n)
            .ok_or("a connection header field longer than the header")?;
        let text = String::from_utf8_lossy(field);
        let (k, v) = text
            .split_once('=')
            .ok_or_else(|| format!("a connection header field without '=': {text}"))?;
        out.insert(k.to_string(), v.to_string());
        at += 4 + n;
    }
    Ok(out)
}

/// One length-prefixed frame.
pub async fn read_frame<R: AsyncRead + Unpin>(r: &mut R) -> std::io::Result<Vec<u8>> {
    let n = r.read_u32_le().await? as usize;
    if n > MAX_FRAME {
        return Err(std::io::Error::other(format!(
            "a frame of {n} bytes (more than {MAX_FRAME})"
        )));
    }
    let mut buf = vec![0; n];
    r.read_exact(&mut buf).await?;
    Ok(buf)
}

pub async fn write_frame<W: AsyncWrite + Unpin>(w: &mut W, body: &[u8]) -> std::io::Result<()> {
    let mut out = (body.len() as u32).to_le_bytes().to_vec();
    out.extend_from_slice(body);
    w.write_all(&out).await
}

pub async fn read_header<R: AsyncRead + Unpin>(
    r: &mut R,
) -> Result<BTreeMap<String, String>, String> {
    let body = read_frame(r).await.map_err(|e| e.to_string())?;
    decode_header(&body)
}

/// A field's type as genmsg hashes it: built-in types as written, nested messages by
/// their md5sum (without array brackets).
fn hashed_type(base: &BaseType, shape: Shape, ifaces: &Interfaces) -> Result<String, String> {
    let suffix = match shape {
        Shape::Single => String::new(),
        Shape::Array(n) => format!("[{n}]"),
        Shape::Sequence { .. } => "[]".to_string(),
    };
    Ok(match base {
        BaseType::Primitive(p) => format!("{}{suffix}", p.name()),
        BaseType::Message(m) if m == "rostime/msg/Time" => format!("time{suffix}"),
        BaseType::Message(m) if m == "rostime/msg/Duration" => format!("duration{suffix}"),
        BaseType::Message(m) => md5sum(ifaces, m)?,
    })
}

/// The text genmsg hashes for one message: constants, then fields, nested types by
/// their own md5sum.
fn md5_text(ifaces: &Interfaces, def: &MessageDef) -> Result<String, String> {
    let mut lines = Vec::new();
    for c in &def.constants {
        lines.push(format!("{} {}={}", c.type_name, c.name, c.value.trim()));
    }
    for f in &def.fields {
        let ty = hashed_type(&f.base, f.shape, ifaces)?;
        lines.push(format!("{ty} {}", f.name));
    }
    Ok(lines.join("\n"))
}

fn message(ifaces: &Interfaces, type_name: &str) -> Result<std::sync::Arc<MessageDef>, String> {
    ifaces.message(type_name).map_err(|e| e.to_string())
}

/// The md5sum ROS 1 identifies a message type by.
pub fn md5sum(ifaces: &Interfaces, type_name: &str) -> Result<String, String> {
    let def = message(ifaces, type_name)?;
    Ok(format!("{:x}", md5::compute(md5_text(ifaces, &def)?)))
}

/// The md5sum of a service (`pkg/srv/Name`): its request's text and its response's.
pub fn service_md5sum(ifaces: &Interfaces, service_type: &str) -> Result<String, String> {
    let ty = normalize_type(service_type);
    let req = message(ifaces, &format!("{ty}_Request"))?;
    let res = message(ifaces, &format!("{ty}_Response"))?;
    let text = md5_text(ifaces, &req)? + &md5_text(ifaces, &res)?;
    Ok(format!("{:x}", md5::compute(text)))
}

/// The full definition a connection carries: the type's text, then each nested type
/// once under `MSG: pkg/Name`.
pub fn full_text(ifaces: &Interfaces, type_name: &str) -> Result<String, String> {
    let def = message(ifaces, type_name)?;
    let mut out = def.text.clone();
    let mut seen = Vec::new();
    // Depth first, in field order (a stack: pushed reversed).
    let mut queue: Vec<String> = nested(&def).rev().collect();
    while let Some(name) = queue.pop() {
        if seen.contains(&name) || name.starts_with("rostime/") {
            continue;
        }
        let d = message(ifaces, &name)?;
        out.push_str(&format!(
            "{}\nMSG: {}\n{}",
            "=".repeat(80),
            ros1_type(&name),
            d.text
        ));
        queue.extend(nested(&d).rev());
        seen.push(name);
    }
    Ok(out)
}

fn nested(def: &MessageDef) -> impl DoubleEndedIterator<Item = String> + '_ {
    def.fields.iter().filter_map(|f| match &f.base {
        BaseType::Message(m) => Some(m.clone()),
        BaseType::Primitive(_) => None,
    })
}

/// Add the definitions in a connection's `message_definition` to `ifaces`, the first as
/// `type_name`, and check the result hashes to `md5`: a definition read differently
/// than its sender meant would decode garbage.
pub fn learn(ifaces: &Interfaces, type_name: &str, text: &str, md5: &str) -> Result<(), String> {
    let mut name = normalize_type(type_name);
    let mut body = String::new();
    let mut sections = Vec::new();
    for line in text.lines() {
        if line.len() >= 3 && line.chars().all(|c| c == '=') {
            sections.push((name.clone(), std::mem::take(&mut body)));
            name = String::new();
            continue;
        }
        if name.is_empty() {
            if let Some(n) = line.trim().strip_prefix("MSG:") {
                name = normalize_type(n.trim());
                continue;
            }
        }
        body.push_str(line);
        body.push('\n');
    }
    sections.push((name, body));
    // Nested types first, so a failed parse leaves the table as it was for the main one.
    for (name, body) in sections.iter().rev() {
        if name.is_empty() {
            return Err(format!(
                "a definition section of {type_name} without `MSG: name`"
            ));
        }
        ifaces.add(name, body).map_err(|e| e.to_string())?;
    }
    let ours = md5sum(ifaces, type_name)?;
    if md5 != "*" && ours != md5 {
        return Err(format!(
            "{type_name}: the definition sent hashes to {ours}, not to the md5sum {md5} sent with it"
        ));
    }
    Ok(())
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
        learn(&t, "rosgraph_msgs/Log", &text, &md5).unwrap();
        assert_eq!(md5sum(&t, "rosgraph_msgs/Log").unwrap(), md5);
        let other = table();
        let e = learn(&other, "rosgraph_msgs/Log", &text, "0123").unwrap_err();
        assert!(e.contains("not to the md5sum"), "{e}");
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
