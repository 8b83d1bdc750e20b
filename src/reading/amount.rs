//! Amounts in the argument's unit. A number argument whose tool declares its unit (in
//! its description, "Meters to drive", or its name, `theta_deg`: `units::declared`) is
//! held in a turn's grammar to the amounts the request writes in a unit of that kind,
//! converted to the argument's own: "roll 30 cm" gives a distance in meters of 0.3 or
//! -0.3, "spin 2 radians" an angle in degrees of 114.592 or -114.592, "wait two minutes"
//! a pause in seconds of 120.
//!
//! A small model copies the number it reads: asked for 50 centimeters, it drove 50
//! meters' worth (5 m, the tool's bound); asked for 1.5 radians, it turned 1.5 degrees.
//! Once the value must be one the request's amounts give in the argument's unit, the
//! number copied is right whatever unit it was said in, and an amount of another kind
//! is not taken. An argument the request already gives in its own unit is left to the
//! copy bias, as before: llguidance's number grammar offers one spelling of a value
//! ("2" or "2.0"), and a model writes either.
//!
//! Both signs are offered where a sign keeps the unit's meaning (the request's "back",
//! "right" or "clockwise" are the model's to read), and only values within the
//! argument's own bounds. An argument of a kind the request gives no amount of, and a
//! request with no unit after its numbers, leave the grammar as it was. Only the grammar
//! changes: the prompt shows the tools as before.

use serde_json::{json, Map, Value};

use crate::lexicon::same_number;
use crate::tool::schema::is_open;
use crate::units::{between, declared, Amount};

/// Significant digits of an amount converted for an argument: 0.3048 m a foot, 114.592°
/// for 2 rad (a turn of 2 rad is 114.5916°; the difference is well below what a robot
/// drives or turns).
const DIGITS: i32 = 6;

/// Hold each number argument of `schema` whose unit it declares to `amounts` of that
/// unit's kind, converted (see the module's header). Objects within it are held too, and
/// each branch of a choice of them. Whether any argument was held.
pub(crate) fn hold(schema: &mut Value, amounts: &[Amount]) -> bool {
    walk(schema, amounts, false)
}

/// Whether an argument of `schema` takes one of `amounts` in its own unit, whether or
/// not `hold` would need to convert it.
pub(crate) fn takes(schema: &Value, amounts: &[Amount]) -> bool {
    walk(&mut schema.clone(), amounts, true)
}

/// `hold` through `schema`'s branches and objects; `any_unit`: an amount already in the
/// argument's unit counts too.
fn walk(schema: &mut Value, amounts: &[Amount], any_unit: bool) -> bool {
    if amounts.is_empty() {
        return false;
    }
    let mut held = false;
    if let Some(branches) = schema.get_mut("anyOf").and_then(Value::as_array_mut) {
        for b in branches {
            held |= walk(b, amounts, any_unit);
        }
    }
    let Some(props) = schema.get_mut("properties").and_then(Value::as_object_mut) else {
        return held;
    };
    for (name, prop) in props.iter_mut() {
        held |= if is_open(prop, &["number", "integer"]) {
            hold_one(name, prop, amounts, any_unit)
        } else {
            walk(prop, amounts, any_unit)
        };
    }
    held
}

/// One number argument held to `amounts` of its declared unit's kind, within its
/// bounds (the nearest whole number for an integer); left as it is when it declares no
/// unit or none of them fits, and, unless `any_unit`, when one of them is in its unit
/// already: the copy bias writes that number as the model spells it ("2" or "2.0"),
/// which llguidance's number grammar cannot offer both of.
fn hold_one(name: &str, prop: &mut Value, amounts: &[Amount], any_unit: bool) -> bool {
    let description = prop["description"].as_str().unwrap_or_default();
    let Some(unit) = declared(description, name) else {
        return false;
    };
    let own = |a: &Amount| a.unit.kind == unit.kind && a.unit.symbols == unit.symbols;
    if !any_unit && amounts.iter().any(own) {
        return false;
    }
    let Some(obj) = prop.as_object_mut() else {
        return false;
    };
    let whole = obj.get("type").is_some_and(|t| {
        t == "integer"
            || t.as_array()
                .is_some_and(|t| !t.iter().any(|t| t == "number"))
    });
    let mut values: Vec<f64> = Vec::new();
    for a in amounts {
        let Some(v) = between(a.value, a.unit, unit) else {
            continue;
        };
        let v = if whole { v.round() } else { rounded(v) };
        let signed = a.unit.signed() && unit.signed();
        let candidates = if signed { [v.abs(), -v.abs()] } else { [v, v] };
        for v in candidates {
            if within(obj, v) && !values.iter().any(|&x| same_number(x, v)) {
                values.push(v);
            }
        }
    }
    if values.is_empty() {
        return false;
    }
    for bound in [
        "minimum",
        "maximum",
        "exclusiveMinimum",
        "exclusiveMaximum",
        "multipleOf",
        "format",
    ] {
        obj.remove(bound);
    }
    obj.insert(
        "enum".into(),
        Value::Array(values.into_iter().map(number).collect()),
    );
    true
}

/// `v` to `DIGITS` significant digits.
fn rounded(v: f64) -> f64 {
    if v == 0.0 || !v.is_finite() {
        return v;
    }
    let scale = 10f64.powi(DIGITS - 1 - v.abs().log10().floor() as i32);
    (v * scale).round() / scale
}

/// Whether `v` lies within the bounds `prop` declares.
fn within(prop: &Map<String, Value>, v: f64) -> bool {
    let at = |k: &str| prop.get(k).and_then(Value::as_f64);
    at("minimum").is_none_or(|m| v >= m)
        && at("maximum").is_none_or(|m| v <= m)
        && at("exclusiveMinimum").is_none_or(|m| v > m)
        && at("exclusiveMaximum").is_none_or(|m| v < m)
}

/// `v` as the grammar writes it: a whole number without a decimal point ("120", not
/// "120.0"), which is how a model writes one.
fn number(v: f64) -> Value {
    if v.fract() == 0.0 && v.abs() < 1e15 {
        json!(v as i64)
    } else {
        json!(v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::units::amounts;

    fn drive() -> Value {
        json!({
            "type": "object",
            "properties": {
                "span": {"type": "number", "description": "Metres to roll, -4 to 4.",
                         "minimum": -4.0, "maximum": 4.0},
                "pace": {"type": ["number", "null"], "description": "Pace in m/s, up to 1.",
                         "minimum": 0.0, "maximum": 1.0},
                "spin_deg": {"type": "integer"},
                "count": {"type": "integer", "description": "How many times."},
            },
            "required": ["span"],
        })
    }

    /// The values an argument is held to, or none.
    fn values(p: &Value) -> Option<Vec<f64>> {
        p.get("enum")?
            .as_array()?
            .iter()
            .map(Value::as_f64)
            .collect()
    }

    fn held(request: &str) -> Value {
        let mut s = drive();
        hold(&mut s, &amounts(request));
        s["properties"].clone()
    }

    #[test]
    fn an_amount_is_offered_in_the_arguments_own_unit() {
        let p = held("roll 30 centimetres at 1.8 km/h");
        assert_eq!(values(&p["span"]), Some(vec![0.3, -0.3]));
        assert!(p["span"].get("minimum").is_none());
        assert_eq!(values(&p["pace"]), Some(vec![0.5]));
        assert_eq!(values(&p["spin_deg"]), None);
        assert_eq!(values(&p["count"]), None);

        let p = held("tourne de 1 radian puis avance de 2 mètres");
        // Meters given in meters: the copy bias writes them as before.
        assert_eq!(values(&p["span"]), None);
        assert!(takes(&drive(), &amounts("roll 2 meters")));
        // A whole number of degrees: the nearest.
        assert_eq!(values(&p["spin_deg"]), Some(vec![57.0, -57.0]));
        assert_eq!(p["spin_deg"]["enum"], json!([57, -57]));
    }

    #[test]
    fn an_amount_beyond_the_bounds_or_of_no_declared_kind_leaves_the_argument_free() {
        let p = held("roll 20 feet");
        assert_eq!(values(&p["span"]), None);
        assert_eq!(p["span"]["maximum"], 4.0);
        let p = held("roll 3 and wait 10 s");
        assert_eq!(values(&p["span"]), None);
        assert_eq!(held("roll 3"), drive()["properties"]);
    }
}
