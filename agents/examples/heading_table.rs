//! Print the thesis's 48 start configurations with each heading rule's initial error.
//!
//! `cargo run -p ima-agents --example heading_table [RANGE_NOISE_M]` (default 0.05 m, the
//! SICK LMS's ±50 mm).

use ima_agents::heading::sweep_48;

fn main() {
    let noise = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(0.05);
    let rows = sweep_48(noise);
    println!(
        "angle_deg,ds_m,dt_m,true_heading_deg,thesis_err_deg,range_exact_err_deg,range_noisy_err_deg"
    );
    for r in &rows {
        println!(
            "{},{},{},{:.2},{:.2},{:.2},{:.2}",
            r.angle_deg,
            r.ds_m,
            r.dt_m,
            r.true_heading_deg,
            r.thesis_error_deg,
            r.range_exact_error_deg,
            r.range_noisy_error_deg
        );
    }
    println!();
    println!(
        "summary (range noise ±{noise} m): angle | thesis max/mean | exact max/mean | noisy max/mean"
    );
    for a in [45.0, 90.0, 135.0] {
        let sel: Vec<_> = rows.iter().filter(|r| r.angle_deg == a).collect();
        let stat = |f: &dyn Fn(&&ima_agents::heading::SweepRow) -> f64| {
            let v: Vec<f64> = sel.iter().map(f).collect();
            (
                v.iter().copied().fold(0.0, f64::max),
                v.iter().sum::<f64>() / v.len() as f64,
            )
        };
        let t = stat(&|r| r.thesis_error_deg);
        let e = stat(&|r| r.range_exact_error_deg);
        let n = stat(&|r| r.range_noisy_error_deg);
        println!(
            "{a:>5} | {:6.2} / {:6.2} | {:5.2} / {:5.2} | {:5.2} / {:5.2}",
            t.0, t.1, e.0, e.1, n.0, n.1
        );
    }
}
