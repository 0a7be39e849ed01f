//! Parsing of command-line values, each with a clear error.

use std::ffi::OsString;
use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use octoproxy_core::PairParams;
use octoproxy_cpu::BuildParams;

/// The next option as `--long` or `-s`, and the error to give if it is not one we take.
/// Positional arguments are an error right away.
pub fn next_option(parser: &mut lexopt::Parser) -> Result<Option<(String, lexopt::Error)>> {
    let Some(arg) = parser.next()? else {
        return Ok(None);
    };
    let name = match &arg {
        lexopt::Arg::Long(s) => format!("--{s}"),
        lexopt::Arg::Short(c) => format!("-{c}"),
        lexopt::Arg::Value(_) => return Err(arg.unexpected().into()),
    };
    Ok(Some((name, arg.unexpected())))
}

/// Takes the value of an option as a string.
pub fn string(parser: &mut lexopt::Parser, name: &str) -> Result<String> {
    let v: OsString = parser
        .value()
        .with_context(|| format!("{name} needs a value"))?;
    v.into_string()
        .map_err(|v| anyhow::anyhow!("{name}: {v:?} is not valid UTF-8"))
}

/// Takes the value of an option as a path.
pub fn path(parser: &mut lexopt::Parser, name: &str) -> Result<PathBuf> {
    Ok(PathBuf::from(
        parser
            .value()
            .with_context(|| format!("{name} needs a value"))?,
    ))
}

/// Parses a number, naming the option in the error.
pub fn number<T: std::str::FromStr>(parser: &mut lexopt::Parser, name: &str) -> Result<T> {
    let s = string(parser, name)?;
    s.trim()
        .parse()
        .map_err(|_| anyhow::anyhow!("{name}: {s:?} is not a valid number"))
}

/// The steps of `dt` seconds that play an animation of `duration` seconds from `start`: at
/// least one, and an error naming the count where it is more than a run can take (a `u32`)
/// instead of a count silently cut to it.
pub fn animation_steps(file: &std::path::Path, duration: f64, start: f64, dt: f32) -> Result<u32> {
    let steps = ((duration - start) / dt as f64).ceil().max(1.0);
    if !(steps <= u32::MAX as f64) {
        bail!(
            "{}: the animation runs {duration} s from {start} s: {steps:.3e} steps of {dt} s, more than {} a run can take; give --steps",
            file.display(),
            u32::MAX
        );
    }
    Ok(steps as u32)
}

/// Refuses an output path that cannot be written, before any work (a bake or a simulation
/// that ends in an error at its last write loses all of it): an existing folder, a folder
/// that does not exist, or one this process may not create files in (tried with a probe file
/// beside the output, removed at once).
pub fn writable(path: &std::path::Path, name: &str) -> Result<()> {
    if path.is_dir() {
        bail!("{name} {}: is a folder", path.display());
    }
    let file = path
        .file_name()
        .with_context(|| format!("{name} {}: names no file", path.display()))?;
    let folder = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    if !folder.is_dir() {
        bail!(
            "{name} {}: the folder {} does not exist",
            path.display(),
            folder.display()
        );
    }
    let mut probe_name = file.to_os_string();
    probe_name.push(format!(".octoproxy-probe-{}", std::process::id()));
    let probe = folder.join(probe_name);
    match std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
    {
        Ok(_) => {
            let _ = std::fs::remove_file(&probe);
            Ok(())
        }
        Err(e) => bail!("{name} {}: cannot write there: {e}", path.display()),
    }
}

/// [`fits_in_memory`] for `n` particles made by the command: each held twice, emitted and in
/// the backend.
pub fn particles_fit(name: &str, n: usize) -> Result<()> {
    let each = 2 * std::mem::size_of::<octoproxy_core::Particle>() as u64;
    fits_in_memory(
        name,
        n,
        each,
        "the particles (32 bytes each, emitted and the backend's copy)",
    )
}

/// Refuses a count whose memory alone, `bytes_each` per item (a lower bound of what the
/// command will hold: `what` says of what), is more than this machine's memory and swap,
/// before any work is done: a clear error instead of an allocation that aborts the process
/// later, perhaps after a long bake. No check where the machine's memory is not known (only
/// Linux's `/proc/meminfo` is read); the allocations then fail with their own errors.
pub fn fits_in_memory(name: &str, count: usize, bytes_each: u64, what: &str) -> Result<()> {
    fits_in(name, count, bytes_each, what, memory_and_swap())
}

fn fits_in(name: &str, count: usize, bytes_each: u64, what: &str, have: Option<u64>) -> Result<()> {
    let need = (count as u64).saturating_mul(bytes_each);
    match have {
        Some(have) if need > have => bail!(
            "{name} {count}: {what} need at least {}, more than this machine's {} of memory and swap",
            crate::scene::bytes(need),
            crate::scene::bytes(have)
        ),
        _ => Ok(()),
    }
}

/// `MemTotal` plus `SwapTotal` from `/proc/meminfo`, in bytes.
fn memory_and_swap() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let field = |key: &str| -> Option<u64> {
        let line = info.lines().find(|l| l.starts_with(key))?;
        let kib: u64 = line[key.len()..]
            .trim()
            .trim_end_matches("kB")
            .trim()
            .parse()
            .ok()?;
        Some(kib.saturating_mul(1024))
    };
    Some(field("MemTotal:")?.saturating_add(field("SwapTotal:").unwrap_or(0)))
}

/// Parses `N` comma-separated finite floats (negative numbers fine: `--gravity 0,-9.81,0`).
pub fn floats<const N: usize>(parser: &mut lexopt::Parser, name: &str) -> Result<[f32; N]> {
    let s = string(parser, name)?;
    let parts: Vec<&str> = s.split(',').collect();
    if parts.len() != N {
        bail!("{name}: expected {N} comma-separated numbers, got {s:?}");
    }
    let mut out = [0.0f32; N];
    for (o, p) in out.iter_mut().zip(parts) {
        *o = p
            .trim()
            .parse()
            .map_err(|_| anyhow::anyhow!("{name}: {p:?} is not a number"))?;
        if !o.is_finite() {
            bail!("{name}: {p:?} is not a finite number");
        }
    }
    Ok(out)
}

/// The options of the particle–particle pass, shared by `sim` and `check`.
#[derive(Default)]
pub struct PairFlags {
    /// `--collide-particles`.
    pub collide: bool,
    pub restitution: Option<f32>,
    pub friction: Option<f32>,
    pub iterations: Option<u32>,
    pub max_iterations: Option<u32>,
    pub substeps: Option<u32>,
    /// `--particle-substeps speed` (true) or `gravity` (false).
    pub follow_speed: Option<bool>,
    pub relaxation: Option<f32>,
    pub stacking: Option<f32>,
}

/// The help lines of [`PairFlags`].
pub const PAIR_HELP: &str =
    "  --collide-particles          Green's uniform grid and position-based contacts
  --particle-restitution E     in [0, 1] (default: --restitution)
  --particle-friction F        Coulomb coefficient >= 0 (default: --friction)
  --particle-iterations N      the fewest Jacobi iterations per substep, 1..=64 (default 8);
                               a step takes one per 12 grains in its deepest column
  --particle-max-iterations N  the most, up to 64 (default 64): deeper piles are reported
  --particle-substeps N|speed|gravity
                               substeps per step, 1..=256, or chosen each step: speed (the
                               default) keeps gravity's closing per substep under 1 % of the
                               radius and no particle moving more than R in one (none passes
                               through another); gravity: the first rule alone
  --particle-relaxation B      share of an overlap removed per substep, (0, 1] (default 0.4)
  --particle-stacking S        how much more of a correction the upper particle of a pair
                               takes, [0, 1] (default 1: a stack does not sink)";

impl PairFlags {
    /// Consumes the option if it is one of the pass's; returns whether it was.
    pub fn parse(&mut self, name: &str, parser: &mut lexopt::Parser) -> Result<bool> {
        match name {
            "--collide-particles" => self.collide = true,
            "--particle-restitution" => self.restitution = Some(number(parser, name)?),
            "--particle-friction" => self.friction = Some(number(parser, name)?),
            "--particle-iterations" => self.iterations = Some(number(parser, name)?),
            "--particle-max-iterations" => self.max_iterations = Some(number(parser, name)?),
            "--particle-substeps" => {
                let v = string(parser, name)?;
                match v.trim() {
                    "speed" => self.follow_speed = Some(true),
                    "gravity" => self.follow_speed = Some(false),
                    n => {
                        self.substeps = Some(n.parse().map_err(|_| {
                            anyhow::anyhow!(
                                "{name}: {v:?} is neither a number, \"speed\" nor \"gravity\""
                            )
                        })?)
                    }
                }
            }
            "--particle-relaxation" => self.relaxation = Some(number(parser, name)?),
            "--particle-stacking" => self.stacking = Some(number(parser, name)?),
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// Whether any `--particle-*` option is given.
    pub fn any_option(&self) -> bool {
        self.restitution.is_some()
            || self.friction.is_some()
            || self.iterations.is_some()
            || self.max_iterations.is_some()
            || self.substeps.is_some()
            || self.follow_speed.is_some()
            || self.relaxation.is_some()
            || self.stacking.is_some()
    }

    /// The pass's parameters when `--collide-particles` is given (`--particle-*`, else
    /// `--restitution`/`--friction` as stepped), checked; an error for `--particle-*`
    /// without it.
    pub fn params(&self, step: &octoproxy_core::StepParams) -> Result<Option<PairParams>> {
        if !self.collide {
            if self.any_option() {
                anyhow::bail!("--particle-* options go with --collide-particles");
            }
            return Ok(None);
        }
        let d = PairParams::default();
        if self.substeps == Some(0) {
            anyhow::bail!(
                "--particle-substeps must be at least 1 (leave it out for the automatic choice)"
            );
        }
        let pairs = PairParams {
            restitution: self.restitution.unwrap_or(step.restitution),
            friction: self.friction.unwrap_or(step.friction),
            relaxation: self.relaxation.unwrap_or(d.relaxation),
            stacking: self.stacking.unwrap_or(d.stacking),
            // A cap under the default fewest lowers the fewest with it.
            iterations: self.iterations.unwrap_or(
                d.iterations
                    .min(self.max_iterations.unwrap_or(d.iterations))
                    .max(1),
            ),
            max_iterations: self.max_iterations.unwrap_or(d.max_iterations),
            substeps: self.substeps.unwrap_or(d.substeps),
            follow_speed: self.follow_speed.unwrap_or(d.follow_speed),
            max_candidates: d.max_candidates,
        };
        pairs.validate(step)?;
        Ok(Some(pairs))
    }
}

/// The options that shape a bake, shared by `bake` and `sim`.
#[derive(Default)]
pub struct BuildFlags {
    pub dmin: Option<u32>,
    pub dmax: Option<u32>,
    pub epsilon: Option<f32>,
    pub lut_depth: Option<u32>,
    /// The particle radius (`--radius`): a bake for it, and the radius stepped. Not counted
    /// by [`BuildFlags::any`]: with a proxy file it is a step parameter.
    pub radius: Option<f32>,
}

impl BuildFlags {
    /// Consumes the option if it is a build flag; returns whether it was.
    pub fn parse(&mut self, name: &str, parser: &mut lexopt::Parser) -> Result<bool> {
        match name {
            "--dmin" => self.dmin = Some(number(parser, name)?),
            "--dmax" => self.dmax = Some(number(parser, name)?),
            "--epsilon" => self.epsilon = Some(number(parser, name)?),
            "--lut-depth" => self.lut_depth = Some(number(parser, name)?),
            "--radius" => self.radius = Some(number(parser, name)?),
            _ => return Ok(false),
        }
        Ok(true)
    }

    /// Whether any was given.
    pub fn any(&self) -> bool {
        self.dmin.is_some()
            || self.dmax.is_some()
            || self.epsilon.is_some()
            || self.lut_depth.is_some()
    }

    /// The particle radius, 0 when not given, checked.
    pub fn radius(&self) -> Result<f32> {
        let r = self.radius.unwrap_or(0.0);
        if !(r >= 0.0) || !r.is_finite() {
            anyhow::bail!("--radius must be a finite number >= 0, got {r}");
        }
        Ok(r)
    }

    /// The parameters, defaults filled in, checked.
    pub fn params(&self) -> Result<BuildParams> {
        let d = BuildParams::default();
        let p = BuildParams {
            dmin: self.dmin.unwrap_or(d.dmin),
            dmax: self.dmax.unwrap_or(d.dmax),
            epsilon: self.epsilon.unwrap_or(d.epsilon),
            lut_depth: self.lut_depth.unwrap_or(d.lut_depth),
            max_nodes: d.max_nodes,
        };
        p.validate()?;
        Ok(p)
    }
}

/// The build-flag help lines.
// Not a `"\` continuation: it would eat the first line's indent.
pub const BUILD_HELP: &str =
    "  --dmin N          depth below which nodes always subdivide (default 4)
  --dmax N          maximum depth, 2..=16 (default 8)
  --epsilon X       normal-variance tolerance, >= 0 (default 0.01)
  --lut-depth N     lookup-table depth, 0..=8, clamped to the tree depth (default 5)
  --radius R        the particles' radius, >= 0: bake the offset surface at R from the mesh
                    (a glTF scene: each mesh once per world scale s, at R/s; no animated
                    scale) (default 0; with a proxy or a baked scene, its own)";

/// The substeps of a step with the pass, as the messages of `sim` and `check` say them: the
/// caller's count, gravity's, or the rule that follows speed.
pub fn substeps_said(params: &octoproxy_core::StepParams, pairs: &PairParams) -> String {
    let gravity = octoproxy_core::pair_substeps(params, pairs);
    if pairs.substeps != 0 {
        format!("{gravity} a step, --particle-substeps")
    } else if pairs.follow_speed {
        format!(
            "at least {gravity} a step for gravity, more while a particle moves more than a radius in one"
        )
    } else {
        format!("{gravity} a step for gravity")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_count_beyond_memory_is_refused_with_the_sizes() {
        let e = fits_in("--emit", 4_000_000_000, 64, "the particles", Some(24 << 30))
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "--emit 4000000000: the particles need at least 238.42 GiB, more than this machine's 24.00 GiB of memory and swap"
        );
        assert!(fits_in("--emit", 1_000_000, 64, "the particles", Some(24 << 30)).is_ok());
        // Unknown memory: no check. An overflowing product saturates and is refused.
        assert!(fits_in("--emit", usize::MAX, 64, "the particles", None).is_ok());
        assert!(fits_in(
            "--emit",
            usize::MAX,
            64,
            "the particles",
            Some(u64::MAX - 1)
        )
        .is_err());
    }

    #[test]
    fn outputs_that_cannot_be_written_are_found_first() {
        let dir = std::env::temp_dir().join(format!("octoproxy-writable-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        assert!(writable(&dir.join("out.ply"), "--out").is_ok());
        // The probe is gone, and nothing else was made.
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0);
        let e = writable(&dir, "--out").unwrap_err().to_string();
        assert!(e.ends_with("is a folder"), "{e}");
        let e = writable(&dir.join("missing").join("out.ply"), "--out")
            .unwrap_err()
            .to_string();
        assert!(e.contains("does not exist"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn an_animation_too_long_to_play_is_an_error_not_a_cut() {
        let file = std::path::Path::new("long.gltf");
        assert_eq!(animation_steps(file, 1.0, 0.0, 0.25).unwrap(), 4);
        assert_eq!(animation_steps(file, 1.0, 2.0, 0.25).unwrap(), 1);
        let e = animation_steps(file, 2e30, 0.0, 1.0 / 60.0)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("long.gltf: the animation runs") && e.contains("give --steps"),
            "{e}"
        );
    }

    #[test]
    fn this_machines_memory_is_read_where_linux_tells_it() {
        if cfg!(target_os = "linux") {
            let have = memory_and_swap().expect("/proc/meminfo has MemTotal");
            assert!(have >= 1 << 26, "{have} bytes");
        }
    }
}
