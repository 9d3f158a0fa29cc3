//! The speed-versus-accuracy chart of `livereg bench`: target registration error (mm)
//! against computation time per frame (ms), one marker per configuration, and the Pareto
//! front of the configurations that no other one beats on both.
//!
//! Text, font and file writing: `charts/output.rs`.

use std::ops::Range;
use std::path::Path;

use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::output::{write_png_svg, Figure, FAMILY};

/// Width of the chart (pixels, PNG and SVG).
const WIDTH: u32 = 1024;
/// Height of the chart (pixels, PNG and SVG).
const HEIGHT: u32 = 768;
/// Height of the strip under the plot holding the note on points not shown (pixels).
const NOTE_HEIGHT: u32 = 30;

/// Marker of an ordinary configuration.
const POINT_COLOUR: RGBColor = RGBColor(31, 119, 180);
/// Marker of the default configuration.
const DEFAULT_COLOUR: RGBColor = RGBColor(214, 39, 40);
/// The Pareto front's line.
const FRONT_COLOUR: RGBColor = RGBColor(44, 160, 44);
/// Labels and notes.
const TEXT_COLOUR: RGBColor = RGBColor(40, 40, 40);

/// One configuration's point on the chart.
#[derive(Debug, Clone, PartialEq)]
pub struct ChartPoint {
    /// Name of the configuration; written next to its point when it is on the Pareto front.
    pub label: String,
    /// Computation time per frame (ms), e.g. the median over the frames.
    pub ms_per_frame: f64,
    /// Target registration error (mm), e.g. the mean over targets and frames.
    pub tre_mm: f64,
    /// Whether this is the default configuration (drawn with its own marker, "default" in
    /// the legend).
    pub is_default: bool,
}

impl ChartPoint {
    /// Both coordinates (ms, mm) are finite: the point can be drawn and compared.
    fn is_finite(&self) -> bool {
        self.ms_per_frame.is_finite() && self.tre_mm.is_finite()
    }
}

/// Indices of the points on the Pareto front (no other point is both at most as slow and
/// at most as inaccurate, and strictly better in one), sorted by ms_per_frame ascending.
/// Non-finite points are never on the front.
///
/// "Slow" compares `ms_per_frame` (ms), "inaccurate" compares `tre_mm` (mm); lower is
/// better for both. Points with a non-finite coordinate neither are on the front nor
/// remove others from it. Identical points do not dominate each other, so all copies of
/// a front point are on it; ties in `ms_per_frame` are ordered by index. O(n log n).
pub fn pareto_front(points: &[ChartPoint]) -> Vec<usize> {
    // `+ 0.0` turns -0.0 into 0.0, so that the total order agrees with `==` on ties.
    let key = |x: f64| x + 0.0;
    let mut order: Vec<usize> = (0..points.len())
        .filter(|&i| points[i].is_finite())
        .collect();
    order.sort_by(|&a, &b| {
        let (p, q) = (&points[a], &points[b]);
        key(p.ms_per_frame)
            .total_cmp(&key(q.ms_per_frame))
            .then(key(p.tre_mm).total_cmp(&key(q.tre_mm)))
            .then(a.cmp(&b))
    });
    let mut front = Vec::new();
    // Lowest TRE (mm) among the points strictly faster than the current group.
    let mut best = f64::INFINITY;
    let mut start = 0;
    while start < order.len() {
        let ms = points[order[start]].ms_per_frame;
        let len = order[start..]
            .iter()
            .take_while(|&&i| points[i].ms_per_frame == ms)
            .count();
        let group = &order[start..start + len];
        // Sorted by TRE within the group: the first has the group's lowest.
        let lowest = points[group[0]].tre_mm;
        if lowest < best {
            front.extend(
                group
                    .iter()
                    .copied()
                    .filter(|&i| points[i].tre_mm == lowest),
            );
            best = lowest;
        }
        start += len;
    }
    front
}

/// Writes the chart to `png` and `svg` (either may be None), with the title given.
/// x axis: ms per frame (log scale when max/min > 20, else linear); y axis: TRE mm (linear,
/// from 0). One marker per configuration, the Pareto front drawn as a staircase through
/// its points, each front point labelled with its label (small text), and a legend.
/// Returns Err(String) naming the file on an I/O or drawing error. Points with a
/// non-finite coordinate are skipped, and counted in a note under the plot
/// ("n configurations without a finite result not shown").
///
/// Both files are 1024 × 768 pixels. Ordinary configurations are blue circles, the
/// default configuration a red filled triangle. The front is a green staircase through
/// the front points (across at a point's TRE to the next point's time, then down), and
/// each front point is labelled with its `label` (points at the same coordinates share
/// one label, names joined by ", "). The x axis (ms) is logarithmic when all times are
/// positive and max/min > 20. The SVG names the `sans-serif` font family. Each file is
/// drawn to a temporary file beside it and renamed into place. The PNG is written first;
/// when it fails the SVG is not attempted.
pub fn write_chart(
    points: &[ChartPoint],
    title: &str,
    png: Option<&Path>,
    svg: Option<&Path>,
) -> Result<(), String> {
    if png.is_none() && svg.is_none() {
        return Ok(());
    }
    let plan = Plan::new(points);
    write_png_svg(
        &ParetoFigure { plan: &plan, title },
        (WIDTH, HEIGHT),
        png,
        svg,
    )
}

/// The chart of a [`Plan`] with its title.
struct ParetoFigure<'a> {
    plan: &'a Plan<'a>,
    title: &'a str,
}

impl Figure for ParetoFigure<'_> {
    fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        render(root, self.plan, self.title)
    }
}

/// What to draw, in data units (ms, mm), independent of the backend.
struct Plan<'a> {
    /// The points with finite coordinates.
    shown: Vec<&'a ChartPoint>,
    /// How many points were left out for a non-finite coordinate.
    hidden: usize,
    /// The points of the Pareto front, by ms ascending.
    front: Vec<&'a ChartPoint>,
    /// x axis range (ms).
    x: Range<f64>,
    /// Whether the x axis is logarithmic.
    log_x: bool,
    /// y axis range (mm).
    y: Range<f64>,
}

impl<'a> Plan<'a> {
    fn new(points: &'a [ChartPoint]) -> Self {
        let shown: Vec<&ChartPoint> = points.iter().filter(|p| p.is_finite()).collect();
        let hidden = points.len() - shown.len();
        let front = pareto_front(points)
            .into_iter()
            .map(|i| &points[i])
            .collect();
        let (x, log_x) = x_axis(shown.iter().map(|p| p.ms_per_frame));
        let y = y_axis(shown.iter().map(|p| p.tre_mm));
        Plan {
            shown,
            hidden,
            front,
            x,
            log_x,
            y,
        }
    }

    /// The note under the plot on the points not shown, if any.
    fn note(&self) -> Option<String> {
        match self.hidden {
            0 => None,
            1 => Some("1 configuration without a finite result not shown".to_string()),
            n => Some(format!(
                "{n} configurations without a finite result not shown"
            )),
        }
    }
}

/// The x range (ms) and whether it is logarithmic: log when every time is positive and
/// max/min > 20, with a factor 1.5 of room on both sides; else linear with 8 % room
/// (not below 0 when no time is negative).
fn x_axis(values: impl Iterator<Item = f64>) -> (Range<f64>, bool) {
    let Some((lo, hi)) = min_max(values) else {
        return (0.0..1.0, false);
    };
    if lo > 0.0 && hi / lo > 20.0 {
        let range = lo / 1.5..hi * 1.5;
        if range.start > 0.0 && range.end.is_finite() {
            return (range, true);
        }
    }
    let span = hi - lo;
    let pad = if span > 0.0 {
        0.08 * span
    } else if lo != 0.0 {
        0.1 * lo.abs()
    } else {
        1.0
    };
    let start = if lo >= 0.0 {
        (lo - pad).max(0.0)
    } else {
        lo - pad
    };
    let range = start..hi + pad;
    if range.start.is_finite() && range.end.is_finite() && range.start < range.end {
        (range, false)
    } else {
        (lo.min(0.0)..hi.max(1.0), false)
    }
}

/// The y range (mm): from 0 (or below, for negative values) to 20 % above the largest
/// TRE, leaving room for the labels and the legend.
fn y_axis(values: impl Iterator<Item = f64>) -> Range<f64> {
    let Some((lo, hi)) = min_max(values) else {
        return 0.0..1.0;
    };
    let end = if hi > 0.0 { hi * 1.2 } else { 1.0 };
    let start = if lo < 0.0 { lo * 1.1 } else { 0.0 };
    if start.is_finite() && end.is_finite() {
        start..end
    } else {
        0.0..1.0
    }
}

/// Smallest and largest of `values` (None when empty).
fn min_max(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    values.fold(None, |acc, v| match acc {
        None => Some((v, v)),
        Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
    })
}

/// A tick value with as few digits as it needs (3 significant below 100).
fn tick(v: f64) -> String {
    let a = v.abs();
    let s = if a == 0.0 {
        return "0".to_string();
    } else if a >= 100.0 {
        format!("{v:.0}")
    } else if a >= 10.0 {
        format!("{v:.1}")
    } else if a >= 1.0 {
        format!("{v:.2}")
    } else if a >= 0.001 {
        format!("{v:.4}")
    } else {
        return format!("{v:.1e}");
    };
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

/// Ticks of a logarithmic axis over `range` (positive): labelled ones at 1, 2 and 5 times
/// the powers of ten, grid lines at 1 to 9 times them.
fn log_ticks(range: &Range<f64>) -> (Vec<f64>, Vec<f64>) {
    let (mut bold, mut light) = (Vec::new(), Vec::new());
    let first = range.start.log10().floor() as i32;
    let last = range.end.log10().ceil() as i32;
    for e in first..=last {
        let decade = 10f64.powi(e);
        for m in 1..10 {
            // Rounded so that the labels read 0.2, not 0.20000000000000004.
            let v = format!("{:.12e}", m as f64 * decade).parse().unwrap_or(0.0);
            if range.contains(&v) {
                light.push(v);
                if matches!(m, 1 | 2 | 5) {
                    bold.push(v);
                }
            }
        }
    }
    (bold, light)
}

/// Draws the whole chart on `root` (white background, plot, note), without presenting it.
fn render<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    plan: &Plan<'_>,
    title: &str,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    root.fill(&WHITE)?;
    let plot_area = match plan.note() {
        Some(note) => {
            let (upper, lower) = root.split_vertically(HEIGHT - NOTE_HEIGHT);
            let style = TextStyle::from((FAMILY, 15).into_font())
                .color(&TEXT_COLOUR)
                .pos(Pos::new(HPos::Left, VPos::Center));
            lower.draw(&Text::new(
                format!("Note: {note}."),
                (20, NOTE_HEIGHT as i32 / 2 - 4),
                style,
            ))?;
            upper
        }
        None => root.clone(),
    };
    if plan.log_x {
        let (bold, light) = log_ticks(&plan.x);
        let x_spec = plan
            .x
            .clone()
            .log_scale()
            .with_key_points(bold)
            .with_light_points(light);
        draw_plot(&plot_area, x_spec, plan, title)
    } else {
        draw_plot(&plot_area, plan.x.clone(), plan, title)
    }
}

/// The chart's coordinates: x time per frame (ms, linear or logarithmic as `X`), y TRE (mm).
type PlotChart<'a, DB, X> = ChartContext<'a, DB, Cartesian2d<X, RangedCoordf64>>;

/// Draws the caption, axes, markers, front, labels and legend with x coordinates `x_spec`
/// (linear or logarithmic ms).
fn draw_plot<DB, XS>(
    area: &DrawingArea<DB, Shift>,
    x_spec: XS,
    plan: &Plan<'_>,
    title: &str,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>>
where
    DB: DrawingBackend,
    XS: AsRangedCoord<Value = f64>,
    XS::CoordDescType: ValueFormatter<f64>,
{
    let mut chart = ChartBuilder::on(area)
        .caption(title, (FAMILY, 26).into_font().color(&BLACK))
        .margin(18)
        .x_label_area_size(56)
        .y_label_area_size(70)
        .build_cartesian_2d(x_spec, plan.y.clone())?;
    draw_mesh(&mut chart, plan.log_x)?;
    let steps = front_steps(&plan.front);
    draw_front(&mut chart, &steps)?;
    draw_markers(&mut chart, &plan.shown)?;
    let mut layout = Layout::new(&chart, &plan.shown, &steps);
    draw_front_labels(&mut chart, &plan.front, &mut layout)?;
    if plan.shown.is_empty() {
        return Ok(());
    }
    draw_legend(&mut chart, area, &layout)
}

/// A point's chart coordinates: (time per frame in ms, TRE in mm).
fn at(p: &ChartPoint) -> (f64, f64) {
    (p.ms_per_frame, p.tre_mm)
}

/// Draws the axes, their descriptions (x in ms, y in mm), tick labels and grid lines.
fn draw_mesh<DB, X>(
    chart: &mut PlotChart<'_, DB, X>,
    log_x: bool,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>>
where
    DB: DrawingBackend,
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let x_desc = if log_x {
        "time per frame (ms, log scale)"
    } else {
        "time per frame (ms)"
    };
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc("TRE (mm)")
        .x_labels(12)
        .y_labels(10)
        .x_label_formatter(&|v| tick(*v))
        .y_label_formatter(&|v| tick(*v))
        .label_style((FAMILY, 15).into_font().color(&TEXT_COLOUR))
        .axis_desc_style((FAMILY, 18).into_font().color(&BLACK))
        .bold_line_style(RGBColor(218, 218, 218))
        .light_line_style(RGBColor(242, 242, 242))
        .max_light_lines(4)
        .draw()
}

/// The vertices (ms, mm) of the front drawn as a staircase: from each point across at its
/// TRE to the next (slower) point's time, then down to that point's TRE.
fn front_steps(front: &[&ChartPoint]) -> Vec<(f64, f64)> {
    let mut steps = Vec::with_capacity(2 * front.len());
    for (k, p) in front.iter().enumerate() {
        if k > 0 {
            steps.push((p.ms_per_frame, front[k - 1].tre_mm));
        }
        steps.push(at(p));
    }
    steps
}

/// Draws the front's staircase `steps` (ms, mm) with its legend entry, when there is one.
fn draw_front<DB, X>(
    chart: &mut PlotChart<'_, DB, X>,
    steps: &[(f64, f64)],
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>>
where
    DB: DrawingBackend,
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    if !steps.is_empty() {
        let line = FRONT_COLOUR.stroke_width(2);
        chart
            .draw_series(LineSeries::new(steps.to_vec(), line))?
            .label("Pareto front")
            .legend(move |(x, y)| PathElement::new(vec![(x - 8, y), (x + 12, y)], line));
    }
    Ok(())
}

/// Draws the markers of the points shown: circles for ordinary configurations, then
/// triangles for the default one (on top, so that it stays visible where points overlap),
/// each kind with its legend entry when it occurs.
fn draw_markers<DB, X>(
    chart: &mut PlotChart<'_, DB, X>,
    shown: &[&ChartPoint],
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>>
where
    DB: DrawingBackend,
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let ordinary = shown.iter().filter(|p| !p.is_default);
    if shown.iter().any(|p| !p.is_default) {
        chart
            .draw_series(ordinary.map(|p| Circle::new(at(p), 5, POINT_COLOUR.filled())))?
            .label("configuration")
            .legend(|(x, y)| Circle::new((x + 2, y), 5, POINT_COLOUR.filled()));
    }
    if shown.iter().any(|p| p.is_default) {
        let defaults = shown.iter().filter(|p| p.is_default);
        chart
            .draw_series(defaults.map(|p| TriangleMarker::new(at(p), 9, DEFAULT_COLOUR.filled())))?
            .label("default")
            .legend(|(x, y)| TriangleMarker::new((x + 2, y), 9, DEFAULT_COLOUR.filled()));
    }
    Ok(())
}

/// Whether two pixel boxes [x0, y0, x1, y1] overlap (sharing an edge is not overlapping).
fn overlaps(a: &[i32; 4], b: &[i32; 4]) -> bool {
    a[0] < b[2] && b[0] < a[2] && a[1] < b[3] && b[1] < a[3]
}

/// Where things are on the plot, in pixels: for placing the labels and the legend.
struct Layout {
    /// What labels and legend should not cover (pixel boxes [x0, y0, x1, y1]): markers, the
    /// front's line, and the labels placed so far.
    obstacles: Vec<[i32; 4]>,
    /// Horizontal extent of the plotting area (pixels).
    x_pixels: Range<i32>,
    /// Vertical extent of the plotting area (pixels).
    y_pixels: Range<i32>,
}

impl Layout {
    /// The plotting area with the markers of `shown` (14 × 14 pixels each) and the segments
    /// of the front's staircase `steps` (ms, mm; 1 pixel of margin) as obstacles.
    fn new<DB, X>(chart: &PlotChart<'_, DB, X>, shown: &[&ChartPoint], steps: &[(f64, f64)]) -> Self
    where
        DB: DrawingBackend,
        X: Ranged<ValueType = f64> + ValueFormatter<f64>,
    {
        let mut obstacles: Vec<[i32; 4]> = Vec::new();
        for p in shown {
            let (px, py) = chart.backend_coord(&at(p));
            obstacles.push([px - 7, py - 7, px + 7, py + 7]);
        }
        for w in steps.windows(2) {
            let ((ax, ay), (bx, by)) = (chart.backend_coord(&w[0]), chart.backend_coord(&w[1]));
            obstacles.push([
                ax.min(bx) - 1,
                ay.min(by) - 1,
                ax.max(bx) + 1,
                ay.max(by) + 1,
            ]);
        }
        let (x_pixels, y_pixels) = chart.plotting_area().get_pixel_range();
        Layout {
            obstacles,
            x_pixels,
            y_pixels,
        }
    }

    /// Whether the pixel box `r` lies inside the plotting area, 2 pixels clear of its edges.
    fn inside(&self, r: &[i32; 4]) -> bool {
        r[0] >= self.x_pixels.start + 2
            && r[2] <= self.x_pixels.end - 2
            && r[1] >= self.y_pixels.start + 2
            && r[3] <= self.y_pixels.end - 2
    }

    /// How many obstacles the pixel box `r` overlaps.
    fn obstacles_under(&self, r: &[i32; 4]) -> usize {
        self.obstacles.iter().filter(|o| overlaps(r, o)).count()
    }

    /// The offset (pixels) of a label of `size` (w, h pixels) from its point at pixel `at`,
    /// at the first free place among: below left of the point (nothing else can be there:
    /// it would dominate the point), below right, above right, above left, then further
    /// down; else the place covering the fewest things (a place outside the plotting area
    /// counting as 1000). The label's box becomes an obstacle.
    fn place_label(&mut self, at: (i32, i32), size: (i32, i32)) -> (i32, i32) {
        let ((px, py), (w, h)) = (at, size);
        let (left, right, below, above) = (-8 - w, 8, 8, -8 - h);
        let mut offsets = vec![(left, below), (right, below), (right, above), (left, above)];
        for row in 1..=4 {
            offsets.push((left, below + row * (h + 3)));
            offsets.push((right, below + row * (h + 3)));
        }
        let boxed = |(dx, dy): (i32, i32)| [px + dx, py + dy, px + dx + w, py + dy + h];
        let covered = |&offset: &(i32, i32)| {
            let r = boxed(offset);
            let outside = if self.inside(&r) { 0 } else { 1000 };
            outside + self.obstacles_under(&r)
        };
        let offset = offsets
            .iter()
            .copied()
            .find(|o| covered(o) == 0)
            .or_else(|| offsets.iter().copied().min_by_key(covered))
            .unwrap_or((right, below));
        self.obstacles.push(boxed(offset));
        offset
    }

    /// The corner of the plot for a legend of `legend_w` × `legend_h` pixels (12 pixels in
    /// from the edges): the one covering the fewest obstacles, the upper right one on a tie.
    fn legend_corner(&self, legend_w: i32, legend_h: i32) -> SeriesLabelPosition {
        let (left, right) = (self.x_pixels.start + 12, self.x_pixels.end - 12 - legend_w);
        let (top, bottom) = (self.y_pixels.start + 12, self.y_pixels.end - 12 - legend_h);
        let corners = [
            (SeriesLabelPosition::UpperRight, right, top),
            (SeriesLabelPosition::LowerLeft, left, bottom),
            (SeriesLabelPosition::UpperLeft, left, top),
            (SeriesLabelPosition::LowerRight, right, bottom),
        ];
        let hidden_under =
            |x: i32, y: i32| self.obstacles_under(&[x, y, x + legend_w, y + legend_h]);
        corners
            .into_iter()
            .min_by_key(|&(_, x, y)| hidden_under(x, y))
            .map(|(corner, _, _)| corner)
            .unwrap_or(SeriesLabelPosition::UpperRight)
    }
}

/// The label of the first point of `front` and the points after it at the same
/// coordinates: how many points share it, and their labels joined by ", ".
fn shared_label(front: &[&ChartPoint]) -> (usize, String) {
    let same = front.iter().take_while(|p| at(p) == at(front[0])).count();
    let text = front[..same]
        .iter()
        .map(|p| p.label.as_str())
        .collect::<Vec<_>>()
        .join(", ");
    (same, text)
}

/// Draws the labels of the front points, one per distinct position, each where
/// [`Layout::place_label`] puts it.
fn draw_front_labels<DB, X>(
    chart: &mut PlotChart<'_, DB, X>,
    front: &[&ChartPoint],
    layout: &mut Layout,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>>
where
    DB: DrawingBackend,
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let style = TextStyle::from((FAMILY, 14).into_font())
        .color(&TEXT_COLOUR)
        .pos(Pos::new(HPos::Left, VPos::Top));
    let mut k = 0;
    while k < front.len() {
        let (same, text) = shared_label(&front[k..]);
        let position = at(front[k]);
        let pixel = chart.backend_coord(&position);
        let (w, h) = chart.plotting_area().estimate_text_size(&text, &style)?;
        let offset = layout.place_label(pixel, (w as i32, h as i32));
        chart.draw_series(std::iter::once(
            EmptyElement::at(position) + Text::new(text, offset, style.clone()),
        ))?;
        k += same;
    }
    Ok(())
}

/// Draws the legend in the corner of the plot where it covers the fewest markers, labels
/// and pieces of the front (see [`Layout::legend_corner`]); its size (pixels) is estimated
/// on `area` from the longest entry.
fn draw_legend<'a, DB, X>(
    chart: &mut PlotChart<'a, DB, X>,
    area: &DrawingArea<DB, Shift>,
    layout: &Layout,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>>
where
    DB: DrawingBackend + 'a,
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let legend_style = (FAMILY, 15).into_font().color(&TEXT_COLOUR);
    let mut legend_w = 0;
    for name in ["Pareto front", "configuration", "default"] {
        legend_w = legend_w.max(area.estimate_text_size(name, &legend_style)?.0 as i32);
    }
    let (legend_w, legend_h) = (legend_w + 60, 3 * 20 + 20);
    let corner = layout.legend_corner(legend_w, legend_h);
    chart
        .configure_series_labels()
        .position(corner)
        .margin(12)
        .label_font(legend_style)
        .background_style(WHITE.mix(0.9))
        .border_style(RGBColor(190, 190, 190))
        .draw()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    /// A tiny deterministic generator (Knuth's MMIX LCG), so the tests need no crate.
    struct Lcg(u64);

    impl Lcg {
        fn next(&mut self) -> u64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            self.0 >> 33
        }
        fn below(&mut self, n: u64) -> u64 {
            self.next() % n
        }
        /// A coordinate: now and then non-finite, often on a coarse grid (ties), else
        /// spread out.
        fn coordinate(&mut self) -> f64 {
            match self.below(20) {
                0 => f64::NAN,
                1 => f64::INFINITY,
                2 => f64::NEG_INFINITY,
                3..=11 => self.below(6) as f64 * 0.5,
                _ => self.below(1_000_000) as f64 / 1000.0,
            }
        }
    }

    fn point(label: &str, ms: f64, tre: f64) -> ChartPoint {
        ChartPoint {
            label: label.to_string(),
            ms_per_frame: ms,
            tre_mm: tre,
            is_default: false,
        }
    }

    /// The definition, checked pair by pair.
    fn front_brute_force(points: &[ChartPoint]) -> Vec<usize> {
        let ok = |p: &ChartPoint| p.ms_per_frame.is_finite() && p.tre_mm.is_finite();
        let dominates = |q: &ChartPoint, p: &ChartPoint| {
            q.ms_per_frame <= p.ms_per_frame
                && q.tre_mm <= p.tre_mm
                && (q.ms_per_frame < p.ms_per_frame || q.tre_mm < p.tre_mm)
        };
        let mut front: Vec<usize> = (0..points.len())
            .filter(|&i| ok(&points[i]))
            .filter(|&i| !points.iter().any(|q| ok(q) && dominates(q, &points[i])))
            .collect();
        front.sort_by(|&a, &b| {
            let (p, q) = (&points[a], &points[b]);
            p.ms_per_frame
                .partial_cmp(&q.ms_per_frame)
                .unwrap()
                .then(a.cmp(&b))
        });
        front
    }

    /// A fresh, empty directory for one test's files.
    fn scratch_dir(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("livereg-charts-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    /// Width and height (pixels) from a PNG's IHDR chunk, after checking the signature.
    fn png_size(bytes: &[u8]) -> (u32, u32) {
        assert!(bytes.len() > 24, "PNG too short: {} bytes", bytes.len());
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "not a PNG signature");
        assert_eq!(&bytes[12..16], b"IHDR", "first chunk is not IHDR");
        let be = |b: &[u8]| u32::from_be_bytes([b[0], b[1], b[2], b[3]]);
        (be(&bytes[16..20]), be(&bytes[20..24]))
    }

    /// A sweep-like set: a clear front, dominated points, the default, times over two
    /// decades (log axis).
    fn sweep_points() -> Vec<ChartPoint> {
        let mut pts = vec![
            point("h8-fast", 4.0, 6.5),
            point("h6-fast", 9.0, 4.2),
            point("h6", 22.0, 2.9),
            point("h4", 60.0, 2.1),
            point("h4-tight", 140.0, 1.8),
            point("h3-tight", 420.0, 1.7),
            point("h6-slow", 45.0, 3.6),
            point("h4-loose", 80.0, 2.6),
            point("h3", 300.0, 2.4),
        ];
        pts[3].is_default = true;
        pts
    }

    #[test]
    fn front_matches_brute_force_on_random_sets() {
        let mut rng = Lcg(0x5eed);
        for trial in 0..2000 {
            let n = rng.below(40) as usize;
            let pts: Vec<ChartPoint> = (0..n)
                .map(|i| point(&format!("p{i}"), rng.coordinate(), rng.coordinate()))
                .collect();
            let front = pareto_front(&pts);
            assert_eq!(front, front_brute_force(&pts), "trial {trial}: {pts:?}");
            // Along the front time never decreases and TRE never increases.
            for w in front.windows(2) {
                let (a, b) = (&pts[w[0]], &pts[w[1]]);
                assert!(a.ms_per_frame <= b.ms_per_frame && a.tre_mm >= b.tre_mm);
            }
        }
    }

    #[test]
    fn front_ties() {
        // Identical points are both on the front; equal time keeps only the lower TRE;
        // equal TRE keeps only the faster.
        let pts = vec![
            point("a", 2.0, 1.0),
            point("b", 1.0, 3.0),
            point("a-copy", 2.0, 1.0),
            point("same-ms-worse", 2.0, 1.5),
            point("same-tre-slower", 5.0, 1.0),
            point("c", 0.5, 3.0),
            point("d", 0.5, 4.0),
        ];
        assert_eq!(pareto_front(&pts), vec![5, 0, 2]);
        // -0.0 and 0.0 are the same value.
        let zeros = vec![point("z", 0.0, 1.0), point("minus-z", -0.0, 1.0)];
        assert_eq!(pareto_front(&zeros), vec![0, 1]);
        assert!(pareto_front(&[]).is_empty());
    }

    #[test]
    fn front_skips_non_finite_points() {
        let pts = vec![
            point("nan-ms", f64::NAN, 0.1),
            point("ok", 10.0, 2.0),
            point("nan-tre", 1.0, f64::NAN),
            point("inf", f64::INFINITY, 0.0),
            point("neg-inf", f64::NEG_INFINITY, 5.0),
            point("neg-inf-tre", 20.0, f64::NEG_INFINITY),
            point("ok2", 5.0, 3.0),
        ];
        // The non-finite points would dominate "ok" and "ok2" if they counted.
        assert_eq!(pareto_front(&pts), vec![6, 1]);
        let all_bad = vec![
            point("x", f64::NAN, f64::NAN),
            point("y", 1.0, f64::INFINITY),
        ];
        assert!(pareto_front(&all_bad).is_empty());
    }

    #[test]
    fn writes_png_and_svg_with_labels_and_title() {
        let dir = scratch_dir("both");
        let (png, svg) = (dir.join("chart.png"), dir.join("chart.svg"));
        let pts = sweep_points();
        let title = "Speed against accuracy: tool-push, 40 frames";
        write_chart(&pts, title, Some(&png), Some(&svg)).unwrap();
        assert_eq!(png_size(&std::fs::read(&png).unwrap()), (WIDTH, HEIGHT));
        assert_eq!((WIDTH, HEIGHT), (1024, 768));
        let text = std::fs::read_to_string(&svg).unwrap();
        assert!(text.starts_with("<svg") && text.contains("width=\"1024\""));
        assert!(text.contains(title));
        let front = pareto_front(&pts);
        assert_eq!(front, vec![0, 1, 2, 3, 4, 5]);
        for &i in &front {
            assert!(
                text.contains(&pts[i].label),
                "{} not in the SVG",
                pts[i].label
            );
        }
        assert!(text.contains("default") && text.contains("log scale"));
        assert!(!text.contains("not shown"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn linear_axis_non_finite_note_and_degenerate_sets() {
        let dir = scratch_dir("linear");
        let svg = dir.join("chart.svg");
        let mut pts = vec![
            point("a", 10.0, 2.0),
            point("b", 12.0, 1.0),
            point("broken", f64::NAN, 1.0),
            point("diverged", 11.0, f64::INFINITY),
        ];
        pts[0].is_default = true;
        write_chart(&pts, "linear", None, Some(&svg)).unwrap();
        let text = std::fs::read_to_string(&svg).unwrap();
        assert!(text.contains("2 configurations without a finite result not shown"));
        assert!(!text.contains("log scale") && !text.contains("broken"));
        // A single point, identical points, nothing finite, nothing at all.
        let png = dir.join("chart.png");
        let cases: Vec<Vec<ChartPoint>> = vec![
            vec![point("only", 3.0, 0.0)],
            vec![point("x", 3.0, 1.0), point("x-again", 3.0, 1.0)],
            vec![point("nan", f64::NAN, f64::NAN)],
            vec![],
        ];
        for pts in &cases {
            write_chart(pts, "edge", Some(&png), Some(&svg)).unwrap();
            assert_eq!(png_size(&std::fs::read(&png).unwrap()), (WIDTH, HEIGHT));
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn nothing_to_write_is_ok() {
        write_chart(&sweep_points(), "none", None, None).unwrap();
    }

    #[test]
    fn unwritable_path_gives_an_error_naming_it() {
        let dir = scratch_dir("unwritable");
        let missing = dir.join("no-such-directory");
        let png = missing.join("chart.png");
        let svg = missing.join("chart.svg");
        let e = write_chart(&sweep_points(), "t", Some(&png), None).unwrap_err();
        assert!(e.contains(&png.display().to_string()), "{e}");
        let e = write_chart(&sweep_points(), "t", None, Some(&svg)).unwrap_err();
        assert!(e.contains(&svg.display().to_string()), "{e}");
        assert!(!missing.exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn any_file_name_works_and_no_temporary_file_is_left() {
        // The PNG encoder alone would want a `.png` extension.
        let dir = scratch_dir("names");
        let (png, svg) = (dir.join("chart"), dir.join("chart-svg"));
        // Twice: the second replaces the first.
        for title in ["first", "second"] {
            write_chart(&sweep_points(), title, Some(&png), Some(&svg)).unwrap();
        }
        assert_eq!(png_size(&std::fs::read(&png).unwrap()), (WIDTH, HEIGHT));
        assert!(std::fs::read_to_string(&svg).unwrap().contains("second"));
        let mut names: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        names.sort();
        assert_eq!(names, ["chart", "chart-svg"]);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn ticks_are_short() {
        assert_eq!(tick(0.0), "0");
        assert_eq!(tick(200.0), "200");
        assert_eq!(tick(12.5), "12.5");
        assert_eq!(tick(2.0), "2");
        assert_eq!(tick(0.25), "0.25");
        assert_eq!(tick(0.00002), "2.0e-5");
    }
}
