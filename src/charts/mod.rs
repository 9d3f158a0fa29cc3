//! Charts of the project's measurements (plotters; PNG and SVG, text in the bundled DejaVu Sans).
//!
//! - [`pareto`]: TRE against ms per frame, one marker per configuration, the Pareto front.

pub mod pareto;

pub use pareto::{pareto_front, write_chart, ChartPoint};
