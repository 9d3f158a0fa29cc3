//! Registration sessions: the model's state carried from frame to frame.
//!
//! A [`Session`] owns one patient's [`Model`](crate::model::Model) and registers
//! a stream of intra-operative clouds ([`Frame`]) to it: rigid ICP (tracking from the last
//! pose), then non-rigid ICP warm-started from the last good displacement field, within an
//! optional per-frame time budget. A frame that fails leaves the session exactly as it was, and
//! its [`FrameResult`] carries the last good state, flagged, with the cause.
//!
//! Inside, a session composes its parts, each a type of its own in
//! `registration_session/`: the pose (`PoseTracker`), the tests of what changed and the still
//! window (`ChangeTests`), the shape with its coarse start and recovery ladder
//! (`NonRigidStage`), the contact force and refit (`ContactForceEstimator`), the model's
//! surfaces for signed distances (`ModelSurfaces`) and the last good state (`GoodState`).

pub(crate) mod frame;
pub(crate) mod frame_files;
pub(crate) mod frame_flag;
pub(crate) mod memory_estimate;
pub(crate) mod observer;
pub(crate) mod registration_session;
pub(crate) mod settings;
pub(crate) mod still_window;

pub use frame::{Frame, FrameError, FrameResult, StageTimes};
pub use frame_files::{frame_files, FrameFiles};
pub use frame_flag::{flag_texts, FrameFlag};
pub use memory_estimate::{still_window_bytes, ModelSize};
pub use observer::FrameObserver;
pub use registration_session::{
    damped_newton, recovery_ladder, recovery_settings, RecoveryRung, Session, BEFORE_RECOVERY,
};
pub use settings::{
    PoseUpdate, RigidMode, SessionSettings, BACKGROUND_FACTORIZATION_LAG, DEFAULT_CONTACT_RADIUS,
    DEFAULT_REFIT_FACTORIZATIONS, DEFAULT_STILL_FRAMES,
};
pub use still_window::StillWindow;
