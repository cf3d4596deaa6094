//! The noise family of the shader library (Bourque–Dudek §3.1): fractal
//! Perlin noise and the patterns built on it (clouds, turbulence, marble,
//! wood).

use noise::{NoiseFn, Perlin};

use super::Kind::{Continuous, Periodic};
use super::ParamSpec;

/// Fractal sum of 4 octaves of Perlin noise, about [−1, 1]; `abs` sums
/// |noise| (turbulence), about [0, 1].
pub(super) fn fbm(noise: &Perlin, u: f64, v: f64, scale: f64, roughness: f64, abs: bool) -> f64 {
    let (mut sum, mut norm, mut amp, mut f) = (0.0, 0.0, 1.0, scale);
    for o in 0..4 {
        // Octave offsets keep the lattice zeros of one octave off the others'.
        let off = 17.31 * f64::from(o) + 0.37;
        let n = noise.get([u * f + off, v * f - off]);
        sum += amp * if abs { n.abs() } else { n };
        norm += amp;
        amp *= roughness;
        f *= 2.0;
    }
    sum / norm
}

pub(super) const CLOUDS: &[ParamSpec] = &[
    ParamSpec::new(
        "scale",
        2.0,
        6.0,
        Continuous,
        "base frequency, cycles per unit",
    ),
    ParamSpec::new(
        "roughness",
        0.3,
        0.75,
        Continuous,
        "amplitude kept per octave",
    ),
];

pub(super) fn clouds(p: &[f64], n: &Perlin, u: f64, v: f64) -> f64 {
    0.5 + 0.7 * fbm(n, u, v, p[0], p[1], false)
}

pub(super) fn turbulence(p: &[f64], n: &Perlin, u: f64, v: f64) -> f64 {
    1.2 * fbm(n, u, v, p[0], p[1], true)
}

pub(super) const MARBLE: &[ParamSpec] = &[
    ParamSpec::new("veins", 1.0, 8.0, Continuous, "veins per unit"),
    ParamSpec::new("angle", 0.0, 180.0, Periodic, "vein direction, degrees"),
    ParamSpec::new("turbulence", 0.2, 2.5, Continuous, "vein distortion"),
];

pub(super) fn marble(p: &[f64], n: &Perlin, u: f64, v: f64) -> f64 {
    let a = p[1].to_radians();
    let d = u * a.cos() + v * a.sin();
    let t = fbm(n, u, v, 4.0, 0.5, true);
    (std::f64::consts::PI * (p[0] * d + p[2] * t))
        .sin()
        .abs()
        .sqrt()
}

pub(super) const WOOD: &[ParamSpec] = &[
    ParamSpec::new("rings", 4.0, 20.0, Continuous, "rings per unit"),
    ParamSpec::new(
        "distortion",
        0.0,
        0.6,
        Continuous,
        "grain noise in the rings",
    ),
    ParamSpec::new("sharpness", 1.0, 5.0, Continuous, "ring profile exponent"),
];

pub(super) fn wood(p: &[f64], n: &Perlin, u: f64, v: f64) -> f64 {
    // The tree's axis is off the square, so the rings are arcs.
    let r = (u + 0.4).hypot(v - 0.35);
    let g = n.get([u * 3.0 + 0.31, v * 12.0 + 0.77]);
    let c = 0.5 + 0.5 * (std::f64::consts::TAU * (p[0] * r + p[1] * g)).cos();
    c.powf(p[2])
}
