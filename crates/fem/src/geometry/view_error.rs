//! Errors of cameras and visibility queries.

/// A camera or a surface that cannot be used for visibility queries. Messages quote the
/// offending values.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ViewError {
    /// The surface has no triangles (or no vertices).
    #[error("the surface is empty ({vertices} vertices, {triangles} triangles)")]
    EmptySurface {
        /// Number of vertices.
        vertices: usize,
        /// Number of triangles.
        triangles: usize,
    },
    /// The surface cannot be used (out-of-range index, non-finite coordinate, ...).
    #[error("invalid surface: {0}")]
    InvalidSurface(String),
    /// The camera is unusable (position equal to `look_at`, `up` parallel to the view, bad
    /// field of view, non-finite values).
    #[error("invalid camera: {0}")]
    InvalidCamera(String),
}
