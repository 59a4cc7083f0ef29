//! A small rasteriser of robot bodies: the pictures of `coadapt render` and the pixel
//! observations of [`crate::pixels::Pixels`].
//!
//! The picture is a cabinet projection of the world (x forward, z up): planar robots, which live
//! in the y = 0 plane, appear exactly side-on; the hexapod's depth axis y is drawn receding up
//! and to the right. Frames are palette indices (one byte per pixel); [`PALETTE`] gives their
//! colours. The ground carries a tick every 0.5 m so forward motion is visible.

use crate::Shape;

/// Colours of the palette indices: sky, ground, ticks, then the body's parts in turn.
pub const PALETTE: [[u8; 3]; 10] = [
    [236, 240, 245], // sky
    [90, 90, 96],    // ground
    [40, 40, 44],    // ticks
    [200, 80, 50],   // body colours from here on
    [50, 110, 190],
    [60, 160, 90],
    [220, 160, 40],
    [140, 80, 170],
    [40, 150, 160],
    [180, 60, 110],
];

/// Cabinet projection: world (x, y, z) to picture-plane metres (u, v).
pub fn project(p: [f32; 3]) -> (f32, f32) {
    (p[0] + 0.5 * p[1], p[2] + 0.3 * p[1])
}

/// Where the picture looks and at what scale.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Pixels per metre.
    pub scale: f32,
    /// The picture-plane point at the picture's horizontal centre and its ground line.
    pub u0: f32,
    pub v0: f32,
    pub w: usize,
    pub h: usize,
}

impl Camera {
    /// Picture-plane metres to pixel coordinates.
    pub fn px(&self, u: f32, v: f32) -> (f32, f32) {
        (self.w as f32 / 2.0 + (u - self.u0) * self.scale, self.h as f32 * 0.85 - (v - self.v0) * self.scale)
    }
}

fn draw_capsule(frame: &mut [u8], cam: &Camera, a: (f32, f32), b: (f32, f32), r: f32, colour: u8) {
    let (ax, ay) = cam.px(a.0, a.1);
    let (bx, by) = cam.px(b.0, b.1);
    let r = (r * cam.scale).max(1.0);
    let (x0, x1) = ((ax.min(bx) - r).floor().max(0.0) as usize, ((ax.max(bx) + r).ceil() as usize).min(cam.w));
    let (y0, y1) = ((ay.min(by) - r).floor().max(0.0) as usize, ((ay.max(by) + r).ceil() as usize).min(cam.h));
    let (dx, dy) = (bx - ax, by - ay);
    let len2 = (dx * dx + dy * dy).max(1e-9);
    for y in y0..y1 {
        for x in x0..x1 {
            let (px, py) = (x as f32 + 0.5 - ax, y as f32 + 0.5 - ay);
            let t = ((px * dx + py * dy) / len2).clamp(0.0, 1.0);
            let (ex, ey) = (px - t * dx, py - t * dy);
            if ex * ex + ey * ey <= r * r {
                frame[y * cam.w + x] = colour;
            }
        }
    }
}

/// Draws `shapes` seen by `cam` into `frame` (`cam.w x cam.h` palette indices).
pub fn draw_frame(frame: &mut [u8], cam: &Camera, shapes: &[Shape]) {
    frame.fill(0);
    let (_, ground) = cam.px(0.0, 0.0);
    let ground = ground.max(0.0) as usize;
    for row in frame.chunks_exact_mut(cam.w).skip(ground) {
        row.fill(1);
    }
    // Ticks every 0.5 m along x at the ground line.
    let first = ((cam.u0 - cam.w as f32 / cam.scale) / 0.5).floor() as i64;
    for k in first..first + (2.0 * cam.w as f32 / cam.scale / 0.5) as i64 + 2 {
        let (x, _) = cam.px(k as f32 * 0.5, 0.0);
        if (0.0..cam.w as f32).contains(&x) {
            for y in ground..(ground + 6).min(cam.h) {
                frame[y * cam.w + x as usize] = 2;
            }
        }
    }
    // Far (large y) first, so nearer parts are drawn over them.
    let mut order: Vec<usize> = (0..shapes.len()).collect();
    let depth = |s: &Shape| match s {
        Shape::Capsule { a, b, .. } => a[1] + b[1],
        Shape::Sphere { centre, .. } => 2.0 * centre[1],
    };
    order.sort_by(|&i, &j| depth(&shapes[j]).total_cmp(&depth(&shapes[i])));
    for i in order {
        let colour = 3 + (i % (PALETTE.len() - 3)) as u8;
        match shapes[i] {
            Shape::Capsule { a, b, radius } => draw_capsule(frame, cam, project(a), project(b), radius, colour),
            Shape::Sphere { centre, radius } => {
                let c = project(centre);
                draw_capsule(frame, cam, c, c, radius, colour)
            }
        }
    }
}

/// The picture-plane box `(u_lo, u_hi, v_lo, v_hi)` of `shapes`.
pub fn extent(shapes: &[Shape]) -> (f32, f32, f32, f32) {
    let mut e = (f32::INFINITY, f32::NEG_INFINITY, f32::INFINITY, f32::NEG_INFINITY);
    let mut add = |p: [f32; 3], r: f32| {
        let (u, v) = project(p);
        e = (e.0.min(u - r), e.1.max(u + r), e.2.min(v - r), e.3.max(v + r));
    };
    for s in shapes {
        match *s {
            Shape::Capsule { a, b, radius } => {
                add(a, radius);
                add(b, radius);
            }
            Shape::Sphere { centre, radius } => add(centre, radius),
        }
    }
    e
}
