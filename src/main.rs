//! The `step` binary: parses the command line and hands over to [`step::cli`].

fn main() -> std::process::ExitCode {
    step::cli::main()
}
