//! A rendered view of a registered surface beside the truth, coloured by error: what a person
//! looks at before reading numbers. Orthographic projection along a view direction, triangles
//! painted back to front (painter's algorithm) with Lambert shading; the registered surface is
//! coloured by each triangle's mean vertex error on a blue → red scale, the truth is grey.
//! PNG and SVG; lengths in any one unit, errors in mm.

use std::path::Path;

use nalgebra::{Point3, Vector3};
use plotters::prelude::*;

use super::output::{write_png_svg, Figure};
use crate::mesh::TriSurface;

const WIDTH: u32 = 1100;
const HEIGHT: u32 = 560;

/// What to draw: the registered surface with an error (mm) per vertex, and the truth.
pub struct SurfaceView<'a> {
    /// The registered surface.
    pub registered: &'a TriSurface,
    /// Error per vertex of `registered`, mm.
    pub error_mm: &'a [f64],
    /// The true surface (same units).
    pub truth: &'a TriSurface,
    /// Direction the viewer looks along.
    pub view: Vector3<f64>,
    /// Top of the colour scale, mm (errors above are red).
    pub scale_mm: f64,
}

/// Blue (0) → green → red (`scale_mm` and above).
fn heat(e: f64, scale: f64) -> RGBColor {
    let t = (e / scale.max(1e-12)).clamp(0.0, 1.0);
    let (r, g, b) = if t < 0.5 {
        let u = t / 0.5;
        (0.0, u, 1.0 - u)
    } else {
        let u = (t - 0.5) / 0.5;
        (u, 1.0 - u, 0.0)
    };
    RGBColor(
        (40.0 + 215.0 * r) as u8,
        (40.0 + 200.0 * g) as u8,
        (40.0 + 215.0 * b) as u8,
    )
}

/// Writes the view to `png` and/or `svg` with `title`. Errors name the file.
pub fn write_surface_view(
    v: &SurfaceView,
    title: &str,
    png: Option<&Path>,
    svg: Option<&Path>,
) -> Result<(), String> {
    if v.error_mm.len() != v.registered.vertices.len() {
        return Err(format!(
            "{} errors for {} vertices",
            v.error_mm.len(),
            v.registered.vertices.len()
        ));
    }
    write_png_svg(&ViewFigure { v, title }, (WIDTH, HEIGHT), png, svg)
}

struct ViewFigure<'a, 'b> {
    v: &'a SurfaceView<'b>,
    title: &'a str,
}

impl Figure for ViewFigure<'_, '_> {
    fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, plotters::coord::Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        render(root, self.v, self.title)
    }
}

/// An orthonormal screen basis (right, up) for looking along `view`.
fn basis(view: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
    let d = view.try_normalize(1e-12).unwrap_or(-Vector3::y());
    let hint = if d.z.abs() > 0.9 {
        Vector3::y()
    } else {
        Vector3::z()
    };
    let right = d.cross(&hint).normalize();
    let up = right.cross(&d);
    (right, up, d)
}

fn render<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    v: &SurfaceView,
    title: &str,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    root.fill(&WHITE)?;
    let root = root.titled(title, ("sans-serif", 20))?;
    let (body, bar) = root.split_horizontally(WIDTH - 90);
    let panels = body.split_evenly((1, 2));
    let (right, up, d) = basis(&v.view);
    // One frame for both panels: the union of the two projections.
    let project = |p: &Point3<f64>| (p.coords.dot(&right), p.coords.dot(&up));
    let all: Vec<(f64, f64)> = v
        .registered
        .vertices
        .iter()
        .chain(&v.truth.vertices)
        .map(project)
        .collect();
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for (x, y) in &all {
        x0 = x0.min(*x);
        x1 = x1.max(*x);
        y0 = y0.min(*y);
        y1 = y1.max(*y);
    }
    let span = (x1 - x0).max(y1 - y0).max(1e-12) * 1.05;
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    for (panel, (surface, coloured, label)) in panels.iter().zip([
        (v.registered, true, "registered, coloured by error"),
        (v.truth, false, "truth"),
    ]) {
        let (w, h) = panel.dim_in_pixel();
        let side = w.min(h.saturating_sub(30)) as f64;
        let to_px = |p: &Point3<f64>| {
            let (x, y) = project(p);
            (
                (w as f64 / 2.0 + (x - cx) / span * side) as i32,
                (h as f64 / 2.0 + 10.0 - (y - cy) / span * side) as i32,
            )
        };
        let mut order: Vec<(f64, usize)> = (0..surface.triangles.len())
            .map(|t| {
                let c = surface.corners(t);
                (-(c[0].coords + c[1].coords + c[2].coords).dot(&d), t)
            })
            .collect();
        order.sort_by(|a, b| a.0.total_cmp(&b.0));
        for (_, t) in order {
            let n = surface.scaled_normal(t);
            let Some(n) = n.try_normalize(1e-300) else {
                continue;
            };
            let facing = -n.dot(&d);
            if facing <= 0.0 {
                continue; // back face
            }
            let shade = 0.35 + 0.65 * facing;
            let base = if coloured {
                let tri = surface.triangles[t];
                let e = tri.iter().map(|&i| v.error_mm[i]).sum::<f64>() / 3.0;
                heat(e, v.scale_mm)
            } else {
                RGBColor(200, 200, 200)
            };
            let c = RGBColor(
                (base.0 as f64 * shade) as u8,
                (base.1 as f64 * shade) as u8,
                (base.2 as f64 * shade) as u8,
            );
            let pts: Vec<(i32, i32)> = surface.corners(t).iter().map(to_px).collect();
            panel.draw(&Polygon::new(pts, c.filled()))?;
        }
        panel.draw_text(
            label,
            &("sans-serif", 16).into_font().color(&BLACK),
            (10, 5),
        )?;
    }
    // Colour bar.
    let (_, bh) = bar.dim_in_pixel();
    let (top, bottom) = (40, bh as i32 - 40);
    for py in top..bottom {
        let e = (bottom - py) as f64 / (bottom - top) as f64 * v.scale_mm;
        bar.draw(&Rectangle::new(
            [(10, py), (35, py + 1)],
            heat(e, v.scale_mm).filled(),
        ))?;
    }
    let font = ("sans-serif", 14).into_font().color(&BLACK);
    bar.draw_text(&format!("{:.1} mm", v.scale_mm), &font, (5, top - 20))?;
    bar.draw_text("0 mm", &font, (5, bottom + 5))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::primitives::icosphere;

    /// A sphere against itself moved: both panels are drawn, the PNG decodes as a PNG with red
    /// where the error is largest, and a wrong error count is refused.
    #[test]
    fn draws_both_panels_and_checks_its_input() {
        let truth = icosphere(Point3::origin(), 50.0, 3);
        let registered = truth.clone();
        let error: Vec<f64> = registered
            .vertices
            .iter()
            .map(|p| (p.x + 50.0) / 10.0)
            .collect();
        let dir = std::env::temp_dir().join(format!("livereg-view-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let view = SurfaceView {
            registered: &registered,
            error_mm: &error,
            truth: &truth,
            view: -Vector3::y(),
            scale_mm: 10.0,
        };
        let (png, svg) = (dir.join("v.png"), dir.join("v.svg"));
        write_surface_view(&view, "test", Some(&png), Some(&svg)).unwrap();
        assert_eq!(&std::fs::read(&png).unwrap()[1..4], b"PNG");
        let text = std::fs::read_to_string(&svg).unwrap();
        assert!(text.contains("registered") && text.contains("truth"));
        let short = SurfaceView {
            error_mm: &error[1..],
            ..view
        };
        assert!(write_surface_view(&short, "x", Some(&png), None).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
