//! A pattern (Bourque–Dudek §3.1): a shader, its parameters and two
//! colours, a texture at any resolution; and its JSON form (the `--params`
//! of `texsyn match`, the stops of `texsyn match transform`).

use anyhow::{ensure, Context, Result};
use serde_json::{json, Value};

use super::shaders::{colourise, Shader, COLOUR_PARAMS};
use crate::imaging::ColorImage;

/// A shader with parameters and colours: a texture at any resolution.
#[derive(Clone, Debug)]
pub struct Pattern {
    pub shader: &'static Shader,
    pub params: Vec<f64>,
    /// RGB at pattern value 0 and 1 (may lie outside 0..=255 when the
    /// pattern never reaches 0 or 1; renders are clamped).
    pub colours: [[f64; 3]; 2],
}

impl Pattern {
    /// Renders `width`×`height`; the unit square spans the shorter side.
    pub fn render(&self, width: usize, height: usize) -> ColorImage {
        let f = self
            .shader
            .render_field(&self.params, width, height, width.min(height));
        colourise(&f, width, height, &self.colours)
    }

    /// The pattern as JSON: shader, named parameters, colours.
    pub fn to_json(&self) -> Value {
        let params: serde_json::Map<String, Value> = self
            .shader
            .params
            .iter()
            .zip(&self.params)
            .map(|(p, &v)| (p.name.to_string(), json!(round(v, 4))))
            .collect();
        let c = |c: &[f64; 3]| json!(c.map(|x| round(x, 1)));
        json!({
            "shader": self.shader.name,
            "parameters": params,
            "colours": { COLOUR_PARAMS[0]: c(&self.colours[0]), COLOUR_PARAMS[1]: c(&self.colours[1]) },
        })
    }

    /// Reads [`Pattern::to_json`] (e.g. a `--params` file of `texsyn match`).
    pub fn from_json(v: &Value) -> Result<Self> {
        let name = v["shader"]
            .as_str()
            .context("the pattern has no \"shader\" name")?;
        let shader = super::shaders::by_name(name)
            .with_context(|| format!("unknown shader '{name}' in the pattern"))?;
        let mut params = Vec::new();
        for p in shader.params {
            let x = v["parameters"][p.name]
                .as_f64()
                .with_context(|| format!("the pattern lacks parameter \"{}\" of {name}", p.name))?;
            ensure!(
                x >= p.min && x <= p.max,
                "parameter {} = {x} of {name} is outside {}..={}",
                p.name,
                p.min,
                p.max
            );
            params.push(p.legal(x));
        }
        let mut colours = [[0.0; 3]; 2];
        for (k, c) in COLOUR_PARAMS.iter().enumerate() {
            let a = v["colours"][c]
                .as_array()
                .filter(|a| a.len() == 3)
                .with_context(|| format!("the pattern lacks colour \"{c}\" as [R, G, B]"))?;
            for (i, x) in a.iter().enumerate() {
                colours[k][i] = x
                    .as_f64()
                    .filter(|x| x.is_finite())
                    .with_context(|| format!("colour \"{c}\" is not three numbers"))?;
            }
        }
        Ok(Self {
            shader,
            params,
            colours,
        })
    }
}

/// `x` rounded to `digits` decimals (for the JSON reports).
pub(super) fn round(x: f64, digits: i32) -> f64 {
    let m = 10f64.powi(digits);
    (x * m).round() / m
}
