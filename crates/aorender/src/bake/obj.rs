//! Baking into Wavefront OBJ files: the file is kept as its lines, read as one mesh (every
//! object and group together, as the scene loader merges them), and written back line for
//! line with each `v` line given the AO as its vertex colour (`v x y z r g b`, r = g = b =
//! AO, the extension most OBJ readers take: MeshLab, Blender, `tobj`, Open3D). Every other
//! line is copied through byte for byte, line endings included.
//!
//! OBJ has no per-face attribute nor a place for standard errors or bent normals: a bake
//! at faces is refused (PLY and glTF take it), and the other two are left out with a note.
//!
//! A texture bake writes the map beside the file; generated texture coordinates go in as
//! `vt` lines before the first face, each face's corners given theirs (`v/vt`, `v/vt/vn`).

use super::asset::{
    Asset, AssetMesh, BakeAt, BakedValues, GeneratedUvs, MeshUvs, TextureMap, UvSet, WriteOptions, write_maps_beside,
};
use crate::error::{Error, Result};
use crate::output::gzip::GzipWriter;
use crate::scene::input::{LoadOptions, Meter, ReadLimits, UTF8_BOM, UTF16_MESSAGE, is_gzip, read_text, starts_utf16};
use crate::scene::mesh::IndexedMesh;
use crate::scene::obj::{Keep, ObjData, continued_at, read_obj};
use glam::Vec3;
use std::io::{self, Write};
use std::path::Path;

/// A OBJ file read for baking.
pub struct ObjAsset {
    /// The file as read (decompressed), every line with its own ending.
    text: Vec<u8>,
    /// The file's one mesh.
    meshes: Vec<AssetMesh>,
}

impl ObjAsset {
    /// [`ObjAsset::read_with`] within the read budget of [`LoadOptions::from_env`].
    #[cfg(test)]
    pub fn read(path: &Path) -> Result<ObjAsset> {
        ObjAsset::read_with(path, &LoadOptions::from_env()?)
    }

    /// Reads `path` (`.obj` or `.obj.gz`) for baking with the scene loader's reader
    /// (`scene::obj`): its positions, the faces of `f` lines (polygons kept; `l` and `p`
    /// lines and faces of fewer than three corners ignored, as the scene ignores them), the
    /// texture coordinates of each corner, and per-vertex normals from the `vn` the faces
    /// reference (see [`vertex_normals`]). The file and what is read from it must fit in the
    /// read budget of `options`.
    pub fn read_with(path: &Path, options: &LoadOptions) -> Result<ObjAsset> {
        let mut meter = Meter::new(&options.limits, "the mesh");
        let mut data = read_obj(path, &mut meter, Keep { text: true, attributes: true })?;
        let text = as_read(std::mem::take(&mut data.text), path, &mut meter)?;
        let label = path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned());
        let mut mesh = asset_mesh(data, label, path, &mut meter)?;
        if textures_repeat(path, &text, &options.limits) {
            mesh.repeating_sets = vec![0];
        }
        Ok(ObjAsset { text, meshes: vec![mesh] })
    }

    /// The mesh the scene loader reads from `path`, this file: the vertices its faces use,
    /// each face split as a fan.
    pub(crate) fn scene_mesh(&self, path: &Path) -> IndexedMesh {
        let m = &self.meshes[0];
        crate::scene::obj::scene_mesh(path, &m.positions, &m.face_starts, &m.face_indices)
    }
}

/// The bake's mesh of what was read of an OBJ file, the memory it takes beyond that
/// charged to `meter`: per-vertex normals when the file has `vn` lines, per-corner texture
/// coordinates when it has `vt` lines (a corner without one NaN).
fn asset_mesh(data: ObjData, label: String, path: &Path, meter: &mut Meter) -> Result<AssetMesh> {
    let corners = data.face_indices.len() as u64;
    let normals_bytes = if data.normal_count > 0 { 12 * data.positions.len() as u64 + 8 * corners } else { 0 };
    let uv_bytes = if data.texcoord_count > 0 { 8 * corners } else { 0 };
    meter.charge(path, normals_bytes + uv_bytes)?;
    let normals = (data.normal_count > 0).then(|| {
        let pairs = data.face_indices.iter().zip(&data.corner_normals).filter(|(_, n)| **n != u32::MAX);
        vertex_normals(data.positions.len(), &data.normals, pairs.map(|(&v, &n)| (v, n)).collect())
    });
    let uv_sets = if data.texcoord_count == 0 {
        Vec::new()
    } else {
        let uv = |&k: &u32| data.uvs.get(k as usize).copied().unwrap_or(glam::Vec2::NAN);
        vec![UvSet { set: 0, corners: data.corner_uvs.iter().map(uv).collect() }]
    };
    Ok(AssetMesh {
        label,
        positions: data.positions,
        normals,
        face_starts: data.face_starts,
        face_indices: data.face_indices,
        to_file: glam::Mat3::IDENTITY,
        uv_sets,
        uv_v_down: false,
        material: None,
        repeating_sets: Vec::new(),
    })
}

/// The text of the material library `name` in the folder `dir`, within `limits`; `None`
/// when it cannot be read or lies outside the folder (an absolute name, `..`, a symbolic
/// link leading out): only the OBJ file's own folder is read.
fn read_library(dir: &Path, name: &str, limits: &ReadLimits) -> Option<String> {
    let file = Path::new(name);
    if !file.components().all(|c| matches!(c, std::path::Component::Normal(_))) {
        return None;
    }
    let real = dir.join(file).canonicalize().ok()?;
    if !real.starts_with(dir.canonicalize().ok()?) {
        return None;
    }
    let bytes = read_text(&real, limits, 1, "the material library").ok()?;
    Some(bytes)
}

/// Whether the textures of the materials the file's faces use repeat, so that texture
/// coordinates outside [0, 1] wrap: an MTL texture map repeats unless it says `-clamp on`
/// (the MTL format, Wavefront 1995). True when the `.mtl` files the OBJ names (`mtllib`,
/// relative names inside the OBJ's directory, read within the budget; others are not read) give the materials it
/// uses (`usemtl`; every material when it names none) at least one map and none clamps.
fn textures_repeat(path: &Path, text: &[u8], limits: &ReadLimits) -> bool {
    let text = String::from_utf8_lossy(text);
    let mut libraries = Vec::new();
    let mut used = std::collections::BTreeSet::new();
    for line in text.lines() {
        let mut words = line.split_whitespace();
        match words.next() {
            Some("mtllib") => libraries.extend(words.map(str::to_string)),
            Some("usemtl") => {
                used.insert(words.collect::<Vec<_>>().join(" "));
            }
            _ => {}
        }
    }
    let dir = match path.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => dir,
        _ => Path::new("."),
    };
    let (mut maps, mut clamped) = (0, 0);
    for library in libraries {
        let Some(mtl) = read_library(dir, &library, limits) else { continue };
        let mut current = String::new();
        for line in mtl.lines() {
            let mut words = line.split_whitespace();
            let Some(keyword) = words.next() else { continue };
            if keyword == "newmtl" {
                current = words.collect::<Vec<_>>().join(" ");
                continue;
            }
            let is_map = keyword.starts_with("map_") || ["bump", "disp", "decal", "refl", "norm"].contains(&keyword);
            if !is_map || !(used.is_empty() || used.contains(&current)) {
                continue;
            }
            maps += 1;
            let options: Vec<&str> = words.collect();
            if options.windows(2).any(|w| w[0] == "-clamp" && w[1] == "on") {
                clamped += 1;
            }
        }
    }
    maps > 0 && clamped == 0
}

/// The text of an OBJ file as the scene loader reads it, and as it is written back: a
/// UTF-8 byte-order mark dropped, UTF-16 refused, each line continued with `\` joined to
/// the next (an empty line after it, so that lines keep their numbers), and a comment after
/// a vertex's numbers dropped (a `v` line is written back with its colour after them).
fn as_read(mut text: Vec<u8>, path: &Path, meter: &mut Meter) -> Result<Vec<u8>> {
    if starts_utf16(&text) {
        return Err(Error::scene(path, UTF16_MESSAGE));
    }
    if text.starts_with(UTF8_BOM) {
        text.drain(..UTF8_BOM.len());
    }
    let is_comment = |line: &[u8]| line.iter().find(|b| !b.is_ascii_whitespace()) == Some(&b'#');
    let commented_vertex = |line: &[u8]| line.contains(&b'#') && keyword(&String::from_utf8_lossy(line)) == Some("v");
    let changes = |line: &[u8]| !is_comment(line) && (continued_at(line).is_some() || commented_vertex(line));
    if !lines(&text).any(changes) {
        return Ok(text);
    }
    meter.charge(path, text.len() as u64)?;
    let mut out = Vec::with_capacity(text.len());
    let mut line = Vec::new();
    let mut joined = 0;
    for physical in lines(&text) {
        let continued = if joined > 0 || !is_comment(physical) { continued_at(physical) } else { None };
        match continued {
            Some(at) => {
                line.extend_from_slice(&physical[..at]);
                line.push(b' ');
                joined += 1;
            }
            None => {
                line.extend_from_slice(physical);
                if !is_comment(&line) && commented_vertex(&line) {
                    let ending: Vec<u8> =
                        line.iter().rev().take_while(|&&b| b == b'\n' || b == b'\r').copied().collect();
                    line.truncate(line.iter().position(|&b| b == b'#').unwrap_or(line.len()));
                    line.extend(ending.iter().rev());
                }
                out.append(&mut line);
                out.extend(std::iter::repeat_n(b'\n', std::mem::take(&mut joined)));
            }
        }
    }
    out.append(&mut line);
    Ok(out)
}

/// The lines of `text`, each with its ending (`\n` or `\r\n`; none for a last line without).
fn lines(text: &[u8]) -> impl Iterator<Item = &[u8]> {
    text.split_inclusive(|&b| b == b'\n')
}

/// Bytes of the file one rayon task rewrites at a time (then up to the end of a line).
const WRITE_BLOCK_BYTES: usize = 1 << 20;

/// The first word of `line`, as `tobj` splits it.
fn keyword(line: &str) -> Option<&str> {
    line.split_whitespace().next()
}

/// One normal per vertex from the file's `vn`, as the faces' corners name them (OBJ
/// gives normals per corner, the bake wants one per vertex): a vertex whose corners all
/// name one normal (or several equal ones) gets it as it is; a vertex whose corners name
/// different normals (a hard edge, a seam) gets the sum of the different ones each
/// normalised, their mean direction, where an unusable one (zero, non-finite) adds
/// nothing; a vertex no corner gives a normal gets zero, which the bake replaces with the
/// area-weighted face normal. `corner_normals` holds (vertex, normal index) pairs.
fn vertex_normals(vertices: usize, normals: &[Vec3], mut corner_normals: Vec<(u32, u32)>) -> Vec<Vec3> {
    // Distinct (vertex, normal value) pairs, in a fixed order so that the sums are too.
    let bits = |n: Vec3| n.to_array().map(f32::to_bits);
    corner_normals.sort_unstable();
    corner_normals.dedup();
    let mut pairs: Vec<(u32, [u32; 3])> = corner_normals.iter().map(|&(v, n)| (v, bits(normals[n as usize]))).collect();
    pairs.sort_unstable();
    pairs.dedup();

    let mut out = vec![Vec3::ZERO; vertices];
    for group in pairs.chunk_by(|a, b| a.0 == b.0) {
        let value = |(_, n): &(u32, [u32; 3])| Vec3::from_array(n.map(f32::from_bits));
        out[group[0].0 as usize] = match group {
            [one] => value(one),
            several => several.iter().map(|p| value(p).normalize_or_zero()).sum(),
        };
    }
    out
}

/// The byte ranges of the words of `line`, as `split_whitespace` finds them.
fn word_spans(line: &str) -> Vec<(usize, usize)> {
    let mut spans = Vec::new();
    let mut start = None;
    for (i, c) in line.char_indices() {
        match (c.is_whitespace(), start) {
            (true, Some(s)) => {
                spans.push((s, i));
                start = None;
            }
            (false, None) => start = Some(i),
            _ => {}
        }
    }
    if let Some(s) = start {
        spans.push((s, line.len()));
    }
    spans
}

/// What writing the `v` lines changed besides adding colours.
#[derive(Clone, Copy, Default)]
struct VertexChanges {
    /// `v` lines whose own colour was replaced.
    colours_replaced: usize,
    /// `v` lines whose `w` was divided out (a colour cannot follow a `w`).
    w_divided: usize,
}

/// Writes the `v` line `line` (with its ending) with the colour `ao`: the coordinates'
/// text kept verbatim (divided by `w` when the line has a `w` other than 1, written so
/// that they read back to `position` bit for bit), its own colour replaced.
fn write_vertex_line(
    out: &mut dyn Write,
    line: &[u8],
    position: Vec3,
    ao: f32,
    changes: &mut VertexChanges,
) -> io::Result<()> {
    let text = std::str::from_utf8(line).map_err(|e| io::Error::new(io::ErrorKind::InvalidData, e))?;
    let spans = word_spans(text);
    let invalid = || io::Error::new(io::ErrorKind::InvalidData, format!("not a vertex line: {text:?}"));
    let (&(x_start, _), &(_, z_end), &(_, last_end)) =
        (spans.get(1).ok_or_else(invalid)?, spans.get(3).ok_or_else(invalid)?, spans.last().ok_or_else(invalid)?);
    match spans.len() {
        5 if text[spans[4].0..spans[4].1].parse::<f32>() != Ok(1.0) => {
            changes.w_divided += 1;
            write!(out, "{}{} {} {}", &text[..x_start], position.x, position.y, position.z)?;
        }
        7 => {
            changes.colours_replaced += 1;
            out.write_all(&line[..z_end])?;
        }
        _ => out.write_all(&line[..z_end])?,
    }
    write!(out, " {ao} {ao} {ao}")?;
    out.write_all(&line[last_end..])
}

impl ObjAsset {
    /// Writes the file with `ao` as the colour of every `v` line, every other line as it
    /// was: blocks of whole lines rewritten on rayon's threads (each block's `v` lines
    /// counted first, to number its vertices), a round at a time, written in order.
    fn write_lines(&self, out: &mut dyn Write, ao: &[f32]) -> io::Result<VertexChanges> {
        use rayon::prelude::*;
        let positions = &self.meshes[0].positions;
        let is_vertex = |line: &[u8]| keyword(&String::from_utf8_lossy(line)) == Some("v");
        let mut blocks = Vec::new();
        let mut rest = &self.text[..];
        while !rest.is_empty() {
            let end = match rest.get(WRITE_BLOCK_BYTES..).and_then(|r| memchr::memchr(b'\n', r)) {
                Some(e) => WRITE_BLOCK_BYTES + e + 1,
                None => rest.len(),
            };
            let (block, next) = rest.split_at(end);
            blocks.push(block);
            rest = next;
        }
        let counts: Vec<usize> = blocks.par_iter().map(|b| lines(b).filter(|l| is_vertex(l)).count()).collect();
        let firsts: Vec<usize> = counts.iter().scan(0, |k, c| Some(std::mem::replace(k, *k + c))).collect();
        let rewrite = |block: &[u8], mut k: usize| -> io::Result<(Vec<u8>, VertexChanges)> {
            let mut text = Vec::with_capacity(block.len() + block.len() / 2);
            let mut changes = VertexChanges::default();
            for line in lines(block) {
                if !is_vertex(line) {
                    text.extend_from_slice(line);
                    continue;
                }
                let (Some(&p), Some(&value)) = (positions.get(k), ao.get(k)) else {
                    return Err(io::Error::other("more vertex lines than when the file was read"));
                };
                write_vertex_line(&mut text, line, p, value, &mut changes)?;
                k += 1;
            }
            Ok((text, changes))
        };
        let mut changes = VertexChanges::default();
        // Two blocks a thread: memory stays a few blocks a core whatever the file's size.
        let round = 2 * rayon::current_num_threads().max(1);
        for (blocks, firsts) in blocks.chunks(round).zip(firsts.chunks(round)) {
            let texts: Vec<_> = blocks.par_iter().zip(firsts).map(|(b, &k)| rewrite(b, k)).collect();
            for text in texts {
                let (text, c) = text?;
                out.write_all(&text)?;
                changes.colours_replaced += c.colours_replaced;
                changes.w_divided += c.w_divided;
            }
        }
        Ok(changes)
    }
}

impl ObjAsset {
    /// Writes the file with the coordinates `uvs` (the file has none): their `vt` lines
    /// before the first face line, and each face's corners naming theirs.
    fn write_uv_lines(&self, out: &mut dyn Write, uvs: &MeshUvs) -> io::Result<()> {
        let mesh = &self.meshes[0];
        let (mut face, mut wrote_uvs) = (0, false);
        for line in lines(&self.text) {
            let text = String::from_utf8_lossy(line);
            if keyword(&text) != Some("f") {
                out.write_all(line)?;
                continue;
            }
            if !wrote_uvs {
                for c in &uvs.uvs {
                    writeln!(out, "vt {} {}", c.x, c.y)?;
                }
                wrote_uvs = true;
            }
            let spans = word_spans(&text);
            if spans.len() < 4 {
                // Fewer than three corners: not a face of the mesh.
                out.write_all(line)?;
                continue;
            }
            let Some(&start) = mesh.face_starts.get(face) else {
                return Err(io::Error::other("more faces than when the file was read"));
            };
            let mut last_end = 0;
            for (k, &(a, b)) in spans.iter().enumerate().skip(1) {
                out.write_all(&text.as_bytes()[last_end..a])?;
                let vt = uvs.corners[start as usize + k - 1] + 1;
                match text[a..b].split_once('/') {
                    None => write!(out, "{}/{vt}", &text[a..b])?,
                    // `v//vn` (the file has no `vt`, so the middle is empty).
                    Some((v, rest)) => write!(out, "{v}/{vt}{}", rest.trim_start_matches(|c| c != '/'))?,
                }
                last_end = b;
            }
            out.write_all(&text.as_bytes()[last_end..])?;
            face += 1;
        }
        Ok(())
    }
}

impl Asset for ObjAsset {
    fn meshes(&self) -> &[AssetMesh] {
        &self.meshes
    }

    /// Writes the file with AO as the colour of every vertex. Refuses [`BakeAt::Faces`]
    /// (OBJ has no per-face attribute that readers take); standard errors and bent normals
    /// have no place in OBJ and are left out with a note.
    fn write(&self, path: &Path, values: &[BakedValues], options: &WriteOptions) -> Result<Vec<String>> {
        if options.at == BakeAt::Faces {
            return Err(Error::output(
                path,
                "OBJ has no per-face attribute to hold AO per face: bake it at vertices, or convert the mesh to PLY or glTF",
            ));
        }
        let positions = self.meshes[0].positions.len();
        let values = match values {
            [v] if v.ao.len() == positions => v,
            [v] => {
                return Err(Error::output(path, format!("{} AO values for {positions} vertices", v.ao.len())));
            }
            _ => return Err(Error::output(path, format!("values for {} meshes, the OBJ file has 1", values.len()))),
        };

        let gzip = is_gzip(path);
        let mut changes = VertexChanges::default();
        crate::output::write_output_with(path, &mut |w| {
            changes = if gzip {
                let mut encoder = GzipWriter::new(w)?;
                let changes = self.write_lines(&mut encoder, &values.ao)?;
                encoder.finish()?;
                changes
            } else {
                self.write_lines(w, &values.ao)?
            };
            Ok(())
        })?;

        let mut notes = Vec::new();
        let vertices = |n: usize| if n == 1 { "1 vertex".to_string() } else { format!("{n} vertices") };
        if changes.colours_replaced > 0 {
            notes.push(format!("{} had colours of their own, replaced by the AO", vertices(changes.colours_replaced)));
        }
        if changes.w_divided > 0 {
            notes.push(format!(
                "{} had a w coordinate: written divided by it, since a colour cannot follow a w",
                vertices(changes.w_divided)
            ));
        }
        let elsewhere = "OBJ has no place for them (.ply and .gltf/.glb have)";
        if options.std_error {
            notes.push(format!("standard errors not written: {elsewhere}"));
        }
        if values.bent_normals.is_some() {
            notes.push(format!("bent normals not written: {elsewhere}"));
        }
        Ok(notes)
    }

    /// Writes the map beside the file (`STEM_ao.png`) and the file with the generated
    /// coordinates, when there are some; else the file as it was.
    fn write_textures(&self, path: &Path, maps: &[TextureMap], uvs: Option<&GeneratedUvs>) -> Result<Vec<String>> {
        let uvs = uvs.and_then(|g| g.meshes.first());
        if uvs.is_some() && !self.meshes[0].uv_sets.is_empty() {
            return Err(Error::output(path, "the file has texture coordinates of its own: OBJ holds one set"));
        }
        let gzip = is_gzip(path);
        write_maps_beside(path, maps)?;
        let body = |out: &mut dyn Write| match uvs {
            Some(uvs) => self.write_uv_lines(out, uvs),
            None => out.write_all(&self.text),
        };
        crate::output::write_output_with(path, &mut |w| {
            if gzip {
                let mut encoder = GzipWriter::new(w)?;
                body(&mut encoder)?;
                encoder.finish().map(|_| ())
            } else {
                body(w)
            }
        })?;
        Ok(Vec::new())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::ReadLimits;
    use crate::scene::input::Input;
    use std::io::Read;
    use std::path::PathBuf;

    /// Writes `bytes` to `name` in a new directory; returns the directory and the path.
    fn file(name: &str, bytes: &[u8]) -> (tempfile::TempDir, PathBuf) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        (dir, path)
    }

    fn read_text(text: &str) -> Result<ObjAsset> {
        let (_dir, path) = file("m.obj", text.as_bytes());
        ObjAsset::read(&path)
    }

    fn mesh(text: &str) -> AssetMesh {
        read_text(text).unwrap().meshes[0].clone()
    }

    fn faces(mesh: &AssetMesh) -> Vec<Vec<u32>> {
        (0..mesh.face_count()).map(|f| mesh.face(f).to_vec()).collect()
    }

    /// AO values that are distinct and need all of an f32's digits.
    fn values(n: usize) -> BakedValues {
        BakedValues { ao: (0..n).map(|i| (i as f32 + 1.0) / (n as f32 + 2.0) / 3.0).collect(), ..Default::default() }
    }

    /// The file at `path`, decompressed when it is gzipped.
    fn read_back(path: &Path) -> Vec<u8> {
        let mut bytes = Vec::new();
        Input::open(path, &ReadLimits::with_memory(1 << 30)).unwrap().read_to_end(&mut bytes).unwrap();
        bytes
    }

    /// The triangles of `mesh`, its polygons split as fans, as bit patterns, sorted.
    fn fan_triangles(mesh: &AssetMesh) -> Vec<[[u32; 3]; 3]> {
        let bits = |i: u32| mesh.positions[i as usize].to_array().map(f32::to_bits);
        let mut out: Vec<_> = (0..mesh.face_count())
            .flat_map(|f| {
                let c = mesh.face(f);
                (2..c.len()).map(move |k| [bits(c[0]), bits(c[k - 1]), bits(c[k])])
            })
            .collect();
        out.sort_unstable();
        out
    }

    /// The triangles of the scene loader for `path`, as bit patterns, sorted.
    fn loader_triangles(path: &Path) -> Vec<[[u32; 3]; 3]> {
        let m = crate::scene::obj::load_obj(path, &mut Meter::unlimited()).unwrap();
        let bits = |i: u32| m.positions[i as usize].to_array().map(f32::to_bits);
        let mut out: Vec<_> = m.triangles.iter().map(|t| t.map(bits)).collect();
        out.sort_unstable();
        out
    }

    /// Every kind of line, faces in every form, a quad and a pentagon, two groups.
    const CUBE_CORNER: &str = "# a corner\nmtllib m.mtl\no first\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n\
        v 0.1 0.2 1.5e-1\nvt 0 0\nvt 1 0\nvn 0 0 1\nvn 0 0 2\nusemtl grey\ns 1\n\
        f 1/1/1 2/2/1 3/1/2 4/2/1\ng second part\nf -1//2 1//2 2//1\nf 1 2 3 4 5\nf 2/1 3/2 5/1\n\
        l 1 2 3\np 4\n";

    #[test]
    fn positions_and_faces_are_read_as_the_scene_loader_reads_them() {
        let hand_written = [
            CUBE_CORNER,
            "v 1 2 3 2\nv 0.3 0.7 0.1 0.5\nv 1e-7 -0 3\nv 1 1 1 0.2 0.3 0.4\r\nf 1 2 3\r\nf 4 3 2 1\n",
            "  v 0 0 0\n\tv 1 0 0\nv 0 1 0\ng a\nf 1 2 3\ng b\nf 3 2 1\no c\nf -3 -2 -1",
            "v 0 0 0\nv 1 0 0 0.5 0.5 0.5\nv 0 1 0\nv 1 1 0\nf\nf 1/1/1 2/-9/0 3 4\nl 1 2 3\nf 1 2\nusemtl\n",
        ];
        for text in hand_written {
            let (_dir, path) = file("m.obj", text.as_bytes());
            let asset = ObjAsset::read(&path).unwrap();
            assert_eq!(fan_triangles(&asset.meshes()[0]), loader_triangles(&path), "{text}");
        }
        let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
        for name in ["bunny.obj", "teapot.obj"] {
            let path = scenes.join(name);
            let asset = ObjAsset::read(&path).unwrap();
            let mesh = &asset.meshes()[0];
            assert_eq!(mesh.label, name);
            assert!(mesh.face_count() > 1000, "{name}");
            assert_eq!(fan_triangles(mesh), loader_triangles(&path), "{name}");
            // Baked, the file still loads as the same triangles.
            let dir = tempfile::tempdir().unwrap();
            let out = dir.path().join(name);
            let notes = asset.write(&out, &[values(mesh.positions.len())], &WriteOptions::default()).unwrap();
            assert!(notes.is_empty(), "{notes:?}");
            assert_eq!(loader_triangles(&out), fan_triangles(mesh), "{name} baked");
        }
    }

    #[test]
    fn faces_of_every_form_with_relative_indices_and_polygons() {
        let m = mesh(CUBE_CORNER);
        assert_eq!(m.label, "m.obj");
        assert_eq!(m.positions.len(), 5);
        assert_eq!(m.positions[4].to_array().map(f32::to_bits), [0.1f32, 0.2, 1.5e-1].map(f32::to_bits));
        assert_eq!(faces(&m), [vec![0, 1, 2, 3], vec![4, 0, 1], vec![0, 1, 2, 3, 4], vec![1, 2, 4]]);
        // Relative indices count back from the line they are on.
        let m = mesh("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 1 1 0\nvt 0 0\nf -4/-1 -1 -2\n");
        assert_eq!(faces(&m), [vec![0, 1, 2], vec![0, 3, 2]]);
        // Indices of texture coordinates and normals a file has none of are ignored, as
        // tobj ignores them.
        let m = mesh("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/0/0 2/-5/-5 3/9/9\n");
        assert_eq!((faces(&m), m.normals), (vec![vec![0, 1, 2]], None));
        // A face may name a vertex defined below it, as tobj allows.
        assert_eq!(faces(&mesh("f 1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\n")), [vec![0, 1, 2]]);
        // No faces at all is a mesh of no faces (the bake decides what to do with it).
        let m = mesh("v 0 0 0\nf 1 1\n");
        assert_eq!((m.face_count(), m.face_starts.as_slice()), (0, [0].as_slice()));
    }

    /// `vt` per face corner, relative indices too; a corner without one is NaN; a file
    /// without `vt` has no set.
    #[test]
    fn texture_coordinates_are_read_per_corner() {
        let m = mesh("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0.1 0.2\nvt 0.3 0.4 0\nvt 0.5\nf 1/1 2/-2 3/3\nf 1/3 3 2/1\n");
        let uv: Vec<[f32; 2]> = m.uv_set(0).unwrap().corners.iter().map(|c| c.to_array()).collect();
        assert_eq!(&uv[..4], &[[0.1, 0.2], [0.3, 0.4], [0.5, 0.0], [0.5, 0.0]]);
        assert!(uv[4][0].is_nan());
        assert_eq!(uv[5], [0.1, 0.2]);
        assert!(!m.uv_v_down);
        assert!(mesh("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").uv_sets.is_empty());
    }

    /// Texture coordinates repeat when the materials the faces use have maps and none
    /// says `-clamp on`; a library outside the file's directory is not read.
    #[test]
    fn mtl_textures_repeat_unless_clamped() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        std::fs::write(d.join("m.mtl"), "newmtl wood\nKd 1 1 1\nmap_Kd -s 2 2 1 wood.png\nnewmtl steel\nmap_Kd -clamp on steel.png\nnewmtl plain\nKd 1 1 1\n").unwrap();
        std::fs::create_dir(d.join("sub")).unwrap();
        let repeats = |obj: &str| {
            let path = d.join("sub/../t.obj");
            std::fs::write(&path, obj).unwrap();
            ObjAsset::read(&path).unwrap().meshes[0].repeating_sets == [0]
        };
        let faces = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 2 0\nvt 0 2\nf 1/1 2/2 3/3\n";
        assert!(repeats(&format!("mtllib m.mtl\nusemtl wood\n{faces}")));
        assert!(!repeats(&format!("mtllib m.mtl\nusemtl steel\n{faces}")), "clamped");
        assert!(!repeats(&format!("mtllib m.mtl\nusemtl wood\n{faces}usemtl steel\n{faces}")), "one clamps");
        assert!(!repeats(&format!("mtllib m.mtl\nusemtl plain\n{faces}")), "no map");
        assert!(!repeats(&format!("mtllib missing.mtl\nusemtl wood\n{faces}")));
        assert!(!repeats(faces), "no library");
        std::fs::write(d.join("sub/out.mtl"), "newmtl wood\nmap_Kd wood.png\n").unwrap();
        assert!(!repeats(&format!(
            "mtllib ../{}/sub/out.mtl\nusemtl wood\n{faces}",
            d.file_name().unwrap().to_string_lossy()
        )));
    }

    #[test]
    fn normals_come_from_the_corners_that_name_them() {
        let m = mesh(CUBE_CORNER);
        let n = m.normals.unwrap();
        // Vertex 1 names normals 1 and 2 (parallel, of lengths 1 and 2): their unit sum.
        assert_eq!(n[0], Vec3::new(0.0, 0.0, 2.0));
        // The others name one normal each, kept as it is.
        assert_eq!(n[1..], [Vec3::Z, Vec3::Z * 2.0, Vec3::Z, Vec3::Z * 2.0]);

        let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nvn 1 0 0\nvn 0 3 0\nvn 1 0 0\nvn 0 0 0\n\
            f 1//1 2//2 3//4\nf 1//2 2//2 3//1\nf 1//3 2//2 3//4\n";
        let n = mesh(text).normals.unwrap();
        // Different normals: the sum of each normalised; an equal one under another
        // index counts once; a zero one adds nothing.
        assert_eq!(n[0], Vec3::new(1.0, 1.0, 0.0));
        assert_eq!(n[1], Vec3::new(0.0, 3.0, 0.0));
        assert_eq!(n[2], Vec3::new(1.0, 0.0, 0.0));
        // Never named with a normal: zero.
        assert_eq!(n[3], Vec3::ZERO);
        // A file with no `vn` has no normals; one whose faces name none has zero ones.
        assert_eq!(mesh("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").normals, None);
        assert_eq!(mesh("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1 2 3\n").normals, Some(vec![Vec3::ZERO; 3]));
    }

    /// Bakes `text` into `out_name` with distinct values; returns the values, the notes
    /// and the bytes written (decompressed).
    fn bake(text: &[u8], in_name: &str, out_name: &str) -> (BakedValues, Vec<String>, Vec<u8>, tempfile::TempDir) {
        let (dir, path) = file(in_name, text);
        let asset = ObjAsset::read(&path).unwrap();
        let values = values(asset.meshes()[0].positions.len());
        let out = dir.path().join(out_name);
        let notes = asset.write(&out, std::slice::from_ref(&values), &WriteOptions::default()).unwrap();
        let bytes = read_back(&out);
        (values, notes, bytes, dir)
    }

    /// A file of several blocks (rewritten in parallel) gets each vertex's own AO, its
    /// other lines as they were, and the changes counted over every block.
    #[test]
    fn a_file_of_many_blocks_numbers_its_vertices_across_them() {
        let mut text = String::new();
        let n = 120_000;
        for i in 0..n {
            let x = i as f32 * 0.25;
            match i % 10 {
                0 => text += &format!("# comment {i}\nv {x} 1.5 -2\n"),
                3 => text += &format!("v {x} 1.5 -2 0.1 0.2 0.3\n"),
                _ => text += &format!("v {x} 1.5 -2\n"),
            }
        }
        for i in 1..n - 1 {
            text += &format!("f {i} {} {}\n", i + 1, i + 2);
        }
        assert!(text.len() > 3 * WRITE_BLOCK_BYTES, "{} bytes", text.len());
        let (values, notes, bytes, _dir) = bake(text.as_bytes(), "m.obj", "out.obj");
        assert_eq!(notes, [format!("{} vertices had colours of their own, replaced by the AO", n / 10)]);
        let mut k = 0;
        for (a, b) in lines(text.as_bytes()).zip(lines(&bytes)) {
            let (a, b) = (std::str::from_utf8(a).unwrap(), std::str::from_utf8(b).unwrap());
            if !a.starts_with("v ") {
                assert_eq!(a, b);
                continue;
            }
            let ao = values.ao[k];
            let coordinates = a.split_whitespace().take(4).collect::<Vec<_>>().join(" ");
            assert_eq!(b, format!("{coordinates} {ao} {ao} {ao}\n"), "vertex {k}");
            k += 1;
        }
        assert_eq!(k, n);
        assert_eq!(lines(&bytes).count(), lines(text.as_bytes()).count());
    }

    #[test]
    fn a_round_trip_keeps_everything_but_adds_colours() {
        let (values, notes, bytes, dir) = bake(CUBE_CORNER.as_bytes(), "m.obj", "out.obj");
        assert!(notes.is_empty(), "{notes:?}");
        let out = dir.path().join("out.obj");

        // Every line but the `v` ones byte for byte; those keep their coordinates' text.
        let (old, new): (Vec<_>, Vec<_>) = (lines(CUBE_CORNER.as_bytes()).collect(), lines(&bytes).collect());
        assert_eq!(old.len(), new.len());
        let mut k = 0;
        for (a, b) in old.iter().zip(&new) {
            if a.starts_with(b"v ") {
                let a = std::str::from_utf8(a).unwrap().trim_end();
                let ao = values.ao[k];
                assert_eq!(std::str::from_utf8(b).unwrap(), format!("{a} {ao} {ao} {ao}\n"));
                k += 1;
            } else {
                assert_eq!(a, b);
            }
        }
        assert_eq!(k, 5);

        // Read again by this reader and by the scene loader: the same mesh.
        let original = mesh(CUBE_CORNER);
        let again = ObjAsset::read(&out).unwrap();
        assert_eq!(
            again.meshes()[0].positions.iter().map(|p| p.to_array().map(f32::to_bits)).collect::<Vec<_>>(),
            original.positions.iter().map(|p| p.to_array().map(f32::to_bits)).collect::<Vec<_>>()
        );
        // Texture coordinates compare by their bits (a corner without one is NaN).
        let bits = |m: &AssetMesh| -> Vec<Vec<[u32; 2]>> {
            m.uv_sets.iter().map(|s| s.corners.iter().map(|c| c.to_array().map(f32::to_bits)).collect()).collect()
        };
        assert_eq!(bits(&again.meshes()[0]), bits(&original));
        let without_uvs = |m: &AssetMesh| AssetMesh { uv_sets: Vec::new(), ..m.clone() };
        assert_eq!(without_uvs(&again.meshes()[0]), AssetMesh { label: "out.obj".into(), ..without_uvs(&original) });
        assert_eq!(loader_triangles(&out), fan_triangles(&original));

        // Read by tobj on its own: every corner's position and colour.
        let options =
            tobj::LoadOptions { triangulate: false, single_index: false, ignore_points: true, ignore_lines: true };
        let mut reader = io::BufReader::new(&bytes[..]);
        let (models, _) = tobj::load_obj_buf(&mut reader, &options, |_| Ok(Default::default())).unwrap();
        let mut corners = Vec::new();
        for model in &models {
            let m = &model.mesh;
            for &i in &m.indices {
                let i = i as usize * 3;
                let p = Vec3::from_slice(&m.positions[i..i + 3]);
                corners.push((p.to_array().map(f32::to_bits), m.vertex_color[i..i + 3].to_vec()));
            }
        }
        let expected: Vec<_> = original
            .face_indices
            .iter()
            .map(|&v| {
                let ao = values.ao[v as usize];
                (original.positions[v as usize].to_array().map(f32::to_bits), vec![ao, ao, ao])
            })
            .collect();
        // tobj takes the polyline `l 1 2 3` for a triangle, after the faces.
        assert_eq!(corners.len(), expected.len() + 3);
        assert_eq!(corners[..expected.len()], expected);
        assert_eq!(corners[expected.len()..], expected[7..10]);
    }

    #[test]
    fn line_endings_are_kept() {
        let crlf = CUBE_CORNER.replace('\n', "\r\n");
        let (values, _, bytes, _dir) = bake(crlf.as_bytes(), "m.obj", "out.obj");
        let ao = values.ao[0];
        assert!(
            bytes
                .starts_with(format!("# a corner\r\nmtllib m.mtl\r\no first\r\nv 0 0 0 {ao} {ao} {ao}\r\n").as_bytes())
        );
        assert_eq!(bytes.split(|&b| b == b'\n').count(), crlf.split('\n').count());
        assert_eq!(bytes.iter().filter(|&&b| b == b'\r').count(), crlf.matches('\r').count());
        // A last line without an ending, and one with trailing blanks.
        let (values, _, bytes, _dir) = bake(b"v 0 0 0  \nv 1 0 0\nv 0 1 0", "m.obj", "out.obj");
        let expected = format!(
            "v 0 0 0 {0} {0} {0}  \nv 1 0 0 {1} {1} {1}\nv 0 1 0 {2} {2} {2}",
            values.ao[0], values.ao[1], values.ao[2]
        );
        assert_eq!(String::from_utf8(bytes).unwrap(), expected);
    }

    #[test]
    fn own_colours_are_replaced_and_w_divided_out() {
        let text = "v 1 2 3 0.1 0.2 0.3\nv 1 2 3 2\nv 0.3 0.7 0.1 0.3\nv 4 5 6 1.0\nv 0 0 1\nf 1 2 3\nf 3 4 5\n";
        let (values, notes, bytes, dir) = bake(text.as_bytes(), "m.obj", "out.obj");
        assert_eq!(
            notes,
            [
                "1 vertex had colours of their own, replaced by the AO",
                "2 vertices had a w coordinate: written divided by it, since a colour cannot follow a w"
            ]
        );
        let written = String::from_utf8(bytes).unwrap();
        let line = |k: usize| written.lines().nth(k).unwrap().to_string();
        let ao = &values.ao;
        assert_eq!(line(0), format!("v 1 2 3 {0} {0} {0}", ao[0]));
        assert_eq!(line(1), format!("v 0.5 1 1.5 {0} {0} {0}", ao[1]));
        assert_eq!(line(3), format!("v 4 5 6 {0} {0} {0}", ao[3]));
        // Positions read back bit for bit, by this reader and by the scene loader.
        let out = dir.path().join("out.obj");
        let before = mesh(text);
        let after = ObjAsset::read(&out).unwrap();
        let bits = |m: &AssetMesh| m.positions.iter().map(|p| p.to_array().map(f32::to_bits)).collect::<Vec<_>>();
        assert_eq!(bits(&after.meshes()[0]), bits(&before));
        assert_eq!(loader_triangles(&out), fan_triangles(&before));
    }

    #[test]
    fn gzip_in_and_out() {
        use flate2::{Compression, write::GzEncoder};
        let mut gz = GzEncoder::new(Vec::new(), Compression::default());
        gz.write_all(CUBE_CORNER.as_bytes()).unwrap();
        let compressed = gz.finish().unwrap();
        let (_, _, from_gz, dir) = bake(&compressed, "m.obj.gz", "out.obj.gz");
        let raw = std::fs::read(dir.path().join("out.obj.gz")).unwrap();
        assert!(raw.starts_with(&[0x1f, 0x8b]), "not gzipped");
        let (_, _, plain, _dir) = bake(CUBE_CORNER.as_bytes(), "m.obj", "out.obj");
        assert_eq!(from_gz, plain);
        assert!(!from_gz.starts_with(&[0x1f, 0x8b]));
    }

    #[test]
    fn faces_are_refused_and_what_obj_cannot_hold_is_noted() {
        let (dir, path) = file("m.obj", CUBE_CORNER.as_bytes());
        let asset = ObjAsset::read(&path).unwrap();
        let out = dir.path().join("out.obj");
        let faces = WriteOptions { at: BakeAt::Faces, ..Default::default() };
        let e = asset.write(&out, &[values(4)], &faces).unwrap_err().to_string();
        assert!(e.contains("out.obj: OBJ has no per-face attribute") && e.contains("PLY or glTF"), "{e}");
        assert!(!out.exists());

        let mut v = values(5);
        v.std_error = vec![0.01; 5];
        v.bent_normals = Some(vec![Vec3::Z; 5]);
        let options = WriteOptions { std_error: true, ..Default::default() };
        let notes = asset.write(&out, &[v], &options).unwrap();
        assert_eq!(
            notes,
            [
                "standard errors not written: OBJ has no place for them (.ply and .gltf/.glb have)",
                "bent normals not written: OBJ has no place for them (.ply and .gltf/.glb have)"
            ]
        );

        for (values, want) in [(vec![values(4)], "4 AO values for 5 vertices"), (vec![], "values for 0 meshes")] {
            let e = asset.write(&out, &values, &WriteOptions::default()).unwrap_err().to_string();
            assert!(e.contains(want), "{e}");
        }
    }

    #[test]
    fn bad_files_are_refused_in_one_line() {
        let tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\n";
        let cases = [
            (format!("{tri}v 1 2\n"), "line 4: invalid OBJ: a vertex position needs 3 numbers, found 2"),
            (format!("{tri}v 1 2 3 4 5\n"), "found 5 numbers"),
            (format!("{tri}v 1 x 3\n"), "line 4: invalid OBJ: 'x' is not a number"),
            (format!("{tri}v 1 2 3 0\n"), "line 4: invalid OBJ: a vertex with w = 0"),
            (format!("{tri}v 1 nan 3\n"), "vertex 4 (line 4) has a non-finite coordinate (y = NaN)"),
            (format!("{tri}v 1e39 0 3\n"), "vertex 4 (line 4) has a non-finite coordinate (x = inf)"),
            (format!("{tri}vn 0 1\n"), "line 4: invalid OBJ: a normal needs 3 numbers"),
            (format!("{tri}vn 0 1 z\n"), "line 4: invalid OBJ: 'z' is not a number"),
            (format!("{tri}f 1 2 0\n"), "line 4: invalid OBJ: face vertex index out of bounds (0: OBJ counts from 1)"),
            (format!("{tri}f 1 2 4\n"), "line 4: invalid OBJ: face vertex index out of bounds (4, with 3 vertices)"),
            (
                format!("{tri}f 1 2 -4\n"),
                "line 4: invalid OBJ: face vertex index out of bounds (-4, with 3 vertices before it)",
            ),
            (format!("{tri}f 1 2 3.5\n"), "line 4: invalid OBJ: the face corner '3.5' has '3.5', not an index"),
            (
                format!("{tri}vt 0 0\nf 1/2 2 3\n"),
                "line 5: invalid OBJ: face texture coordinate index out of bounds (2, with 1 texture coordinates)",
            ),
            (
                format!("{tri}f 1/-1 2 3\nvt 0 0\n"),
                "line 4: invalid OBJ: face texture coordinate index out of bounds (-1, with 0 texture coordinates before it)",
            ),
            (format!("{tri}f 1/x 2 3\n"), "line 4: invalid OBJ: the face corner '1/x' has 'x', not an index"),
            (
                format!("{tri}vn 0 0 1\nf 1//2 2 3\n"),
                "line 5: invalid OBJ: face normal index out of bounds (2, with 1 normals)",
            ),
            (format!("{tri}vn 0 0 1\nf 1//0 2 3\n"), "line 5: invalid OBJ: face normal index out of bounds (0"),
            (format!("{tri}f 1/1/1/1 2 3\n"), "line 4: invalid OBJ: the face corner '1/1/1/1' has more than v/vt/vn"),
            (format!("{tri}f /1 2 3\n"), "line 4: invalid OBJ: the face corner '/1' names no vertex"),
            (
                format!("{tri}f 1 2 99999999999\n"),
                "line 4: invalid OBJ: face vertex index out of bounds (99999999999, with 3 vertices)",
            ),
        ];
        for (text, want) in cases {
            let (_dir, path) = file("bad.obj", text.as_bytes());
            let e = ObjAsset::read(&path).err().unwrap_or_else(|| panic!("{text:?} was read")).to_string();
            assert!(e.starts_with(&path.display().to_string()), "{e}");
            assert!(e.contains(want), "{text:?}: {e}");
            assert_eq!(e.lines().count(), 1, "{e}");
        }
        let e = ObjAsset::read(Path::new("no such file.obj")).err().unwrap().to_string();
        assert!(e.starts_with("no such file.obj: "), "{e}");
    }
}
