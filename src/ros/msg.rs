//! ROS interface definitions (`.msg`, `.srv`, `.action`) as data: parsing the text, the
//! bundle shipped with ferrosa for the common packages, and lookup by any spelling of a
//! type name (`geometry_msgs/Twist`, `geometry_msgs/msg/Twist`,
//! `geometry_msgs::msg::dds_::Twist_`).
//!
//! A service `pkg/srv/X` is stored as two messages, `pkg/srv/X_Request` and
//! `pkg/srv/X_Response`; an action `pkg/action/X` as `X_Goal`, `X_Result`, `X_Feedback`.
//! Definitions not in the bundle are read from an installed ROS (`AMENT_PREFIX_PATH`,
//! `share/<pkg>/<kind>/<Name>.<kind>`) on first use, or added by the ROS 2 graph from a
//! peer's `~/get_type_description` answer (`Interfaces::add`).
//!
//! A definition may come from a peer (ROS 1 connection headers, ROS 2 type
//! descriptions), so every parse is bounded before it allocates: bytes of text, fields
//! per message, fixed array sizes; and a set of definitions is measured (`check_extent`)
//! before it is used: nesting depth, values per message, and no type that contains
//! itself. Errors, never a crash or an unbounded allocation.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::{Arc, RwLock};

/// The bundled definitions: one file per package, sections headed `=== pkg/kind/Name`
/// (made by `scripts/bundle-interfaces.py`).
const BUNDLE: &[&str] = &[
    include_str!("interfaces/action_msgs.idl"),
    include_str!("interfaces/builtin_interfaces.idl"),
    include_str!("interfaces/diagnostic_msgs.idl"),
    include_str!("interfaces/geometry_msgs.idl"),
    include_str!("interfaces/nav_msgs.idl"),
    include_str!("interfaces/nav2_msgs.idl"),
    include_str!("interfaces/rcl_interfaces.idl"),
    include_str!("interfaces/rosgraph_msgs.idl"),
    include_str!("interfaces/sensor_msgs.idl"),
    include_str!("interfaces/std_msgs.idl"),
    include_str!("interfaces/std_srvs.idl"),
    include_str!("interfaces/turtlesim.idl"),
    include_str!("interfaces/unique_identifier_msgs.idl"),
    include_str!("interfaces/type_description_interfaces.idl"),
];

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MsgError {
    #[error("unknown interface type {0}; `ros_interface_show` lists what is known, or install its package and set AMENT_PREFIX_PATH")]
    Unknown(String),
    #[error("{type_name} line {line}: {reason}")]
    Parse {
        type_name: String,
        line: usize,
        reason: String,
    },
    #[error("{type_name}: {reason}; a definition past ferrosa's bounds is refused (check the peer that sent it)")]
    TooLarge { type_name: String, reason: String },
    #[error("{type_name} contains itself ({path}); a recursive definition has no end and is refused (check the peer that sent it)")]
    Recursive { type_name: String, path: String },
}

/// Most bytes of definition text parsed at once (a whole ROS 1 `message_definition`
/// with every nested type; MoveIt's largest are tens of KB).
pub(crate) const MAX_DEFINITION_BYTES: usize = 1 << 20;

/// Most fields and constants one message may declare.
pub(crate) const MAX_FIELDS: usize = 1024;

/// Most levels of message inside message (ROS types nest about ten deep at most).
pub const MAX_DEPTH: usize = 32;

/// Most types one definition may bring with it (a ROS 1 `message_definition`'s sections,
/// a ROS 2 description's referenced types).
pub(crate) const MAX_TYPES: usize = 256;

/// The most values (scalars and strings, every fixed array counted in full, a sequence
/// as one element) one message type may hold: a peer's type must not make a template
/// or an encoding allocate without bound.
pub const MAX_LEAVES: u64 = 1 << 20;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Primitive {
    Bool,
    Byte,
    Char,
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
    String,
}

impl Primitive {
    fn parse(name: &str) -> Option<Primitive> {
        Some(match name {
            "bool" => Primitive::Bool,
            "byte" => Primitive::Byte,
            "char" => Primitive::Char,
            "int8" => Primitive::I8,
            "uint8" => Primitive::U8,
            "int16" => Primitive::I16,
            "uint16" => Primitive::U16,
            "int32" => Primitive::I32,
            "uint32" => Primitive::U32,
            "int64" => Primitive::I64,
            "uint64" => Primitive::U64,
            "float32" => Primitive::F32,
            "float64" => Primitive::F64,
            "string" => Primitive::String,
            _ => return None,
        })
    }

    pub fn name(self) -> &'static str {
        match self {
            Primitive::Bool => "bool",
            Primitive::Byte => "byte",
            Primitive::Char => "char",
            Primitive::I8 => "int8",
            Primitive::U8 => "uint8",
            Primitive::I16 => "int16",
            Primitive::U16 => "uint16",
            Primitive::I32 => "int32",
            Primitive::U32 => "uint32",
            Primitive::I64 => "int64",
            Primitive::U64 => "uint64",
            Primitive::F32 => "float32",
            Primitive::F64 => "float64",
            Primitive::String => "string",
        }
    }
}

/// The element type of a field.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum BaseType {
    Primitive(Primitive),
    /// A nested message, by full name (`geometry_msgs/msg/Vector3`).
    Message(String),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    Single,
    /// `T[N]`: exactly N elements, no length on the wire.
    Array(usize),
    /// `T[]` or `T[<=N]`: a length, then the elements.
    Sequence {
        max: Option<usize>,
    },
}

#[derive(Debug, Clone, PartialEq)]
pub struct Field {
    pub name: String,
    pub base: BaseType,
    pub shape: Shape,
    /// `string<=N`
    pub string_max: Option<usize>,
    /// The declared default, as written.
    pub default: Option<String>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Constant {
    pub name: String,
    pub type_name: String,
    pub value: String,
}

/// One message type.
#[derive(Debug, Clone, PartialEq)]
pub struct MessageDef {
    pub name: String,
    pub fields: Vec<Field>,
    pub constants: Vec<Constant>,
    /// The definition's text (comments removed), for `ros_interface_show`.
    pub text: String,
}

/// Every spelling of a type name resolved to `pkg/kind/Name`; `kind` defaults to `msg`.
pub(crate) fn normalize_type(name: &str) -> String {
    let name = name.trim();
    if let Some(rest) = name.strip_suffix('_') {
        // DDS form: pkg::msg::dds_::Name_
        let parts: Vec<&str> = rest.split("::").collect();
        if parts.len() == 4 && parts[2] == "dds_" {
            return format!("{}/{}/{}", parts[0], parts[1], parts[3]);
        }
    }
    let parts: Vec<&str> = name.split('/').filter(|p| !p.is_empty()).collect();
    match parts.as_slice() {
        [pkg, ty] => format!("{pkg}/msg/{ty}"),
        _ => parts.join("/"),
    }
}

fn parse_base(token: &str, package: &str) -> Result<(BaseType, Option<usize>), String> {
    if let Some((head, max)) = token.split_once("<=") {
        if head == "string" || head == "wstring" {
            let max = max
                .parse()
                .map_err(|_| format!("bad string bound in {token}"))?;
            return parse_base(head, package).map(|(b, _)| (b, Some(max)));
        }
    }
    if token == "wstring" {
        return Err("wstring fields are not supported".into());
    }
    if let Some(p) = Primitive::parse(token) {
        return Ok((BaseType::Primitive(p), None));
    }
    let full = match token.split('/').collect::<Vec<_>>().as_slice() {
        [ty] if *ty == "Header" => "std_msgs/msg/Header".to_string(),
        // ROS 1's two built-in time types, as messages of their own (`ros1::wire`).
        [ty] if *ty == "time" => "rostime/msg/Time".to_string(),
        [ty] if *ty == "duration" => "rostime/msg/Duration".to_string(),
        [ty] => format!("{package}/msg/{ty}"),
        [pkg, ty] => format!("{pkg}/msg/{ty}"),
        [pkg, kind, ty] => format!("{pkg}/{kind}/{ty}"),
        _ => return Err(format!("bad type {token}")),
    };
    Ok((BaseType::Message(full), None))
}

/// Largest fixed array a definition may declare: a message of a billion zeros (a peer
/// may claim one) would be allocated whole before a single byte is read.
pub(crate) const MAX_FIXED_ARRAY: usize = 1 << 16;

fn parse_shape(token: &str) -> Result<(&str, Shape), String> {
    let Some(open) = token.find('[') else {
        return Ok((token, Shape::Single));
    };
    let inner = token[open + 1..]
        .strip_suffix(']')
        .ok_or_else(|| format!("unclosed [ in {token}"))?;
    let shape = if inner.is_empty() {
        Shape::Sequence { max: None }
    } else if let Some(max) = inner.strip_prefix("<=") {
        Shape::Sequence {
            max: Some(max.parse().map_err(|_| format!("bad bound in {token}"))?),
        }
    } else {
        let n: usize = inner
            .parse()
            .map_err(|_| format!("bad array size in {token}"))?;
        if n > MAX_FIXED_ARRAY {
            return Err(format!(
                "fixed array of {n} elements in {token}: more than {MAX_FIXED_ARRAY}"
            ));
        }
        Shape::Array(n)
    };
    Ok((&token[..open], shape))
}

/// Parse one message body (no `---`). `name` is the full type name. Bounded: at most
/// `MAX_DEFINITION_BYTES` of text and `MAX_FIELDS` fields and constants, checked before
/// anything is kept.
pub fn parse_message(name: &str, body: &str) -> Result<MessageDef, MsgError> {
    let package = name.split('/').next().unwrap_or_default();
    let too_large = |reason: String| MsgError::TooLarge {
        type_name: name.to_string(),
        reason,
    };
    if body.len() > MAX_DEFINITION_BYTES {
        return Err(too_large(format!(
            "{} bytes of definition, more than {MAX_DEFINITION_BYTES}",
            body.len()
        )));
    }
    let mut def = MessageDef {
        name: name.to_string(),
        fields: Vec::new(),
        constants: Vec::new(),
        text: String::new(),
    };
    for (i, raw) in body.lines().enumerate() {
        let line = strip_comment(raw).trim();
        if line.is_empty() {
            continue;
        }
        def.text.push_str(line);
        def.text.push('\n');
        let err = |reason: String| MsgError::Parse {
            type_name: name.to_string(),
            line: i + 1,
            reason,
        };
        let (type_token, rest) = line
            .split_once(char::is_whitespace)
            .ok_or_else(|| err(format!("expected `TYPE NAME`, found {line:?}")))?;
        let rest = rest.trim();
        if def.fields.len() + def.constants.len() >= MAX_FIELDS {
            return Err(too_large(format!(
                "more than {MAX_FIELDS} fields and constants"
            )));
        }
        // A constant: NAME=VALUE (spaces allowed around '=') and an upper-case name.
        if let Some((cname, value)) = rest.split_once('=') {
            let cname = cname.trim();
            if !cname.contains(char::is_whitespace) {
                def.constants.push(Constant {
                    name: cname.to_string(),
                    type_name: type_token.to_string(),
                    value: value.trim().to_string(),
                });
                continue;
            }
        }
        let (fname, default) = match rest.split_once(char::is_whitespace) {
            Some((n, d)) => (n, Some(d.trim().to_string())),
            None => (rest, None),
        };
        let (elem, shape) = parse_shape(type_token).map_err(err)?;
        let (base, string_max) = parse_base(elem, package).map_err(err)?;
        def.fields.push(Field {
            name: fname.to_string(),
            base,
            shape,
            string_max,
            default,
        });
    }
    Ok(def)
}

fn strip_comment(line: &str) -> &str {
    // A '#' inside quotes belongs to a string constant or default.
    let mut quote = None;
    for (i, c) in line.char_indices() {
        match (c, quote) {
            ('"' | '\'', None) => quote = Some(c),
            (c, Some(q)) if c == q => quote = None,
            ('#', None) => return &line[..i],
            _ => {}
        }
    }
    line
}

/// What `check_extent` found of a type: how deep its nesting goes below it (1 for a
/// message of primitives) and how many values it holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Extent {
    pub depth: usize,
    pub leaves: u64,
}

/// Measure `name` as the definitions `lookup` gives make it: nesting at most
/// `MAX_DEPTH` deep, at most `MAX_LEAVES` values, no type containing itself. A name
/// `lookup` lacks counts as one value (a type known already, and bounded). The walk
/// recurses at most `MAX_DEPTH` levels and visits each type once.
pub fn check_extent(
    name: &str,
    lookup: &dyn Fn(&str) -> Option<Arc<MessageDef>>,
) -> Result<Extent, MsgError> {
    let mut memo = BTreeMap::new();
    let mut path = Vec::new();
    extent_at(name, lookup, &mut path, &mut memo)
}

/// The error for `name` met again on `path` (the types being walked, outermost first):
/// a type that contains itself has no end. `None` when `name` is not on the path.
pub fn recursion(name: &str, path: &[String]) -> Option<MsgError> {
    if !path.iter().any(|p| p == name) {
        return None;
    }
    let mut cycle = path.to_vec();
    cycle.push(name.to_string());
    Some(MsgError::Recursive {
        type_name: path[0].clone(),
        path: cycle.join(" > "),
    })
}

fn extent_at(
    name: &str,
    lookup: &dyn Fn(&str) -> Option<Arc<MessageDef>>,
    path: &mut Vec<String>,
    memo: &mut BTreeMap<String, Extent>,
) -> Result<Extent, MsgError> {
    if let Some(e) = recursion(name, path) {
        return Err(e);
    }
    let root = path.first().cloned().unwrap_or_else(|| name.to_string());
    let too_large = |reason: String| MsgError::TooLarge {
        type_name: root.clone(),
        reason,
    };
    if let Some(e) = memo.get(name) {
        if path.len() + e.depth > MAX_DEPTH {
            return Err(too_large(format!("nested more than {MAX_DEPTH} deep")));
        }
        return Ok(*e);
    }
    if path.len() >= MAX_DEPTH {
        return Err(too_large(format!("nested more than {MAX_DEPTH} deep")));
    }
    let Some(def) = lookup(name) else {
        return Ok(Extent {
            depth: 0,
            leaves: 1,
        });
    };
    path.push(name.to_string());
    let mut depth = 0;
    let mut leaves: u64 = 0;
    let over = || format!("more than {MAX_LEAVES} values in one message");
    for f in &def.fields {
        let one = match &f.base {
            BaseType::Message(m) => {
                let e = extent_at(m, lookup, path, memo)?;
                depth = depth.max(e.depth);
                e.leaves
            }
            BaseType::Primitive(_) => 1,
        };
        let count = match f.shape {
            Shape::Array(n) => n as u64,
            Shape::Single | Shape::Sequence { .. } => 1,
        };
        leaves = one
            .checked_mul(count)
            .and_then(|n| leaves.checked_add(n))
            .filter(|n| *n <= MAX_LEAVES)
            .ok_or_else(|| too_large(over()))?;
    }
    path.pop();
    let e = Extent {
        depth: depth + 1,
        leaves: leaves.max(1),
    };
    memo.insert(name.to_string(), e);
    Ok(e)
}

/// Split a `.srv` or `.action` file into its parts and name them.
fn split_parts(name: &str, text: &str) -> Vec<(String, String)> {
    let mut parts = vec![String::new()];
    for line in text.lines() {
        if strip_comment(line).trim() == "---" {
            parts.push(String::new());
        } else {
            let last = parts.last_mut().expect("one part at least");
            last.push_str(line);
            last.push('\n');
        }
    }
    let kind = name.split('/').nth(1).unwrap_or("msg");
    let suffixes: &[&str] = match kind {
        "srv" => &["_Request", "_Response"],
        "action" => &["_Goal", "_Result", "_Feedback"],
        _ => &[""],
    };
    suffixes
        .iter()
        .zip(parts.into_iter().chain(std::iter::repeat(String::new())))
        .map(|(s, p)| (format!("{name}{s}"), p))
        .collect()
}

/// All known definitions: the bundle, then an installed ROS on demand.
#[derive(Clone)]
pub struct Interfaces {
    inner: Arc<RwLock<Known>>,
}

#[derive(Default)]
struct Known {
    messages: BTreeMap<String, Arc<MessageDef>>,
    /// Source text per interface (`pkg/srv/X` keeps its `---` parts).
    sources: BTreeMap<String, String>,
    search: Vec<PathBuf>,
}

impl Default for Interfaces {
    fn default() -> Self {
        Interfaces::bundled()
    }
}

impl Interfaces {
    /// The bundle, plus `share/` folders from `AMENT_PREFIX_PATH`. Parsed once per
    /// process and shared (the graph and the sim in one process read the same table;
    /// definitions found later are valid for both).
    pub fn bundled() -> Interfaces {
        static SHARED: std::sync::OnceLock<Interfaces> = std::sync::OnceLock::new();
        SHARED.get_or_init(Interfaces::parse_bundle).clone()
    }

    fn parse_bundle() -> Interfaces {
        let mut known = Known::default();
        for file in BUNDLE {
            for section in file.split("=== ").filter(|s| !s.trim().is_empty()) {
                let (name, body) = section.split_once('\n').unwrap_or((section, ""));
                known
                    .add(name.trim(), body)
                    .expect("bundled interface definitions parse");
            }
        }
        if let Ok(paths) = std::env::var("AMENT_PREFIX_PATH") {
            known.search = std::env::split_paths(&paths)
                .map(|p| p.join("share"))
                .collect();
        }
        Interfaces {
            inner: Arc::new(RwLock::new(known)),
        }
    }

    /// A table of nothing but `defs` (`name`, text), searching no installed ROS: the
    /// ROS 1 graph's, whose definitions come from its peers.
    pub fn of(defs: &[(&str, &str)]) -> Result<Interfaces, MsgError> {
        let mut known = Known::default();
        for (name, text) in defs {
            known.add(name, text)?;
        }
        Ok(Interfaces {
            inner: Arc::new(RwLock::new(known)),
        })
    }

    /// Whether `type_name` is in the table now (no search of installed files).
    pub fn has(&self, type_name: &str) -> bool {
        self.inner
            .read()
            .expect("interfaces lock")
            .messages
            .contains_key(&normalize_type(type_name))
    }

    /// Add definitions from text (a `.msg`, `.srv` or `.action` file) under `name`
    /// (`pkg/kind/Name`).
    pub fn add(&self, name: &str, text: &str) -> Result<(), MsgError> {
        self.inner.write().expect("interfaces lock").add(name, text)
    }

    /// Add definitions learnt from a peer (built by `typedesc` from a verified
    /// description, or by `ros1::wire::learn` from a definition checked by its md5sum).
    /// A name already known, shipped, installed or learnt before, is never replaced: a
    /// peer cannot redefine `geometry_msgs/msg/Twist`. Returns how many were new.
    pub fn learn(&self, defs: Vec<MessageDef>) -> usize {
        let mut known = self.inner.write().expect("interfaces lock");
        let mut added = 0;
        for def in defs {
            let name = normalize_type(&def.name);
            if known.messages.contains_key(&name) {
                continue;
            }
            known
                .sources
                .entry(name.clone())
                .or_insert_with(|| def.text.clone());
            known.messages.insert(name, Arc::new(def));
            added += 1;
        }
        added
    }

    /// The message definition of `type_name` (any spelling).
    pub fn message(&self, type_name: &str) -> Result<Arc<MessageDef>, MsgError> {
        let name = normalize_type(type_name);
        if let Some(def) = self
            .inner
            .read()
            .expect("interfaces lock")
            .messages
            .get(&name)
        {
            return Ok(def.clone());
        }
        self.load_installed(&name)?;
        self.inner
            .read()
            .expect("interfaces lock")
            .messages
            .get(&name)
            .cloned()
            .ok_or(MsgError::Unknown(name))
    }

    /// The source text of an interface (`pkg/msg/X`, `pkg/srv/X`, `pkg/action/X`).
    pub fn source(&self, type_name: &str) -> Result<String, MsgError> {
        let name = normalize_type(type_name);
        if let Some(text) = self
            .inner
            .read()
            .expect("interfaces lock")
            .sources
            .get(&name)
        {
            return Ok(text.clone());
        }
        self.load_installed(&name)?;
        self.inner
            .read()
            .expect("interfaces lock")
            .sources
            .get(&name)
            .cloned()
            .ok_or(MsgError::Unknown(name))
    }

    /// Every known interface name, sorted.
    pub fn names(&self) -> Vec<String> {
        self.inner
            .read()
            .expect("interfaces lock")
            .sources
            .keys()
            .cloned()
            .collect()
    }

    fn load_installed(&self, name: &str) -> Result<(), MsgError> {
        // X_Request lives in X.srv, X_Goal in X.action.
        let parts: Vec<&str> = name.split('/').collect();
        let [pkg, kind, ty] = parts.as_slice() else {
            return Err(MsgError::Unknown(name.to_string()));
        };
        let base = ["_Request", "_Response", "_Goal", "_Result", "_Feedback"]
            .iter()
            .find_map(|s| ty.strip_suffix(s))
            .filter(|_| *kind != "msg")
            .unwrap_or(ty);
        let search = self.inner.read().expect("interfaces lock").search.clone();
        for dir in search {
            let path = dir.join(pkg).join(kind).join(format!("{base}.{kind}"));
            if let Ok(text) = std::fs::read_to_string(&path) {
                return self.add(&format!("{pkg}/{kind}/{base}"), &text);
            }
        }
        Err(MsgError::Unknown(name.to_string()))
    }
}

impl Known {
    fn add(&mut self, name: &str, text: &str) -> Result<(), MsgError> {
        let name = normalize_type(name);
        if text.len() > MAX_DEFINITION_BYTES {
            return Err(MsgError::TooLarge {
                type_name: name,
                reason: format!(
                    "{} bytes of definition, more than {MAX_DEFINITION_BYTES}",
                    text.len()
                ),
            });
        }
        for (part, body) in split_parts(&name, text) {
            let def = parse_message(&part, &body)?;
            self.messages.insert(part, Arc::new(def));
        }
        let clean: String = text
            .lines()
            .map(|l| strip_comment(l).trim_end())
            .filter(|l| !l.trim().is_empty())
            .map(|l| format!("{l}\n"))
            .collect();
        self.sources.insert(name, clean);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_in_every_spelling() {
        assert_eq!(
            normalize_type("geometry_msgs/Twist"),
            "geometry_msgs/msg/Twist"
        );
        assert_eq!(
            normalize_type("geometry_msgs/msg/Twist"),
            "geometry_msgs/msg/Twist"
        );
        assert_eq!(
            normalize_type("geometry_msgs::msg::dds_::Twist_"),
            "geometry_msgs/msg/Twist"
        );
        assert_eq!(
            normalize_type("std_srvs::srv::dds_::Trigger_Request_"),
            "std_srvs/srv/Trigger_Request"
        );
    }

    #[test]
    fn fields_shapes_constants_defaults() {
        let def = parse_message(
            "p/msg/T",
            "uint8 OK=0 # fine\nstring NAME = \"a#b\"\nHeader header\nfloat64[9] cov\n\
             int32[] xs\nPoint[<=3] pts\nstring<=8 tag\nfloat32 speed 1.5\n",
        )
        .unwrap();
        assert_eq!(def.constants.len(), 2);
        assert_eq!(def.constants[1].value, "\"a#b\"");
        let shapes: Vec<_> = def
            .fields
            .iter()
            .map(|f| (f.name.as_str(), f.shape))
            .collect();
        assert_eq!(
            shapes,
            [
                ("header", Shape::Single),
                ("cov", Shape::Array(9)),
                ("xs", Shape::Sequence { max: None }),
                ("pts", Shape::Sequence { max: Some(3) }),
                ("tag", Shape::Single),
                ("speed", Shape::Single),
            ]
        );
        assert_eq!(
            def.fields[0].base,
            BaseType::Message("std_msgs/msg/Header".into())
        );
        assert_eq!(def.fields[3].base, BaseType::Message("p/msg/Point".into()));
        assert_eq!(def.fields[4].string_max, Some(8));
        assert_eq!(def.fields[5].default.as_deref(), Some("1.5"));
    }

    #[test]
    fn definitions_past_the_bounds_are_errors_not_crashes() {
        let huge = "int32 a\n".repeat(MAX_DEFINITION_BYTES / 8 + 1);
        assert!(matches!(
            parse_message("p/msg/T", &huge),
            Err(MsgError::TooLarge { .. })
        ));
        let wide: String = (0..=MAX_FIELDS).map(|i| format!("int32 f{i}\n")).collect();
        assert!(matches!(
            parse_message("p/msg/T", &wide),
            Err(MsgError::TooLarge { .. })
        ));
        assert!(parse_message("p/msg/T", "int32[4000000000] a\n").is_err());
        let table = |defs: &[(&str, &str)]| {
            let t: BTreeMap<String, Arc<MessageDef>> = defs
                .iter()
                .map(|(n, b)| (n.to_string(), Arc::new(parse_message(n, b).unwrap())))
                .collect();
            move |n: &str| t.get(n).cloned()
        };
        let looped = table(&[("p/msg/A", "B b\n"), ("p/msg/B", "A[] a\n")]);
        assert!(matches!(
            check_extent("p/msg/A", &looped),
            Err(MsgError::Recursive { .. })
        ));
        // A chain one past the bound, and a binary tree of 2^24 values from 24 types.
        let chain: Vec<(String, String)> = (0..=MAX_DEPTH)
            .map(|k| (format!("p/msg/C{k}"), format!("C{} next\n", k + 1)))
            .collect();
        let pairs: Vec<(&str, &str)> = chain
            .iter()
            .map(|(a, b)| (a.as_str(), b.as_str()))
            .collect();
        assert!(matches!(
            check_extent("p/msg/C0", &table(&pairs)),
            Err(MsgError::TooLarge { .. })
        ));
        let tree: Vec<(String, String)> = (1..=24)
            .map(|k| (format!("p/msg/T{k}"), format!("T{0} l\nT{0} r\n", k - 1)))
            .chain([("p/msg/T0".to_string(), "int8 v\n".to_string())])
            .collect();
        let pairs: Vec<(&str, &str)> = tree.iter().map(|(a, b)| (a.as_str(), b.as_str())).collect();
        assert!(matches!(
            check_extent("p/msg/T24", &table(&pairs)),
            Err(MsgError::TooLarge { .. })
        ));
        assert_eq!(
            check_extent("p/msg/T10", &table(&pairs)).unwrap(),
            Extent {
                depth: 11,
                leaves: 1024
            }
        );
    }

    #[test]
    fn bundle_has_services_and_actions() {
        let known = Interfaces::bundled();
        let req = known.message("turtlesim/srv/Spawn_Request").unwrap();
        assert_eq!(req.fields.len(), 4);
        let resp = known.message("turtlesim/srv/Spawn_Response").unwrap();
        assert_eq!(resp.fields[0].name, "name");
        assert!(known
            .message("std_srvs/srv/Empty_Request")
            .unwrap()
            .fields
            .is_empty());
        assert_eq!(
            known
                .message("turtlesim/action/RotateAbsolute_Feedback")
                .unwrap()
                .fields[0]
                .name,
            "remaining"
        );
        assert!(known
            .source("std_srvs/srv/SetBool")
            .unwrap()
            .contains("---"));
        // Every nested type in the bundle resolves.
        for name in known.names() {
            if name.contains("/msg/") {
                let def = known.message(&name).unwrap();
                for f in &def.fields {
                    if let BaseType::Message(m) = &f.base {
                        known
                            .message(m)
                            .unwrap_or_else(|e| panic!("{name}.{}: {e}", f.name));
                    }
                }
            }
        }
        assert!(matches!(
            known.message("nope_msgs/Nope"),
            Err(MsgError::Unknown(_))
        ));
    }
}
