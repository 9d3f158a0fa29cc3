//! Observers of a run of frames: whatever wants each registered frame as soon as it exists
//! (a recorder, a visualiser, a VTK series writer), told in order by the loop that runs the
//! session.

use super::{Frame, FrameResult};

/// Told about every frame as soon as it is registered (recorders, visualisers).
pub trait FrameObserver {
    /// Frame `index` of the run: `frame` as registered (`None` when its input could not be
    /// read), received at `received_ns` (ns since the Unix epoch), and its result.
    fn frame_done(
        &mut self,
        index: usize,
        frame: Option<&Frame>,
        received_ns: u64,
        result: &FrameResult,
    ) -> Result<(), String>;
}
