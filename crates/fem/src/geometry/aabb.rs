//! Axis-aligned bounding boxes.

use nalgebra::{Point3, Vector3};

/// Axis-aligned box `[min.x, max.x] × [min.y, max.y] × [min.z, max.z]`, closed (its faces belong
/// to it), in the surface's length units.
///
/// A box with `min > max` on some axis is empty; [`Aabb::EMPTY`] is the canonical empty box and
/// the neutral element of [`Aabb::union`] and [`Aabb::grow`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    /// Lower corner (smallest coordinate on every axis).
    pub min: Point3<f64>,
    /// Upper corner (largest coordinate on every axis).
    pub max: Point3<f64>,
}

impl Aabb {
    /// The empty box (`min = +∞`, `max = −∞`): contains nothing, intersects nothing.
    pub const EMPTY: Aabb = Aabb {
        min: Point3::new(f64::INFINITY, f64::INFINITY, f64::INFINITY),
        max: Point3::new(f64::NEG_INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY),
    };

    /// The box spanned by two opposite corners `a` and `b`, given in any order
    /// (the corners are sorted per axis).
    pub fn new(a: Point3<f64>, b: Point3<f64>) -> Self {
        Aabb {
            min: a.inf(&b),
            max: a.sup(&b),
        }
    }

    /// Smallest box containing all `points`; [`Aabb::EMPTY`] when there are none.
    pub fn from_points<'a, I>(points: I) -> Self
    where
        I: IntoIterator<Item = &'a Point3<f64>>,
    {
        let mut b = Aabb::EMPTY;
        for p in points {
            b.grow(p);
        }
        b
    }

    /// True when the box contains no point (`min > max` on some axis, or a NaN bound).
    pub fn is_empty(&self) -> bool {
        !(self.min.x <= self.max.x && self.min.y <= self.max.y && self.min.z <= self.max.z)
    }

    /// Centre of the box, in length units.
    pub fn center(&self) -> Point3<f64> {
        nalgebra::center(&self.min, &self.max)
    }

    /// Full edge lengths `max − min` per axis, in length units.
    pub fn extents(&self) -> Vector3<f64> {
        self.max - self.min
    }

    /// Half edge lengths `(max − min) / 2` per axis, in length units.
    pub fn half_extents(&self) -> Vector3<f64> {
        (self.max - self.min) * 0.5
    }

    /// Index (0 = x, 1 = y, 2 = z) of the axis along which the box is longest.
    pub fn longest_axis(&self) -> usize {
        self.extents().imax()
    }

    /// True when `p` lies in the closed box (points on faces are contained).
    pub fn contains(&self, p: &Point3<f64>) -> bool {
        (0..3).all(|i| self.min[i] <= p[i] && p[i] <= self.max[i])
    }

    /// True when `other` lies entirely in this (closed) box.
    pub fn contains_box(&self, other: &Aabb) -> bool {
        (0..3).all(|i| self.min[i] <= other.min[i] && other.max[i] <= self.max[i])
    }

    /// True when the two closed boxes share at least one point (touching faces, edges or
    /// corners count as intersecting).
    pub fn intersects(&self, other: &Aabb) -> bool {
        (0..3).all(|i| self.min[i] <= other.max[i] && other.min[i] <= self.max[i])
    }

    /// Enlarges the box (in place) to contain `p`.
    pub fn grow(&mut self, p: &Point3<f64>) {
        self.min = self.min.inf(p);
        self.max = self.max.sup(p);
    }

    /// Smallest box containing both boxes.
    pub fn union(&self, other: &Aabb) -> Aabb {
        Aabb {
            min: self.min.inf(&other.min),
            max: self.max.sup(&other.max),
        }
    }

    /// The box grown by `margin` (length units) on every side; a negative margin shrinks it.
    pub fn expanded(&self, margin: f64) -> Aabb {
        let m = Vector3::repeat(margin);
        Aabb {
            min: self.min - m,
            max: self.max + m,
        }
    }

    /// Squared Euclidean distance from `p` to the closed box (0 inside), in length units².
    pub fn distance_squared(&self, p: &Point3<f64>) -> f64 {
        (0..3)
            .map(|i| {
                let d = (self.min[i] - p[i]).max(p[i] - self.max[i]).max(0.0);
                d * d
            })
            .sum()
    }

    /// One of the 8 octants obtained by halving the box on every axis at its centre.
    ///
    /// Bit 0 of `i` selects the upper half in x, bit 1 in y, bit 2 in z, so `octant(0)` holds
    /// `min` and `octant(7)` holds `max`. The octants tile the box exactly: neighbouring
    /// octants share the same (bit-identical) splitting coordinate.
    ///
    /// # Panics
    /// If `i >= 8`.
    pub fn octant(&self, i: usize) -> Aabb {
        assert!(i < 8, "octant index {i} out of range 0..8");
        let c = self.center();
        let mut min = self.min;
        let mut max = self.max;
        for axis in 0..3 {
            if (i >> axis) & 1 == 1 {
                min[axis] = c[axis];
            } else {
                max[axis] = c[axis];
            }
        }
        Aabb { min, max }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit() -> Aabb {
        Aabb::new(Point3::new(1.0, 0.0, 0.0), Point3::new(0.0, 1.0, 1.0))
    }

    #[test]
    fn new_sorts_corners_and_helpers() {
        let b = unit();
        assert_eq!(b.min, Point3::new(0.0, 0.0, 0.0));
        assert_eq!(b.max, Point3::new(1.0, 1.0, 1.0));
        assert_eq!(b.center(), Point3::new(0.5, 0.5, 0.5));
        assert_eq!(b.extents(), Vector3::new(1.0, 1.0, 1.0));
        assert_eq!(b.half_extents(), Vector3::new(0.5, 0.5, 0.5));
        assert!(b.contains(&Point3::new(1.0, 0.0, 0.5)));
        assert!(!b.contains(&Point3::new(1.0 + 1e-12, 0.0, 0.5)));
        assert!(!b.is_empty());
        assert!(Aabb::EMPTY.is_empty());
        assert!(!Aabb::EMPTY.intersects(&b));
        assert_eq!(b.distance_squared(&Point3::new(2.0, 0.5, 3.0)), 5.0);
        assert_eq!(b.distance_squared(&Point3::new(0.2, 0.5, 0.3)), 0.0);
    }

    #[test]
    fn intersects_touching_counts() {
        let b = unit();
        let touching = Aabb::new(Point3::new(1.0, 1.0, 1.0), Point3::new(2.0, 2.0, 2.0));
        assert!(b.intersects(&touching));
        let apart = Aabb::new(
            Point3::new(1.0 + 1e-12, 0.0, 0.0),
            Point3::new(2.0, 2.0, 2.0),
        );
        assert!(!b.intersects(&apart));
    }

    #[test]
    fn from_points_and_union() {
        let pts = [Point3::new(0.0, 2.0, -1.0), Point3::new(3.0, -2.0, 1.0)];
        let b = Aabb::from_points(&pts);
        assert_eq!(b.min, Point3::new(0.0, -2.0, -1.0));
        assert_eq!(b.max, Point3::new(3.0, 2.0, 1.0));
        assert!(Aabb::from_points(&[]).is_empty());
        assert_eq!(Aabb::EMPTY.union(&b), b);
        assert_eq!(b.longest_axis(), 1);
    }

    #[test]
    fn octants_tile_the_box() {
        let b = Aabb::new(Point3::new(-1.0, 0.0, 2.0), Point3::new(0.3, 0.7, 2.9));
        let mut vol = 0.0;
        for i in 0..8 {
            let o = b.octant(i);
            assert!(b.contains_box(&o));
            vol += o.extents().product();
            for j in 0..8 {
                // Octants touch (share faces/edges/corners) but never overlap in volume.
                let p = o.octant(j).center();
                let owners = (0..8).filter(|&k| b.octant(k).contains(&p)).count();
                assert_eq!(owners, 1);
            }
        }
        assert!((vol - b.extents().product()).abs() < 1e-14);
        assert_eq!(b.octant(0).min, b.min);
        assert_eq!(b.octant(7).max, b.max);
    }
}
