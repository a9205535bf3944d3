//! The benchmark's plots, drawn with plotters into an RGB buffer and written as PNG.
//! Text uses DejaVu Sans, embedded, so no system font is needed.

use super::{Results, Run, SceneResult};
use anyhow::{Result, anyhow};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;

/// One plotted line: its label, colour and points.
type Series = (String, RGBColor, Vec<(f64, f64)>);

/// The font family the plots name; registered once with the embedded font.
const FONT: &str = "sans-serif";
/// Side of one panel of a grid, in pixels.
const PANEL: (u32, u32) = (420, 300);

fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // DejaVu Sans is a valid TrueType font: registering it cannot fail.
        let _ = plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular());
    });
}

/// Line colour of a sampler.
fn sampler_colour(sampler: &str) -> RGBColor {
    match sampler {
        "independent" => RGBColor(31, 119, 180),
        "stratified" => RGBColor(255, 127, 14),
        "grid" => RGBColor(140, 140, 140),
        "sobol" => RGBColor(214, 39, 40),
        _ => RGBColor(44, 160, 44),
    }
}

const GPU_COLOUR: RGBColor = RGBColor(31, 119, 180);
const CPU_COLOUR: RGBColor = RGBColor(20, 20, 20);
const GUIDE: RGBColor = RGBColor(170, 170, 170);

type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

fn plot_err<E: std::fmt::Debug>(path: &Path) -> impl Fn(E) -> anyhow::Error + '_ {
    move |e| anyhow!("{}: cannot draw the plot: {e:?}", path.display())
}

/// Draws into a `width × height` RGB image and writes it to `path` as PNG.
fn draw_png(path: &Path, width: u32, height: u32, draw: &mut dyn FnMut(&Area) -> Result<()>) -> Result<()> {
    register_font();
    let mut buf = vec![255u8; width as usize * height as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (width, height)).into_drawing_area();
        draw(&root)?;
        root.present().map_err(plot_err(path))?;
    }
    let img = image::RgbImage::from_raw(width, height, buf).expect("buffer matches size");
    let mut bytes = Vec::new();
    image::DynamicImage::ImageRgb8(img)
        .write_to(&mut std::io::Cursor::new(&mut bytes), image::ImageFormat::Png)
        .map_err(|e| anyhow!("{}: {e}", path.display()))?;
    aorender::output::write_output(path, &bytes)?;
    Ok(())
}

/// A range of positive values padded by a factor on each side, for a log axis.
fn log_range(values: impl Iterator<Item = f64>) -> std::ops::Range<f64> {
    let (lo, hi) = values
        .filter(|v| v.is_finite() && *v > 0.0)
        .fold((f64::INFINITY, 0.0f64), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if !lo.is_finite() {
        return 0.1..10.0;
    }
    let (lo, hi) = if hi / lo < 10.0 { (lo / 2.0, hi * 2.0) } else { (lo / 1.3, hi * 1.3) };
    lo..hi
}

/// What the x axis of a convergence grid is.
#[derive(Clone, Copy, PartialEq)]
pub enum Axis {
    /// Samples per pixel.
    Spp,
    /// Seconds of rendering.
    Seconds,
}

/// RMSE against spp or seconds, log-log: one row of panels per scene, one column per
/// hemisphere (or overcast sky sampling), one line per sampler. The spp grid draws a slope
/// −1/2 guide through the independent sampler's first point and the reference's floor; the
/// seconds grid adds the CPU reference's run to the baseline's panel.
pub fn convergence(results: &Results, axis: Axis, path: &Path) -> Result<()> {
    let scenes: Vec<&SceneResult> = results.scenes.iter().filter(|s| !s.runs.is_empty()).collect();
    let mut hemispheres: Vec<String> = Vec::new();
    for s in &scenes {
        for r in s.runs.iter().filter(|r| r.device == "gpu") {
            if !hemispheres.contains(&r.distribution()) {
                hemispheres.push(r.distribution());
            }
        }
    }
    let (rows, cols) = (scenes.len().max(1), hemispheres.len().max(1));
    let title_h = 40;
    let (w, h) = (PANEL.0 * cols as u32, PANEL.1 * rows as u32 + title_h);
    let x_of = |c: &super::Checkpoint| match axis {
        Axis::Spp => c.spp as f64,
        Axis::Seconds => c.seconds,
    };
    let err = plot_err(path);
    draw_png(path, w, h, &mut |root| {
        root.fill(&WHITE).map_err(&err)?;
        let title = match axis {
            Axis::Spp => "RMSE against samples per pixel",
            Axis::Seconds => "RMSE against seconds of rendering",
        };
        let (top, body) = root.split_vertically(title_h);
        top.titled(&format!("{title} — {}", results.adapter.name), (FONT, 20)).map_err(&err)?;
        let panels = body.split_evenly((rows, cols));
        for (i, s) in scenes.iter().enumerate() {
            for (j, hemi) in hemispheres.iter().enumerate() {
                let panel = &panels[i * cols + j];
                let mut runs: Vec<&Run> =
                    s.runs.iter().filter(|r| r.device == "gpu" && &r.distribution() == hemi).collect();
                if axis == Axis::Seconds && runs.iter().any(|r| r.baseline) {
                    runs.extend(s.runs.iter().filter(|r| r.device == "cpu"));
                }
                let points = |r: &Run| -> Vec<(f64, f64)> {
                    r.checkpoints.iter().map(|c| (x_of(c), c.rmse)).filter(|p| p.0 > 0.0 && p.1 > 0.0).collect()
                };
                let floor = s.reference.rmse_floor;
                let xr = log_range(runs.iter().flat_map(|r| points(r)).map(|p| p.0));
                let yr = log_range(runs.iter().flat_map(|r| points(r)).map(|p| p.1).chain([floor]));
                let mut chart = ChartBuilder::on(panel)
                    .caption(format!("{} — {hemi}", s.name), (FONT, 15))
                    .margin(8)
                    .x_label_area_size(36)
                    .y_label_area_size(56)
                    .build_cartesian_2d(xr.clone().log_scale(), yr.clone().log_scale())
                    .map_err(&err)?;
                chart
                    .configure_mesh()
                    .x_desc(if axis == Axis::Spp { "samples per pixel" } else { "seconds" })
                    .y_desc("RMSE")
                    .x_labels(6)
                    .y_labels(6)
                    .x_label_formatter(&|v| short(*v))
                    .y_label_formatter(&|v| short(*v))
                    .label_style((FONT, 11))
                    .axis_desc_style((FONT, 12))
                    .light_line_style(WHITE.mix(0.0))
                    .draw()
                    .map_err(&err)?;
                if floor > 0.0 {
                    chart
                        .draw_series(DashedLineSeries::new(
                            [(xr.start, floor), (xr.end, floor)],
                            4,
                            4,
                            GUIDE.stroke_width(1),
                        ))
                        .map_err(&err)?
                        .label("reference floor")
                        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], GUIDE));
                }
                if axis == Axis::Spp
                    && let Some(first) =
                        runs.iter().find(|r| r.sampler == "independent").and_then(|r| points(r).first().copied())
                {
                    let guide: Vec<(f64, f64)> = [xr.start.max(first.0), xr.end]
                        .iter()
                        .map(|&x| (x, first.1 * (x / first.0).powf(-0.5)))
                        .collect();
                    chart
                        .draw_series(DashedLineSeries::new(guide, 6, 4, BLACK.mix(0.5).stroke_width(1)))
                        .map_err(&err)?
                        .label("slope −1/2")
                        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLACK.mix(0.5)));
                }
                for r in &runs {
                    let colour = if r.device == "cpu" { CPU_COLOUR } else { sampler_colour(&r.sampler) };
                    let pts = points(r);
                    let label = if r.device == "cpu" {
                        "CPU reference, independent".to_string()
                    } else {
                        match r.slope {
                            Some(k) => format!("{} ({k:.2})", r.sampler),
                            None => r.sampler.clone(),
                        }
                    };
                    chart
                        .draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))
                        .map_err(&err)?
                        .label(label)
                        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2)));
                    chart.draw_series(pts.iter().map(|&p| Circle::new(p, 2, colour.filled()))).map_err(&err)?;
                }
                chart
                    .configure_series_labels()
                    .position(SeriesLabelPosition::LowerLeft)
                    .background_style(WHITE.mix(0.85))
                    .border_style(BLACK.mix(0.3))
                    .label_font((FONT, 10))
                    .margin(4)
                    .draw()
                    .map_err(&err)?;
            }
        }
        Ok(())
    })
}

/// A tick label: plain for moderate values, exponent notation beyond.
fn short(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if (1e-2..1e5).contains(&a) {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        format!("{v:.0e}")
    }
}

/// One line per device through `(x, y)` points, log-log, in `area`.
#[allow(clippy::too_many_arguments)]
fn series_panel(
    area: &Area,
    path: &Path,
    caption: &str,
    x_desc: &str,
    y_desc: &str,
    lines: &[Series],
    labels: &[(f64, f64, String)],
) -> Result<()> {
    let err = plot_err(path);
    let xr = log_range(lines.iter().flat_map(|l| l.2.iter().map(|p| p.0)));
    let yr = log_range(lines.iter().flat_map(|l| l.2.iter().map(|p| p.1)));
    let mut chart = ChartBuilder::on(area)
        .caption(caption, (FONT, 15))
        .margin(10)
        .x_label_area_size(38)
        .y_label_area_size(60)
        .build_cartesian_2d(xr.log_scale(), yr.log_scale())
        .map_err(&err)?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .x_labels(6)
        .y_labels(6)
        .x_label_formatter(&|v| short(*v))
        .y_label_formatter(&|v| short(*v))
        .label_style((FONT, 11))
        .axis_desc_style((FONT, 12))
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(&err)?;
    for (name, colour, pts) in lines {
        let colour = *colour;
        chart
            .draw_series(LineSeries::new(pts.clone(), colour.stroke_width(2)))
            .map_err(&err)?
            .label(name.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2)));
        chart.draw_series(pts.iter().map(|&p| Circle::new(p, 3, colour.filled()))).map_err(&err)?;
    }
    // Labels sit beside their points, offset in pixels.
    chart
        .draw_series(labels.iter().map(|(x, y, t)| {
            EmptyElement::at((*x, *y)) + Text::new(t.clone(), (5, -14), (FONT, 10).into_font().color(&BLACK.mix(0.7)))
        }))
        .map_err(&err)?;
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.3))
        .label_font((FONT, 11))
        .draw()
        .map_err(&err)?;
    Ok(())
}

/// Rays per second against primitives (triangles, plus spheres for aobench), GPU and
/// CPU, from each scene's cosine / independent run at N spp.
pub fn rays_vs_triangles(results: &Results, path: &Path) -> Result<()> {
    let mut lines = Vec::new();
    let mut labels = Vec::new();
    for (device, name, colour) in
        [("gpu", results.adapter.name.as_str(), GPU_COLOUR), ("cpu", "CPU reference", CPU_COLOUR)]
    {
        let mut pts: Vec<(f64, f64)> = Vec::new();
        for s in &results.scenes {
            if let Some(r) = s.runs.iter().find(|r| r.device == device && r.baseline) {
                let p = ((s.triangles + s.spheres).max(1) as f64, r.last().rays_per_second / 1e6);
                pts.push(p);
                if device == "gpu" {
                    labels.push((p.0, p.1, s.name.clone()));
                }
            }
        }
        pts.sort_by(|a, b| a.0.total_cmp(&b.0));
        if !pts.is_empty() {
            lines.push((name.to_string(), colour, pts));
        }
    }
    let err = plot_err(path);
    draw_png(path, 760, 520, &mut |root| {
        root.fill(&WHITE).map_err(&err)?;
        series_panel(
            root,
            path,
            "Rays per second against scene size (cosine / independent)",
            "primitives (triangles; spheres for aobench)",
            "million rays per second",
            &lines,
            &labels,
        )
    })
}

/// Seconds per million rays against image size and against spp, and the BVH presets'
/// trace speed against their build time.
pub fn scaling(results: &Results, path: &Path) -> Result<()> {
    let series = |name: &str| -> Vec<Series> {
        let mut out = Vec::new();
        let mut keys: Vec<(String, String)> = Vec::new();
        for p in results.scaling.iter().filter(|p| p.series == name) {
            let k = (p.scene.clone(), p.device.clone());
            if !keys.contains(&k) {
                keys.push(k);
            }
        }
        for (scene, device) in keys {
            let mut pts: Vec<(f64, f64)> = results
                .scaling
                .iter()
                .filter(|p| p.series == name && p.scene == scene && p.device == device)
                .map(|p| (p.x, p.seconds_per_mray))
                .collect();
            pts.sort_by(|a, b| a.0.total_cmp(&b.0));
            let colour = if device == "cpu" { CPU_COLOUR } else { GPU_COLOUR };
            out.push((format!("{scene}, {}", device.to_uppercase()), colour, pts));
        }
        out
    };
    let spp_lines: Vec<_> = {
        // One scene's spp series: the one the resolution series uses, else the first.
        let all = series("spp");
        let pick = results.scaling.iter().find(|p| p.series == "resolution").map(|p| p.scene.clone());
        let scene = pick.or_else(|| all.first().map(|l| l.0.split(',').next().unwrap_or("").to_string()));
        all.into_iter().filter(|l| scene.as_ref().is_some_and(|s| l.0.starts_with(&format!("{s},")))).collect()
    };
    let mut preset_lines = Vec::new();
    let mut preset_labels = Vec::new();
    let mut preset_scenes: Vec<String> = Vec::new();
    for p in &results.bvh_presets {
        if !preset_scenes.contains(&p.scene) {
            preset_scenes.push(p.scene.clone());
        }
    }
    let palette = [GPU_COLOUR, RGBColor(214, 39, 40), RGBColor(44, 160, 44), RGBColor(255, 127, 14)];
    for (k, scene) in preset_scenes.iter().enumerate() {
        let pts: Vec<(f64, f64)> = results
            .bvh_presets
            .iter()
            .filter(|p| &p.scene == scene)
            .map(|p| {
                preset_labels.push((p.build_seconds, p.gpu_rays_per_second / 1e6, p.preset.clone()));
                (p.build_seconds, p.gpu_rays_per_second / 1e6)
            })
            .collect();
        preset_lines.push((format!("{scene}, GPU"), palette[k % palette.len()], pts));
    }
    let err = plot_err(path);
    draw_png(path, 1500, 460, &mut |root| {
        root.fill(&WHITE).map_err(&err)?;
        let panels = root.split_evenly((1, 3));
        series_panel(
            &panels[0],
            path,
            "Cost per ray against image size",
            "pixels",
            "seconds per million rays",
            &series("resolution"),
            &[],
        )?;
        series_panel(
            &panels[1],
            path,
            "Cost per ray against samples per pixel",
            "spp (samples from spp/2 to spp)",
            "seconds per million rays",
            &spp_lines,
            &[],
        )?;
        series_panel(
            &panels[2],
            path,
            "BVH presets: trace speed against build time",
            "build seconds",
            "GPU million rays per second",
            &preset_lines,
            &preset_labels,
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_ranges_are_padded_and_positive() {
        let r = log_range([1.0, 100.0, 0.0, f64::NAN].into_iter());
        assert!(r.start > 0.0 && r.start < 1.0 && r.end > 100.0);
        let r = log_range([2.0, 3.0].into_iter());
        assert_eq!(r, 1.0..6.0);
        assert_eq!(log_range(std::iter::empty()), 0.1..10.0);
    }
}
