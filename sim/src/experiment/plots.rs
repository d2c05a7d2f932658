//! The heading experiment's figures (`f.svg`, `trajectories-{θ}.svg`), drawn with
//! `ima-plot`.

use ima_plot::plotters::prelude::*;
use ima_plot::plotters::style::text_anchor::{HPos, Pos, VPos};
use ima_plot::{Frame, LegendRow, Mark};

use super::{ANGLES_DEG, DISTANCES_M, RunResult, TARGET_RADIUS_M, find};

/// The rules in plotting order, those present in `results` only.
fn rules_in(results: &[RunResult]) -> Vec<&'static str> {
    ["thesis", "range-aware"]
        .into_iter()
        .filter(|r| results.iter().any(|x| x.rule == *r))
        .collect()
}

/// Red (0) → yellow (0.5) → green (1).
fn colour_for(f: f64) -> RGBColor {
    let f = if f.is_finite() {
        f.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let (r, g) = if f < 0.5 {
        (220.0, 40.0 + 360.0 * f)
    } else {
        (220.0 - 380.0 * (f - 0.5), 220.0)
    };
    RGBColor(r.clamp(0.0, 255.0) as u8, g.clamp(0.0, 220.0) as u8, 60)
}

/// `f` with two decimals, `—` when it is not a number.
fn fmt_f(f: f64) -> String {
    if f.is_finite() {
        format!("{f:.2}")
    } else {
        "—".to_owned()
    }
}

/// Pixels per metre of the `f` grids (a cell is 1 m of Ds by 1 m of Dt).
const CELL_PX: f64 = 44.0;
/// Width of the colour bar beside the `f` grids, pixels.
const COLOUR_BAR_W: u32 = 80;

/// An SVG of `f` per configuration: one 4×4 grid per rule (rows of panels) and angle
/// (columns), Skeeter–Scooter distance Ds across and Skeeter–target distance Dt up, cells
/// coloured red (0) → green (1) with the value written in (`*`: not reached), a colour bar.
#[must_use]
pub fn svg_f(results: &[RunResult]) -> String {
    let mut rules = rules_in(results);
    if rules.is_empty() {
        rules.push("thesis");
    }
    let frame = Frame::new(1.5..5.5, 1.5..5.5);
    let (pw, ph) = ima_plot::metric_chart_size(&frame, CELL_PX);
    let ph = ph + ima_plot::CAPTION_H;
    let cols = ANGLES_DEG.len() as u32;
    let rows = rules.len() as u32;
    let width = pw * cols + COLOUR_BAR_W;
    let height = ima_plot::TITLE_SUB_H + ph * rows;
    ima_plot::render(width, height, |root| {
        let body = ima_plot::titled(
            root,
            "Heading experiment: performance index f per configuration",
            Some(
                "Ds: Skeeter–Scooter distance, Dt: Skeeter–target distance, θ: angle \
                 Scooter–Skeeter–target; * not reached (f = 0)",
            ),
        )?;
        let (grids, bar) = body.split_horizontally(pw * cols);
        for (ri, rule) in rules.iter().enumerate() {
            for (ai, angle) in ANGLES_DEG.iter().enumerate() {
                let x = pw * ai as u32;
                let y = ph * ri as u32;
                let panel = grids.clone().shrink((x, y), (pw, ph));
                let panel = ima_plot::captioned(&panel, &format!("{rule} rule, θ = {angle:.0}°"))?;
                let mut chart = ima_plot::metric_chart(&panel, &frame, "Ds (m)", "Dt (m)")?;
                for dt in DISTANCES_M {
                    for ds in DISTANCES_M {
                        let run = find(results, rule, *angle, ds, dt);
                        let fill = run.map_or(RGBColor(221, 221, 221), |r| colour_for(r.f));
                        let corners = [(ds - 0.5, dt - 0.5), (ds + 0.5, dt + 0.5)];
                        let area = chart.plotting_area();
                        area.draw(&Rectangle::new(corners, fill.filled()))?;
                        area.draw(&Rectangle::new(corners, WHITE.stroke_width(1)))?;
                        let text = match run {
                            Some(r) if r.reason == "reached" => fmt_f(r.f),
                            Some(r) => format!("{}*", fmt_f(r.f)),
                            None => "—".to_owned(),
                        };
                        ima_plot::label(
                            &mut chart,
                            (ds, dt),
                            &text,
                            (0, 0),
                            &ima_plot::text_style(12.0, ima_plot::INK),
                            Pos::new(HPos::Center, VPos::Center),
                        )?;
                    }
                }
            }
        }
        ima_plot::colour_bar(&bar, "f", (0.0, 1.0), 20, colour_for)
    })
}

/// The colour of a corner configuration of the trajectory plots.
fn config_colour(ds: f64, dt: f64) -> RGBColor {
    ima_plot::run_colour(usize::from(ds > 3.5) * 2 + usize::from(dt > 3.5))
}

/// Whether a run is one of the four corner configurations (`Ds, Dt ∈ {2, 5}`) at `angle_deg`.
fn is_plotted(r: &RunResult, angle_deg: f64) -> bool {
    r.angle_deg == angle_deg && (r.ds_m == 2.0 || r.ds_m == 5.0) && (r.dt_m == 2.0 || r.dt_m == 5.0)
}

/// An SVG of trajectories for one angle: one panel per rule present, Skeeter at the origin,
/// the runs of that angle with `Ds, Dt ∈ {2, 5}` (four configurations), each configuration
/// in its own colour in both panels; starts as squares labelled Ds, targets as red discs
/// labelled Dt, ends as crosses; a legend with every run's f.
#[must_use]
pub fn svg_trajectories(results: &[RunResult], angle_deg: f64) -> String {
    let runs: Vec<&RunResult> = results
        .iter()
        .filter(|r| is_plotted(r, angle_deg))
        .collect();
    let mut rules: Vec<&str> = ["thesis", "range-aware"]
        .into_iter()
        .filter(|rule| runs.iter().any(|r| r.rule == *rule))
        .collect();
    if rules.is_empty() {
        rules.push("thesis");
    }
    let mut pts: Vec<(f64, f64)> = vec![(-0.4, -0.4), (0.4, 0.4)];
    for r in &runs {
        pts.extend(r.trajectory.iter().map(|p| (p[0], p[1])));
        pts.push((r.start[0], r.start[1]));
        pts.push((r.target[0], r.target[1]));
    }
    let frame = Frame::around(pts, 0.6).unwrap_or_else(|| Frame::new(-6.0..6.0, -2.0..6.0));
    let px_per_m = (460.0 / frame.width().max(frame.height())).clamp(10.0, 60.0);
    let (pw, ph) = ima_plot::metric_chart_size(&frame, px_per_m);
    let ph = ph + ima_plot::CAPTION_H;
    let skeeter = RGBColor(85, 85, 85);
    let target = RGBColor(220, 34, 34);
    let mut legend = vec![LegendRow::Heading("Runs (one colour per Ds, Dt)".into())];
    for rule in &rules {
        legend.push(LegendRow::Heading(format!("{rule} rule")));
        let mut of_rule: Vec<&&RunResult> = runs.iter().filter(|r| r.rule == *rule).collect();
        of_rule.sort_by(|a, b| {
            (a.ds_m, a.dt_m)
                .partial_cmp(&(b.ds_m, b.dt_m))
                .unwrap_or(core::cmp::Ordering::Equal)
        });
        for r in of_rule {
            let end = if r.reason == "reached" {
                String::new()
            } else {
                format!(", {}", r.reason)
            };
            legend.push(LegendRow::entry(
                Mark::Line,
                config_colour(r.ds_m, r.dt_m),
                format!(
                    "Ds {:.0} m, Dt {:.0} m: f {}{end}",
                    r.ds_m,
                    r.dt_m,
                    fmt_f(r.f)
                ),
            ));
        }
    }
    if runs.is_empty() {
        legend.push(LegendRow::Note(format!("no run at θ = {angle_deg:.0}°")));
    }
    legend.extend([
        LegendRow::Heading("Marks".into()),
        LegendRow::entry(Mark::Square, ima_plot::INK, "Scooter's start (Ds)"),
        LegendRow::entry(Mark::Dot, target, "target (Dt)"),
        LegendRow::entry(Mark::Cross, ima_plot::INK, "end of the run (its colour)"),
        LegendRow::entry(Mark::Dot, skeeter, "Skeeter"),
        LegendRow::entry(
            Mark::Dashed,
            RGBColor(170, 170, 170),
            "distance Dt from Skeeter",
        ),
        LegendRow::scale_bar(px_per_m),
    ]);
    let (lw, lh) = ima_plot::legend_size(&legend);
    let panels = rules.len() as u32;
    let width = pw * panels + lw;
    let height = ima_plot::TITLE_SUB_H + ph.max(lh);
    ima_plot::render(width, height, |root| {
        let body = ima_plot::titled(
            root,
            &format!("Heading experiment, θ = {angle_deg:.0}°: Scooter's paths"),
            Some("Ds: Skeeter–Scooter distance, Dt: Skeeter–target distance, both 2 or 5 m"),
        )?;
        let (plots, side) = body.split_horizontally(pw * panels);
        let small = ima_plot::text_style(11.0, ima_plot::INK);
        for (i, rule) in rules.iter().enumerate() {
            let panel = plots.clone().shrink((pw * i as u32, 0), (pw, ph));
            let panel = ima_plot::captioned(&panel, &format!("{rule} rule"))?;
            let mut chart = ima_plot::metric_chart(&panel, &frame, "x (m)", "y (m)")?;
            for d in [2.0, 5.0] {
                ima_plot::ring(&mut chart, (0.0, 0.0), d, RGBColor(170, 170, 170), true)?;
            }
            ima_plot::disc(&mut chart, (0.0, 0.0), 0.33, Some(skeeter.to_rgba()), None)?;
            let below = Pos::new(HPos::Center, VPos::Top);
            ima_plot::label(&mut chart, (0.0, -0.33), "Skeeter", (0, 3), &small, below)?;
            // Starts and targets of the angle's four configurations, labelled once, over
            // the paths.
            let mut starts: Vec<(f64, [f64; 2])> = Vec::new();
            let mut targets: Vec<(f64, [f64; 2])> = Vec::new();
            for r in &runs {
                if !starts.iter().any(|s| s.0 == r.ds_m) {
                    starts.push((r.ds_m, r.start));
                }
                if !targets.iter().any(|t| t.0 == r.dt_m) {
                    targets.push((r.dt_m, r.target));
                }
            }
            for r in runs.iter().filter(|r| r.rule == *rule) {
                let colour = config_colour(r.ds_m, r.dt_m);
                let path = r.trajectory.iter().map(|p| (p[0], p[1]));
                ima_plot::line(&mut chart, path, colour, 2, false)?;
            }
            for (dt, t) in &targets {
                let at = (t[0], t[1]);
                ima_plot::disc(
                    &mut chart,
                    at,
                    TARGET_RADIUS_M,
                    Some(target.to_rgba()),
                    None,
                )?;
                let right = Pos::new(HPos::Left, VPos::Center);
                let text = format!("Dt {dt:.0}");
                ima_plot::label_backed(&mut chart, at, &text, (10, 0), &small, right)?;
            }
            for r in runs.iter().filter(|r| r.rule == *rule) {
                if let Some(end) = r.trajectory.last() {
                    let colour = config_colour(r.ds_m, r.dt_m);
                    ima_plot::mark(&mut chart, (end[0], end[1]), Mark::Cross, colour)?;
                }
            }
            for (ds, s) in &starts {
                let at = (s[0], s[1]);
                ima_plot::mark(&mut chart, at, Mark::Square, ima_plot::INK)?;
                let text = format!("Ds {ds:.0}");
                ima_plot::label_backed(&mut chart, at, &text, (0, 8), &small, below)?;
            }
        }
        ima_plot::legend(&side, &legend)
    })
}
