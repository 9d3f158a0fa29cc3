//! Surface meshes and point clouds: readers (OBJ, STL, PLY, OFF, Gmsh 2 MSH, VTK, point text
//! files), writers (OBJ, VTK, point text), validation and simple primitive solids. Lengths are always in the
//! file's units; unit conversion is done by the caller with [`TriSurface::scale`].

pub(crate) mod error;
pub(crate) mod finite_points;
pub(crate) mod msh;
pub(crate) mod obj;
pub(crate) mod off;
pub(crate) mod ply;
pub(crate) mod points;
pub mod primitives;
pub(crate) mod stl;
pub(crate) mod surface;
pub(crate) mod validate;
pub mod vtk;

mod assemble;
#[cfg(test)]
mod fixtures;
mod text;

use std::path::Path;

pub use error::MeshError;
pub use finite_points::{first_non_finite_point, is_finite_point};
pub use msh::read_msh;
pub use obj::{read_obj, write_obj};
pub use off::read_off;
pub use ply::{read_ply, read_ply_vertices};
pub use points::{read_points, write_points, POINT_EXTENSIONS};
pub use stl::read_stl;
pub use surface::TriSurface;
pub use validate::{orient_outward, validate, SurfaceReport};
pub use vtk::{read_vtk, read_vtk_points, write_vtk};

/// The surface formats [`read_surface`] understands, by extension.
pub const SURFACE_EXTENSIONS: [&str; 7] = ["obj", "stl", "ply", "off", "msh", "vtk", "vtp"];

/// Reads a triangle surface, choosing the reader from the file extension (case-insensitive):
/// `obj`, `stl`, `ply`, `off`, `msh` (Gmsh 2.x ASCII), `vtk` (legacy) or `vtp` (XML PolyData). Lengths are in the file's units.
pub fn read_surface(path: &Path) -> Result<TriSurface, MeshError> {
    match extension(path).as_deref() {
        Some("obj") => read_obj(path),
        Some("stl") => read_stl(path),
        Some("ply") => read_ply(path),
        Some("off") => read_off(path),
        Some("msh") => read_msh(path),
        Some("vtk" | "vtp") => read_vtk(path),
        Some(other) => Err(MeshError::unsupported(
            path,
            format!(
                "unknown surface file extension '{other}' (supported: {})",
                SURFACE_EXTENSIONS.join(", ")
            ),
        )),
        None => Err(MeshError::unsupported(
            path,
            format!(
                "the file name has no extension to tell its format (supported: {})",
                SURFACE_EXTENSIONS.join(", ")
            ),
        )),
    }
}

/// The lower-cased extension of `path`, if any.
pub fn extension(path: &Path) -> Option<String> {
    path.extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
}

#[cfg(test)]
mod tests {
    use super::fixtures::{assert_err, cube, TempDir};
    use super::*;

    #[test]
    fn dispatch_is_case_insensitive() {
        let dir = TempDir::new("dispatch");
        let path = dir.path("Liver.OBJ");
        write_obj(&path, &cube()).unwrap();
        assert_eq!(read_surface(&path).unwrap(), cube());
    }

    #[test]
    fn dispatch_reaches_every_reader() {
        let dir = TempDir::new("dispatch-all");
        let files = [
            ("t.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"),
            (
                "t.Stl",
                "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n\
                 vertex 0 1 0\nendloop\nendfacet\nendsolid t\n",
            ),
            (
                "t.ply",
                "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
                 property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
                 end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
            ),
            ("t.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"),
            (
                "t.msh",
                "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n3\n1 0 0 0\n2 1 0 0\n3 0 1 0\n\
                 $EndNodes\n$Elements\n1\n1 2 0 1 2 3\n$EndElements\n",
            ),
        ];
        for (name, text) in files {
            let s = read_surface(&dir.write(name, text)).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(s.triangles.len(), 1, "{name}");
            assert_eq!(s.scaled_normal(0).z, 1.0, "{name}: orientation kept");
        }
    }

    #[test]
    fn unknown_extension_names_file_extension_and_supported_ones() {
        let dir = TempDir::new("dispatch-bad");
        let path = dir.write("liver.wrl", "");
        let msg = assert_err(
            read_surface(&path),
            &path,
            &["'wrl'", "obj, stl, ply, off, msh, vtk, vtp"],
        );
        assert!(msg.contains("liver.wrl"));
        let path = dir.write("liver", "");
        assert_err(read_surface(&path), &path, &["no extension", "obj, stl"]);
    }
}
