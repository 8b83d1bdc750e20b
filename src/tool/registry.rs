//! The registry: tools erased to `DynTool` (JSON arguments in, JSON out), grouped in
//! named packages that a robot enables or not.

use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;

use serde_json::Value;

use super::{schema, Effect, Tool, ToolContext, ToolError, ToolSpec};

pub type BoxFuture<'a, T> = Pin<Box<dyn Future<Output = T> + Send + 'a>>;

/// A tool with its types erased: what the agent runs.
pub trait DynTool: Send + Sync {
    fn spec(&self) -> &ToolSpec;
    fn effect(&self) -> Effect;
    /// The spec with the arguments the robot can take now (`Tool::live_parameters`),
    /// when they are narrower than the spec's.
    fn live_spec(&self) -> Option<ToolSpec> {
        None
    }
    /// How long a call may take unless the policy says (`Tool::time_limit`).
    fn time_limit(&self) -> Option<std::time::Duration> {
        None
    }
    /// Run with JSON arguments (already validated against the schema by the policy).
    fn call<'a>(
        &'a self,
        args: Value,
        cx: &'a ToolContext,
    ) -> BoxFuture<'a, Result<Value, ToolError>>;
}

struct Typed<T: Tool> {
    tool: T,
    spec: ToolSpec,
}

impl<T: Tool> DynTool for Typed<T> {
    fn spec(&self) -> &ToolSpec {
        &self.spec
    }

    fn effect(&self) -> Effect {
        T::EFFECT
    }

    fn time_limit(&self) -> Option<std::time::Duration> {
        self.tool.time_limit()
    }

    fn live_spec(&self) -> Option<ToolSpec> {
        let parameters = self.tool.live_parameters()?;
        Some(ToolSpec {
            parameters,
            ..self.spec.clone()
        })
    }

    fn call<'a>(
        &'a self,
        args: Value,
        cx: &'a ToolContext,
    ) -> BoxFuture<'a, Result<Value, ToolError>> {
        Box::pin(async move {
            let args: T::Args = serde_json::from_value(args)
                .map_err(|e| ToolError::InvalidArguments(e.to_string()))?;
            self.tool.call(args, cx).await
        })
    }
}

/// Erase a typed tool; its schema comes from `T::Args`.
pub(crate) fn erase<T: Tool>(tool: T) -> Arc<dyn DynTool> {
    let mut spec = ToolSpec::new(T::NAME, tool.description(), schema::schema_for::<T::Args>())
        .unwrap_or_else(|e| panic!("tool {} has an invalid schema: {e}", T::NAME));
    spec.sequence = T::SEQUENCE.iter().map(|s| s.to_string()).collect();
    spec.records = T::RECORDS;
    spec.computes = T::COMPUTES;
    spec.lists = T::LISTS.map(str::to_string);
    Arc::new(Typed { tool, spec })
}

/// A named group of tools ("calc", "system", "ros", "turtle").
#[derive(Clone)]
pub struct Package {
    pub name: String,
    pub tools: Vec<Arc<dyn DynTool>>,
}

impl Package {
    pub fn new(name: impl Into<String>) -> Package {
        Package {
            name: name.into(),
            tools: Vec::new(),
        }
    }

    pub fn with<T: Tool>(mut self, tool: T) -> Package {
        self.tools.push(erase(tool));
        self
    }

    pub fn with_dyn(mut self, tool: Arc<dyn DynTool>) -> Package {
        self.tools.push(tool);
        self
    }
}

#[derive(Default, Clone)]
pub struct Registry {
    tools: Vec<(String, Arc<dyn DynTool>)>,
}

impl Registry {
    pub fn new() -> Registry {
        Registry::default()
    }

    /// Add a package's tools; a later tool with a taken name replaces the earlier one
    /// (a robot package may override a generic tool).
    pub fn add(&mut self, package: Package) -> &mut Registry {
        for t in package.tools {
            let name = t.spec().name.clone();
            self.tools.retain(|(_, x)| x.spec().name != name);
            self.tools.push((package.name.clone(), t));
        }
        self
    }

    pub fn get(&self, name: &str) -> Option<&Arc<dyn DynTool>> {
        self.tools
            .iter()
            .find(|(_, t)| t.spec().name == name)
            .map(|(_, t)| t)
    }

    pub fn tools(&self) -> impl Iterator<Item = &Arc<dyn DynTool>> {
        self.tools.iter().map(|(_, t)| t)
    }

    pub fn specs(&self) -> Vec<ToolSpec> {
        self.tools().map(|t| t.spec().clone()).collect()
    }

    /// Drop every tool that actuates (`--read-only`).
    /// Only the observing tools, and the actuating ones `keep` names (those some of
    /// whose calls the policy counts as observing).
    pub(crate) fn without_actuators(&self, keep: impl Fn(&str) -> bool) -> Registry {
        Registry {
            tools: self
                .tools
                .iter()
                .filter(|(_, t)| t.effect() != Effect::Actuates || keep(&t.spec().name))
                .cloned()
                .collect(),
        }
    }

    pub fn len(&self) -> usize {
        self.tools.len()
    }

    pub fn is_empty(&self) -> bool {
        self.tools.is_empty()
    }
}
