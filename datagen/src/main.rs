//! `datagen`: the synthetic-dataset factory's command line (`matedit_datagen::cli`).

fn main() -> std::process::ExitCode {
    matedit_datagen::cli::main()
}
