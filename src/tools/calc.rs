//! Calculation tools: fewer, well-typed tools covering ROSA's thirty (arithmetic over
//! lists, statistics, trigonometry, unit conversion, geometry). Each returns the result
//! and what it was computed from, so the model copies a number instead of doing maths.

use schemars::JsonSchema;
use serde::Deserialize;
use serde_json::{json, Value};

use super::expr;
use crate::tool::{Effect, Package, Tool, ToolContext, ToolError};

pub fn package() -> Package {
    Package::new("calc")
        .with(CalcEval)
        .with(CalcStats)
        .with(CalcConvert)
        .with(CalcGeometry)
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
        Ok(json!({"expression": args.expression, "result": value}))
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

/// The units a conversion's grammar offers, as `unit` and the temperatures read them
/// (the operator's own spelling among them, for the copy bias to find): a small model
/// otherwise writes units of its own ("100" to "30" for a percentage; a robot's topic
/// name, repeated).
const UNITS: &[&str] = &[
    "m",
    "meter",
    "meters",
    "metre",
    "metres",
    "cm",
    "mm",
    "km",
    "in",
    "inch",
    "inches",
    "ft",
    "foot",
    "feet",
    "mi",
    "mile",
    "miles",
    "rad",
    "radian",
    "radians",
    "deg",
    "degree",
    "degrees",
    "m/s",
    "km/h",
    "mph",
    "kn",
    "knot",
    "knots",
    "s",
    "sec",
    "second",
    "seconds",
    "min",
    "minute",
    "minutes",
    "h",
    "hour",
    "hours",
    "kg",
    "g",
    "lb",
    "lbs",
    "pound",
    "pounds",
    "C",
    "celsius",
    "F",
    "fahrenheit",
    "K",
    "kelvin",
];

/// (kind, factor to the kind's base unit, offset) for linear units; temperatures are special.
fn unit(u: &str) -> Option<(&'static str, f64)> {
    Some(match u.trim().to_lowercase().as_str() {
        "m" | "meter" | "meters" | "metre" | "metres" => ("length", 1.0),
        "cm" => ("length", 0.01),
        "mm" => ("length", 0.001),
        "km" => ("length", 1000.0),
        "in" | "inch" | "inches" => ("length", 0.0254),
        "ft" | "foot" | "feet" => ("length", 0.3048),
        "mi" | "mile" | "miles" => ("length", 1609.344),
        "rad" | "radian" | "radians" => ("angle", 1.0),
        "deg" | "degree" | "degrees" => ("angle", std::f64::consts::PI / 180.0),
        "m/s" | "mps" => ("speed", 1.0),
        "km/h" | "kph" | "kmh" => ("speed", 1.0 / 3.6),
        "mph" => ("speed", 0.44704),
        "kn" | "knot" | "knots" => ("speed", 1852.0 / 3600.0),
        "s" | "sec" | "second" | "seconds" => ("time", 1.0),
        "min" | "minute" | "minutes" => ("time", 60.0),
        "h" | "hour" | "hours" => ("time", 3600.0),
        "kg" => ("mass", 1.0),
        "g" => ("mass", 0.001),
        "lb" | "lbs" | "pound" | "pounds" => ("mass", 0.453_592_37),
        _ => return None,
    })
}

fn to_kelvin(v: f64, u: &str) -> Option<f64> {
    match u.trim().to_lowercase().as_str() {
        "c" | "celsius" => Some(v + 273.15),
        "f" | "fahrenheit" => Some((v - 32.0) * 5.0 / 9.0 + 273.15),
        "k" | "kelvin" => Some(v),
        _ => None,
    }
}

fn from_kelvin(k: f64, u: &str) -> Option<f64> {
    match u.trim().to_lowercase().as_str() {
        "c" | "celsius" => Some(k - 273.15),
        "f" | "fahrenheit" => Some((k - 273.15) * 9.0 / 5.0 + 32.0),
        "k" | "kelvin" => Some(k),
        _ => None,
    }
}

impl Tool for CalcConvert {
    type Args = ConvertArgs;
    const NAME: &'static str = "calc_convert";
    const EFFECT: Effect = Effect::Observes;

    fn description(&self) -> String {
        "Convert a value between units of length (m, cm, km, in, ft, mi), angle (deg, rad), speed (m/s, km/h, mph, kn), temperature (C, F, K), time (s, min, h) or mass (kg, g, lb).".into()
    }

    /// `from` and `to` held to the units it converts (`UNITS`); the prompt still shows
    /// them as text, which also takes the units' longer names.
    fn live_parameters(&self) -> Option<Value> {
        let unit = |what: &str| json!({"type": "string", "enum": UNITS, "description": what});
        Some(json!({
            "type": "object",
            "properties": {
                "value": {"type": "number"},
                "from": unit("Unit of `value`."),
                "to": unit("Unit to convert to (same kind as `from`)."),
            },
            "required": ["value", "from", "to"],
            "additionalProperties": false,
        }))
    }

    async fn call(&self, a: ConvertArgs, _: &ToolContext) -> Result<Value, ToolError> {
        let result = if let (Some(k), true) = (
            to_kelvin(a.value, &a.from),
            from_kelvin(0.0, &a.to).is_some(),
        ) {
            from_kelvin(k, &a.to)
        } else {
            match (unit(&a.from), unit(&a.to)) {
                (Some((k1, f1)), Some((k2, f2))) if k1 == k2 => Some(a.value * f1 / f2),
                (Some((k1, _)), Some((k2, _))) => {
                    return Err(ToolError::InvalidArguments(format!(
                        "cannot convert {k1} ({}) to {k2} ({})",
                        a.from, a.to
                    )))
                }
                _ => None,
            }
        };
        let result = result.ok_or_else(|| {
            ToolError::InvalidArguments(format!(
                "unknown unit {:?} or {:?}; use e.g. m, ft, deg, rad, m/s, km/h, C, F",
                a.from, a.to
            ))
        })?;
        Ok(json!({"value": a.value, "from": a.from, "to": a.to, "result": result}))
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
    fn the_grammar_offers_only_units_it_converts() {
        for u in UNITS {
            assert!(unit(u).is_some() || to_kelvin(0.0, u).is_some(), "{u}");
        }
        let live = CalcConvert.live_parameters().unwrap();
        assert_eq!(live["properties"]["from"]["enum"], json!(UNITS));
        assert_eq!(live["properties"]["to"]["enum"], json!(UNITS));
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
