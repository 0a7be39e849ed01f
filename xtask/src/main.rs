//! `octoproxy`: the command line.
//!
//! - `demo`: a built-in scene, stepped on the best backend, with a summary and a picture.
//! - `bake`: meshes → proxy file.
//! - `sim`: a proxy (or meshes) and particles → stepped particles, optionally every frame.
//! - `check`: the penetration harness against exact ground truth.
//! - `bench` (feature `dev`, as `cargo xtask bench`): octoproxy against the alternatives,
//!   with a table, plots and JSON.
//!
//! Installed with `cargo install --path xtask --locked`; developers run the same binary with
//! its development extras as `cargo xtask <command>`. Errors print as one line and exit
//! non-zero.

mod backends;
mod bake;
#[cfg(feature = "dev")]
mod bench;
mod check;
mod demo;
mod flags;
mod instanced;
#[cfg(feature = "dev")]
mod plot;
mod progress;
mod render;
mod sand;
mod scene;
mod sim;

use std::process::ExitCode;

/// The top-level help; `bench` is listed where it is built.
fn usage() -> String {
    format!(
        "\
usage: octoproxy <command> [options]

commands:
  demo   run a built-in scene and write a picture of it
  bake   --mesh MESH [--mesh MESH...] -o FILE [--dmin N --dmax N --epsilon X --lut-depth N]
  sim    (--mesh MESH... | --proxy FILE) (--particles IN.ply | --emit N ...) -o OUT.ply [options]
  check  (--mesh MESH... | --scene NAME) [options]: count penetrations against exact ground truth
{BENCH_USAGE}
run `octoproxy <command> --help` for a command's options"
    )
}

#[cfg(feature = "dev")]
const BENCH_USAGE: &str =
    "  bench  [--quick] [--backends cpu,wgpu] [--scenes ...] [--particles ...]: speed, memory, leaks\n";
#[cfg(not(feature = "dev"))]
const BENCH_USAGE: &str = "";

/// `bench` in a build without the development extras: say where it is.
#[cfg(not(feature = "dev"))]
mod bench {
    pub fn run(_: Vec<std::ffi::OsString>) -> anyhow::Result<()> {
        anyhow::bail!(
            "bench is a development command: run it in the repository as `cargo xtask bench` \
             (the `dev` feature, which builds the baselines it compares against)"
        )
    }
}

fn main() -> ExitCode {
    // The Vulkan loader complains on every start without it; the value does not matter to us.
    if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
        std::env::set_var("XDG_RUNTIME_DIR", std::env::temp_dir());
    }
    let mut args = std::env::args_os().skip(1);
    let Some(cmd) = args.next() else {
        eprintln!("{}", usage());
        return ExitCode::from(2);
    };
    let rest: Vec<_> = args.collect();
    let result = match cmd.to_str() {
        Some("demo") => demo::run(rest),
        Some("bake") => bake::run(rest),
        Some("sim") => sim::run(rest),
        Some("check") => check::run(rest),
        Some("bench") => bench::run(rest),
        Some("-h" | "--help" | "help") => {
            println!("{}", usage());
            return ExitCode::SUCCESS;
        }
        _ => {
            eprintln!("error: unknown command {cmd:?} (commands: demo, bake, sim, check, bench; see `octoproxy --help`)");
            return ExitCode::from(2);
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // One readable line: the error and its causes (a cause an error already says
            // in its own message is not said again).
            let mut msg = String::new();
            for cause in e.chain() {
                let text = cause.to_string();
                if !msg.contains(&text) {
                    if !msg.is_empty() {
                        msg.push_str(": ");
                    }
                    msg.push_str(&text);
                }
            }
            let msg = msg.replace('\n', " ");
            eprintln!("error: {msg}");
            ExitCode::FAILURE
        }
    }
}
