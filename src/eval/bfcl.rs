//! Berkeley Function Calling Leaderboard files as published: one JSON object per line
//! (`id`, `question`, `function`), answers in `possible_answer/<same name>`. Function docs
//! use Python-flavoured types (`dict`, `float`, `tuple`, `any`); they become JSON schema.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use serde::Deserialize;
use serde_json::{json, Map, Value};

use crate::tool::ToolSpec;

/// One function of an expected answer: its name and allowed argument values.
type Answer = (String, Map<String, Value>);

#[derive(Debug, thiserror::Error)]
pub enum BfclError {
    #[error("cannot read {path}: {message}")]
    Read { path: PathBuf, message: String },
    #[error("{path} line {line}: {message}")]
    Line {
        path: PathBuf,
        line: usize,
        message: String,
    },
}

#[derive(Debug, Clone, Deserialize)]
struct RawCase {
    id: String,
    question: Vec<Vec<Value>>,
    function: Vec<Value>,
}

/// One question with its functions and, when published, the allowed answers.
#[derive(Debug, Clone)]
pub struct Case {
    pub id: String,
    pub category: String,
    /// The first turn's messages (role, content).
    pub messages: Vec<(String, String)>,
    pub functions: Vec<ToolSpec>,
    /// Declared parameter types per function (for the checker's type rules).
    pub types: HashMap<String, Map<String, Value>>,
    /// Expected calls: function name → parameter → allowed values. Empty for irrelevance.
    pub answer: Vec<(String, Map<String, Value>)>,
}

/// Category from a file name: `BFCL_v4_simple_python.json` → `simple_python`.
pub(crate) fn category_of(path: &Path) -> String {
    let stem = path
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("unknown");
    let rest = stem.strip_prefix("BFCL_").unwrap_or(stem);
    match rest.split_once('_') {
        Some((v, cat)) if v.starts_with('v') => cat.to_string(),
        _ => rest.to_string(),
    }
}

/// Python-flavoured BFCL types to JSON schema.
pub(crate) fn to_schema(p: &Value) -> Value {
    let Some(obj) = p.as_object() else {
        return json!({});
    };
    let mut out = Map::new();
    let ty = obj.get("type").and_then(Value::as_str).unwrap_or("any");
    match ty {
        "dict" | "object" => {
            out.insert("type".into(), json!("object"));
            let props: Map<String, Value> = obj
                .get("properties")
                .and_then(Value::as_object)
                .map(|m| m.iter().map(|(k, v)| (k.clone(), to_schema(v))).collect())
                .unwrap_or_default();
            out.insert("properties".into(), Value::Object(props));
            if let Some(r) = obj.get("required") {
                out.insert("required".into(), r.clone());
            }
        }
        "float" | "number" => {
            out.insert("type".into(), json!("number"));
        }
        "integer" | "int" => {
            out.insert("type".into(), json!("integer"));
        }
        "string" | "str" => {
            out.insert("type".into(), json!("string"));
        }
        "boolean" | "bool" => {
            out.insert("type".into(), json!("boolean"));
        }
        "array" | "tuple" | "list" => {
            out.insert("type".into(), json!("array"));
            if let Some(items) = obj.get("items") {
                out.insert("items".into(), to_schema(items));
            }
        }
        // "any" and unknown types: any JSON value.
        _ => {}
    }
    if let Some(e) = obj.get("enum") {
        out.insert("enum".into(), e.clone());
    }
    if let Some(d) = obj.get("description").and_then(Value::as_str) {
        out.insert("description".into(), json!(d));
    }
    Value::Object(out)
}

fn read_lines(path: &Path) -> Result<Vec<(usize, Value)>, BfclError> {
    let text = std::fs::read_to_string(path).map_err(|e| BfclError::Read {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| {
            serde_json::from_str(l)
                .map(|v| (i + 1, v))
                .map_err(|e| BfclError::Line {
                    path: path.to_path_buf(),
                    line: i + 1,
                    message: e.to_string(),
                })
        })
        .collect()
}

/// Load a category file and its answers (from `possible_answer/` beside it, if any):
/// the questions after the first `skip`, at most `limit` of them.
pub fn load(path: &Path, skip: usize, limit: Option<usize>) -> Result<Vec<Case>, BfclError> {
    let category = category_of(path);
    let answers_path = path
        .parent()
        .unwrap_or(Path::new("."))
        .join("possible_answer")
        .join(path.file_name().unwrap_or_default());
    let mut answers: HashMap<String, Vec<Answer>> = HashMap::new();
    if answers_path.exists() {
        for (_, v) in read_lines(&answers_path)? {
            let id = v["id"].as_str().unwrap_or_default().to_string();
            let calls = v["ground_truth"]
                .as_array()
                .map(|a| {
                    a.iter()
                        .filter_map(|c| {
                            c.as_object()?.iter().next().map(|(k, v)| {
                                (k.clone(), v.as_object().cloned().unwrap_or_default())
                            })
                        })
                        .collect()
                })
                .unwrap_or_default();
            answers.insert(id, calls);
        }
    }
    let mut cases = Vec::new();
    for (line, v) in read_lines(path)?.into_iter().skip(skip) {
        let err = |message: String| BfclError::Line {
            path: path.to_path_buf(),
            line,
            message,
        };
        let raw: RawCase = serde_json::from_value(v).map_err(|e| err(e.to_string()))?;
        let messages = raw
            .question
            .first()
            .map(|turn| {
                turn.iter()
                    .map(|m| {
                        (
                            m["role"].as_str().unwrap_or("user").to_string(),
                            m["content"].as_str().unwrap_or_default().to_string(),
                        )
                    })
                    .collect()
            })
            .unwrap_or_default();
        let mut functions = Vec::new();
        let mut types = HashMap::new();
        for f in &raw.function {
            let name = f["name"].as_str().unwrap_or_default();
            let schema = to_schema(&f["parameters"]);
            let declared = f["parameters"]["properties"]
                .as_object()
                .cloned()
                .unwrap_or_default();
            types.insert(name.to_string(), declared);
            let spec = ToolSpec::new(name, f["description"].as_str().unwrap_or_default(), schema)
                .map_err(|e| err(e.to_string()))?;
            functions.push(spec);
        }
        let answer = answers.remove(&raw.id).unwrap_or_default();
        cases.push(Case {
            id: raw.id,
            category: category.clone(),
            messages,
            functions,
            types,
            answer,
        });
        if limit.is_some_and(|n| cases.len() >= n) {
            break;
        }
    }
    Ok(cases)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn python_types_become_json_schema() {
        let s = to_schema(&json!({
            "type": "dict",
            "properties": {
                "a": {"type": "float", "description": "x"},
                "b": {"type": "tuple", "items": {"type": "integer"}},
                "c": {"type": "any"},
                "d": {"type": "string", "enum": ["x", "y"]}
            },
            "required": ["a"]
        }));
        assert_eq!(s["type"], json!("object"));
        assert_eq!(s["properties"]["a"]["type"], json!("number"));
        assert_eq!(
            s["properties"]["b"],
            json!({"type": "array", "items": {"type": "integer"}})
        );
        assert_eq!(s["properties"]["c"], json!({}));
        assert_eq!(s["properties"]["d"]["enum"], json!(["x", "y"]));
        assert_eq!(s["required"], json!(["a"]));
    }

    #[test]
    fn categories_from_file_names() {
        assert_eq!(
            category_of(Path::new("x/BFCL_v4_simple_python.json")),
            "simple_python"
        );
        assert_eq!(
            category_of(Path::new("BFCL_v3_parallel_multiple.json")),
            "parallel_multiple"
        );
    }

    #[test]
    fn skip_and_limit_pick_questions_and_keep_their_answers() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("BFCL_v4_simple_python.json");
        let question = |i: usize| {
            json!({
                "id": format!("simple_python_{i}"),
                "question": [[{"role": "user", "content": format!("area of a square of side {i}")}]],
                "function": [{
                    "name": "square_area",
                    "description": "Area of a square.",
                    "parameters": {"type": "dict", "properties": {"side": {"type": "integer"}}, "required": ["side"]}
                }]
            })
            .to_string()
        };
        let lines: Vec<String> = (0..4).map(question).collect();
        std::fs::write(&path, lines.join("\n")).unwrap();
        std::fs::create_dir(dir.path().join("possible_answer")).unwrap();
        let answers: Vec<String> = (0..4)
            .map(|i| {
                json!({"id": format!("simple_python_{i}"), "ground_truth": [{"square_area": {"side": [i]}}]})
                    .to_string()
            })
            .collect();
        std::fs::write(
            dir.path()
                .join("possible_answer")
                .join("BFCL_v4_simple_python.json"),
            answers.join("\n"),
        )
        .unwrap();

        let cases = load(&path, 1, Some(2)).unwrap();
        let ids: Vec<&str> = cases.iter().map(|c| c.id.as_str()).collect();
        assert_eq!(ids, ["simple_python_1", "simple_python_2"]);
        assert_eq!(cases[1].answer[0].1["side"], json!([2]));
        assert_eq!(load(&path, 0, None).unwrap().len(), 4);
        assert!(load(&path, 9, Some(2)).unwrap().is_empty());
    }
}
