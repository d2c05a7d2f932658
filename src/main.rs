//! `ima`: the command-line program.

fn main() {
    eprintln!("ima: not implemented yet");
    std::process::exit(2);
}
