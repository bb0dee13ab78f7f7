//! Debian ships shaderc's `libshaderc_combined.a` without glslang and SPIRV-Tools inside it, so the
//! static link needs those archives too. Directives printed here reach every binary (and build
//! script) that depends on this crate.
use std::path::Path;

fn main() {
    let candidates = [
        std::env::var("SHADERC_LIB_DIR").unwrap_or_default(),
        "/usr/lib/x86_64-linux-gnu".to_string(),
        "/usr/lib/aarch64-linux-gnu".to_string(),
        "/usr/lib64".to_string(),
        "/usr/lib".to_string(),
    ];
    let dir = candidates.iter().filter(|d| !d.is_empty()).find(|d| Path::new(d).join("libglslang.a").exists());
    let Some(dir) = dir else {
        println!(
            "cargo:warning=libglslang.a not found: install Debian's libshaderc-dev glslang-dev spirv-tools \
             (see README) or set SHADERC_LIB_DIR"
        );
        return;
    };
    println!("cargo:rustc-link-search=native={dir}");
    for lib in [
        "glslang",
        "MachineIndependent",
        "OSDependent",
        "GenericCodeGen",
        "OGLCompiler",
        "SPIRV",
        "SPIRV-Tools-opt",
        "SPIRV-Tools",
        "glslang-default-resource-limits",
        "HLSL",
    ] {
        if Path::new(dir).join(format!("lib{lib}.a")).exists() {
            println!("cargo:rustc-link-lib=static={lib}");
        }
    }
    println!("cargo:rustc-link-lib=dylib=stdc++");
    println!("cargo:rerun-if-env-changed=SHADERC_LIB_DIR");
}
