//! Assembling a [`TriSurface`] from parsed data, shared by all readers: fan triangulation of
//! polygons, pre-allocation bounded by the file size rather than by untrusted header counts, and
//! the final check that the mesh is not empty.

use std::path::Path;

use nalgebra::Point3;

use super::error::MeshError;
use super::surface::TriSurface;

/// Appends the fan triangulation `(p0, p[i], p[i+1])` of polygon `poly` to `out`, keeping its
/// orientation; a polygon with fewer than 3 vertices is an error built by `err`.
pub(crate) fn fan(
    poly: &[usize],
    out: &mut Vec<[usize; 3]>,
    err: impl FnOnce(String) -> MeshError,
) -> Result<(), MeshError> {
    if poly.len() < 3 {
        return Err(err(format!(
            "a face needs at least 3 vertices, this one has {}",
            poly.len()
        )));
    }
    out.extend(poly[1..].windows(2).map(|w| [poly[0], w[0], w[1]]));
    Ok(())
}

/// Capacity to reserve for `count` items announced by a header when `available` bytes remain
/// and each item takes at least `min_item_bytes`: never more than the data can hold.
pub(crate) fn bounded_capacity(count: usize, available: usize, min_item_bytes: usize) -> usize {
    count.min(available / min_item_bytes.max(1))
}

/// The surface made of `vertices` and `triangles`, or an error if there is no triangle.
pub(crate) fn finish(
    path: &Path,
    vertices: Vec<Point3<f64>>,
    triangles: Vec<[usize; 3]>,
) -> Result<TriSurface, MeshError> {
    if triangles.is_empty() {
        return Err(MeshError::empty(path, "triangles"));
    }
    Ok(TriSurface::new(vertices, triangles))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fan_keeps_orientation_and_rejects_short_polygons() {
        let mut out = vec![];
        fan(&[4, 5, 6, 7, 8], &mut out, |m| {
            MeshError::malformed(Path::new("a"), m)
        })
        .unwrap();
        assert_eq!(out, vec![[4, 5, 6], [4, 6, 7], [4, 7, 8]]);
        let e = fan(&[1, 2], &mut out, |m| {
            MeshError::parse(Path::new("a.off"), 7, m)
        });
        assert_eq!(
            e.unwrap_err().to_string(),
            "a.off:7: a face needs at least 3 vertices, this one has 2"
        );
        assert_eq!(out.len(), 3);
    }

    #[test]
    fn capacity_is_bounded_by_available_bytes() {
        assert_eq!(bounded_capacity(usize::MAX, 1000, 12), 83);
        assert_eq!(bounded_capacity(5, 1000, 12), 5);
        assert_eq!(bounded_capacity(5, 1000, 0), 5);
    }

    #[test]
    fn finish_rejects_empty() {
        let e = finish(Path::new("x.stl"), vec![Point3::origin()], vec![]).unwrap_err();
        assert_eq!(e.to_string(), "x.stl: the file contains no triangles");
    }
}
