//! Charts of the project's measurements (plotters; PNG and SVG, text in the bundled DejaVu Sans).
//!
//! - `output`: PNG and SVG writing, the bundled font.
//! - [`pareto`]: TRE against ms per frame, one marker per configuration, the Pareto front.
//! - [`per_frame`]: error per frame of a sequence, one line per method.
//! - [`surface_view`]: the registered surface coloured by error beside the truth.

mod output;
pub mod pareto;
pub mod per_frame;
pub mod surface_view;

pub use pareto::{pareto_front, write_chart, ChartPoint};
