//! Finds the ROS 2 headers (rcl, rcutils, rmw), checks the declarations `src/lib.rs` relies on
//! against them by compiling `probe.c`, and writes the layouts and versions the crate uses. Without
//! headers the crate builds with no layouts and every constructor says why (`cfg(rcl_headers)` off).

use std::env;
use std::fs;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The packages whose headers and versions the crate depends on.
const PACKAGES: [&str; 3] = ["rcl", "rcutils", "rmw"];

/// Install prefixes to look in, in order: `SABRE_ROS_PREFIX` (`none` turns the search off), the
/// virtual environment the ROS 2 wheels install into, then each entry of `AMENT_PREFIX_PATH`.
fn candidates() -> Vec<PathBuf> {
    if let Ok(prefix) = env::var("SABRE_ROS_PREFIX") {
        return if prefix == "none" {
            Vec::new()
        } else {
            vec![PathBuf::from(prefix)]
        };
    }
    let mut found: Vec<PathBuf> = env::var_os("VIRTUAL_ENV").map(PathBuf::from).into_iter().collect();
    if let Some(paths) = env::var_os("AMENT_PREFIX_PATH") {
        found.extend(env::split_paths(&paths));
    }
    found
}

fn has_headers(prefix: &Path) -> bool {
    prefix.join("include/rcl/rcl/publisher.h").is_file()
}

/// `<version>` of `<prefix>/share/<package>/package.xml`.
fn version(prefix: &Path, package: &str) -> Option<String> {
    let xml = fs::read_to_string(prefix.join("share").join(package).join("package.xml")).ok()?;
    let start = xml.find("<version>")? + "<version>".len();
    let end = start + xml[start..].find("</version>")?;
    Some(xml[start..end].trim().to_string())
}

fn main() {
    println!("cargo::rustc-check-cfg=cfg(rcl_headers)");
    println!("cargo::rerun-if-changed=probe.c");
    for var in ["SABRE_ROS_PREFIX", "VIRTUAL_ENV", "AMENT_PREFIX_PATH"] {
        println!("cargo::rerun-if-env-changed={var}");
    }
    let candidates = candidates();
    for prefix in &candidates {
        // a ROS 2 installed into a prefix later (the `ros` extra after a first build) is picked up
        let include = prefix.join("include");
        if include.is_dir() {
            println!("cargo::rerun-if-changed={}", include.display());
        }
    }
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    let searched = candidates
        .iter()
        .map(|p| p.display().to_string())
        .collect::<Vec<_>>()
        .join(", ");
    let generated = match candidates.iter().find(|p| has_headers(p)) {
        Some(prefix) => {
            println!("cargo::rustc-cfg=rcl_headers");
            probe(prefix, &out)
        }
        None => format!(
            "pub const MISSING: &str = {:?};\n",
            format!(
                "sabre was built without the ROS 2 headers (rcl/publisher.h under <prefix>/include; searched: {}); \
                 install the `ros` extra and rebuild, or set SABRE_ROS_PREFIX",
                if searched.is_empty() { "nothing" } else { &searched }
            )
        ),
    };
    fs::write(out.join("layout.rs"), generated).expect("OUT_DIR is writable");
}

/// Compiles and runs `probe.c` against `prefix`'s headers; its output and the packages' versions.
fn probe(prefix: &Path, out: &Path) -> String {
    let mut build = cc::Build::new();
    build.cargo_warnings(false).cargo_metadata(false);
    let compiler = build.get_compiler();
    let mut command = compiler.to_command();
    // every package directory: rcl's headers include those of rmw, rosidl and the interfaces they use
    let include = prefix.join("include");
    let mut dirs: Vec<PathBuf> = fs::read_dir(&include)
        .expect("the include directory is readable")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    dirs.sort();
    for dir in &dirs {
        command.arg("-I").arg(dir);
    }
    let binary = out.join("probe");
    command.args(["-std=c11", "-Werror", "-o"]).arg(&binary).arg("probe.c");
    let result = command.output().expect("the C compiler runs");
    if !result.status.success() {
        panic!(
            "the ROS 2 headers under {} differ from the declarations sabre-rcl was written for \
             (or do not compile); set SABRE_ROS_PREFIX=none to build without rcl:\n{}",
            include.display(),
            String::from_utf8_lossy(&result.stderr)
        );
    }
    let printed = Command::new(&binary).output().expect("the probe runs");
    assert!(printed.status.success(), "the probe failed");
    let mut generated = String::from_utf8(printed.stdout).expect("the probe prints text");
    let versions: Vec<String> = PACKAGES
        .iter()
        .map(|p| format!("({p:?}, {:?})", version(prefix, p).unwrap_or_default()))
        .collect();
    generated.push_str(&format!(
        "pub const VERSIONS: [(&str, &str); {}] = [{}];\npub const PREFIX: &str = {:?};\n",
        PACKAGES.len(),
        versions.join(", "),
        prefix.display().to_string()
    ));
    generated
}
