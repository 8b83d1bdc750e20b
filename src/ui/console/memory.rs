//! The console's memory panel: what the robot keeps across sessions (its places, from
//! the robot file and taught at run time; the facts the operator stated; the latest
//! requests), for the page to list and to draw on the robot view, and what the operator
//! deletes from it. Everything shown passes the fence, as answers do.

use std::sync::Arc;

use serde::Deserialize;
use serde_json::{json, Value};

use crate::fence::Fence;
use crate::store::{same_name, Place, Store};

/// The latest requests the panel shows.
const RUNS_SHOWN: usize = 10;

/// One robot's memory as the console sees it.
pub struct Memory {
    /// The memory file, or why this session has none.
    store: Result<Arc<Store>, String>,
    /// The robot file's places (listed and drawn, never deleted here).
    file_places: Vec<Place>,
    fence: Arc<Fence>,
}

/// What the operator deletes: one of a place taught at run time, a fact (by its id),
/// the request log, or everything kept.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Forget {
    #[serde(default)]
    place: Option<String>,
    #[serde(default)]
    fact: Option<i64>,
    #[serde(default)]
    runs: bool,
    #[serde(default)]
    all: bool,
}

impl Memory {
    pub fn new(
        store: Result<Arc<Store>, String>,
        file_places: Vec<Place>,
        fence: Arc<Fence>,
    ) -> Memory {
        Memory {
            store,
            file_places,
            fence,
        }
    }

    /// No memory and no places (a console not given any).
    pub fn none() -> Memory {
        Memory::new(
            Err("this console was given no memory".into()),
            Vec::new(),
            Arc::new(Fence::default()),
        )
    }

    /// The panel's content: `places` (each with `kept_in`: "robot file" or "memory"),
    /// `facts`, the latest `runs`, and `kept` (false, with `why`, when nothing is kept).
    pub fn view(&self) -> Value {
        let file = self.file_places.iter().map(|p| self.place(p, "robot file"));
        let kept = self.store.clone().and_then(|store| {
            let read = || -> Result<Value, crate::store::StoreError> {
                let taught: Vec<Value> = store
                    .places()?
                    .iter()
                    .map(|p| self.place(p, "memory"))
                    .collect();
                let facts: Vec<Value> = store
                    .facts()?
                    .into_iter()
                    .map(|f| json!({"id": f.id, "text": self.fence.redact(&f.text), "at": f.created}))
                    .collect();
                let runs: Vec<Value> = store
                    .runs(RUNS_SHOWN)?
                    .into_iter()
                    .map(|r| {
                        json!({"at": r.at, "request": self.fence.redact(&r.request),
                               "answer": self.fence.redact(&r.answer), "finish": r.finish})
                    })
                    .collect();
                Ok(json!({"kept": true, "robot": store.robot(),
                          "places": file.clone().chain(taught).collect::<Vec<_>>(),
                          "facts": facts, "runs": runs}))
            };
            read().map_err(|e| e.to_string())
        });
        kept.unwrap_or_else(|why| {
            json!({"kept": false, "why": self.fence.redact(&why),
                   "places": file.collect::<Vec<_>>(), "facts": [], "runs": []})
        })
    }

    fn place(&self, p: &Place, kept_in: &str) -> Value {
        json!({"name": self.fence.redact(&p.name), "frame": p.frame, "x": p.x, "y": p.y,
               "yaw": p.yaw, "kept_in": kept_in})
    }

    /// Delete what `what` names; what was deleted, or why nothing was (a clear error:
    /// a robot file's place, a name or id memory does not keep).
    pub fn forget(&self, what: &Forget) -> Result<Value, String> {
        let store = self
            .store
            .as_ref()
            .map_err(|why| format!("nothing is kept this session: {why}"))?;
        let failed = |e: crate::store::StoreError| e.to_string();
        match (what.place.as_deref(), what.fact, what.runs, what.all) {
            (Some(name), None, false, false) => {
                if self.file_places.iter().any(|p| same_name(&p.name, name)) {
                    return Err(format!(
                        "{:?} is in the robot file, not in memory: edit the robot file to remove it",
                        self.fence.redact(name)
                    ));
                }
                match store.forget_place(name).map_err(failed)? {
                    true => Ok(json!({"forgot": "place", "name": self.fence.redact(name)})),
                    false => Err(format!(
                        "memory keeps no place called {:?}",
                        self.fence.redact(name)
                    )),
                }
            }
            (None, Some(id), false, false) => match store.forget_fact(id).map_err(failed)? {
                true => Ok(json!({"forgot": "fact", "id": id})),
                false => Err(format!("memory keeps no fact number {id}")),
            },
            (None, None, true, false) => {
                let n = store.forget_runs().map_err(failed)?;
                Ok(json!({"forgot": "runs", "count": n}))
            }
            (None, None, false, true) => {
                store.forget_all().map_err(failed)?;
                Ok(json!({"forgot": "all"}))
            }
            _ => Err(
                "say one thing to forget: {\"place\": NAME}, {\"fact\": ID}, {\"runs\": true} or {\"all\": true}"
                    .into(),
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn place(name: &str) -> Place {
        Place {
            name: name.into(),
            frame: "map".into(),
            x: 1.0,
            y: 2.0,
            yaw: 0.0,
            aliases: Vec::new(),
            description: String::new(),
        }
    }

    #[test]
    fn the_panel_lists_and_forgets_what_memory_keeps_and_never_the_robot_file() {
        let dir = tempfile::tempdir().unwrap();
        let store = Arc::new(Store::open(&dir.path().join("m.sqlite"), "sim").unwrap());
        store.put_place(&place("bench")).unwrap();
        let fact = store
            .add_fact("the charger is behind /secret/door")
            .unwrap();
        let fence = Arc::new(Fence::new(&["^/secret".to_string()]).unwrap());
        let m = Memory::new(Ok(store.clone()), vec![place("dock")], fence);
        let v = m.view();
        let kept: Vec<(&str, &str)> = v["places"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| (p["name"].as_str().unwrap(), p["kept_in"].as_str().unwrap()))
            .collect();
        assert_eq!(kept, [("dock", "robot file"), ("bench", "memory")]);
        assert!(!v.to_string().contains("/secret"), "{v}");
        let forget = |text: &str| m.forget(&serde_json::from_str(text).unwrap());
        assert!(forget(r#"{"place": "Dock"}"#)
            .unwrap_err()
            .contains("robot file"));
        assert!(forget(r#"{"place": "attic"}"#)
            .unwrap_err()
            .contains("no place"));
        assert!(forget(r#"{"runs": true, "all": true}"#).is_err());
        forget(r#"{"place": "bench"}"#).unwrap();
        forget(&format!(r#"{{"fact": {fact}}}"#)).unwrap();
        let v = m.view();
        assert_eq!(v["places"].as_array().unwrap().len(), 1, "{v}");
        assert_eq!(v["facts"], json!([]), "{v}");
        let none = Memory::new(
            Err("no data directory".into()),
            vec![place("dock")],
            m.fence,
        );
        assert_eq!(none.view()["kept"], false);
        assert!(none
            .forget(&Forget {
                place: None,
                fact: None,
                runs: false,
                all: true
            })
            .is_err());
    }
}
