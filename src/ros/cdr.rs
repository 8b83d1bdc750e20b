//! CDR (little-endian, XCDR1 as ROS 2 puts on the wire) to and from JSON, driven by
//! interface definitions at run time, so any type can be echoed, published and called
//! without compile-time structs.
//!
//! Bytes here are the body after the 4-byte encapsulation header. `origin` is the body
//! offset of the first byte given, because alignment counts from the body's start: a
//! payload nested after other data (an action result after its status byte) decodes
//! with its real offset.
//!
//! ROS 1's serialisation is the same walk without alignment, with strings unterminated and
//! empty messages empty (`Wire::Ros1`, `encode_ros1` / `decode_ros1`).
//!
//! JSON uses the definition's field names. Encoding fills absent fields with their
//! declared default or zero, and refuses unknown fields, wrong types and out-of-range
//! numbers with the field's path, so the model can correct a call.
//!
//! Payloads come from peers, and so may definitions (ROS 1): decoding checks every count
//! against the bytes left before allocating, bounds nesting (`MAX_DEPTH`), and bounds the
//! items that take no bytes at all (an empty message in ROS 1), so what a payload decodes
//! to stays within a small multiple of its size (issue 41). Shapes built from definitions
//! alone (defaults, templates) are bounded in values (`MAX_SHAPE_VALUES`).

use serde_json::{json, Map, Number, Value};

use super::msg::{BaseType, Field, Interfaces, MessageDef, MsgError, Primitive, Shape};

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CodecError {
    #[error(transparent)]
    Type(#[from] MsgError),
    #[error("{path}: {reason}")]
    Value { path: String, reason: String },
    #[error("message ends early at byte {at} while reading {path} (payload {len} bytes)")]
    Short { path: String, at: usize, len: usize },
}

fn value_err(path: &str, reason: impl Into<String>) -> CodecError {
    CodecError::Value {
        path: if path.is_empty() {
            "message".into()
        } else {
            path.to_string()
        },
        reason: reason.into(),
    }
}

fn join(path: &str, name: &str) -> String {
    if path.is_empty() {
        name.to_string()
    } else {
        format!("{path}.{name}")
    }
}

fn width(p: Primitive) -> usize {
    match p {
        Primitive::Bool | Primitive::Byte | Primitive::Char | Primitive::I8 | Primitive::U8 => 1,
        Primitive::I16 | Primitive::U16 => 2,
        Primitive::I32 | Primitive::U32 | Primitive::F32 | Primitive::String => 4,
        Primitive::I64 | Primitive::U64 | Primitive::F64 => 8,
    }
}

/// The two serialisations the codec writes and reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Wire {
    /// ROS 2: aligned to each primitive's width, strings NUL-terminated, an empty
    /// structure one placeholder byte.
    Cdr,
    /// ROS 1: packed, strings without a terminator, an empty message no bytes.
    Ros1,
}

// ---------------------------------------------------------------- encoding

struct Writer {
    buf: Vec<u8>,
    origin: usize,
    wire: Wire,
    /// Offsets of alignment padding (other stacks leave garbage there; tests skip them).
    pads: Vec<usize>,
    /// Values the defaults of absent fields may still build (`MAX_SHAPE_VALUES`).
    shape_budget: usize,
}

impl Writer {
    fn align(&mut self, n: usize) {
        if self.wire == Wire::Ros1 {
            return;
        }
        while (self.origin + self.buf.len()) % n != 0 {
            self.pads.push(self.buf.len());
            self.buf.push(0);
        }
    }
    fn put(&mut self, bytes: &[u8]) {
        self.align(bytes.len().clamp(1, 8));
        self.buf.extend_from_slice(bytes);
    }
    fn put_len(&mut self, n: usize) {
        self.put(&(n as u32).to_le_bytes());
    }
}

/// Encode `value` as `type_name`, the first byte at body offset `origin`.
pub fn encode(
    ifaces: &Interfaces,
    type_name: &str,
    value: &Value,
    origin: usize,
) -> Result<Vec<u8>, CodecError> {
    encode_traced(ifaces, type_name, value, origin, Wire::Cdr).map(|(bytes, _)| bytes)
}

/// Encode `value` as `type_name` in ROS 1's serialisation.
pub(crate) fn encode_ros1(
    ifaces: &Interfaces,
    type_name: &str,
    value: &Value,
) -> Result<Vec<u8>, CodecError> {
    encode_traced(ifaces, type_name, value, 0, Wire::Ros1).map(|(bytes, _)| bytes)
}

/// `encode`, also returning the offsets of padding bytes.
fn encode_traced(
    ifaces: &Interfaces,
    type_name: &str,
    value: &Value,
    origin: usize,
    wire: Wire,
) -> Result<(Vec<u8>, Vec<usize>), CodecError> {
    let def = ifaces.message(type_name)?;
    let mut w = Writer {
        buf: Vec::new(),
        origin,
        wire,
        pads: Vec::new(),
        shape_budget: MAX_SHAPE_VALUES,
    };
    encode_message(ifaces, &def, value, "", 0, &mut w)?;
    Ok((w.buf, w.pads))
}

fn encode_message(
    ifaces: &Interfaces,
    def: &MessageDef,
    value: &Value,
    path: &str,
    depth: usize,
    w: &mut Writer,
) -> Result<(), CodecError> {
    too_deep(path, depth)?;
    let empty = Map::new();
    let obj = match value {
        Value::Object(m) => m,
        Value::Null => &empty,
        other => {
            return Err(value_err(
                path,
                format!("expected an object ({}), found {other}", def.name),
            ))
        }
    };
    for key in obj.keys() {
        if !def.fields.iter().any(|f| &f.name == key) {
            let names: Vec<&str> = def.fields.iter().map(|f| f.name.as_str()).collect();
            return Err(value_err(
                &join(path, key),
                format!(
                    "{} has no field {key}; its fields: {}",
                    def.name,
                    names.join(", ")
                ),
            ));
        }
    }
    if def.fields.is_empty() {
        // ROS 2 gives an empty structure one placeholder byte.
        if w.wire == Wire::Cdr {
            w.put(&[0]);
        }
        return Ok(());
    }
    for field in &def.fields {
        let fpath = join(path, &field.name);
        let given = obj.get(&field.name);
        let default;
        let v = match given {
            Some(v) => v,
            None => {
                default = field_default(ifaces, field, &mut w.shape_budget)?;
                &default
            }
        };
        encode_field(ifaces, field, v, &fpath, depth, w)?;
    }
    Ok(())
}

fn encode_field(
    ifaces: &Interfaces,
    field: &Field,
    v: &Value,
    path: &str,
    depth: usize,
    w: &mut Writer,
) -> Result<(), CodecError> {
    match field.shape {
        Shape::Single => encode_elem(ifaces, field, v, path, depth, w),
        Shape::Array(n) | Shape::Sequence { max: Some(n) } if !matches!(v, Value::Array(_)) => {
            Err(value_err(
                path,
                format!("expected an array of up to {n} items, found {v}"),
            ))
        }
        Shape::Array(n) => {
            let items = v.as_array().expect("checked above");
            if items.len() != n {
                return Err(value_err(
                    path,
                    format!("expected exactly {n} items, found {}", items.len()),
                ));
            }
            for (i, item) in items.iter().enumerate() {
                encode_elem(ifaces, field, item, &format!("{path}[{i}]"), depth, w)?;
            }
            Ok(())
        }
        Shape::Sequence { max } => {
            let items = v
                .as_array()
                .ok_or_else(|| value_err(path, format!("expected an array, found {v}")))?;
            if let Some(max) = max {
                if items.len() > max {
                    return Err(value_err(
                        path,
                        format!("at most {max} items, found {}", items.len()),
                    ));
                }
            }
            w.put_len(items.len());
            for (i, item) in items.iter().enumerate() {
                encode_elem(ifaces, field, item, &format!("{path}[{i}]"), depth, w)?;
            }
            Ok(())
        }
    }
}

fn encode_elem(
    ifaces: &Interfaces,
    field: &Field,
    v: &Value,
    path: &str,
    depth: usize,
    w: &mut Writer,
) -> Result<(), CodecError> {
    match &field.base {
        BaseType::Message(name) => {
            let def = ifaces.message(name)?;
            encode_message(ifaces, &def, v, path, depth + 1, w)
        }
        BaseType::Primitive(Primitive::String) => {
            let s = v
                .as_str()
                .ok_or_else(|| value_err(path, format!("expected a string, found {v}")))?;
            if let Some(max) = field.string_max {
                if s.len() > max {
                    return Err(value_err(
                        path,
                        format!("at most {max} bytes, found {}", s.len()),
                    ));
                }
            }
            if s.contains('\0') {
                return Err(value_err(path, "strings cannot hold NUL"));
            }
            let terminated = w.wire == Wire::Cdr;
            w.put_len(s.len() + usize::from(terminated));
            w.buf.extend_from_slice(s.as_bytes());
            if terminated {
                w.buf.push(0);
            }
            Ok(())
        }
        BaseType::Primitive(p) => encode_primitive(*p, v, path, w),
    }
}

fn int_in(v: &Value, path: &str, lo: i128, hi: i128, ty: &str) -> Result<i128, CodecError> {
    let n = match v {
        Value::Number(n) => {
            if let Some(i) = n.as_i64() {
                i as i128
            } else if let Some(u) = n.as_u64() {
                u as i128
            } else {
                let f = n.as_f64().unwrap_or(f64::NAN);
                if f.fract() != 0.0 || !f.is_finite() {
                    return Err(value_err(
                        path,
                        format!("{ty} needs a whole number, found {f}"),
                    ));
                }
                f as i128
            }
        }
        Value::Bool(b) => *b as i128,
        other => return Err(value_err(path, format!("expected {ty}, found {other}"))),
    };
    if n < lo || n > hi {
        return Err(value_err(
            path,
            format!("{n} is out of range for {ty} ({lo}..={hi})"),
        ));
    }
    Ok(n)
}

fn encode_primitive(p: Primitive, v: &Value, path: &str, w: &mut Writer) -> Result<(), CodecError> {
    let ty = p.name();
    match p {
        Primitive::Bool => {
            let b = match v {
                Value::Bool(b) => *b,
                Value::Number(n) if n.as_u64() == Some(0) || n.as_u64() == Some(1) => {
                    n.as_u64() == Some(1)
                }
                other => {
                    return Err(value_err(
                        path,
                        format!("expected true or false, found {other}"),
                    ))
                }
            };
            w.put(&[b as u8]);
        }
        Primitive::Byte | Primitive::Char | Primitive::U8 => {
            w.put(&[int_in(v, path, 0, u8::MAX as i128, ty)? as u8])
        }
        Primitive::I8 => {
            w.put(&(int_in(v, path, i8::MIN as i128, i8::MAX as i128, ty)? as i8).to_le_bytes())
        }
        Primitive::I16 => {
            w.put(&(int_in(v, path, i16::MIN as i128, i16::MAX as i128, ty)? as i16).to_le_bytes())
        }
        Primitive::U16 => w.put(&(int_in(v, path, 0, u16::MAX as i128, ty)? as u16).to_le_bytes()),
        Primitive::I32 => {
            w.put(&(int_in(v, path, i32::MIN as i128, i32::MAX as i128, ty)? as i32).to_le_bytes())
        }
        Primitive::U32 => w.put(&(int_in(v, path, 0, u32::MAX as i128, ty)? as u32).to_le_bytes()),
        Primitive::I64 => {
            w.put(&(int_in(v, path, i64::MIN as i128, i64::MAX as i128, ty)? as i64).to_le_bytes())
        }
        Primitive::U64 => w.put(&(int_in(v, path, 0, u64::MAX as i128, ty)? as u64).to_le_bytes()),
        Primitive::F32 | Primitive::F64 => {
            let f = match v {
                Value::Number(n) => n.as_f64().unwrap_or(f64::NAN),
                // A null is no number: sending it as NaN would slip past every bound.
                other => {
                    return Err(value_err(
                        path,
                        format!("expected a number ({ty}), found {other}"),
                    ))
                }
            };
            if p == Primitive::F32 {
                if f.is_finite() && f.abs() > f32::MAX as f64 {
                    return Err(value_err(path, format!("{f} is out of range for float32")));
                }
                w.put(&(f as f32).to_le_bytes());
            } else {
                w.put(&f.to_le_bytes());
            }
        }
        Primitive::String => unreachable!("strings are encoded by encode_elem"),
    }
    Ok(())
}

/// Nested messages deeper than this are refused: a type that contains itself (a peer
/// may define one) would otherwise recurse without end.
pub const MAX_DEPTH: usize = 32;

/// Most items of no bytes (elements of an empty message, in ROS 1) one payload decodes
/// to: every other item takes at least one byte of the payload.
pub(crate) const MAX_EMPTY_ITEMS: usize = 1 << 16;

/// Most values a shape built from definitions alone (a default, a template) holds:
/// nested fixed arrays multiply.
pub(crate) const MAX_SHAPE_VALUES: usize = 1 << 20;

fn too_large(path: &str) -> CodecError {
    value_err(
        path,
        format!("its definition builds more than {MAX_SHAPE_VALUES} values (nested fixed arrays?)"),
    )
}

fn too_deep(path: &str, depth: usize) -> Result<(), CodecError> {
    if depth > MAX_DEPTH {
        return Err(value_err(
            path,
            format!("messages nest more than {MAX_DEPTH} deep (a type that contains itself?)"),
        ));
    }
    Ok(())
}

/// The value an absent field takes: its declared default, else zero / empty, within
/// `budget` values (what is left of `MAX_SHAPE_VALUES` for the message being encoded).
fn field_default(
    ifaces: &Interfaces,
    field: &Field,
    budget: &mut usize,
) -> Result<Value, CodecError> {
    field_default_at(ifaces, field, 0, budget)
}

/// `budget`: values still allowed in the shape being built.
fn field_default_at(
    ifaces: &Interfaces,
    field: &Field,
    depth: usize,
    budget: &mut usize,
) -> Result<Value, CodecError> {
    too_deep(&field.name, depth)?;
    *budget = budget
        .checked_sub(1)
        .ok_or_else(|| too_large(&field.name))?;
    if let Some(text) = &field.default {
        let text = text.trim();
        if let Ok(v) = serde_json::from_str::<Value>(text) {
            return Ok(v);
        }
        return Ok(match text {
            "True" | "true" => Value::Bool(true),
            "False" | "false" => Value::Bool(false),
            _ => Value::String(text.trim_matches(|c| c == '"' || c == '\'').to_string()),
        });
    }
    Ok(match field.shape {
        Shape::Sequence { .. } => Value::Array(Vec::new()),
        Shape::Array(n) => {
            let one = elem_zero(ifaces, &field.base, depth, budget)?;
            // The copies cost what the first did (counted as it was built).
            let each = count_values(&one);
            *budget = n
                .saturating_sub(1)
                .checked_mul(each)
                .and_then(|more| budget.checked_sub(more))
                .ok_or_else(|| too_large(&field.name))?;
            Value::Array(vec![one; n])
        }
        Shape::Single => elem_zero(ifaces, &field.base, depth, budget)?,
    })
}

/// Values in `v`, itself included.
fn count_values(v: &Value) -> usize {
    match v {
        Value::Array(items) => 1 + items.iter().map(count_values).sum::<usize>(),
        Value::Object(m) => 1 + m.values().map(count_values).sum::<usize>(),
        _ => 1,
    }
}

fn elem_zero(
    ifaces: &Interfaces,
    base: &BaseType,
    depth: usize,
    budget: &mut usize,
) -> Result<Value, CodecError> {
    Ok(match base {
        BaseType::Primitive(Primitive::Bool) => Value::Bool(false),
        BaseType::Primitive(Primitive::String) => Value::String(String::new()),
        BaseType::Primitive(Primitive::F32 | Primitive::F64) => Value::from(0.0),
        BaseType::Primitive(_) => Value::from(0),
        BaseType::Message(name) => template_at(ifaces, name, depth + 1, budget)?,
    })
}

/// A complete message of `type_name` with every field at its default: what the model
/// is shown as the shape to fill in.
pub fn template(ifaces: &Interfaces, type_name: &str) -> Result<Value, CodecError> {
    let mut budget = MAX_SHAPE_VALUES;
    template_at(ifaces, type_name, 0, &mut budget)
}

fn template_at(
    ifaces: &Interfaces,
    type_name: &str,
    depth: usize,
    budget: &mut usize,
) -> Result<Value, CodecError> {
    too_deep(type_name, depth)?;
    let def = ifaces.message(type_name)?;
    let mut out = Map::new();
    for field in &def.fields {
        out.insert(
            field.name.clone(),
            field_default_at(ifaces, field, depth, budget)?,
        );
    }
    Ok(Value::Object(out))
}

/// The JSON schema of a message of `type_name` as the encoder takes it: every field
/// optional (an absent field is its default), no other key, integers within their width,
/// fixed arrays of their length. What a grammar holds a message argument to.
pub fn schema(ifaces: &Interfaces, type_name: &str) -> Result<Value, CodecError> {
    let mut budget = MAX_SHAPE_VALUES;
    schema_at(ifaces, type_name, 0, &mut budget)
}

/// `budget`: fields still allowed in the schema being built (message fields of message
/// types multiply).
fn schema_at(
    ifaces: &Interfaces,
    type_name: &str,
    depth: usize,
    budget: &mut usize,
) -> Result<Value, CodecError> {
    too_deep(type_name, depth)?;
    let def = ifaces.message(type_name)?;
    let mut properties = Map::new();
    for field in &def.fields {
        *budget = budget
            .checked_sub(1)
            .ok_or_else(|| too_large(&field.name))?;
        let one = elem_schema(ifaces, &field.base, depth, budget)?;
        let s = match field.shape {
            Shape::Single => one,
            Shape::Array(n) => json!({"type": "array", "items": one, "minItems": n, "maxItems": n}),
            Shape::Sequence { max: Some(n) } => {
                json!({"type": "array", "items": one, "maxItems": n})
            }
            Shape::Sequence { max: None } => json!({"type": "array", "items": one}),
        };
        properties.insert(field.name.clone(), s);
    }
    Ok(json!({"type": "object", "properties": properties, "additionalProperties": false}))
}

fn elem_schema(
    ifaces: &Interfaces,
    base: &BaseType,
    depth: usize,
    budget: &mut usize,
) -> Result<Value, CodecError> {
    let int = |min: i64, max: i64| json!({"type": "integer", "minimum": min, "maximum": max});
    Ok(match base {
        BaseType::Primitive(p) => match p {
            Primitive::Bool => json!({"type": "boolean"}),
            Primitive::String => json!({"type": "string"}),
            Primitive::F32 | Primitive::F64 => json!({"type": "number"}),
            Primitive::Byte | Primitive::Char | Primitive::U8 => int(0, u8::MAX.into()),
            Primitive::I8 => int(i8::MIN.into(), i8::MAX.into()),
            Primitive::I16 => int(i16::MIN.into(), i16::MAX.into()),
            Primitive::U16 => int(0, u16::MAX.into()),
            Primitive::I32 => int(i32::MIN.into(), i32::MAX.into()),
            Primitive::U32 => int(0, u32::MAX.into()),
            Primitive::I64 | Primitive::U64 => json!({"type": "integer"}),
        },
        BaseType::Message(name) => schema_at(ifaces, name, depth + 1, budget)?,
    })
}

// ---------------------------------------------------------------- decoding

struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
    origin: usize,
    wire: Wire,
    /// Items of no bytes still allowed (`MAX_EMPTY_ITEMS`).
    empty_left: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize, align: usize, path: &str) -> Result<&'a [u8], CodecError> {
        while self.wire == Wire::Cdr && (self.origin + self.pos) % align != 0 {
            self.pos += 1;
        }
        let end = self.pos + n;
        if end > self.buf.len() {
            return Err(CodecError::Short {
                path: if path.is_empty() {
                    "message".into()
                } else {
                    path.to_string()
                },
                at: self.pos,
                len: self.buf.len(),
            });
        }
        let out = &self.buf[self.pos..end];
        self.pos = end;
        Ok(out)
    }
    fn len(&mut self, path: &str) -> Result<usize, CodecError> {
        let b = self.take(4, 4, path)?;
        let n = u32::from_le_bytes(b.try_into().expect("4 bytes")) as usize;
        // Every element takes at least one byte: a larger count is a corrupt payload.
        if n > self.buf.len() - self.pos.min(self.buf.len()) + 1 {
            return Err(CodecError::Short {
                path: path.to_string(),
                at: self.pos,
                len: self.buf.len(),
            });
        }
        Ok(n)
    }
}

/// Decode a payload of `type_name` whose first byte is at body offset `origin`.
pub fn decode(
    ifaces: &Interfaces,
    type_name: &str,
    bytes: &[u8],
    origin: usize,
) -> Result<Value, CodecError> {
    decode_wire(ifaces, type_name, bytes, origin, Wire::Cdr)
}

/// Decode a ROS 1 payload of `type_name`.
pub fn decode_ros1(
    ifaces: &Interfaces,
    type_name: &str,
    bytes: &[u8],
) -> Result<Value, CodecError> {
    decode_wire(ifaces, type_name, bytes, 0, Wire::Ros1)
}

fn decode_wire(
    ifaces: &Interfaces,
    type_name: &str,
    bytes: &[u8],
    origin: usize,
    wire: Wire,
) -> Result<Value, CodecError> {
    let def = ifaces.message(type_name)?;
    let mut r = Reader {
        buf: bytes,
        pos: 0,
        origin,
        wire,
        empty_left: MAX_EMPTY_ITEMS,
    };
    decode_message(ifaces, &def, "", 0, &mut r)
}

/// A message, counted against `MAX_EMPTY_ITEMS` when it took no bytes (fields of empty
/// messages multiply as arrays of them do).
fn decode_message(
    ifaces: &Interfaces,
    def: &MessageDef,
    path: &str,
    depth: usize,
    r: &mut Reader,
) -> Result<Value, CodecError> {
    let before = r.pos;
    let v = decode_fields(ifaces, def, path, depth, r)?;
    if r.pos == before {
        r.empty_left = r.empty_left.checked_sub(1).ok_or_else(|| {
            value_err(
                path,
                format!("more than {MAX_EMPTY_ITEMS} items of no bytes: a payload cannot hold that many"),
            )
        })?;
    }
    Ok(v)
}

fn decode_fields(
    ifaces: &Interfaces,
    def: &MessageDef,
    path: &str,
    depth: usize,
    r: &mut Reader,
) -> Result<Value, CodecError> {
    too_deep(path, depth)?;
    let mut out = Map::new();
    if def.fields.is_empty() {
        // The placeholder byte; tolerate its absence at the very end.
        if r.wire == Wire::Cdr && r.pos < r.buf.len() {
            r.take(1, 1, path)?;
        }
        return Ok(Value::Object(out));
    }
    for field in &def.fields {
        let fpath = join(path, &field.name);
        let v = match field.shape {
            Shape::Single => decode_elem(ifaces, field, &fpath, depth, r)?,
            Shape::Array(n) => decode_items(ifaces, field, n, &fpath, depth, r)?,
            Shape::Sequence { .. } => {
                let n = r.len(&fpath)?;
                decode_items(ifaces, field, n, &fpath, depth, r)?
            }
        };
        out.insert(field.name.clone(), v);
    }
    Ok(Value::Object(out))
}

fn decode_items(
    ifaces: &Interfaces,
    field: &Field,
    n: usize,
    path: &str,
    depth: usize,
    r: &mut Reader,
) -> Result<Value, CodecError> {
    // Every element takes at least one byte (an empty message its placeholder): more
    // elements than bytes left is a corrupt payload or a lying definition.
    if n > r.buf.len().saturating_sub(r.pos) + 1 {
        return Err(CodecError::Short {
            path: path.to_string(),
            at: r.pos,
            len: r.buf.len(),
        });
    }
    let mut items = Vec::with_capacity(n.min(1 << 16));
    for i in 0..n {
        items.push(decode_elem(
            ifaces,
            field,
            &format!("{path}[{i}]"),
            depth,
            r,
        )?);
    }
    Ok(Value::Array(items))
}

fn decode_elem(
    ifaces: &Interfaces,
    field: &Field,
    path: &str,
    depth: usize,
    r: &mut Reader,
) -> Result<Value, CodecError> {
    let p = match &field.base {
        BaseType::Message(name) => {
            let def = ifaces.message(name)?;
            return decode_message(ifaces, &def, path, depth + 1, r);
        }
        BaseType::Primitive(p) => *p,
    };
    let b = r.take(width(p), width(p), path)?;
    Ok(match p {
        Primitive::Bool => Value::Bool(b[0] != 0),
        Primitive::Byte | Primitive::Char | Primitive::U8 => Value::from(b[0]),
        Primitive::I8 => Value::from(b[0] as i8),
        Primitive::I16 => Value::from(i16::from_le_bytes(b.try_into().expect("2"))),
        Primitive::U16 => Value::from(u16::from_le_bytes(b.try_into().expect("2"))),
        Primitive::I32 => Value::from(i32::from_le_bytes(b.try_into().expect("4"))),
        Primitive::U32 => Value::from(u32::from_le_bytes(b.try_into().expect("4"))),
        Primitive::I64 => Value::from(i64::from_le_bytes(b.try_into().expect("8"))),
        Primitive::U64 => Value::from(u64::from_le_bytes(b.try_into().expect("8"))),
        Primitive::F32 => float(f32::from_le_bytes(b.try_into().expect("4")) as f64, true),
        Primitive::F64 => float(f64::from_le_bytes(b.try_into().expect("8")), false),
        Primitive::String => {
            let n = u32::from_le_bytes(b.try_into().expect("4")) as usize;
            let raw = r.take(n, 1, path)?;
            let text = raw.strip_suffix(&[0]).unwrap_or(raw);
            Value::String(String::from_utf8_lossy(text).into_owned())
        }
    })
}

/// JSON for a float: a float32 printed with the digits it really has (0.1, not
/// 0.10000000149011612); NaN and infinities as null.
fn float(f: f64, single: bool) -> Value {
    let f = if single {
        format!("{}", f as f32).parse::<f64>().unwrap_or(f)
    } else {
        f
    };
    Number::from_f64(f)
        .map(Value::Number)
        .unwrap_or(Value::Null)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn round_trip(ty: &str, v: Value) -> Value {
        let ifaces = Interfaces::bundled();
        let bytes = encode(&ifaces, ty, &v, 0).unwrap();
        decode(&ifaces, ty, &bytes, 0).unwrap()
    }

    #[test]
    fn twist_layout_is_six_doubles() {
        let ifaces = Interfaces::bundled();
        let v = json!({"linear": {"x": 1.5}, "angular": {"z": -0.5}});
        let bytes = encode(&ifaces, "geometry_msgs/Twist", &v, 0).unwrap();
        assert_eq!(bytes.len(), 48);
        assert_eq!(&bytes[..8], &1.5f64.to_le_bytes());
        assert_eq!(&bytes[40..], &(-0.5f64).to_le_bytes());
        let back = decode(&ifaces, "geometry_msgs/msg/Twist", &bytes, 0).unwrap();
        assert_eq!(back["linear"]["x"], json!(1.5));
        assert_eq!(back["linear"]["y"], json!(0.0));
    }

    #[test]
    fn alignment_counts_from_the_origin() {
        let ifaces = Interfaces::bundled();
        // RotateAbsolute result after a one-byte status: float32 pads to offset 4.
        let bytes = encode(
            &ifaces,
            "turtlesim/action/RotateAbsolute_Result",
            &json!({"delta": 0.5}),
            1,
        )
        .unwrap();
        assert_eq!(bytes.len(), 7);
        let back = decode(&ifaces, "turtlesim/action/RotateAbsolute_Result", &bytes, 1).unwrap();
        assert_eq!(back, json!({"delta": 0.5}));
    }

    #[test]
    fn strings_sequences_nested_round_trip() {
        let v = json!({
            "header": {"stamp": {"sec": 12, "nanosec": 34}, "frame_id": "base"},
            "status": [{"level": 1, "name": "motor", "message": "warm", "hardware_id": "m1",
                        "values": [{"key": "temp", "value": "61"}]}]
        });
        let back = round_trip("diagnostic_msgs/msg/DiagnosticArray", v.clone());
        assert_eq!(back, v);
    }

    #[test]
    fn empty_messages_take_one_byte() {
        let ifaces = Interfaces::bundled();
        assert_eq!(
            encode(&ifaces, "std_srvs/srv/Empty_Request", &json!({}), 0).unwrap(),
            [0]
        );
        assert_eq!(
            decode(&ifaces, "std_srvs/srv/Empty_Response", &[0], 0).unwrap(),
            json!({})
        );
    }

    #[test]
    fn bad_values_name_the_field() {
        let ifaces = Interfaces::bundled();
        let err = encode(
            &ifaces,
            "geometry_msgs/Twist",
            &json!({"linear": {"w": 1}}),
            0,
        )
        .unwrap_err();
        assert!(err.to_string().contains("linear.w"), "{err}");
        assert!(err.to_string().contains("x, y, z"), "{err}");
        let err = encode(
            &ifaces,
            "turtlesim/srv/SetPen_Request",
            &json!({"r": 300}),
            0,
        )
        .unwrap_err();
        assert!(err.to_string().contains("out of range for uint8"), "{err}");
        let err = encode(&ifaces, "std_msgs/String", &json!({"data": 5}), 0).unwrap_err();
        assert!(err.to_string().contains("expected a string"), "{err}");
        let err = encode(&ifaces, "std_msgs/Int32", &json!({"data": 1.5}), 0).unwrap_err();
        assert!(err.to_string().contains("whole number"), "{err}");
    }

    #[test]
    fn truncated_payloads_are_errors_not_panics() {
        let ifaces = Interfaces::bundled();
        let bytes = encode(&ifaces, "std_msgs/String", &json!({"data": "hello"}), 0).unwrap();
        for cut in 0..bytes.len() {
            assert!(
                decode(&ifaces, "std_msgs/String", &bytes[..cut], 0).is_err(),
                "cut {cut}"
            );
        }
        // A sequence claiming 4 billion items.
        let huge = [0xff, 0xff, 0xff, 0xff];
        assert!(decode(
            &ifaces,
            "std_msgs/Int32MultiArray",
            &[0, 0, 0, 0, 0, 0, 0, 0, 0xff, 0xff, 0xff, 0xff],
            0
        )
        .is_err());
        assert!(decode(&ifaces, "std_msgs/UInt8MultiArray", &huge, 0).is_err());
    }

    /// Bytes made by rclpy (Jazzy, Fast DDS): see scripts/make-cdr-fixtures.py.
    #[test]
    fn matches_cdr_from_a_real_ros2_stack() {
        let ifaces = Interfaces::bundled();
        let fixtures = include_str!("../../tests/data/cdr/fixtures.jsonl");
        let mut n = 0;
        for line in fixtures.lines() {
            let case: Value = serde_json::from_str(line).unwrap();
            let ty = case["type"].as_str().unwrap();
            let hex = case["cdr"].as_str().unwrap();
            let theirs: Vec<u8> = (0..hex.len())
                .step_by(2)
                .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).unwrap())
                .collect();
            let decoded = decode(&ifaces, ty, &theirs, 0).unwrap_or_else(|e| panic!("{ty}: {e}"));
            assert_eq!(decoded, case["message"], "{ty} decoded");
            let (ours, pads) = encode_traced(&ifaces, ty, &case["message"], 0, Wire::Cdr).unwrap();
            // Fast CDR may leave unset bytes after the end, and leaves padding unset.
            assert!(
                theirs.len() >= ours.len(),
                "{ty} length {} vs {}",
                ours.len(),
                theirs.len()
            );
            for (i, (a, b)) in ours.iter().zip(&theirs).enumerate() {
                assert!(
                    a == b || pads.contains(&i) || (ty.ends_with("/Empty") && i == 0 && *b == 0),
                    "{ty} byte {i}: {a:#x} vs {b:#x}"
                );
            }
            n += 1;
        }
        assert!(n >= 19, "{n} fixtures");
    }

    #[test]
    fn items_of_no_bytes_and_shapes_of_nested_arrays_are_bounded() {
        let ifaces = Interfaces::of(&[
            ("peer/msg/Nothing", ""),
            ("peer/msg/Row", "peer/Nothing[4000] cells\n"),
            ("peer/msg/Grid", "peer/Row[4000] rows\n"),
            ("peer/msg/Small", "peer/Nothing[100] cells\n"),
        ])
        .unwrap();
        let err = decode_ros1(&ifaces, "peer/Grid", &[0; 4000]).unwrap_err();
        assert!(err.to_string().contains("items of no bytes"), "{err}");
        let err = template(&ifaces, "peer/Grid").unwrap_err();
        assert!(err.to_string().contains("more than"), "{err}");
        // Within the bounds, as before.
        let small = decode_ros1(&ifaces, "peer/Small", &[0; 100]).unwrap();
        assert_eq!(small["cells"].as_array().unwrap().len(), 100);
        assert_eq!(template(&ifaces, "peer/Small").unwrap(), small);
        // Encoding fills an absent field with its default: bounded the same way.
        let err = encode_ros1(&ifaces, "peer/Grid", &json!({})).unwrap_err();
        assert!(err.to_string().contains("more than"), "{err}");
        // Fields of message types, ten to a level, six levels: a million fields from a
        // few lines of definitions, whatever is built from them.
        let mut defs = vec![("peer/msg/L0".to_string(), String::new())];
        for level in 1..=6 {
            let fields: String = (0..10)
                .map(|i| format!("peer/L{} f{i}\n", level - 1))
                .collect();
            defs.push((format!("peer/msg/L{level}"), fields));
        }
        let defs: Vec<(&str, &str)> = defs.iter().map(|(n, t)| (n.as_str(), t.as_str())).collect();
        let ifaces = Interfaces::of(&defs).unwrap();
        assert!(schema(&ifaces, "peer/L6").is_err());
        assert!(template(&ifaces, "peer/L6").is_err());
        assert!(decode_ros1(&ifaces, "peer/L6", &[]).is_err());
        assert!(schema(&ifaces, "peer/L3").is_ok());
    }

    #[test]
    fn float32_reads_as_written() {
        let back = round_trip("turtlesim/msg/Pose", json!({"x": 5.544445, "theta": 0.1}));
        assert_eq!(back["x"], json!(5.544445));
        assert_eq!(back["theta"], json!(0.1));
    }
}
