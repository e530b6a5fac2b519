//! `volwarp-client`: the volwarp thin client (`--help` lists options and window controls).
#![forbid(unsafe_code)]

use clap::Parser;
use std::process::ExitCode;
use volwarp_client::Options;

fn main() -> ExitCode {
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("info")).init();
    let opts = Options::parse();
    match volwarp_client::run(&opts) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("volwarp-client: error: {e}");
            ExitCode::from(e.exit_code())
        }
    }
}
