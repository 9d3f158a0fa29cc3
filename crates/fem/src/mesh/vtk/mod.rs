//! VTK surfaces and point sets: reading legacy `.vtk` (ASCII or binary) and XML `.vtp`
//! PolyData files, writing them, and ParaView `.pvd` time series of them. Legacy files are
//! parsed, and both formats written, by the `vtkio` crate; `.vtp` files are read by
//! [`xml_polydata`](self) here (see its notes). This module maps them to [`TriSurface`] and
//! point lists and checks what the parsers leave unchecked (indices in range, finite
//! coordinates, cell sizes).
//!
//! Coordinates are in the file's units (millimetres for a patient model). A legacy file
//! whose title line says `SPACE=RAS` (3D Slicer before 4.11, or when asked) is turned into
//! LPS, the frame 3D Slicer has written since 4.11 and the one livereg's labelmap reader
//! uses: x and y change sign. Any other file is taken as it is.
//!
//! [`TriSurface`]: super::TriSurface

mod pvd;
mod read;
mod write;
mod xml_polydata;

#[cfg(test)]
mod tests;

pub use pvd::PvdSeries;
pub use read::{read_vtk, read_vtk_points};
pub use write::{write_vtk, PointArray, VtkPolyData};
