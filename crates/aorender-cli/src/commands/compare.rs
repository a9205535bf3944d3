//! Comparison grids: one scene rendered at several sample counts (columns) with several
//! hemisphere distributions and point samplers (rows), composed into one labelled image.
//!
//! Every cell is a render of its own, with the scene's settings except for the sample
//! count, hemisphere and sampler, so the stratified sampler uses n×n cells at 4, 9, 16, …
//! samples per pixel.
//!
//! One session serves every cell: the BVH is built and uploaded once, and each cell is a
//! request with its own settings.

use crate::args::{
    SceneArgs, SizeArgs, SkyArgs, check_output_extension, hemisphere_parser, invalid_option, sampler_parser, write_json,
};
use crate::output;
use anyhow::{Result, anyhow};
use aorender::output::{FilePlan, linear_to_srgb8, write_output};
use aorender::{Control, Hemisphere, ImageRequest, Progress, Sampler, Session};
use image::{GrayImage, Luma};
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(clap::Args)]
pub struct CompareArgs {
    #[command(flatten)]
    scene: SceneArgs,
    #[command(flatten)]
    size: SizeArgs,
    /// Output image (.png).
    #[arg(short, long, default_value = "compare.png")]
    output: PathBuf,
    /// Samples per pixel of the columns, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "1,4,9,16,256,1024")]
    spp: Vec<u32>,
    /// Hemisphere distributions of the rows, comma-separated.
    #[arg(long, value_delimiter = ',', value_parser = hemisphere_parser(), default_value = "uniform,cosine")]
    hemisphere: Vec<Hemisphere>,
    /// Point samplers, comma-separated; each gets one row per hemisphere.
    #[arg(long, value_delimiter = ',', value_parser = sampler_parser(), default_value = "independent")]
    sampler: Vec<Sampler>,
    /// Write the statistics of every cell as JSON.
    #[arg(long)]
    stats: Option<PathBuf>,
    /// The sky of every cell.
    #[command(flatten)]
    sky: SkyArgs,
}

pub fn command(args: CompareArgs) -> Result<()> {
    let mut plan = FilePlan::new();
    output::plan_scene(&mut plan, args.scene.scene.as_deref());
    plan.output(&args.output, "-o")?;
    if let Some(path) = &args.stats {
        plan.output(path, "--stats")?;
    }
    let mut scene = args.scene.load()?;
    args.size.apply(&mut scene);
    args.sky.apply(&mut scene)?;
    validate(&args.spp, &args.hemisphere, &args.sampler).map_err(|m| anyhow!("invalid option: {m}"))?;
    scene.settings.spp = args.spp.iter().copied().max().unwrap_or(1);
    scene.settings.validate().map_err(invalid_option)?;
    check_output_extension(&args.output, &["png"])?;
    let start = Instant::now();
    let session = Session::new(&args.scene.device()?, scene, &args.scene.bvh())?;
    let mut on_progress = |p: &CompareProgress| {
        if p.render.is_none() {
            crate::say!(
                "rendering {}/{} at {} spp ({} of {})",
                p.hemisphere.name(),
                p.sampler.name(),
                p.spp,
                p.cell + 1,
                p.cells
            );
        }
    };
    let mut grid = run(&session, &args.spp, &args.hemisphere, &args.sampler, &mut on_progress)?;
    grid.total_seconds = start.elapsed().as_secs_f64();
    grid.write_png(&args.output)?;
    if let Some(path) = &args.stats {
        write_json(path, &serde_json::to_string_pretty(&grid)?)?;
    }
    let mut table = format!("{:<12} {:<12} {:>6} {:>8} {:>8}\n", "sampler", "hemisphere", "spp", "mean", "seconds");
    for c in &grid.cells {
        table += &format!(
            "{:<12} {:<12} {:>6} {:>8.4} {:>8.2}\n",
            c.sampler.name(),
            c.hemisphere.name(),
            c.spp,
            c.image_mean,
            c.render_seconds
        );
    }
    output::print(&table)?;
    crate::say!(
        "{}: {} cells of {}x{} in {:.1} s on {} ({})",
        args.output.display(),
        grid.cells.len(),
        grid.width,
        grid.height,
        grid.total_seconds,
        grid.adapter,
        grid.backend
    );
    Ok(())
}

/// Magnification of the 8×8 font.
const TEXT_SCALE: u32 = 2;
/// Side of a magnified glyph.
const GLYPH: u32 = 8 * TEXT_SCALE;
/// Distance between the tops of consecutive text lines.
const LINE_PITCH: u32 = GLYPH + 4;
/// Border around the whole image.
const MARGIN: u32 = 12;
/// Space between neighbouring tiles.
const TILE_GAP: u32 = 6;
/// Space between the labels and the tiles, and below the title.
const LABEL_GAP: u32 = 10;
/// Background grey (sRGB-encoded).
const BACKGROUND: u8 = 235;
/// Text grey (sRGB-encoded).
const INK: u8 = 20;

/// What is wrong with the lists of a comparison, naming the list and the value.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum ListError {
    /// A list with nothing in it ("sample counts", "hemispheres", "samplers").
    #[error("the list of {0} is empty")]
    Empty(&'static str),
    /// A sample count of zero.
    #[error("samples per pixel must be at least 1, got 0")]
    ZeroSamples,
    /// A sample count given twice.
    #[error("sample count {0} is listed twice")]
    SampleCountTwice(u32),
    /// A hemisphere given twice.
    #[error("hemisphere '{}' is listed twice", .0.name())]
    HemisphereTwice(Hemisphere),
    /// A sampler given twice.
    #[error("sampler '{}' is listed twice", .0.name())]
    SamplerTwice(Sampler),
}

/// Checks the lists of a comparison: none empty, no sample count of zero, no entry twice.
pub fn validate(spps: &[u32], hemispheres: &[Hemisphere], samplers: &[Sampler]) -> std::result::Result<(), ListError> {
    if spps.is_empty() {
        return Err(ListError::Empty("sample counts"));
    }
    if hemispheres.is_empty() {
        return Err(ListError::Empty("hemispheres"));
    }
    if samplers.is_empty() {
        return Err(ListError::Empty("samplers"));
    }
    if spps.contains(&0) {
        return Err(ListError::ZeroSamples);
    }
    if let Some(n) = first_duplicate(spps) {
        return Err(ListError::SampleCountTwice(n));
    }
    if let Some(h) = first_duplicate(hemispheres) {
        return Err(ListError::HemisphereTwice(h));
    }
    if let Some(s) = first_duplicate(samplers) {
        return Err(ListError::SamplerTwice(s));
    }
    Ok(())
}

fn first_duplicate<T: PartialEq + Copy>(items: &[T]) -> Option<T> {
    items.iter().enumerate().find(|(i, x)| items[..*i].contains(x)).map(|(_, &x)| x)
}

/// Figures of one cell's render.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CellStats {
    /// Point sampler.
    pub sampler: Sampler,
    /// Hemisphere distribution.
    pub hemisphere: Hemisphere,
    /// Samples per pixel asked for (the column).
    pub spp: u32,
    /// Samples per pixel rendered (fewer than asked when a time limit hit).
    pub samples_per_pixel: u32,
    /// Mean of the image.
    pub image_mean: f64,
    /// Seconds spent in passes (BVH build and upload excluded).
    pub render_seconds: f64,
    /// Seconds to build the BVH.
    pub bvh_build_seconds: f64,
    /// Seconds to upload buffers and create the pipeline (GPU only).
    pub setup_seconds: f64,
    /// Camera rays plus AO rays.
    pub rays_traced: u64,
    /// rays_traced / render_seconds.
    pub rays_per_second: f64,
}

/// A finished comparison: the per-cell figures (serialised by `--stats`) and images.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Comparison {
    /// Scene name.
    pub scene: String,
    /// Width of each cell's image.
    pub width: u32,
    /// Height of each cell's image.
    pub height: u32,
    /// Random seed shared by all cells.
    pub seed: u32,
    /// The sky of every cell (`Sky::describe`).
    pub sky: String,
    /// Adapter name ("cpu" for the reference).
    pub adapter: String,
    /// wgpu backend, or "cpu".
    pub backend: String,
    /// Wall-clock seconds for all cells, device setup and the BVH build included.
    pub total_seconds: f64,
    /// One entry per cell, row by row: for each sampler, for each hemisphere, for each
    /// sample count, in the order given.
    pub cells: Vec<CellStats>,
    /// Column sample counts.
    #[serde(skip)]
    pub spps: Vec<u32>,
    /// Row (sampler, hemisphere) pairs, top to bottom.
    #[serde(skip)]
    pub rows: Vec<(Sampler, Hemisphere)>,
    /// Per-pixel means of each cell (row-major pixels), in the order of `cells`.
    #[serde(skip)]
    pub tiles: Vec<Vec<f64>>,
}

/// Where a comparison is: reported before each cell (`render` is `None`) and after each
/// pass of its render.
#[derive(Clone, Copy, Debug)]
pub struct CompareProgress {
    /// Index of the cell, from 0.
    pub cell: usize,
    /// Number of cells.
    pub cells: usize,
    /// The cell's sample count.
    pub spp: u32,
    /// The cell's hemisphere.
    pub hemisphere: Hemisphere,
    /// The cell's sampler.
    pub sampler: Sampler,
    /// Progress of the cell's render.
    pub render: Option<Progress>,
}

/// Renders every cell of the grid on `session`: rows are the samplers in order, each
/// split into the hemispheres in order; columns are the sample counts. Each cell renders
/// the session's scene with its settings, except for the cell's sample count, hemisphere
/// and sampler. [`Comparison::total_seconds`] counts the cells' requests.
pub fn run(
    session: &Session,
    spps: &[u32],
    hemispheres: &[Hemisphere],
    samplers: &[Sampler],
    progress: &mut dyn FnMut(&CompareProgress),
) -> Result<Comparison> {
    validate(spps, hemispheres, samplers).map_err(|m| anyhow!("{}: {m}", session.scene().name))?;
    let start = Instant::now();
    let scene = session.scene();
    let rows: Vec<(Sampler, Hemisphere)> =
        samplers.iter().flat_map(|&s| hemispheres.iter().map(move |&h| (s, h))).collect();
    let count = rows.len() * spps.len();
    let mut request: ImageRequest = session.default_request();
    let (mut cells, mut tiles) = (Vec::with_capacity(count), Vec::with_capacity(count));
    let (adapter, backend) = (session.setup().adapter.name.clone(), session.setup().adapter.backend.clone());
    for &(sampler, hemisphere) in &rows {
        for &spp in spps {
            let s = &mut request.settings;
            (s.spp, s.sampling.hemisphere, s.sampling.sampler) = (spp, hemisphere, sampler);
            let mut at = CompareProgress { cell: cells.len(), cells: count, spp, hemisphere, sampler, render: None };
            progress(&at);
            let mut on_progress = |p: &Progress| {
                at.render = Some(*p);
                progress(&at);
            };
            let mut control = Control { progress: Some(&mut on_progress), ..Control::default() };
            let out = session.render(&request)?.complete(&mut control)?;
            let st = out.stats;
            cells.push(CellStats {
                sampler,
                hemisphere,
                spp,
                samples_per_pixel: st.samples_per_pixel,
                image_mean: st.image_mean,
                render_seconds: st.render_seconds,
                bvh_build_seconds: st.bvh_build_seconds,
                setup_seconds: st.setup_seconds,
                rays_traced: st.rays_traced,
                rays_per_second: st.rays_per_second,
            });
            tiles.push(out.film.mean());
        }
    }
    Ok(Comparison {
        scene: scene.name.clone(),
        width: scene.settings.width,
        height: scene.settings.height,
        seed: scene.settings.sampling.seed,
        sky: scene.settings.sampling.sky.describe(),
        adapter,
        backend,
        total_seconds: start.elapsed().as_secs_f64(),
        cells,
        spps: spps.to_vec(),
        rows,
        tiles,
    })
}

impl Comparison {
    /// The labelled grid: title, "N spp" column labels, hemisphere and sampler row labels.
    pub fn image(&self) -> GrayImage {
        let mut title = format!("{}  {}x{}  seed {}", self.scene, self.width, self.height, self.seed);
        if self.sky != "uniform" {
            // The model and its sampling; the rest is in the statistics.
            let sampling = self.sky.split(", ").find(|p| p.ends_with(" sampling")).unwrap_or("");
            title += &format!("  overcast sky, {sampling}");
        }
        let columns: Vec<String> = self.spps.iter().map(|n| format!("{n} spp")).collect();
        let rows: Vec<Vec<String>> =
            self.rows.iter().map(|(s, h)| vec![h.name().to_string(), s.name().to_string()]).collect();
        compose_grid(&Grid {
            title: &title,
            columns: &columns,
            rows: &rows,
            tile_width: self.width,
            tile_height: self.height,
            tiles: &self.tiles,
        })
    }

    /// Writes [`Comparison::image`] as an 8-bit PNG, atomically, whatever the extension.
    pub fn write_png(&self, path: &Path) -> Result<()> {
        let mut buf = std::io::Cursor::new(Vec::new());
        self.image().write_to(&mut buf, image::ImageFormat::Png).map_err(|e| anyhow!("{}: {e}", path.display()))?;
        write_output(path, buf.get_ref())?;
        Ok(())
    }
}

/// What [`compose_grid`] lays out.
#[derive(Clone, Copy, Debug)]
pub struct Grid<'a> {
    /// Line above everything.
    pub title: &'a str,
    /// One label per column, above it.
    pub columns: &'a [String],
    /// One label per row, left of it, one entry per text line.
    pub rows: &'a [Vec<String>],
    /// Width of every tile.
    pub tile_width: u32,
    /// Height of every tile.
    pub tile_height: u32,
    /// Linear per-pixel values of each tile (row-major pixels), row by row:
    /// `rows.len() × columns.len()` tiles.
    pub tiles: &'a [Vec<f64>],
}

/// Composes a labelled grid of tiles into one 8-bit grey image: dark text on a light
/// background, the title on top, column labels centred above the columns, row labels
/// left of the rows, and tiles mapped as PNG renders are (clamped to [0, 1], sRGB
/// encoded, rounded). Text is the 8×8 font at twice its size; characters outside ASCII
/// show as `?`. A column (row) is as wide (tall) as its tile or its label, whichever is
/// larger (a column label with half a glyph of space either side), with the tile
/// centred in it.
///
/// # Panics
/// If the number of tiles is not `rows.len() × columns.len()` or a tile does not hold
/// `tile_width × tile_height` values.
pub fn compose_grid(grid: &Grid) -> GrayImage {
    let (ncols, nrows) = (grid.columns.len() as u32, grid.rows.len() as u32);
    let (tw, th) = (grid.tile_width, grid.tile_height);
    assert_eq!(grid.tiles.len(), (ncols * nrows) as usize, "one tile per row and column");
    let lines = |label: &[String]| label.len() as u32;
    // Column labels keep half a glyph clear on either side.
    let col_w = grid.columns.iter().map(|c| text_width(c) + GLYPH).fold(tw, u32::max);
    let row_h = grid.rows.iter().map(|r| text_height(lines(r))).fold(th, u32::max);
    let label_w = grid.rows.iter().flatten().map(|l| text_width(l)).max().unwrap_or(0);

    let x_tiles = MARGIN + label_w + if label_w > 0 { LABEL_GAP } else { 0 };
    let y_header = MARGIN + GLYPH + LABEL_GAP;
    let y_tiles = y_header + GLYPH + LABEL_GAP;
    let span = |n: u32, size: u32| n * size + n.saturating_sub(1) * TILE_GAP;
    let width = (x_tiles + span(ncols, col_w) + MARGIN).max(2 * MARGIN + text_width(grid.title));
    let height = y_tiles + span(nrows, row_h) + MARGIN;

    let mut img = GrayImage::from_pixel(width, height, Luma([BACKGROUND]));
    draw_text(&mut img, MARGIN, MARGIN, grid.title);
    for (c, label) in grid.columns.iter().enumerate() {
        let x = x_tiles + c as u32 * (col_w + TILE_GAP);
        draw_text(&mut img, x + (col_w - text_width(label)) / 2, y_header, label);
    }
    for (r, label) in grid.rows.iter().enumerate() {
        let y = y_tiles + r as u32 * (row_h + TILE_GAP);
        let top = y + (row_h - text_height(lines(label))) / 2;
        for (i, line) in label.iter().enumerate() {
            draw_text(&mut img, MARGIN, top + i as u32 * LINE_PITCH, line);
        }
        for c in 0..ncols {
            let tile = &grid.tiles[r * ncols as usize + c as usize];
            assert_eq!(tile.len(), (tw * th) as usize, "tile {r},{c} does not match the tile size");
            let x0 = x_tiles + c * (col_w + TILE_GAP) + (col_w - tw) / 2;
            let y0 = y + (row_h - th) / 2;
            for (i, &v) in tile.iter().enumerate() {
                let (x, y) = (i as u32 % tw, i as u32 / tw);
                img.put_pixel(x0 + x, y0 + y, Luma([linear_to_srgb8(v as f32)]));
            }
        }
    }
    img
}

fn text_width(text: &str) -> u32 {
    text.chars().count() as u32 * GLYPH
}

fn text_height(lines: u32) -> u32 {
    (lines * LINE_PITCH).saturating_sub(LINE_PITCH - GLYPH)
}

/// Draws `text` with its top-left corner at `(x, y)`, clipped to the image.
fn draw_text(img: &mut GrayImage, x: u32, y: u32, text: &str) {
    for (i, ch) in text.chars().enumerate() {
        let glyph = font8x8::legacy::BASIC_LEGACY[if ch.is_ascii() { ch as usize } else { '?' as usize }];
        let gx = x + i as u32 * GLYPH;
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..8 {
                if bits >> col & 1 == 0 {
                    continue;
                }
                for dy in 0..TEXT_SCALE {
                    for dx in 0..TEXT_SCALE {
                        let (px, py) = (gx + col * TEXT_SCALE + dx, y + row as u32 * TEXT_SCALE + dy);
                        if px < img.width() && py < img.height() {
                            img.put_pixel(px, py, Luma([INK]));
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sRGB code of a linear value, computed independently of the library.
    fn srgb8(v: f64) -> u8 {
        let v = v.clamp(0.0, 1.0);
        let s = if v <= 0.0031308 { 12.92 * v } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 };
        (s * 255.0).round() as u8
    }

    /// Bounding box (x0, y0, x1, y1), exclusive ends, and count of the pixels equal to `value`.
    fn pixels_equal_to(img: &GrayImage, value: u8) -> ((u32, u32, u32, u32), usize) {
        let (mut x0, mut y0, mut x1, mut y1, mut n) = (u32::MAX, u32::MAX, 0, 0, 0);
        for (x, y, p) in img.enumerate_pixels() {
            if p.0[0] == value {
                (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x + 1), y1.max(y + 1));
                n += 1;
            }
        }
        ((x0, y0, x1, y1), n)
    }

    /// Pixels darker than the tiles' darkest value inside the rectangle [x0, x1) × [y0, y1).
    fn dark_pixels(img: &GrayImage, (x0, y0, x1, y1): (u32, u32, u32, u32)) -> usize {
        (y0..y1).flat_map(|y| (x0..x1).map(move |x| (x, y))).filter(|&(x, y)| img.get_pixel(x, y).0[0] < 32).count()
    }

    #[test]
    fn grid_places_constant_tiles_and_dark_labels() {
        let (tw, th) = (120u32, 48u32);
        // Distinct sRGB codes, none of them the background or the text: each tile can be found
        // by its value. 4.0 is clamped to white.
        let values = [0.02, 0.1, 0.25, 0.5, 0.75, 4.0];
        let tiles: Vec<Vec<f64>> = values.iter().map(|&v| vec![v; (tw * th) as usize]).collect();
        let columns: Vec<String> = ["1 spp", "4 spp", "16 spp"].map(String::from).to_vec();
        let rows = vec![vec!["uniform".to_string(), "independent".to_string()], vec!["cosine".into(), "sobol".into()]];
        let img = compose_grid(&Grid {
            title: "test scene",
            columns: &columns,
            rows: &rows,
            tile_width: tw,
            tile_height: th,
            tiles: &tiles,
        });

        let mut boxes = Vec::new();
        for &v in &values {
            assert_eq!(linear_to_srgb8(v as f32), srgb8(v), "sRGB code of {v}");
            let (bbox, n) = pixels_equal_to(&img, srgb8(v));
            assert_eq!(n, (tw * th) as usize, "pixels of the tile of value {v}");
            assert_eq!((bbox.2 - bbox.0, bbox.3 - bbox.1), (tw, th), "tile of value {v} is not one rectangle");
            boxes.push(bbox);
        }
        assert_eq!(linear_to_srgb8(-1.0f32), 0);
        assert_eq!(linear_to_srgb8(f32::NAN), 0);

        // Row-major order, aligned, separated by a small gap.
        let gap_x = boxes[1].0 - boxes[0].2;
        let gap_y = boxes[3].1 - boxes[0].3;
        assert!((1..=16).contains(&gap_x) && (1..=16).contains(&gap_y), "gaps {gap_x}, {gap_y}");
        for r in 0..2 {
            for c in 0..3 {
                let b = boxes[r * 3 + c];
                assert_eq!(b.0, boxes[0].0 + c as u32 * (tw + gap_x), "tile {r},{c} x");
                assert_eq!(b.1, boxes[0].1 + r as u32 * (th + gap_y), "tile {r},{c} y");
            }
        }
        // The image: the tiles, labels above and left of them, and a narrow border.
        let last = boxes[5];
        assert!((1..=32).contains(&(img.width() - last.2)), "right border of {}", img.width() - last.2);
        assert!((1..=32).contains(&(img.height() - last.3)), "bottom border of {}", img.height() - last.3);
        let label_w = "independent".len() as u32 * 16;
        assert!(boxes[0].0 >= label_w, "row labels need {label_w} px, tiles start at {}", boxes[0].0);
        assert!(boxes[0].1 >= 2 * 16, "title and column labels need two lines, tiles start at {}", boxes[0].1);

        // Background is light; labels are dark text in their places.
        assert!(img.get_pixel(0, 0).0[0] > 200, "background is light");
        let top = boxes[0].1;
        let title_band = (0, 0, img.width(), top / 2);
        assert!(dark_pixels(&img, title_band) > 20, "title has no text");
        for (c, b) in boxes[..3].iter().enumerate() {
            assert!(dark_pixels(&img, (b.0, top / 2, b.2, top)) > 20, "column label {c} has no text");
        }
        for (r, b) in [boxes[0], boxes[3]].iter().enumerate() {
            let upper = dark_pixels(&img, (0, b.1, b.0, b.1 + th / 2));
            let lower = dark_pixels(&img, (0, b.1 + th / 2, b.0, b.3));
            assert!(upper > 20 && lower > 20, "row label {r} lacks a line of text: {upper}, {lower}");
        }
        // Nothing dark between the tiles.
        assert_eq!(dark_pixels(&img, (boxes[0].2, boxes[0].1, boxes[1].0, boxes[0].3)), 0);
    }

    #[test]
    fn lists_are_validated() {
        let (h, s) = ([Hemisphere::Cosine], [Sampler::Independent]);
        assert!(validate(&[1, 4], &h, &s).is_ok());
        /// Sample counts, hemispheres, samplers, and a word the message must contain.
        type Case<'a> = (&'a [u32], &'a [Hemisphere], &'a [Sampler], &'a str);
        let cases: &[Case] = &[
            (&[], &h, &s, "empty"),
            (&[1], &[], &s, "empty"),
            (&[1], &h, &[], "empty"),
            (&[1, 0], &h, &s, "at least 1"),
            (&[4, 1, 4], &h, &s, "4"),
            (&[1], &[Hemisphere::Uniform, Hemisphere::Uniform], &s, "uniform"),
            (&[1], &h, &[Sampler::Sobol, Sampler::Grid, Sampler::Sobol], "sobol"),
        ];
        for (spps, hemispheres, samplers, expect) in cases {
            let e = validate(spps, hemispheres, samplers).expect_err("invalid lists").to_string();
            assert!(e.contains(expect) && !e.contains('\n'), "{spps:?} {hemispheres:?} {samplers:?}: {e}");
        }
    }
}
