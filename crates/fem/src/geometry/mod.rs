//! Geometry of the immersed surface: boxes, triangle–box overlap, a BVH, generalised winding
//! numbers and fast inside/outside classification of points against a closed triangle surface.
//!
//! All lengths are in the surface's units (whatever units its vertices are given in).
//!
//! The entry point is [`InsideTest`]: built once from vertices and outward-oriented triangles,
//! it answers single-point queries ([`InsideTest::contains`], via the fast winding number),
//! batched queries along z-parallel lines ([`InsideTest::classify_line`], via exact signed
//! crossings) and box–surface overlap queries ([`InsideTest::triangles_overlapping`]).
//!
//! For building an immersed grid, the cheap pattern is:
//! * cut cells: [`InsideTest::triangles_overlapping`] for a cell, then
//!   [`InsideTest::filter_overlapping`] of the parent's list for each [`Aabb::octant`] when
//!   refining (much cheaper than a BVH query per sub-cell);
//! * point classification: gather the points sharing an `(x, y)` (e.g. every Gauss point on
//!   one z-parallel line through a whole column of cells) and call
//!   [`InsideTest::classify_line`] once per line (≈ 100–200 ns per line plus ≈ 1 ns per point
//!   on a 20k-triangle surface); it is `Sync`, so lines can be spread over rayon threads.
//!
//! ```
//! use livereg_fem::geometry::{shapes, Aabb, InsideTest};
//! use nalgebra::Point3;
//!
//! let (vertices, triangles) = shapes::icosphere(3, 1.0);
//! let inside = InsideTest::new(&vertices, &triangles);
//! let mut out = Vec::new();
//! inside.classify_line(0.1, 0.2, &[-2.0, 0.0, 0.5, 2.0], &mut out);
//! assert_eq!(out, [false, true, true, false]);
//! assert!(inside.contains(&Point3::new(0.0, 0.0, 0.9)));
//!
//! let cell = Aabb::new(Point3::new(0.9, -0.1, -0.1), Point3::new(1.1, 0.1, 0.1));
//! let mut cut = Vec::new();
//! inside.triangles_overlapping(&cell, &mut cut);
//! assert!(!cut.is_empty());
//! ```

pub(crate) mod aabb;
pub(crate) mod bucket_grid;
pub(crate) mod bvh;
pub(crate) mod camera;
pub(crate) mod closest_point;
pub(crate) mod holes;
pub(crate) mod inside;
pub(crate) mod line_crossings;
pub(crate) mod neighbour_grid;
pub(crate) mod predicates;
pub mod shapes;
pub(crate) mod tri_box;
pub(crate) mod view_error;
pub mod visibility;
pub(crate) mod winding;

#[cfg(test)]
mod tests;

pub use aabb::Aabb;
pub use bvh::{Bvh, BvhNode};
pub use camera::{Camera, DEFAULT_FOV_DEG};
pub use closest_point::{closest_barycentric, closest_point_on_triangle};
pub use inside::{GeometryError, InsideTest};
pub use neighbour_grid::NeighbourGrid;
pub use tri_box::triangle_overlaps_box;
pub use view_error::ViewError;
pub use visibility::VisibleSurface;
pub use winding::{solid_angle, winding_number_brute, ExpansionOrder, FastWinding};
