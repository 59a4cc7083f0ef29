//! A body drawn as SVG: the robot reset at a design (seed 0) and its shapes projected as
//! `coadapt render` projects them (side-on for the planar robots), each part in the palette's
//! colours, on a ground line. Vector, so the page stays small and sharp at any zoom.

use std::collections::HashMap;
use std::fmt::Write as _;
use std::sync::Mutex;

use coadapt_core::render::{PALETTE, project};
use coadapt_core::{Env, Shape};

/// Draws bodies of one robot at one scale (the largest body of the design box fills the
/// picture, so that two pictures compare), remembering the last few.
pub struct Bodies {
    env: Mutex<Option<Box<dyn Env>>>,
    /// The design box's upper corner: the largest body, whose extent sets the scale.
    largest: Vec<f32>,
    drawn: Mutex<HashMap<Vec<u32>, String>>,
}

impl std::fmt::Debug for Bodies {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Bodies").finish_non_exhaustive()
    }
}

impl Bodies {
    /// `env`: the run's robot, or `None` where the page cannot build one (a robot served
    /// elsewhere: the page does not connect to hardware to draw it).
    pub fn new(env: Option<Box<dyn Env>>) -> Self {
        let largest = env.as_ref().map(|e| e.spec().design.high.clone()).unwrap_or_default();
        Self { env: Mutex::new(env), largest, drawn: Mutex::new(HashMap::new()) }
    }

    fn shapes(&self, design: &[f32]) -> Option<Vec<Shape>> {
        let mut env = self.env.lock().unwrap_or_else(|e| e.into_inner());
        let env = env.as_mut()?;
        env.reset(0, design).ok()?;
        let mut shapes = Vec::new();
        env.draw(&mut shapes);
        (!shapes.is_empty()).then_some(shapes)
    }

    /// The body at `design` as an `<svg>` element `w` x `h`, or `None` when the robot cannot
    /// be drawn here.
    pub fn svg(&self, design: &[f32], w: u32, h: u32) -> Option<String> {
        let key: Vec<u32> = design.iter().map(|v| v.to_bits()).chain([w, h]).collect();
        if let Some(s) = self.drawn.lock().unwrap_or_else(|e| e.into_inner()).get(&key) {
            return Some(s.clone());
        }
        let shapes = self.shapes(design)?;
        let (wl, hl) = self.shapes(&self.largest).map_or_else(|| size(&shapes), |l| size(&l));
        let scale = ((w as f32 - 16.0) / wl.max(1e-3)).min((h as f32 - 16.0) / hl.max(1e-3));
        let svg = draw(&shapes, w, h, scale);
        let mut drawn = self.drawn.lock().unwrap_or_else(|e| e.into_inner());
        if drawn.len() > 64 {
            drawn.clear();
        }
        drawn.insert(key, svg.clone());
        Some(svg)
    }
}

fn colour(i: usize) -> String {
    let [r, g, b] = PALETTE[3 + i % (PALETTE.len() - 3)];
    format!("#{r:02x}{g:02x}{b:02x}")
}

/// The width and height (picture-plane metres, the ground included) of `shapes`.
fn size(shapes: &[Shape]) -> (f32, f32) {
    let (lo, hi) = extent(shapes);
    (hi[0] - lo[0], hi[1] - lo[1])
}

/// The picture-plane box of `shapes`, the ground (v = 0) included.
fn extent(shapes: &[Shape]) -> ([f32; 2], [f32; 2]) {
    let (mut lo, mut hi) = ([f32::INFINITY; 2], [f32::NEG_INFINITY; 2]);
    let mut grow = |(u, v): (f32, f32), r: f32| {
        lo = [lo[0].min(u - r), lo[1].min(v - r)];
        hi = [hi[0].max(u + r), hi[1].max(v + r)];
    };
    for s in shapes {
        match *s {
            Shape::Capsule { a, b, radius } => {
                grow(project(a), radius);
                grow(project(b), radius);
            }
            Shape::Sphere { centre, radius } => grow(project(centre), radius),
        }
    }
    lo[1] = lo[1].min(0.0);
    (lo, hi)
}

/// The shapes at `scale` pixels per metre in `w` x `h`, centred, standing on the ground line
/// (v = 0, or the lowest point if that is lower).
fn draw(shapes: &[Shape], w: u32, h: u32, scale: f32) -> String {
    let (lo, hi) = extent(shapes);
    let (wf, hf) = (w as f32, h as f32);
    let left = (wf - (hi[0] - lo[0]) * scale) / 2.0;
    let px = |(u, v): (f32, f32)| (left + (u - lo[0]) * scale, hf - 8.0 - (v - lo[1]) * scale);
    let mut out = format!(r##"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" role="img">"##);
    let (_, ground) = px((0.0, 0.0));
    let _ = write!(out, r##"<line x1="0" y1="{ground:.1}" x2="{wf}" y2="{ground:.1}" stroke="#5a5a60" stroke-width="2"/>"##);
    for (i, s) in shapes.iter().enumerate() {
        let c = colour(i);
        match *s {
            Shape::Capsule { a, b, radius } => {
                let ((x1, y1), (x2, y2)) = (px(project(a)), px(project(b)));
                let sw = (2.0 * radius * scale).max(1.0);
                let _ = write!(
                    out,
                    r##"<line x1="{x1:.1}" y1="{y1:.1}" x2="{x2:.1}" y2="{y2:.1}" stroke="{c}" stroke-width="{sw:.1}" stroke-linecap="round"/>"##
                );
            }
            Shape::Sphere { centre, radius } => {
                let (x, y) = px(project(centre));
                let _ = write!(out, r##"<circle cx="{x:.1}" cy="{y:.1}" r="{:.1}" fill="{c}"/>"##, (radius * scale).max(1.0));
            }
        }
    }
    out.push_str("</svg>");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_body_fits_its_box_and_sits_on_the_ground() {
        let shapes = [
            Shape::Capsule { a: [0.0, 0.0, 0.5], b: [1.0, 0.0, 0.5], radius: 0.1 },
            Shape::Sphere { centre: [0.5, 0.0, 0.9], radius: 0.2 },
        ];
        let (w, h) = size(&shapes);
        assert!((w - 1.2).abs() < 1e-6 && (h - 1.1).abs() < 1e-6, "{w} x {h}");
        let s = draw(&shapes, 200, 100, (184.0 / w).min(84.0 / h));
        assert!(s.starts_with("<svg") && s.ends_with("</svg>"));
        assert_eq!(s.matches("<line").count(), 2);
        assert_eq!(s.matches("<circle").count(), 1);
        // Every coordinate inside the picture.
        for part in s.split('"') {
            if let Ok(v) = part.parse::<f32>() {
                assert!((0.0..=200.0).contains(&v), "{v} outside the picture in {s}");
            }
        }
    }
}
