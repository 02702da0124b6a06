use std::process::ExitCode;

fn main() -> ExitCode {
    toporec::cli::main()
}
