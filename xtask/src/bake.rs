//! `octoproxy bake`: meshes → a proxy file.

use std::ffi::OsString;
use std::path::PathBuf;

use anyhow::{bail, Result};

use crate::flags::{self, BuildFlags};
use crate::instanced::{bake_gltf, SceneFile};
use crate::scene;

fn help() -> String {
    format!(
        "usage: octoproxy bake (--mesh MESH [--mesh MESH...] | --scene FILE.gltf) -o FILE [build options]\n\n\
         Bakes the meshes (PLY, OBJ or STL, each optionally .gz) into one proxy file; or a glTF\n\
         2.0 scene (.gltf, .glb) into a baked scene (write it as FILE.octoscene): every mesh baked\n\
         once, the instance table and the animation, which `sim --scene FILE.octoscene` reads\n\
         without baking again.\n\n{}",
        flags::BUILD_HELP
    )
}

pub fn run(args: Vec<OsString>) -> Result<()> {
    let mut meshes: Vec<PathBuf> = Vec::new();
    let mut scene_file: Option<PathBuf> = None;
    let mut out: Option<PathBuf> = None;
    let mut build = BuildFlags::default();
    let mut parser = lexopt::Parser::from_args(args);
    while let Some((name, unexpected)) = flags::next_option(&mut parser)? {
        if build.parse(&name, &mut parser)? {
            continue;
        }
        match name.as_str() {
            "--mesh" => meshes.push(flags::path(&mut parser, "--mesh")?),
            "--scene" => scene_file = Some(flags::path(&mut parser, "--scene")?),
            "-o" | "--out" => out = Some(flags::path(&mut parser, "--out")?),
            "-h" | "--help" => {
                println!("{}", help());
                return Ok(());
            }
            _ => return Err(unexpected.into()),
        }
    }
    let Some(out) = out else {
        bail!("bake needs --out FILE (or -o FILE)")
    };
    flags::writable(&out, "--out")?;
    if let Some(path) = scene_file {
        if !meshes.is_empty() {
            bail!("give either --mesh or --scene, not both");
        }
        if SceneFile::of(&path) != Some(SceneFile::Gltf) {
            bail!(
                "--scene {}: bake reads glTF 2.0 scenes (.gltf or .glb)",
                path.display()
            );
        }
        if same_file(&path, &out) {
            bail!(
                "--out {} is the input scene; refusing to overwrite it",
                out.display()
            );
        }
        let (baked, _) = bake_gltf(&path, build.params()?, build.radius()?)?;
        baked.write(&out)?;
        println!("wrote {}", out.display());
        return Ok(());
    }
    if meshes.is_empty() {
        bail!("bake needs --mesh MESH (repeat for several) or --scene FILE.gltf");
    }
    if meshes.iter().any(|m| same_file(m, &out)) {
        bail!(
            "--out {} is one of the input meshes; refusing to overwrite it",
            out.display()
        );
    }
    let params = build.params()?;
    let radius = build.radius()?;
    let loaded = scene::load_meshes(&meshes)?;
    let scene = scene::bake_meshes(loaded, &params, radius)?;
    scene::print_bake_summary(&scene)?;
    scene::write_proxy(&out, &scene.words)?;
    println!("wrote {}", out.display());
    Ok(())
}

/// Whether two paths name the same existing file (or are spelled the same).
pub fn same_file(a: &std::path::Path, b: &std::path::Path) -> bool {
    if a == b {
        return true;
    }
    match (std::fs::canonicalize(a), std::fs::canonicalize(b)) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}
