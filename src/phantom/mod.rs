//! The bundled liver phantom, generated deterministically by code: a liver-shaped closed
//! surface (thick right lobe, thin left lobe, umbilical notch, concave visceral face, convex
//! diaphragmatic dome), vessel-bifurcation targets, a small tumour and the ligament region
//! held fixed.
//!
//! Everything is in metres in memory, in a patient-like frame: x from the patient's right to
//! left, y from back (posterior) to front (anterior), z from bottom (inferior) to top
//! (superior), origin roughly at the centre of the bounding box. [`write_phantom`] writes it
//! in millimetres together with a ready-to-run `scene.toml`.
//!
//! ```
//! let phantom = livereg::phantom::liver_phantom();
//! assert!(livereg::mesh::validate(&phantom.surface).watertight);
//! assert!(phantom.targets.len() >= 15);
//! ```

pub mod distance;
pub mod ligament;
pub mod liver_surface;
pub mod measure;
pub mod targets;
pub mod tumour;
pub mod write;

#[cfg(test)]
mod tests;

use nalgebra::Point3;

use crate::geometry::Aabb;
use crate::mesh::TriSurface;

pub use distance::distance_to_surface;
pub use ligament::ligament_box;
pub use liver_surface::{liver_map, liver_surface};
pub use measure::{area_in_box, max_thickness_at};
pub use targets::vessel_targets;
pub use tumour::tumour_surface;
pub use write::{scene_toml, write_phantom, write_phantom_files};

/// The bundled liver phantom; all lengths in metres.
#[derive(Debug, Clone, PartialEq)]
pub struct LiverPhantom {
    /// The liver surface (metres): closed, watertight, outward-oriented, 5120 triangles,
    /// 20.0 × 15.0 × 10.6 cm, 1.21 L.
    pub surface: TriSurface,
    /// Vessel-bifurcation targets (metres), each inside and at least 10 mm from the surface.
    pub targets: Vec<Point3<f64>>,
    /// A small closed tumour mesh (metres), 2.6 × 2.2 × 2.0 cm, inside the right lobe.
    pub tumour: TriSurface,
    /// Box (metres) holding the part of the surface kept fixed: the ligaments and the vena cava
    /// attachment on the posterior-superior face.
    pub ligament: Aabb,
}

/// Builds the liver phantom (deterministic: the same values on every call and platform that
/// follows IEEE-754 and a correctly rounded `sqrt`; `exp`/`tanh` are the platform's).
pub fn liver_phantom() -> LiverPhantom {
    let surface = liver_surface();
    let targets = vessel_targets(&surface);
    let tumour = tumour_surface();
    let ligament = ligament_box(&surface);
    LiverPhantom {
        surface,
        targets,
        tumour,
        ligament,
    }
}
