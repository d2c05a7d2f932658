//! Run the heading sweep and print the tables (the `ima experiment heading` command does the
//! same with files and options): `cargo run --release -p ima-sim --example heading_sweep`.

use ima_sim::experiment::{SweepConfig, markdown_tables, run_sweep, summary};

fn main() {
    let cfg = SweepConfig::default();
    let t = std::time::Instant::now();
    let results = run_sweep(&cfg, &|_, _| {});
    println!("{}", markdown_tables(&results, "thesis"));
    println!("{}", markdown_tables(&results, "range-aware"));
    println!("{}", summary(&results));
    println!(
        "{} runs in {:.1} s",
        results.len(),
        t.elapsed().as_secs_f64()
    );
}
