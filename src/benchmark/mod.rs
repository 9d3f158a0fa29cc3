//! Speed against accuracy: the configuration sweep of `livereg bench`, the
//! stability matrix, and the measurements both rest on.
//!
//! - [`config`]: a registration model configuration applied on top of a scene;
//! - [`workload`]: frames with the true structure positions they are graded on;
//! - [`run`]: registering a workload and measuring TRE, time, iterations, failures, memory;
//! - [`sweep`]: every configuration on every workload, the Pareto front, the report;
//! - [`stability`]: the stability matrix (noise, outliers, visible fraction, deformation,
//!   grid offset, Poisson's ratio, penalty stiffness) with failures by cause;
//! - [`indentation`], [`indentation_stability`]: the tool-indentation class, its
//!   workloads and metrics, and its stability matrix (noise, visible fraction, cloud size,
//!   outliers, Poisson's ratio, law);
//! - [`calibrate`]: the cheapest model that meets a TRE target or a latency budget;
//! - [`memory`]: peak resident memory.

pub mod calibrate;
pub mod config;
pub mod force_truths;
pub mod indentation;
pub mod indentation_stability;
pub mod memory;
pub mod run;
pub mod stability;
pub mod sweep;
pub mod workload;

pub use calibrate::{CalibrationReport, Goal};
pub use config::{sweep_configs, ModelConfig, ResolvedConfig};
pub use run::{run_scene, run_workload, Cause, FrameSample, Metrics};
pub use stability::{run_matrix, Axis, StabilityOptions, StabilityReport};
pub use sweep::{run_sweep, BenchReport, ConfigReport};
pub use workload::Workload;
