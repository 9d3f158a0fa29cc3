//! Registration sessions: the model's state carried from frame to frame.
//!
//! A [`Session`] owns one patient's [`Model`](crate::model::Model) and registers
//! a stream of intra-operative clouds ([`Frame`]) to it: rigid ICP (tracking from the last
//! pose), then non-rigid ICP warm-started from the last good displacement field, within an
//! optional per-frame time budget. A frame that fails leaves the session exactly as it was, and
//! its [`FrameResult`] carries the last good state, flagged, with the cause.

pub mod frame;
pub mod frame_files;
pub mod frame_flag;
pub mod memory_estimate;
pub mod observer;
pub mod registration_session;
pub mod settings;
pub mod still_window;

pub use frame::{Frame, FrameError, FrameResult, StageTimes};
pub use frame_files::{frame_files, FrameFiles};
pub use frame_flag::{flag_texts, FrameFlag};
pub use memory_estimate::ModelSize;
pub use observer::FrameObserver;
pub use registration_session::{
    damped_newton, recovery_ladder, recovery_settings, RecoveryRung, Session, BEFORE_RECOVERY,
};
pub use settings::{PoseUpdate, RigidMode, SessionSettings};
pub use still_window::StillWindow;
