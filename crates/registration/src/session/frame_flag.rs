//! What a frame's result says about how it was registered: the flags of
//! [`FrameResult::flags`](super::FrameResult::flags).
//!
//! Each flag has one text form, the one results files, server answers, OpenIGTLink metadata and
//! recordings carry (docs/registration.md, section Flags); [`FrameFlag::parse`] reads it back.

use std::fmt;

use serde::{Serialize, Serializer};

use super::registration_session::RUNG_NAMES;

/// One flag of a frame's result.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FrameFlag {
    /// `decimated`: the cloud was thinned to `max_cloud_points`.
    Decimated,
    /// `isolated_removed`: isolated points were dropped from the cloud.
    IsolatedRemoved,
    /// `at_rest`: the cloud shows the rest shape; the model was kept at rest.
    AtRest,
    /// `still:<n>`: the frame registered the union of the last `n` (> 1) still clouds.
    Still(usize),
    /// `coarse_start`: a cold frame started from the coarse model's registration.
    CoarseStart,
    /// `recovered:<rung>`: the solver failed and the named rung of the recovery ladder
    /// registered the frame.
    Recovered(&'static str),
    /// `recovery_failed`: the solver failed and no rung of the recovery ladder succeeded.
    RecoveryFailed,
    /// `time_budget`: the frame's time budget stopped the iterations.
    TimeBudget,
    /// `icp_not_converged`: the non-rigid stage stopped at its iteration cap.
    IcpNotConverged,
    /// `rigid_not_converged`: rigid ICP stopped at its iteration cap.
    RigidNotConverged,
    /// `failed`: the frame was rejected; the result carries the last good state.
    Failed,
    /// `pose_searched`: the global pose search replaced plain ICP's pose.
    PoseSearched,
    /// `pose_ambiguous`: the cloud fits two distinct poses about as well.
    PoseAmbiguous,
    /// `pose_uncertain`: the pose's uncertainty is over `max_pose_uncertainty`.
    PoseUncertain,
    /// `pose_reacquired`: the held pose no longer fitted and was searched again.
    PoseReacquired,
    /// `expected_error_high`: the expected error is over `max_expected_error`.
    ExpectedErrorHigh,
    /// `contact_refit`: the field was explained again by a load at the contact alone
    /// (`registration.contact_refit`).
    ContactRefit,
    /// `refit_not_converged`: the kept contact refit's solve stopped at its iteration cap or its
    /// factorisation budget off balance; its field is the solve's last iterate.
    RefitNotConverged,
    /// `force_beyond_linear`: no contact force (null) because the only estimate left, the
    /// first-order rest-compliance fit, is so far beyond small strain for the model's law
    /// that its expected error reaches the force itself.
    ForceBeyondLinear,
}

impl FrameFlag {
    /// Every flag without a value, for [`FrameFlag::parse`].
    const PLAIN: [FrameFlag; 17] = [
        FrameFlag::Decimated,
        FrameFlag::IsolatedRemoved,
        FrameFlag::AtRest,
        FrameFlag::CoarseStart,
        FrameFlag::RecoveryFailed,
        FrameFlag::TimeBudget,
        FrameFlag::IcpNotConverged,
        FrameFlag::RigidNotConverged,
        FrameFlag::Failed,
        FrameFlag::PoseSearched,
        FrameFlag::PoseAmbiguous,
        FrameFlag::PoseUncertain,
        FrameFlag::PoseReacquired,
        FrameFlag::ExpectedErrorHigh,
        FrameFlag::ContactRefit,
        FrameFlag::RefitNotConverged,
        FrameFlag::ForceBeyondLinear,
    ];

    /// The flag's name without its value (`still`, `recovered`, or the whole text).
    pub fn name(&self) -> &'static str {
        match self {
            FrameFlag::Decimated => "decimated",
            FrameFlag::IsolatedRemoved => "isolated_removed",
            FrameFlag::AtRest => "at_rest",
            FrameFlag::Still(_) => "still",
            FrameFlag::CoarseStart => "coarse_start",
            FrameFlag::Recovered(_) => "recovered",
            FrameFlag::RecoveryFailed => "recovery_failed",
            FrameFlag::TimeBudget => "time_budget",
            FrameFlag::IcpNotConverged => "icp_not_converged",
            FrameFlag::RigidNotConverged => "rigid_not_converged",
            FrameFlag::Failed => "failed",
            FrameFlag::PoseSearched => "pose_searched",
            FrameFlag::PoseAmbiguous => "pose_ambiguous",
            FrameFlag::PoseUncertain => "pose_uncertain",
            FrameFlag::PoseReacquired => "pose_reacquired",
            FrameFlag::ExpectedErrorHigh => "expected_error_high",
            FrameFlag::ContactRefit => "contact_refit",
            FrameFlag::RefitNotConverged => "refit_not_converged",
            FrameFlag::ForceBeyondLinear => "force_beyond_linear",
        }
    }

    /// The flag of text form `text` (as [`fmt::Display`] writes it); `None` for any other
    /// text, including a `recovered:` rung this build does not have.
    pub fn parse(text: &str) -> Option<FrameFlag> {
        if let Some(n) = text.strip_prefix("still:") {
            // Only the form Display writes: digits, no sign, no leading zero.
            let canonical =
                n.bytes().all(|b| b.is_ascii_digit()) && !(n.len() > 1 && n.starts_with('0'));
            return n.parse().ok().filter(|_| canonical).map(FrameFlag::Still);
        }
        if let Some(rung) = text.strip_prefix("recovered:") {
            return RUNG_NAMES
                .iter()
                .find(|r| **r == rung)
                .map(|r| FrameFlag::Recovered(r));
        }
        Self::PLAIN.into_iter().find(|f| f.name() == text)
    }
}

impl fmt::Display for FrameFlag {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FrameFlag::Still(n) => write!(f, "still:{n}"),
            FrameFlag::Recovered(rung) => write!(f, "recovered:{rung}"),
            other => f.write_str(other.name()),
        }
    }
}

/// Serialised as its text form.
impl Serialize for FrameFlag {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

/// A flag equals its text form.
impl PartialEq<str> for FrameFlag {
    fn eq(&self, other: &str) -> bool {
        match self {
            FrameFlag::Still(n) => FrameFlag::parse(other) == Some(FrameFlag::Still(*n)),
            FrameFlag::Recovered(rung) => other.strip_prefix("recovered:") == Some(*rung),
            plain => plain.name() == other,
        }
    }
}

/// A flag equals its text form.
impl PartialEq<&str> for FrameFlag {
    fn eq(&self, other: &&str) -> bool {
        self == *other
    }
}

/// The text forms of `flags`, in order (what results files and server answers carry).
pub fn flag_texts(flags: &[FrameFlag]) -> Vec<String> {
    flags.iter().map(ToString::to_string).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every flag reads back from its text form, and the text forms are the ones results
    /// files have always carried.
    #[test]
    fn every_flag_reads_back_from_its_text() {
        let mut all: Vec<FrameFlag> = FrameFlag::PLAIN.to_vec();
        all.push(FrameFlag::Still(3));
        all.extend(RUNG_NAMES.iter().map(|r| FrameFlag::Recovered(r)));
        for flag in &all {
            let text = flag.to_string();
            assert_eq!(FrameFlag::parse(&text), Some(*flag), "{text}");
            assert!(*flag == text.as_str());
        }
        let texts: Vec<String> = all.iter().map(ToString::to_string).collect();
        for expected in [
            "decimated",
            "isolated_removed",
            "at_rest",
            "still:3",
            "coarse_start",
            "recovered:smaller-steps",
            "recovered:damped-newton",
            "recovery_failed",
            "time_budget",
            "icp_not_converged",
            "rigid_not_converged",
            "failed",
            "pose_searched",
            "pose_ambiguous",
            "pose_uncertain",
            "pose_reacquired",
            "expected_error_high",
            "contact_refit",
            "refit_not_converged",
            "force_beyond_linear",
        ] {
            assert!(texts.iter().any(|t| t == expected), "{expected}");
        }
        assert_eq!(texts.len(), 20);
    }

    /// Unknown texts, a still window without a count and an unknown rung are not flags.
    #[test]
    fn other_texts_are_not_flags() {
        for text in [
            "",
            "Failed",
            "still:",
            "still:x",
            "still:+3",
            "still:03",
            "recovered:",
            "recovered:gentle",
        ] {
            assert_eq!(FrameFlag::parse(text), None, "{text}");
        }
    }

    /// The JSON form is the text form.
    #[test]
    fn serialised_as_text() {
        let json = serde_json::to_string(&[FrameFlag::Still(2), FrameFlag::PoseUncertain]).unwrap();
        assert_eq!(json, r#"["still:2","pose_uncertain"]"#);
    }

    /// Every rung of the recovery ladder has a name `parse` knows.
    #[test]
    fn the_ladders_rungs_are_known() {
        let cold = crate::registration::NonRigidSettings::default();
        let newton = livereg_fem::mechanics::NewtonSettings::default();
        for rung in crate::session::recovery_ladder(&cold, &newton) {
            assert!(RUNG_NAMES.contains(&rung.name), "{}", rung.name);
        }
    }
}
