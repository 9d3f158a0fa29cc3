//! Device names and metadata keys livereg uses on OpenIGTLink (see `docs/openigtlink.md`).
//! These are livereg's conventions, not the spec's; device names follow PLUS/3D Slicer habits
//! ("XToY" for a transform from frame X to frame Y). All lengths are in millimetres.

/// Client → server, POLYDATA (points, with or without vertex cells) or POINT: the
/// intra-operative surface samples, in the reference (tracker) frame, mm.
pub const INTRAOP_CLOUD_DEVICE: &str = "IntraopCloud";
/// Client → server, POLYDATA with triangles: the pre-operative liver surface, model frame, mm.
pub const LIVER_MODEL_DEVICE: &str = "LiverModel";
/// Server → client, TRANSFORM: the rigid part of the registration, model frame → reference
/// frame (translation in mm).
pub const LIVER_TO_REFERENCE_DEVICE: &str = "LiverToReference";
/// Server → client, POLYDATA with triangles: the registered (deformed) liver surface in the
/// reference frame, mm.
pub const DEFORMED_LIVER_DEVICE: &str = "DeformedLiver";
/// Server → client, POINT: registered targets (vessels, tumour) in the reference frame, mm.
pub const TARGETS_DEVICE: &str = "Targets";

/// Metadata key: the livereg session id (as in the HTTP `X-Livereg-Session` header).
pub const METADATA_SESSION: &str = "livereg.session";
/// Metadata key: the frame index, decimal, of a cloud or of the result it produced.
pub const METADATA_FRAME: &str = "livereg.frame";
/// Metadata key: the length unit of the content; livereg sends and expects "mm".
pub const METADATA_UNITS: &str = "units";
/// The only value of [`METADATA_UNITS`] livereg uses.
pub const UNITS_MM: &str = "mm";

#[cfg(test)]
mod tests {
    use super::*;
    use crate::openigtlink::{HeaderVersion, Message, StatusMessage};

    #[test]
    fn device_names_are_valid() {
        for name in [
            INTRAOP_CLOUD_DEVICE,
            LIVER_MODEL_DEVICE,
            LIVER_TO_REFERENCE_DEVICE,
            DEFORMED_LIVER_DEVICE,
            TARGETS_DEVICE,
        ] {
            Message::new(name, StatusMessage::ok(""))
                .encode(HeaderVersion::V1)
                .unwrap();
        }
    }
}
