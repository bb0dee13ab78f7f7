//! `cargo run -p penumbra-reference --example compare -- A.exr B.exr [--json] [--diff OUT.png]`
//! (what `penumbra compare` runs, without building the GPU renderer).

use clap::Parser;

#[derive(Parser)]
struct Cli {
    #[command(flatten)]
    args: penumbra_reference::cli::CompareArgs,
}

fn main() -> anyhow::Result<()> {
    penumbra_reference::cli::run_compare(&Cli::parse().args)
}
