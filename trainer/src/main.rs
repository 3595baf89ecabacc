//! `trainer`: trains the material-editing network of Fig. 2 from manifests, evaluates it like
//! Sec. 4 of the paper, and measures the rendering layer (`matedit_trainer::cli`).

use matedit_trainer::alloc::PeakAlloc;
use std::process::ExitCode;

/// Counts heap bytes so that `trainer bench` can report peak memory.
#[global_allocator]
static ALLOC: PeakAlloc = PeakAlloc::new();

fn main() -> ExitCode {
    matedit_trainer::cli::main(Some(&ALLOC))
}
