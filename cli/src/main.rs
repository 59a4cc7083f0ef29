//! `coadapt`: parses the command line and hands over to the library.

use clap::Parser;

fn main() -> std::process::ExitCode {
    let cli = coadapt_cli::Cli::parse();
    match coadapt_cli::run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            coadapt_log::logln!("error: {e:#}");
            // A full disk or a bad config: a supervisor must not start us again (exit.rs).
            std::process::ExitCode::from(coadapt_cli::exit::code_of(&e))
        }
    }
}
