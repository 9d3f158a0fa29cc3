//! Closed triangle surfaces of simple solids, for tests, bundled scenes and benchmarks. All are
//! watertight with outward normals; lengths in the caller's units.

use std::collections::HashMap;

use nalgebra::{Point3, Vector3};

use super::surface::TriSurface;

/// Axis-aligned box `[min, max]` with each face split into `n × n` quads (2 triangles each).
pub fn box_surface(min: Point3<f64>, max: Point3<f64>, n: usize) -> TriSurface {
    let n = n.max(1);
    let mut b = Builder::default();
    // For each axis d and side, a face spanned by the two other axes (right-handed order).
    for d in 0..3 {
        let (e1, e2) = ((d + 1) % 3, (d + 2) % 3);
        for side in [0, 1] {
            let coord = if side == 0 { min[d] } else { max[d] };
            let point = |i: usize, j: usize| {
                let mut p = Point3::origin();
                p[d] = coord;
                p[e1] = min[e1] + (max[e1] - min[e1]) * i as f64 / n as f64;
                p[e2] = min[e2] + (max[e2] - min[e2]) * j as f64 / n as f64;
                p
            };
            for i in 0..n {
                for j in 0..n {
                    let q = [
                        point(i, j),
                        point(i + 1, j),
                        point(i + 1, j + 1),
                        point(i, j + 1),
                    ];
                    // (e1, e2, d) is right-handed: counter-clockwise in (e1, e2) faces +d.
                    if side == 1 {
                        b.quad(q[0], q[1], q[2], q[3]);
                    } else {
                        b.quad(q[0], q[3], q[2], q[1]);
                    }
                }
            }
        }
    }
    b.finish()
}

/// Cylinder of `radius` along +z from `z0` to `z0 + length`, centred on the z axis:
/// `segments` around, `rings` along, and end caps split into concentric rings so that their
/// triangles are of similar size to the side's.
pub fn cylinder_surface(
    radius: f64,
    z0: f64,
    length: f64,
    segments: usize,
    rings: usize,
) -> TriSurface {
    let segments = segments.max(3);
    let rings = rings.max(1);
    let mut b = Builder::default();
    let at = |r: f64, k: usize, z: f64| {
        let t = std::f64::consts::TAU * (k % segments) as f64 / segments as f64;
        Point3::new(r * t.cos(), r * t.sin(), z)
    };
    for i in 0..rings {
        let (za, zb) = (
            z0 + length * i as f64 / rings as f64,
            z0 + length * (i + 1) as f64 / rings as f64,
        );
        for k in 0..segments {
            b.quad(
                at(radius, k, za),
                at(radius, k + 1, za),
                at(radius, k + 1, zb),
                at(radius, k, zb),
            );
        }
    }
    let cap_rings = ((radius * segments as f64 / std::f64::consts::TAU) / (length / rings as f64))
        .round()
        .clamp(1.0, segments as f64 / 2.0) as usize;
    for (z, up) in [(z0, false), (z0 + length, true)] {
        let centre = Point3::new(0.0, 0.0, z);
        for ring in 0..cap_rings {
            let (ri, ro) = (
                radius * ring as f64 / cap_rings as f64,
                radius * (ring + 1) as f64 / cap_rings as f64,
            );
            for k in 0..segments {
                let (a, bb) = (at(ro, k, z), at(ro, k + 1, z));
                if ring == 0 {
                    if up {
                        b.tri(centre, a, bb)
                    } else {
                        b.tri(centre, bb, a)
                    }
                } else {
                    let (c, d) = (at(ri, k + 1, z), at(ri, k, z));
                    if up {
                        b.quad(d, a, bb, c)
                    } else {
                        b.quad(d, c, bb, a)
                    }
                }
            }
        }
    }
    b.finish()
}

/// Sphere of `radius` around `centre`: an icosahedron subdivided `levels` times and projected.
pub fn icosphere(centre: Point3<f64>, radius: f64, levels: usize) -> TriSurface {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut verts: Vec<Vector3<f64>> = [
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ]
    .iter()
    .map(|v| Vector3::new(v[0], v[1], v[2]).normalize())
    .collect();
    let mut tris: Vec<[usize; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..levels {
        let mut mid: HashMap<(usize, usize), usize> = HashMap::new();
        let mut next = Vec::with_capacity(tris.len() * 4);
        for [a, b, c] in tris {
            let mut m = |x: usize, y: usize| {
                *mid.entry((x.min(y), x.max(y))).or_insert_with(|| {
                    verts.push((verts[x] + verts[y]).normalize());
                    verts.len() - 1
                })
            };
            let (ab, bc, ca) = (m(a, b), m(b, c), m(c, a));
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        tris = next;
    }
    TriSurface::new(verts.iter().map(|v| centre + v * radius).collect(), tris)
}

/// Builds an indexed surface from triangles given by positions, welding equal positions.
#[derive(Default)]
struct Builder {
    index: HashMap<[u64; 3], usize>,
    surface: TriSurface,
}

impl Builder {
    fn vertex(&mut self, p: Point3<f64>) -> usize {
        // Normalise -0.0 so that welded keys agree.
        let key = [p.x + 0.0, p.y + 0.0, p.z + 0.0].map(f64::to_bits);
        let verts = &mut self.surface.vertices;
        *self.index.entry(key).or_insert_with(|| {
            verts.push(p);
            verts.len() - 1
        })
    }

    fn tri(&mut self, a: Point3<f64>, b: Point3<f64>, c: Point3<f64>) {
        let t = [self.vertex(a), self.vertex(b), self.vertex(c)];
        self.surface.triangles.push(t);
    }

    fn quad(&mut self, a: Point3<f64>, b: Point3<f64>, c: Point3<f64>, d: Point3<f64>) {
        self.tri(a, b, c);
        self.tri(a, c, d);
    }

    fn finish(self) -> TriSurface {
        self.surface
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn primitives_are_watertight() {
        let surfaces = [
            box_surface(Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 2.0, 3.0), 3),
            cylinder_surface(0.5, -1.0, 2.0, 48, 12),
            icosphere(Point3::origin(), 1.0, 3),
        ];
        for s in &surfaces {
            let report = crate::mesh::validate(s);
            assert!(report.watertight, "{report}");
            assert_eq!(report.degenerate_triangles, 0);
        }
    }

    #[test]
    fn volumes_match_closed_forms() {
        let b = box_surface(Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 2.0, 3.0), 3);
        assert!((b.signed_volume() - 6.0).abs() < 1e-12);
        let c = cylinder_surface(0.5, -1.0, 2.0, 64, 8);
        let polygon = 0.5 * 64.0 * 0.25 * (std::f64::consts::TAU / 64.0).sin();
        assert!((c.signed_volume() - polygon * 2.0).abs() < 1e-12);
        let s = icosphere(Point3::new(1.0, 0.0, 0.0), 2.0, 4);
        let exact = 4.0 / 3.0 * std::f64::consts::PI * 8.0;
        assert!(s.signed_volume() > 0.99 * exact && s.signed_volume() < exact);
    }
}
