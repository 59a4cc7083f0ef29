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

/// The capsules and balls of a rapier3d world (z up), plus each box as the capsules along its
/// edges of the top face so a torso shows.
pub(crate) fn spatial(colliders: &rapier3d::geometry::ColliderSet, out: &mut Vec<Shape>) {
    for (_, c) in colliders.iter() {
        let p = c.position();
        let shape = c.shape();
        if let Some(cap) = shape.as_capsule() {
            let (a, b) = (*p * cap.segment.a, *p * cap.segment.b);
            out.push(Shape::Capsule { a: a.into(), b: b.into(), radius: cap.radius });
        } else if let Some(ball) = shape.as_ball() {
            out.push(Shape::Sphere { centre: p.translation.into(), radius: ball.radius });
        } else if let Some(cuboid) = shape.as_cuboid() {
            let h = cuboid.half_extents;
            let corners = [[-h.x, -h.y], [h.x, -h.y], [h.x, h.y], [-h.x, h.y]];
            for k in 0..4 {
                let (u, v) = (corners[k], corners[(k + 1) % 4]);
                let a = *p * rapier3d::math::Vector::new(u[0], u[1], 0.0);
                let b = *p * rapier3d::math::Vector::new(v[0], v[1], 0.0);
                out.push(Shape::Capsule { a: a.into(), b: b.into(), radius: h.z.max(0.01) });
            }
        }
    }
}
