//! Error per frame of a sequence, one line per method (no registration, rigid, non-rigid):
//! where along a sequence a registration helps, drifts or fails. PNG and SVG.

use std::path::Path;

use plotters::prelude::*;

use super::output::{write_png_svg, Figure};

const WIDTH: u32 = 900;
const HEIGHT: u32 = 520;
const COLOURS: [RGBColor; 4] = [
    RGBColor(120, 120, 120),
    RGBColor(30, 110, 200),
    RGBColor(210, 60, 40),
    RGBColor(40, 160, 80),
];

/// One line: a name and a value (mm) per frame (non-finite values are left out).
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Legend text.
    pub name: String,
    /// Mean error per frame, mm.
    pub values: Vec<f64>,
}

/// The three lines of a registration's chart: no registration, rigid, non-rigid (mm per frame).
pub fn none_rigid_non_rigid(none: Vec<f64>, rigid: Vec<f64>, non_rigid: Vec<f64>) -> Vec<Series> {
    [
        ("no registration", none),
        ("rigid", rigid),
        ("non-rigid", non_rigid),
    ]
    .into_iter()
    .map(|(name, values)| Series {
        name: name.into(),
        values,
    })
    .collect()
}

/// [`none_rigid_non_rigid`] with a fourth line: the non-rigid registration's own estimate of
/// its error per frame (`expected_error`, mm; `None` where a frame has none).
pub fn with_expected_error(mut series: Vec<Series>, expected: Vec<Option<f64>>) -> Vec<Series> {
    series.push(Series {
        name: "expected error (non-rigid)".into(),
        values: expected
            .into_iter()
            .map(|e| e.unwrap_or(f64::NAN))
            .collect(),
    });
    series
}

/// Draws `series` (error in mm against the frame index) to `png` and/or `svg` with `title`.
/// Errors name the file.
pub fn write_per_frame_chart(
    series: &[Series],
    title: &str,
    png: Option<&Path>,
    svg: Option<&Path>,
) -> Result<(), String> {
    write_png_svg(&PerFrameFigure { series, title }, (WIDTH, HEIGHT), png, svg)
}

struct PerFrameFigure<'a> {
    series: &'a [Series],
    title: &'a str,
}

impl Figure for PerFrameFigure<'_> {
    fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, plotters::coord::Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        render(root, self.series, self.title)
    }
}

fn render<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    series: &[Series],
    title: &str,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    root.fill(&WHITE)?;
    let frames = series
        .iter()
        .map(|s| s.values.len())
        .max()
        .unwrap_or(1)
        .max(2);
    let top = series
        .iter()
        .flat_map(|s| s.values.iter().copied().filter(|v| v.is_finite()))
        .fold(0.0, f64::max)
        .max(0.1)
        * 1.1;
    let mut chart = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0f64..(frames - 1) as f64, 0f64..top)?;
    chart
        .configure_mesh()
        .x_desc("frame")
        .y_desc("mean error, mm")
        .label_style(("sans-serif", 14))
        .draw()?;
    for (i, s) in series.iter().enumerate() {
        let colour = COLOURS[i % COLOURS.len()];
        let points: Vec<(f64, f64)> = s
            .values
            .iter()
            .enumerate()
            .filter(|(_, v)| v.is_finite())
            .map(|(k, v)| (k as f64, *v))
            .collect();
        chart
            .draw_series(LineSeries::new(points, colour.stroke_width(2)))?
            .label(s.name.clone())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
            });
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .position(SeriesLabelPosition::UpperLeft)
        .draw()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Both files are written, the PNG is a PNG, and the SVG names every series.
    #[test]
    fn writes_png_and_svg_with_every_series() {
        let dir = std::env::temp_dir().join(format!("livereg-per-frame-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let series = vec![
            Series {
                name: "none".into(),
                values: (0..20).map(|k| k as f64 * 0.5).collect(),
            },
            Series {
                name: "non-rigid".into(),
                values: (0..20).map(|k| 0.3 + 0.01 * k as f64).collect(),
            },
        ];
        let (png, svg) = (dir.join("a.png"), dir.join("a.svg"));
        write_per_frame_chart(&series, "test", Some(&png), Some(&svg)).unwrap();
        let bytes = std::fs::read(&png).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
        let text = std::fs::read_to_string(&svg).unwrap();
        assert!(text.contains("none") && text.contains("non-rigid"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
