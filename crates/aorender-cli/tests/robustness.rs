//! Non-finite numbers in a scene file or a mesh on the command line: one error line naming
//! the file, the object and the coordinate, and nothing written.

mod common;
use common::*;

/// A scene whose camera and single object are given.
fn scene_text(camera: &str, object: &str) -> String {
    format!("[camera]\ntype = \"perspective\"\nfov = 45\n{camera}\n[[object]]\n{object}\n")
}

const CAMERA: &str = "eye = [0, 0, 5]\nlook_at = [0, 0, 0]";
const SPHERE: &str = "type = \"sphere\"\ncenter = [0, 0, 0]\nradius = 1";

/// The command line reports non-finite numbers (in a scene file's object, its camera, a
/// bare mesh) on one line naming the object, and writes nothing.
#[test]
fn the_command_line_names_the_object() {
    let dir = temp_dir();
    let d = dir.path();
    std::fs::write(d.join("nan.obj"), "v 0 0 0\nv 1 0 0\nv 0 nan 0\nf 1 2 3\n").unwrap();
    let mesh = "type = \"mesh\"\nfile = \"nan.obj\"";
    std::fs::write(d.join("scene.toml"), scene_text(CAMERA, &format!("{SPHERE}\n[[object]]\n{mesh}"))).unwrap();
    std::fs::write(d.join("camera.toml"), scene_text("eye = [0, 0, nan]\nlook_at = [0, 0, 0]", SPHERE)).unwrap();
    for (file, expect) in [
        (
            "scene.toml",
            "scene.toml: object 2 (mesh \"nan.obj\"): vertex 3 (line 3) has a non-finite coordinate (y = NaN)",
        ),
        ("camera.toml", "camera.toml: camera: eye has a non-finite coordinate (z = NaN)"),
        ("nan.obj", "nan.obj: vertex 3 (line 3) has a non-finite coordinate (y = NaN)"),
    ] {
        let output = aorender(&["render", file, "-o", "out.png"], d);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success(), "{file} rendered");
        let lines: Vec<&str> = stderr.lines().filter(|l| l.starts_with("aorender:")).collect();
        assert_eq!(lines.len(), 1, "{file}: {stderr}");
        assert!(lines[0].ends_with(expect), "{file}: '{}' does not end with '{expect}'", lines[0]);
        assert!(!d.join("out.png").exists(), "{file}: wrote an image");
    }
}
