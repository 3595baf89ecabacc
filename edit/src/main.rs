//! `matedit`: material editing of photos with a trained network (Sec. 3.4 of the paper;
//! `matedit_edit::cli`).

fn main() -> std::process::ExitCode {
    matedit_edit::cli::main()
}
