//! A rapier world's colliders as [`Shape`]s for pictures (`coadapt render`): capsules and balls,
//! in the world frame of [`Shape`] (x forward, z up; a planar world's y becomes z).

use coadapt_core::Shape;

/// The capsules and balls of a rapier2d world (the ground, a half-space, is left out).
pub(crate) fn planar(colliders: &rapier2d::geometry::ColliderSet, out: &mut Vec<Shape>) {
    for (_, c) in colliders.iter() {
        let p = c.position();
        if let Some(cap) = c.shape().as_capsule() {
            let (a, b) = (*p * cap.segment.a, *p * cap.segment.b);
            out.push(Shape::Capsule { a: [a.x, 0.0, a.y], b: [b.x, 0.0, b.y], radius: cap.radius });
        } else if let Some(ball) = c.shape().as_ball() {
            let t = p.translation;
            out.push(Shape::Sphere { centre: [t.x, 0.0, t.y], radius: ball.radius });
        }
    }
}
