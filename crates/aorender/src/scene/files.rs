//! The files loading a scene reads, listed without loading it: what a command must not
//! write over ([`crate::output::FilePlan`]).

use super::input::{Input, Meter, ReadLimits};
use super::meshes::extension;
use ::gltf::json::{Value, deserialize};
use percent_encoding::percent_decode_str;
use std::path::{Path, PathBuf};

/// The files loading `path` reads, each with its role in words: a bare mesh ("the input
/// mesh"), or a scene file ("the scene file") and every mesh file it names ("the mesh
/// that S names"); and for every `.gltf` among them, the buffer and image files it names
/// ("a file that M names"). Only the scene file's TOML and the `.gltf` files' JSON are
/// read, and only when they are regular files, within the read budget; what cannot be
/// read or parsed is left out, for loading to report.
pub fn input_files(path: &Path) -> Vec<(PathBuf, String)> {
    let mut files = Vec::new();
    let meshes = if extension(path) == "toml" {
        files.push((path.to_path_buf(), "the scene file".to_string()));
        let base = path.parent().unwrap_or(Path::new("."));
        let role = format!("the mesh that {} names", path.display());
        mesh_files(path).into_iter().map(|file| (base.join(file), role.clone())).collect()
    } else {
        vec![(path.to_path_buf(), "the input mesh".to_string())]
    };
    for (mesh, role) in meshes {
        let named = if extension(&mesh) == "gltf" { gltf_files(&mesh) } else { Vec::new() };
        files.push((mesh.clone(), role));
        let role = format!("a file that {} names", mesh.display());
        files.extend(named.into_iter().map(|f| (f, role.clone())));
    }
    files
}

/// The bytes of a regular file (decompressed when gzipped), within the read budget; `None`
/// for anything else: a FIFO or a device is read once, by the loader.
fn read_listed(path: &Path) -> Option<Vec<u8>> {
    if !std::fs::metadata(path).is_ok_and(|m| m.is_file()) {
        return None;
    }
    let limits = ReadLimits::from_env().ok()?;
    let mut meter = Meter::new(&limits, "the file");
    Input::open(path, &limits).ok()?.read_all(path, &mut meter).ok()
}

/// The `file` of every mesh object of a scene file, as written.
fn mesh_files(path: &Path) -> Vec<String> {
    let Some(text) = read_listed(path).and_then(|b| String::from_utf8(b).ok()) else { return Vec::new() };
    let Ok(table) = text.parse::<toml::Table>() else { return Vec::new() };
    let objects = table.get("object").and_then(toml::Value::as_array).map_or(&[][..], Vec::as_slice);
    objects
        .iter()
        .filter(|o| o.get("type").and_then(toml::Value::as_str) == Some("mesh"))
        .filter_map(|o| o.get("file").and_then(toml::Value::as_str).map(str::to_string))
        .collect()
}

/// The files a `.gltf` (or `.gltf.gz`) names as buffers and images, wherever they are
/// (an external URI the user allows is read too).
fn gltf_files(path: &Path) -> Vec<PathBuf> {
    let Some(bytes) = read_listed(path) else { return Vec::new() };
    let Ok(json) = deserialize::from_slice::<Value>(&bytes) else { return Vec::new() };
    ["buffers", "images"]
        .into_iter()
        .filter_map(|key| json.get(key).and_then(Value::as_array))
        .flatten()
        .filter_map(|item| item.get("uri").and_then(Value::as_str))
        .filter_map(|uri| super::gltf::uri_file(path, uri, true, false).ok())
        .collect()
}

/// The relative file name a URI gives, percent-decoded; `None` for `data:` and other
/// URIs with a scheme, and for absolute paths.
pub(crate) fn relative_file(uri: &str) -> Option<PathBuf> {
    if uri.contains(':') {
        return None;
    }
    let name = percent_decode_str(uri).decode_utf8().ok()?;
    let path = PathBuf::from(&*name);
    (!name.starts_with('/') && path.is_relative()).then_some(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_scene_lists_its_meshes_and_their_gltf_files() {
        let dir = std::env::temp_dir().join(format!("aorender-files-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("m")).unwrap();
        let scene = dir.join("s.toml");
        std::fs::write(
            &scene,
            "[camera]\neye=[0,0,1]\nlook_at=[0,0,0]\nfov=45\n\
             [[object]]\ntype=\"mesh\"\nfile=\"m/a.obj\"\n\
             [[object]]\ntype=\"sphere\"\ncenter=[0,0,0]\nradius=1\n\
             [[object]]\ntype=\"mesh\"\nfile=\"m/b.gltf\"\n",
        )
        .unwrap();
        let gltf = r#"{"asset":{"version":"2.0"},"buffers":[{"uri":"b%20data.bin","byteLength":4},
            {"uri":"data:application/octet-stream;base64,AAAA","byteLength":3}],"images":[{"uri":"tex/c.png"}]}"#;
        std::fs::write(dir.join("m/b.gltf"), gltf).unwrap();
        let files = input_files(&scene);
        let names = format!("a file that {} names", dir.join("m/b.gltf").display());
        let expected = vec![
            (scene.clone(), "the scene file".to_string()),
            (dir.join("m/a.obj"), format!("the mesh that {} names", scene.display())),
            (dir.join("m/b.gltf"), format!("the mesh that {} names", scene.display())),
            (dir.join("m/b data.bin"), names.clone()),
            (dir.join("m/tex/c.png"), names),
        ];
        assert_eq!(files, expected);
        assert_eq!(input_files(&dir.join("m/a.obj")), vec![(dir.join("m/a.obj"), "the input mesh".to_string())]);
        // An unparsable scene lists itself alone: loading it reports the error.
        std::fs::write(&scene, "[camera\n").unwrap();
        assert_eq!(input_files(&scene), vec![(scene.clone(), "the scene file".to_string())]);
        std::fs::remove_dir_all(dir).unwrap();
    }
}
