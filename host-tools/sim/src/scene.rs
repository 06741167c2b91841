//! A deterministic 2-D world around the sensor, and what a laser beam sees in it.
//!
//! The sensor sits at the origin looking along +x; angles grow counter-clockwise, as
//! SCIP steps do. Surfaces are line segments (walls, box sides, glass) and moving
//! circles. A beam returns up to three echoes: glass reflects part of the light and lets
//! the rest through, and a beam whose footprint straddles an edge sees both the near and
//! the far surface (multi-echo, scip-reference §4 H*/N*).

/// A surface: what it reflects and what it lets through.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Surface {
    /// Diffuse reflectance, white paper = 1.0.
    pub reflectance: f64,
    /// Part of the light that passes through (0 = opaque; glass ≈ 0.8).
    pub transmittance: f64,
}

impl Surface {
    /// An opaque surface of the given reflectance.
    pub const fn opaque(reflectance: f64) -> Self {
        Self {
            reflectance,
            transmittance: 0.0,
        }
    }

    /// Window glass: a weak reflection, most light passes.
    pub const GLASS: Surface = Surface {
        reflectance: 0.08,
        transmittance: 0.8,
    };
}

/// A straight surface from `a` to `b` (metres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    /// One end.
    pub a: (f64, f64),
    /// The other end.
    pub b: (f64, f64),
    /// Its surface.
    pub surface: Surface,
}

/// A round object moving back and forth between two points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mover {
    /// Where it starts (metres).
    pub from: (f64, f64),
    /// Where it turns back (metres).
    pub to: (f64, f64),
    /// Time for one way, seconds.
    pub period_s: f64,
    /// Radius, metres.
    pub radius: f64,
    /// Its surface.
    pub surface: Surface,
}

impl Mover {
    /// Its centre at time `t` seconds (a triangle wave between `from` and `to`).
    pub fn centre(&self, t: f64) -> (f64, f64) {
        let p = if self.period_s > 0.0 {
            let phase = (t / self.period_s).rem_euclid(2.0);
            if phase > 1.0 {
                2.0 - phase
            } else {
                phase
            }
        } else {
            0.0
        };
        (
            self.from.0 + (self.to.0 - self.from.0) * p,
            self.from.1 + (self.to.1 - self.from.1) * p,
        )
    }
}

/// One echo of a beam.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Echo {
    /// Distance from the scan centre, mm (before noise).
    pub distance_mm: f64,
    /// Reflectance of the surface hit, white paper = 1.0.
    pub reflectance: f64,
    /// Part of the emitted light that reached the surface and came back relative to a
    /// full hit on an opaque surface (glass, a beam split at an edge).
    pub fraction: f64,
}

/// The world: static segments and movers.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Scene {
    /// Walls, box sides, glass.
    pub segments: Vec<Segment>,
    /// Moving objects.
    pub movers: Vec<Mover>,
}

/// Beams whose sub-rays hit surfaces farther apart than this see two echoes (metres).
const EDGE_GAP_M: f64 = 0.3;

impl Scene {
    /// Nothing at all: every beam goes out of range.
    pub fn empty() -> Self {
        Self::default()
    }

    /// One wall across the forward direction at `distance_mm`, 200 m wide, of
    /// reflectance `reflectance`: a beam at angle θ (|θ| < 90°) hits it at
    /// `distance / cos θ`.
    pub fn wall(distance_mm: f64, reflectance: f64) -> Self {
        let x = distance_mm / 1000.0;
        Self {
            segments: vec![Segment {
                a: (x, -100.0),
                b: (x, 100.0),
                surface: Surface::opaque(reflectance),
            }],
            movers: Vec::new(),
        }
    }

    /// A room from a seed, furnished like the rooms of the real captures: four walls
    /// 1.9 to 9.5 m apart around the sensor with a doorway onto a far corridor wall,
    /// three to six boxes, four to ten thin posts (table and chair legs), a glass pane
    /// with a box behind it, and a cylinder walking across.
    pub fn room(seed: u64) -> Self {
        let mut rng = fastrand::Rng::with_seed(seed ^ 0x5CE1_E000);
        let mut between = |lo: f64, hi: f64| lo + (hi - lo) * rng.f64();
        let (w_neg, w_pos) = (between(0.7, 3.0), between(1.0, 3.5));
        let (d_back, d_front) = (between(1.2, 3.5), between(2.0, 6.0));
        let mut segments = Vec::new();
        let wall = |a, b, r| Segment {
            a,
            b,
            surface: Surface::opaque(r),
        };
        let corners = [
            (d_front, w_pos),
            (-d_back, w_pos),
            (-d_back, -w_neg),
            (d_front, -w_neg),
        ];
        // The +y wall has a doorway (0.8 to 1.4 m) onto a corridor wall 4 to 10 m
        // farther, out of a URG-04LX's reach: the beams through it find no echo.
        let door_w = between(0.8, 1.4);
        let door_x = between(-d_back + 0.2, d_front - 0.2 - door_w);
        let corridor = w_pos + between(4.0, 10.0);
        for i in 0..4 {
            let r = between(0.5, 0.9);
            if i == 0 {
                segments.push(wall(corners[0], (door_x + door_w, w_pos), r));
                segments.push(wall((door_x, w_pos), corners[1], r));
                segments.push(wall((100.0, corridor), (-100.0, corridor), r));
            } else {
                segments.push(wall(corners[i], corners[(i + 1) % 4], r));
            }
        }
        let square = |segments: &mut Vec<Segment>, (cx, cy): (f64, f64), half: f64, r| {
            let c = [
                (cx - half, cy - half),
                (cx + half, cy - half),
                (cx + half, cy + half),
                (cx - half, cy + half),
            ];
            for i in 0..4 {
                segments.push(wall(c[i], c[(i + 1) % 4], r));
            }
        };
        let boxes = 3 + (between(0.0, 3.999) as usize);
        for _ in 0..boxes {
            let at = (
                between(-d_back + 0.45, d_front - 0.45),
                between(-w_neg + 0.45, w_pos - 0.45),
            );
            // Not on top of the sensor.
            let at = (at.0.abs().max(0.5).copysign(at.0), at.1);
            square(&mut segments, at, between(0.1, 0.35), between(0.1, 1.0));
        }
        let posts = 4 + (between(0.0, 6.999) as usize);
        for _ in 0..posts {
            let at = (
                between(-d_back + 0.1, d_front - 0.1),
                between(-w_neg + 0.1, w_pos - 0.1),
            );
            let at = (at.0.abs().max(0.4).copysign(at.0), at.1);
            square(&mut segments, at, between(0.015, 0.04), between(0.2, 0.9));
        }
        // A glass pane in front of the back-left region, with a white box behind it.
        let gx = -d_back * 0.5;
        segments.push(Segment {
            a: (gx, w_pos * 0.2),
            b: (gx, w_pos * 0.7),
            surface: Surface::GLASS,
        });
        let bx = -d_back * 0.75;
        let by = w_pos * 0.45;
        for (a, b) in [
            ((bx - 0.2, by - 0.2), (bx - 0.2, by + 0.2)),
            ((bx - 0.2, by + 0.2), (bx + 0.2, by + 0.2)),
            ((bx + 0.2, by + 0.2), (bx + 0.2, by - 0.2)),
            ((bx + 0.2, by - 0.2), (bx - 0.2, by - 0.2)),
        ] {
            segments.push(wall(a, b, 1.0));
        }
        let movers = vec![Mover {
            from: (d_front * 0.6, -w_neg + 0.4),
            to: (d_front * 0.6, w_pos - 0.4),
            period_s: between(4.0, 10.0),
            radius: 0.2,
            surface: Surface::opaque(0.7),
        }];
        Self { segments, movers }
    }

    /// The hits of a ray at `angle` (radians) at time `t` seconds, nearest first, as
    /// (distance m, surface, object number); stops after the first opaque one.
    fn cast(&self, angle: f64, t: f64, hits: &mut Vec<(f64, Surface, usize)>) {
        hits.clear();
        let (dx, dy) = (angle.cos(), angle.sin());
        for (i, s) in self.segments.iter().enumerate() {
            if let Some(d) = ray_segment(dx, dy, s.a, s.b) {
                hits.push((d, s.surface, i));
            }
        }
        let n = self.segments.len();
        for (i, m) in self.movers.iter().enumerate() {
            if let Some(d) = ray_circle(dx, dy, m.centre(t), m.radius) {
                hits.push((d, m.surface, n + i));
            }
        }
        hits.sort_by(|a, b| a.0.total_cmp(&b.0));
        if let Some(i) = hits.iter().position(|h| h.1.transmittance <= 0.0) {
            hits.truncate(i + 1);
        }
    }

    /// The echoes of the beam of one step: centre angle `angle`, angular width `width`
    /// (radians), at time `t` seconds. Nearest first, at most 3; empty when nothing is
    /// in the beam's way.
    pub fn echoes(&self, angle: f64, width: f64, t: f64, out: &mut Vec<Echo>) {
        out.clear();
        let mut hits = Vec::new();
        self.cast(angle, t, &mut hits);
        let mut power = 1.0;
        for &(d, surface, _) in &hits {
            out.push(Echo {
                distance_mm: d * 1000.0,
                reflectance: surface.reflectance,
                fraction: power * (1.0 - surface.transmittance),
            });
            power *= surface.transmittance;
        }
        // The beam's footprint: rays at both edges of the step. One that meets another
        // object, well apart from what the centre sees, is a partial hit (an edge).
        let seen: Vec<usize> = hits.iter().map(|h| h.2).collect();
        for side in [-0.45, 0.45] {
            self.cast(angle + side * width, t, &mut hits);
            let Some(&(d, surface, id)) = hits.iter().find(|h| h.1.transmittance <= 0.0) else {
                continue;
            };
            let far_from_all = out
                .iter()
                .all(|e| (e.distance_mm / 1000.0 - d).abs() > EDGE_GAP_M);
            if !seen.is_empty() && !seen.contains(&id) && far_from_all {
                out.push(Echo {
                    distance_mm: d * 1000.0,
                    reflectance: surface.reflectance,
                    fraction: 0.3,
                });
            }
        }
        out.sort_by(|a, b| a.distance_mm.total_cmp(&b.distance_mm));
        out.truncate(3);
    }
}

/// Distance along the unit ray (dx, dy) from the origin to segment a–b, if it hits.
fn ray_segment(dx: f64, dy: f64, a: (f64, f64), b: (f64, f64)) -> Option<f64> {
    let (ex, ey) = (b.0 - a.0, b.1 - a.1);
    let denom = dx * ey - dy * ex;
    if denom.abs() < 1e-12 {
        return None;
    }
    // Solve t*(dx,dy) = a + u*(ex,ey).
    let t = (a.0 * ey - a.1 * ex) / denom;
    let u = (a.0 * dy - a.1 * dx) / denom;
    (t > 1e-6 && (0.0..=1.0).contains(&u)).then_some(t)
}

/// Distance along the unit ray (dx, dy) from the origin to a circle, if it hits.
fn ray_circle(dx: f64, dy: f64, c: (f64, f64), r: f64) -> Option<f64> {
    let along = c.0 * dx + c.1 * dy;
    let across2 = c.0 * c.0 + c.1 * c.1 - along * along;
    let h2 = r * r - across2;
    if h2 < 0.0 {
        return None;
    }
    let t = along - h2.sqrt();
    (t > 1e-6).then_some(t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wall_at_two_metres() {
        let s = Scene::wall(2000.0, 0.8);
        let mut e = Vec::new();
        s.echoes(0.0, 0.004, 0.0, &mut e);
        assert_eq!(e.len(), 1);
        assert!((e[0].distance_mm - 2000.0).abs() < 1e-6);
        // 60°: 2 m / cos 60° = 4 m.
        s.echoes(core::f64::consts::FRAC_PI_3, 0.004, 0.0, &mut e);
        assert!((e[0].distance_mm - 4000.0).abs() < 1e-6);
        s.echoes(core::f64::consts::PI, 0.004, 0.0, &mut e);
        assert!(e.is_empty());
    }

    #[test]
    fn glass_gives_two_echoes() {
        let mut s = Scene::wall(5000.0, 0.9);
        s.segments.push(Segment {
            a: (2.0, -1.0),
            b: (2.0, 1.0),
            surface: Surface::GLASS,
        });
        let mut e = Vec::new();
        s.echoes(0.0, 0.004, 0.0, &mut e);
        assert_eq!(e.len(), 2);
        assert!((e[0].distance_mm - 2000.0).abs() < 1e-6);
        assert!((e[1].distance_mm - 5000.0).abs() < 1e-6);
        assert!((e[1].fraction - 0.8).abs() < 1e-12);
    }

    #[test]
    fn edge_gives_two_echoes() {
        // A post whose edge lies exactly on the beam's centre line.
        let mut s = Scene::wall(6000.0, 0.9);
        s.segments.push(Segment {
            a: (2.0, 0.0),
            b: (2.0, -1.0),
            surface: Surface::opaque(0.5),
        });
        let mut e = Vec::new();
        s.echoes(0.0, 0.01, 0.0, &mut e);
        assert_eq!(e.len(), 2, "{e:?}");
        assert!((e[0].distance_mm - 2000.0).abs() < 1e-6);
        assert!((e[1].distance_mm - 6000.0).abs() < 1.0);
    }

    #[test]
    fn mover_and_room_are_deterministic() {
        let m = Mover {
            from: (1.0, 0.0),
            to: (3.0, 0.0),
            period_s: 2.0,
            radius: 0.1,
            surface: Surface::opaque(1.0),
        };
        assert_eq!(m.centre(0.0), (1.0, 0.0));
        assert_eq!(m.centre(1.0), (2.0, 0.0));
        assert_eq!(m.centre(3.0), (2.0, 0.0));
        assert_eq!(ray_circle(1.0, 0.0, (2.0, 0.0), 0.1), Some(1.9));
        assert_eq!(Scene::room(7), Scene::room(7));
        assert_ne!(Scene::room(7), Scene::room(8));
        // A room closes around the sensor: every direction hits something.
        let room = Scene::room(3);
        let mut e = Vec::new();
        for i in 0..360 {
            room.echoes(f64::from(i).to_radians(), 0.004, 0.0, &mut e);
            assert!(!e.is_empty(), "no hit at {i}°");
        }
    }
}
