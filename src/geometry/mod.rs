//! Geometry of the immersed surface: boxes, triangle–box overlap, a BVH, generalised winding
//! numbers and fast inside/outside classification of points against a closed triangle surface.
//!
//! All lengths are in the surface's units (whatever units its vertices are given in).
//!
//! The entry point is [`InsideTest`]: built once from vertices and outward-oriented triangles,
//! it answers single-point queries ([`InsideTest::contains`], via the fast winding number),
//! batched queries along z-parallel lines ([`InsideTest::classify_line`], via exact signed
//! crossings) and box–surface overlap queries ([`InsideTest::triangles_overlapping`]).

pub mod aabb;
pub mod bucket_grid;
pub mod bvh;
pub mod holes;
pub mod inside;
pub mod line_crossings;
pub mod predicates;
pub mod shapes;
pub mod tri_box;
pub mod winding;

#[cfg(test)]
mod tests;

pub use aabb::Aabb;
pub use bvh::{Bvh, BvhNode};
pub use inside::{GeometryError, InsideTest};
pub use tri_box::triangle_overlaps_box;
pub use winding::{solid_angle, winding_number_brute, ExpansionOrder, FastWinding};
