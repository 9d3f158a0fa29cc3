//! Registration and sessions on scenes, one module per subject: non-rigid and rigid
//! registration against synthetic truths, the global pose search, rigid tracking, the accuracy
//! claim on partial clouds, a 50-frame session's stability, bad frames, tool indentation, a
//! release on finer cells, and models segmented from labelmaps (written here and by the Python
//! writers nibabel and pynrrd).
//!
//! One test binary of a few (`tests/*/main.rs`, helpers in `tests/common`); one subject alone:
//! `cargo test --test registration bad_frames:: -- --nocapture`.

#[path = "../common/mod.rs"]
mod common;

mod bad_frames;
mod non_rigid_registration;
mod partial_cloud_accuracy;
mod release_after_press;
mod rigid_pose_search;
mod rigid_tracking;
mod segmentation_python;
mod segmentation_registration;
mod segmentation_scene;
mod session_stability;
mod tool_indentation;
