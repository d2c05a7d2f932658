//! Trace one run of the heading experiment (debugging aid):
//! `cargo run --release -p ima-sim --example heading_debug -- thesis 135 3 3`.

use ima_agents::mission::scooter::HeadingRule;
use ima_sim::ScooterSim;
use ima_sim::experiment::{SweepConfig, TARGET_COLOUR, world_for};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let rule = if a.get(1).map(String::as_str) == Some("thesis") {
        HeadingRule::Thesis
    } else {
        HeadingRule::RangeAware
    };
    let num = |i: usize, d: f64| a.get(i).and_then(|s| s.parse().ok()).unwrap_or(d);
    let (angle, ds, dt) = (num(2, 135.0), num(3, 3.0), num(4, 3.0));
    let cfg = SweepConfig::default();
    let mut sim_cfg = cfg.sim.clone();
    sim_cfg.brain.heading_rule = rule;
    sim_cfg.brain.cruise_speed_m_s = cfg.speed_m_s;
    if a.get(5).map(String::as_str) == Some("camera") {
        sim_cfg.observer = ima_sim::Observer::Camera;
    }
    let mut sim = ScooterSim::new(world_for(angle, ds, dt, 1), TARGET_COLOUR, sim_cfg).unwrap();
    for k in 0..40_000 {
        let out = sim.step().clone();
        if k % 50 == 0
            || !out
                .messages
                .iter()
                .all(|m| matches!(m, ima_agents::mission::scooter::ScooterSay::Status { .. }))
        {
            let p = sim.trajectory().last().copied().unwrap_or_default();
            println!(
                "t {:7.1} pos ({:6.2},{:6.2}) dr ({:6.2},{:6.2}) h {:7.1} hd {:?} beh {:?} cmd ({:.2},{:.2}) plan {:?} msgs {:?}",
                sim.now().as_secs_f64(),
                p[0],
                p[1],
                sim.brain().dr_position().x,
                sim.brain().dr_position().y,
                sim.brain().heading().unwrap_or(0.0).to_degrees(),
                sim.brain().desired_heading().map(f64::to_degrees),
                out.behaviour,
                out.command.v_m_s,
                out.command.omega_rad_s,
                sim.brain().plan(),
                out.messages
            );
        }
        if sim.reached_at().is_some() {
            break;
        }
    }
}
