//! Writing a chart to PNG and SVG: the bundled font, the temporary-file-then-rename write, and
//! one drawing routine serving both backends ([`Figure`], [`write_png_svg`]).
//!
//! Text is drawn with the bundled DejaVu Sans (`assets/fonts/DejaVuSans.ttf`, licence in
//! `assets/fonts/LICENSE-DejaVu.txt`), so the PNG does not depend on the fonts installed on the
//! machine. The SVG names the `sans-serif` family and lets the viewer pick a font.

use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::prelude::*;

/// The family every text of the charts uses; the bundled font is registered under it.
pub(crate) const FAMILY: &str = "sans-serif";
/// DejaVu Sans, bundled into the binary.
static FONT: &[u8] = include_bytes!(concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/assets/fonts/DejaVuSans.ttf"
));

/// A chart that draws itself on any plotters backend.
pub(crate) trait Figure {
    /// Draws the whole chart on `root`.
    fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
    ) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>>;
}

/// Draws `figure` at `size` pixels into `png` and/or `svg` (each drawn to a temporary file
/// beside it and renamed into place; the PNG first, and when it fails the SVG is not
/// attempted). Errors name the file.
pub(crate) fn write_png_svg(
    figure: &impl Figure,
    size: (u32, u32),
    png: Option<&Path>,
    svg: Option<&Path>,
) -> Result<(), String> {
    if let Some(path) = png {
        write_via_temporary(path, "png", |tmp| {
            register_bundled_font()?;
            let root = BitMapBackend::new(tmp, size).into_drawing_area();
            figure.draw(&root).map_err(|e| e.to_string())?;
            root.present().map_err(|e| e.to_string())
        })?;
    }
    if let Some(path) = svg {
        write_via_temporary(path, "svg", |tmp| {
            register_bundled_font()?;
            let mut text = String::new();
            {
                let root = SVGBackend::with_string(&mut text, size).into_drawing_area();
                figure.draw(&root).map_err(|e| e.to_string())?;
                root.present().map_err(|e| e.to_string())?;
            }
            std::fs::write(tmp, text).map_err(|e| e.to_string())
        })?;
    }
    Ok(())
}

/// Runs `write` on a temporary file next to `path`, named with the extension `ext` (the
/// PNG encoder picks the format from the extension), then renames it to `path`: any
/// name works for `path`, and a reader never sees half a chart. Errors name `path`;
/// the temporary file is removed on failure.
fn write_via_temporary(
    path: &Path,
    ext: &str,
    write: impl FnOnce(&Path) -> Result<(), String>,
) -> Result<(), String> {
    static COUNTER: AtomicUsize = AtomicUsize::new(0);
    let fail = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = path.with_file_name(format!(
        ".{name}.{}-{}.tmp.{ext}",
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    // Creating it first turns a missing or read-only directory into a plain I/O error.
    let written = std::fs::File::create(&tmp)
        .map_err(|e| e.to_string())
        .and_then(|_| write(&tmp))
        .and_then(|()| std::fs::rename(&tmp, path).map_err(|e| e.to_string()));
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written.map_err(|e| fail(&e))
}

/// Registers the bundled DejaVu Sans as plotters' `sans-serif` (once per process).
fn register_bundled_font() -> Result<(), &'static str> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED
        .get_or_init(|| plotters::style::register_font(FAMILY, FontStyle::Normal, FONT).is_ok());
    if ok {
        Ok(())
    } else {
        Err("the bundled font assets/fonts/DejaVuSans.ttf could not be loaded")
    }
}
