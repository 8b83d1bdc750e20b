//! Calculation tools: fewer, well-typed tools covering ROSA's thirty (arithmetic over
//! lists, statistics, trigonometry, unit conversion, geometry). Each returns the result
//! and what it was computed from, so the model copies a number instead of doing maths.

use schemars::JsonSchema;
use serde::Deserialize;
use serde_json::{json, Value};

use super::expr;
use crate::tool::schema::UNIT;
use crate::tool::{Effect, Package, Tool, ToolContext, ToolError};
use crate::units::{kinds, spellings, unit};

pub fn package() -> Package {
    Package::new("calc")
        .with(CalcEval)
        .with(CalcStats)
        .with(CalcConvert)
        .with(CalcGeometry)
}

/// Significant digits a result is shown with in a summary (the result itself is whole).
const SHOWN_DIGITS: i32 = 6;

/// `x` as a summary shows it: `SHOWN_DIGITS` significant digits, no trailing zeros
/// (0.9144000000000001 → "0.9144", 2.7777777777777777 → "2.77778").
fn shown(x: f64) -> String {
    if x == 0.0 || !x.is_finite() {
        return x.to_string();
    }
    let decimals = (SHOWN_DIGITS - 1 - x.abs().log10().floor() as i32).clamp(0, 15) as usize;
    let text = format!("{x:.decimals$}");
    if text.contains('.') {
        text.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        text
    }
}

pub(crate) struct CalcEval;

#[derive(Deserialize, JsonSchema)]
pub(crate) struct EvalArgs {
    /// An arithmetic expression, e.g. "(3 + 5) * 2", "2^10", "sqrt(2)", "sin(rad(30))".
    pub expression: String,
}

impl Tool for CalcEval {
    type Args = EvalArgs;
    const NAME: &'static str = "calc_eval";
    const EFFECT: Effect = Effect::Observes;
    const COMPUTES: bool = true;

    fn description(&self) -> String {
        "Evaluate an arithmetic expression: + - * / % ^, parentheses, sqrt, abs, sin, cos, tan, asin, acos, atan, atan2, exp, ln, log10, deg, rad, min, max, pi. Angles in radians.".into()
    }

    async fn call(&self, args: EvalArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let value = expr::eval(&args.expression).map_err(|e| match e {
            expr::ExprError::Invalid(_) => {
                ToolError::InvalidArguments(format!("{e}; write e.g. \"(3 + 5) / 2\""))
            }
            // Too long or too deep: the message says what to do.
            e => ToolError::InvalidArguments(e.to_string()),
        })?;
        let summary = format!("{} = {}", args.expression.trim(), shown(value));
        Ok(json!({"summary": summary, "expression": args.expression, "result": value}))
    }
}

pub(crate) struct CalcStats;

#[derive(Deserialize, JsonSchema, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub(crate) enum Stat {
    Mean,
    Median,
    Min,
    Max,
    Sum,
    Std,
    Variance,
    Range,
    Count,
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct StatsArgs {
    /// The numbers, e.g. [3, 5, 10].
    #[schemars(length(min = 1))]
    pub values: Vec<f64>,
    /// Which statistic to return as "result" (all are returned anyway).
    pub stat: Option<Stat>,
}

impl Tool for CalcStats {
    type Args = StatsArgs;
    const NAME: &'static str = "calc_stats";
    const EFFECT: Effect = Effect::Observes;

    fn description(&self) -> String {
        "Statistics of a list of numbers: mean, median, min, max, sum, std (population), variance, range, count.".into()
    }

    async fn call(&self, args: StatsArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let v = &args.values;
        if v.is_empty() {
            return Err(ToolError::InvalidArguments(
                "values is empty; give at least one number".into(),
            ));
        }
        let n = v.len() as f64;
        let sum: f64 = v.iter().sum();
        let mean = sum / n;
        let mut sorted = v.clone();
        sorted.sort_by(f64::total_cmp);
        let median = if sorted.len() % 2 == 1 {
            sorted[sorted.len() / 2]
        } else {
            (sorted[sorted.len() / 2 - 1] + sorted[sorted.len() / 2]) / 2.0
        };
        let variance = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
        let (min, max) = (sorted[0], sorted[sorted.len() - 1]);
        let all = json!({
            "count": v.len(), "sum": sum, "mean": mean, "median": median, "min": min,
            "max": max, "range": max - min, "variance": variance, "std": variance.sqrt(),
        });
        let mut out = json!({"values": v, "statistics": all});
        if let Some(stat) = args.stat {
            let key = match stat {
                Stat::Mean => "mean",
                Stat::Median => "median",
                Stat::Min => "min",
                Stat::Max => "max",
                Stat::Sum => "sum",
                Stat::Std => "std",
                Stat::Variance => "variance",
                Stat::Range => "range",
                Stat::Count => "count",
            };
            out["stat"] = json!(key);
            out["result"] = all[key].clone();
        }
        Ok(out)
    }
}

pub(crate) struct CalcConvert;

#[derive(Deserialize, JsonSchema)]
pub(crate) struct ConvertArgs {
    pub value: f64,
    /// Unit of `value`: m, cm, mm, km, in, ft, mi, rad, deg, m/s, km/h, mph, kn, C, F, K, s, min, h, kg, g, lb.
    pub from: String,
    /// Unit to convert to (same kind as `from`).
    pub to: String,
}

/// `value` in `from` written in `to`, when both are units of one kind
/// (`data/units.toml`).
fn convert(value: f64, from: &str, to: &str) -> Result<f64, ToolError> {
    let (Some(a), Some(b)) = (unit(from), unit(to)) else {
        return Err(ToolError::InvalidArguments(format!(
            "unknown unit {from:?} or {to:?}; use e.g. m, ft, deg, rad, m/s, km/h, C, F"
        )));
    };
    crate::units::between(value, a, b).ok_or_else(|| {
        ToolError::InvalidArguments(format!(
            "cannot convert {} ({from}) to {} ({to})",
            a.kind, b.kind
        ))
    })
}

/// `calc_convert`'s live schema: one branch a kind (`CalcConvert::live_parameters`).
fn live_units() -> Value {
    let branches: Vec<Value> = kinds()
        .into_iter()
        .map(|kind| {
            let units = spellings(kind);
            let unit = |what: &str, role: &str| {
                json!({"type": "string", "enum": units, "description": what, UNIT: role})
            };
            json!({
                "type": "object",
                "properties": {
                    "value": {"type": "number"},
                    "from": unit("Unit of `value`.", "from"),
                    "to": unit("Unit to convert to (same kind as `from`).", "to"),
                },
                "required": ["value", "from", "to"],
                "additionalProperties": false,
            })
        })
        .collect();
    json!({ "anyOf": branches })
}

impl Tool for CalcConvert {
    type Args = ConvertArgs;
    const NAME: &'static str = "calc_convert";
    const EFFECT: Effect = Effect::Observes;

    fn description(&self) -> String {
        "Convert a value between units of length (m, cm, km, in, ft, mi), angle (deg, rad), speed (m/s, km/h, mph, kn), temperature (C, F, K), time (s, min, h) or mass (kg, g, lb).".into()
    }

    /// One branch a kind of quantity, `from` and `to` held to that kind's spellings
    /// (`spellings`): a call converts between units of one kind by construction. `from`
    /// is marked the unit of the value and `to` the unit it goes to (`UNIT`), so the
    /// request's own "3 feet" gives `from` (`reading::bound`). The prompt still shows
    /// them as text. Built once: the units never change, and the agent reads the live
    /// schema on every step.
    fn live_parameters(&self) -> Option<Value> {
        static LIVE: std::sync::OnceLock<Value> = std::sync::OnceLock::new();
        Some(LIVE.get_or_init(live_units).clone())
    }

    async fn call(&self, a: ConvertArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let result = convert(a.value, &a.from, &a.to)?;
        let summary = format!(
            "{} {} = {} {}",
            shown(a.value),
            a.from.trim(),
            shown(result),
            a.to.trim()
        );
        Ok(
            json!({"summary": summary, "value": a.value, "from": a.from, "to": a.to, "result": result}),
        )
    }
}

pub(crate) struct CalcGeometry;

#[derive(Deserialize, JsonSchema, Clone, Copy)]
#[serde(rename_all = "lowercase")]
pub(crate) enum GeoOp {
    /// Straight-line distance from a to b.
    Distance,
    /// Direction from a to b, radians and degrees, counter-clockwise from +x.
    Heading,
    /// The point halfway between a and b.
    Midpoint,
}

#[derive(Deserialize, JsonSchema)]
pub(crate) struct GeometryArgs {
    pub op: GeoOp,
    /// First point [x, y].
    pub a: [f64; 2],
    /// Second point [x, y].
    pub b: [f64; 2],
}

impl Tool for CalcGeometry {
    type Args = GeometryArgs;
    const NAME: &'static str = "calc_geometry";
    const EFFECT: Effect = Effect::Observes;

    fn description(&self) -> String {
        "Plane geometry between two points a and b ([x, y] in meters): distance, heading (angle from +x, counter-clockwise) or midpoint.".into()
    }

    async fn call(&self, g: GeometryArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let (dx, dy) = (g.b[0] - g.a[0], g.b[1] - g.a[1]);
        Ok(match g.op {
            GeoOp::Distance => json!({"op": "distance", "result": dx.hypot(dy)}),
            GeoOp::Heading => {
                let r = dy.atan2(dx);
                json!({"op": "heading", "result": r, "radians": r, "degrees": r.to_degrees()})
            }
            GeoOp::Midpoint => {
                json!({"op": "midpoint", "result": [(g.a[0] + g.b[0]) / 2.0, (g.a[1] + g.b[1]) / 2.0]})
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn cx() -> ToolContext {
        ToolContext::new(Duration::from_secs(1))
    }

    #[test]
    fn the_grammar_offers_only_units_it_converts_one_kind_a_call() {
        let live = CalcConvert.live_parameters().unwrap();
        let branches = live["anyOf"].as_array().unwrap();
        assert_eq!(branches.len(), kinds().len());
        for b in branches {
            let from: Vec<&str> = b["properties"]["from"]["enum"]
                .as_array()
                .unwrap()
                .iter()
                .map(|u| u.as_str().unwrap())
                .collect();
            assert_eq!(
                b["properties"]["to"]["enum"],
                b["properties"]["from"]["enum"]
            );
            let kind = &unit(from[0]).unwrap().kind;
            for u in from {
                assert_eq!(&unit(u).unwrap().kind, kind, "{u}");
            }
        }
        // Every symbol the prompt names is read.
        for u in [
            "m", "cm", "km", "in", "ft", "mi", "deg", "rad", "m/s", "km/h", "mph",
        ] {
            assert!(unit(u).is_some(), "{u}");
        }
        for u in ["kn", "C", "F", "K", "s", "min", "h", "kg", "g", "lb"] {
            assert!(unit(u).is_some(), "{u}");
        }
    }

    #[test]
    fn units_are_read_in_each_language_and_converted_both_ways() {
        let close = |a: f64, b: f64| (a - b).abs() < 1e-9 * b.abs().max(1.0);
        assert!(close(
            convert(180.0, "Grad", "radianes").unwrap(),
            std::f64::consts::PI
        ));
        assert!(close(convert(1.0, "quilômetros", "m").unwrap(), 1000.0));
        assert!(close(
            convert(36.0, "km/h", "mètres par seconde").unwrap(),
            10.0
        ));
        assert!(close(convert(1.0, "nœud", "km/h").unwrap(), 1.852));
        assert!(close(
            convert(-40.0, "°F", "grados celsius").unwrap(),
            -40.0
        ));
        assert!(close(convert(0.0, "K", "C").unwrap(), -273.15));
        assert!(close(convert(2.0, "Stunden", "min").unwrap(), 120.0));
        let out = run(
            CalcConvert,
            json!({"value": 3, "from": "feet", "to": "meters"}),
        )
        .unwrap();
        assert_eq!(out["summary"], "3 feet = 0.9144 meters");
        assert_eq!(shown(2.0 / 3.0 * 100.0), "66.6667");
        assert_eq!(shown(1_609_344.0), "1609344");
        assert_eq!(shown(-0.000_123_456_7), "-0.000123457");
        for (v, a, b) in [(5.0, "ft", "cm"), (21.5, "C", "F"), (3.0, "lb", "gramm")] {
            let there = convert(v, a, b).unwrap();
            assert!(close(convert(there, b, a).unwrap(), v), "{a} {b}");
        }
    }

    fn run<T: Tool>(t: T, args: Value) -> Result<Value, ToolError> {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let tool = crate::tool::registry::erase(t);
        rt.block_on(tool.call(args, &cx()))
    }

    #[test]
    fn stats_give_the_mean_and_everything_else() {
        let out = run(CalcStats, json!({"values": [3, 5, 10], "stat": "mean"})).unwrap();
        assert_eq!(out["result"], json!(6.0));
        assert_eq!(out["statistics"]["median"], json!(5.0));
        assert_eq!(out["statistics"]["count"], json!(3));
    }

    #[test]
    fn conversions_and_their_errors() {
        let out = run(CalcConvert, json!({"value": 5, "from": "ft", "to": "m"})).unwrap();
        assert!((out["result"].as_f64().unwrap() - 1.524).abs() < 1e-9);
        let out = run(CalcConvert, json!({"value": 100, "from": "C", "to": "F"})).unwrap();
        assert!((out["result"].as_f64().unwrap() - 212.0).abs() < 1e-9);
        let err = run(CalcConvert, json!({"value": 1, "from": "m", "to": "deg"})).unwrap_err();
        assert!(err.to_string().contains("cannot convert length"), "{err}");
    }

    #[test]
    fn geometry_and_eval() {
        let out = run(
            CalcGeometry,
            json!({"op": "distance", "a": [0, 0], "b": [3, 4]}),
        )
        .unwrap();
        assert_eq!(out["result"], json!(5.0));
        let out = run(CalcEval, json!({"expression": "2^10"})).unwrap();
        assert_eq!(out["result"], json!(1024.0));
        assert!(run(CalcEval, json!({"expression": "2 +"})).is_err());
    }
}
