//! Reference scenarios from the source texts, shared by tests, examples and benchmarks.

pub mod cylinder;

pub use cylinder::{CylinderBending, CylinderStretching, ScenarioResult};
