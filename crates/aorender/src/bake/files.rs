//! The files of a bake: reading a mesh file for baking, the format a name says, where
//! each object's bake is written, and the output policy's checks before any work.

use super::asset::{Asset, TextureFiles, format_of};
use crate::error::{Error, Result};
use crate::output::{FilePlan, OutputRules};
use crate::scene::input::Meter;
use crate::scene::mesh::IndexedMesh;
use crate::scene::{LoadOptions, MeshObject, ReadLimits, Scene};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Reads a mesh file (`.ply`, `.obj`, `.gltf`, `.glb`, each optionally gzipped) for baking,
/// within the read budget of [`LoadOptions::from_env`], external glTF URIs refused.
pub fn read_asset(path: &Path) -> Result<Box<dyn Asset>> {
    read_asset_with(path, &LoadOptions::from_env()?)
}

/// [`read_asset`] within the read budget of `options`, following glTF URIs as it allows.
pub fn read_asset_with(path: &Path, options: &LoadOptions) -> Result<Box<dyn Asset>> {
    match crate::scene::extension(path).as_str() {
        "ply" => Ok(Box::new(super::ply::PlyAsset::read_with(path, options)?)),
        "obj" => Ok(Box::new(super::obj::ObjAsset::read_with(path, options)?)),
        "gltf" | "glb" => Ok(Box::new(super::gltf::GltfAsset::read_with(path, options)?)),
        ext => Err(not_bakeable(path, ext)),
    }
}

/// The mesh files of a scene read for baking while the scene was loaded
/// ([`load_for_bake`]), each parsed once for both.
#[derive(Clone, Default)]
pub struct ReadInputs {
    /// Each file read, with whether its glTF URIs could lead outside its folder.
    assets: Vec<(PathBuf, bool, Arc<dyn Asset>)>,
}

impl ReadInputs {
    /// The file of `object` as it was read, when it was.
    pub(crate) fn get(&self, object: &MeshObject) -> Option<Arc<dyn Asset>> {
        let found = self.assets.iter().find(|(p, allow, _)| *p == object.path && *allow == object.allow_external_uris);
        found.map(|(_, _, asset)| asset.clone())
    }
}

/// Loads a scene file or a mesh file as [`Scene::load_with`] does, with each mesh file
/// parsed once, by the bake's reader, which keeps what writing the file back needs (give
/// it to [`crate::bake::Bake::with_inputs`]). A file that reader refuses is read again by
/// the scene's, so that an error is the one the scene's loaders give.
pub fn load_for_bake(path: &Path, options: &LoadOptions) -> Result<(Scene, ReadInputs)> {
    let mut inputs = ReadInputs::default();
    // A scene file far from the origin is placed twice: the second time, each file's mesh
    // is made again from what was read (a mesh file is placed once).
    let placed_again = crate::scene::extension(path) == "toml";
    let mut remakes: Vec<Remake> = Vec::new();
    let mut reader = |path: &Path, options: &LoadOptions, meter: &mut Meter| -> Result<IndexedMesh> {
        let key = (path, options.allow_external_uris);
        if let Some(k) = inputs.assets.iter().position(|(p, allow, _)| (p.as_path(), *allow) == key) {
            return Ok(remakes[k]());
        }
        match read_asset_and_mesh(path, options, placed_again) {
            Ok((asset, mesh, remake)) => {
                inputs.assets.push((path.to_path_buf(), options.allow_external_uris, asset));
                remakes.push(remake);
                Ok(mesh)
            }
            Err(e) => Err(crate::scene::meshes::read_format(path, options, meter).err().unwrap_or(e)),
        }
    };
    let scene = Scene::load_reading(path, options, Some(&mut reader))?;
    Ok((scene, inputs))
}

/// Makes the scene's mesh of a file again from what the bake read of it.
type Remake = Box<dyn Fn() -> IndexedMesh>;

/// Reads a mesh file for baking with the mesh the scene's loader reads from it, and how
/// to make that mesh again: PLY and OBJ from their faces, glTF from a copy kept when
/// `again` (else the remake is never called and makes an empty mesh).
fn read_asset_and_mesh(
    path: &Path,
    options: &LoadOptions,
    again: bool,
) -> Result<(Arc<dyn Asset>, IndexedMesh, Remake)> {
    match crate::scene::extension(path).as_str() {
        "ply" => {
            let asset = Arc::new(super::ply::PlyAsset::read_with(path, options)?);
            let (mesh, kept) = (asset.scene_mesh(), asset.clone());
            Ok((asset, mesh, Box::new(move || kept.scene_mesh())))
        }
        "obj" => {
            let asset = Arc::new(super::obj::ObjAsset::read_with(path, options)?);
            let (mesh, kept, path) = (asset.scene_mesh(path), asset.clone(), path.to_path_buf());
            Ok((asset, mesh, Box::new(move || kept.scene_mesh(&path))))
        }
        "gltf" | "glb" => {
            let (asset, mesh) = super::gltf::GltfAsset::read_for_scene(path, options)?;
            let kept = if again { mesh.clone() } else { IndexedMesh::default() };
            Ok((Arc::new(asset), mesh, Box::new(move || kept.clone())))
        }
        ext => Err(not_bakeable(path, ext)),
    }
}

/// The error for a file of extension `ext`, which no bake reads.
fn not_bakeable(path: &Path, ext: &str) -> Error {
    Error::scene(path, format!("cannot bake into '.{ext}' files: expected .ply, .obj, .gltf or .glb"))
}

/// The mesh file of a scene's mesh object read for baking as the scene read it (its glTF
/// URIs followed where the scene allowed them), within `limits`.
pub fn read_object(object: &MeshObject, limits: &ReadLimits) -> Result<Box<dyn Asset>> {
    let options = LoadOptions { limits: limits.clone(), allow_external_uris: object.allow_external_uris };
    read_asset_with(&object.path, &options)
}

/// Where a bake writes mesh object `object` of `objects`: `output` itself for a mesh
/// file; for a scene file, the directory `output` under the mesh file's name, with the
/// object's number added (`NAME-N.EXT`) when other objects place the same file.
pub fn output_path(objects: &[MeshObject], object: &MeshObject, is_scene: bool, output: &Path) -> PathBuf {
    if !is_scene {
        return output.to_path_buf();
    }
    let name = object.path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    if objects.iter().filter(|o| o.path == object.path).count() == 1 {
        return output.join(name);
    }
    match name.split_once('.') {
        Some((stem, ext)) => output.join(format!("{stem}-{}.{ext}", object.number)),
        None => output.join(format!("{name}-{}", object.number)),
    }
}

/// Enters in `plan` the file a bake of `object` writes, `output`, given by `option` (`-o`
/// on the command line): its role is `option` for a mesh file's bake, `the bake of
/// object N (option)` for a scene's; it may replace the object's own mesh file only when
/// `overwrite`. A file in directories still to be made
/// is allowed: the bake makes them. The files written beside it follow with
/// [`plan_companions`].
pub fn plan_output(
    plan: &mut FilePlan,
    object: &MeshObject,
    output: &Path,
    is_scene: bool,
    overwrite: bool,
    option: &str,
) -> Result<()> {
    let replacing = overwrite.then_some(object.path.as_path());
    plan.output_with(output, &output_role(object, is_scene, option), OutputRules { replacing, new_directories: true })?;
    Ok(())
}

/// Enters in `plan` the files a bake of `object` (read into `asset`) writes beside
/// `output` ([`Asset::companion_files`], `texture` as there), named as in [`plan_output`].
pub fn plan_companions(
    plan: &mut FilePlan,
    object: &MeshObject,
    asset: &dyn Asset,
    (output, option): (&Path, &str),
    is_scene: bool,
    texture: Option<&TextureFiles>,
) -> Result<()> {
    let role = output_role(object, is_scene, option);
    let files = if texture.is_none() && is_conversion(&object.path, output) {
        super::convert::companion_files(output)
    } else {
        asset.companion_files(output, texture)
    };
    for (file, what) in files {
        let rules = OutputRules { new_directories: true, ..OutputRules::default() };
        plan.output_with(&file, &format!("{what} beside {role}"), rules)?;
    }
    Ok(())
}

fn output_role(object: &MeshObject, is_scene: bool, option: &str) -> String {
    if is_scene { format!("the bake of object {} ({option})", object.number) } else { option.to_string() }
}

/// Whether a bake of `input` into `output` writes a new file of another format
/// ([`crate::bake::Asset::write`] writes the input's own format back).
pub(crate) fn is_conversion(input: &Path, output: &Path) -> bool {
    format_of(input) != format_of(output)
}

/// Checks, before any work, that `output` can take the bake into vertices or faces of the
/// mesh file `input`: a `.ply`, `.obj`, `.gltf` or `.glb` file (optionally gzipped), any
/// of them whatever the input's format, and not the input itself unless `overwrite`.
pub fn check_mesh_output(input: &Path, output: &Path, overwrite: bool) -> Result<()> {
    if format_of(input).is_none() {
        return check_output(input, output, overwrite);
    }
    if format_of(output).is_none() {
        let name = output.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let ext = name.strip_suffix(".gz").unwrap_or(&name).rsplit_once('.').map_or("", |(_, e)| e).to_string();
        let what = if ext.is_empty() { "a file without an extension".to_string() } else { format!("'.{ext}' files") };
        return Err(Error::output(
            output,
            format!("cannot bake into {what}: expected .ply, .obj, .gltf or .glb, optionally gzipped (.gz)"),
        ));
    }
    if !is_conversion(input, output) {
        return check_output(input, output, overwrite);
    }
    if !overwrite && crate::output::same_file(input, output) {
        return Err(Error::output(
            output,
            "the output would replace the input; choose another path, or allow writing over it (--overwrite)",
        ));
    }
    Ok(())
}

/// Checks, before any work, that `output` can take the texture bake of the mesh file
/// `input`: a file of its format (glTF and GLB are one), and not the input itself unless
/// `overwrite`.
pub fn check_output(input: &Path, output: &Path, overwrite: bool) -> Result<()> {
    let Some(theirs) = format_of(input) else {
        return Err(Error::scene(
            input,
            "cannot bake into this file type: expected .ply, .obj, .gltf, .glb or a scene file (.toml)",
        ));
    };
    if format_of(output) != Some(theirs) {
        let message = format!(
            "the output must be a {theirs} file like the input ({}), optionally gzipped (.gz)",
            input.display()
        );
        return Err(Error::output(output, message));
    }
    if !overwrite && crate::output::same_file(input, output) {
        return Err(Error::output(
            output,
            "the output would replace the input; choose another path, or allow writing over it (--overwrite)",
        ));
    }
    Ok(())
}
