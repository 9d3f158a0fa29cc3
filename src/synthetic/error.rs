//! Errors of the synthetic camera and point-cloud generator.

/// Everything that can go wrong while setting up a synthetic camera or synthesizing a cloud.
/// Messages quote the offending values.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SynthError {
    /// The surface or the camera cannot be used (see [`crate::geometry::ViewError`]).
    #[error(transparent)]
    View(#[from] crate::geometry::ViewError),
    /// A [`crate::synthetic::CloudSpec`] parameter is out of its range.
    #[error("invalid cloud specification: {0}")]
    InvalidSpec(String),
    /// The requested patch is larger than the part of the surface the camera sees.
    #[error(
        "visible_fraction {requested} asks for {requested_area_cm2:.2} cm² but only \
         {visible_area_cm2:.2} cm² ({visible_fraction:.4} of the surface) is visible"
    )]
    PatchTooLarge {
        /// The requested fraction of the whole surface area.
        requested: f64,
        /// The requested patch area, cm².
        requested_area_cm2: f64,
        /// The visible area, cm².
        visible_area_cm2: f64,
        /// The visible area as a fraction of the whole surface area.
        visible_fraction: f64,
    },
    /// No sample of the surface is visible from the camera.
    #[error(
        "nothing is visible: none of the {samples} surface samples lies in the camera's \
         field of view unoccluded (camera at {camera}, looking at {look_at})"
    )]
    NothingVisible {
        /// Number of surface samples drawn.
        samples: usize,
        /// Camera position, formatted.
        camera: String,
        /// Camera target, formatted.
        look_at: String,
    },
}
