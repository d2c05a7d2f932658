//! Mission reporting: trajectories from the world's ground truth, the performance index per
//! target, and an SVG of the world with both robots' paths (drawn with `ima-plot`).

use ima_mock_devices::world::World;
use serde::Serialize;

/// A robot's path: `(t_s, x_m, y_m)` samples of ground truth, world frame.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Trajectory {
    /// Robot name.
    pub robot: String,
    /// Samples.
    pub points: Vec<(f64, f64, f64)>,
}

impl Trajectory {
    /// An empty path of `robot`.
    pub fn new(robot: &str) -> Self {
        Self {
            robot: robot.to_owned(),
            points: Vec::new(),
        }
    }

    /// Add a sample unless it is within 1 cm of the last one.
    pub fn push(&mut self, t_s: f64, x: f64, y: f64) {
        if let Some(&(_, lx, ly)) = self.points.last()
            && (x - lx).hypot(y - ly) < 0.01
        {
            return;
        }
        self.points.push((t_s, x, y));
    }

    /// Path length between times `from_s` and `to_s`, metres.
    pub fn length_between(&self, from_s: f64, to_s: f64) -> f64 {
        let pts: Vec<_> = self
            .points
            .iter()
            .filter(|p| p.0 >= from_s && p.0 <= to_s)
            .collect();
        pts.windows(2)
            .map(|w| match w {
                [a, b] => (b.1 - a.1).hypot(b.2 - a.2),
                _ => 0.0,
            })
            // Not `sum()`: an empty f64 sum is −0.0, which the summary printed as "-0.00 m".
            .fold(0.0, |total, d| total + d)
    }

    /// Total path length, metres.
    pub fn length(&self) -> f64 {
        self.length_between(f64::NEG_INFINITY, f64::INFINITY)
    }
}

/// The thesis's performance index `f = (d_min/d_actual)·(t_min/t_actual)` with
/// `t_min = d_min / cruise`, clamped to `[0, 1]` (0 when nothing was driven or timed).
pub fn performance_index(d_min: f64, d_actual: f64, t_actual: f64, cruise_m_s: f64) -> f64 {
    if !(d_actual > 0.0 && t_actual > 0.0 && cruise_m_s > 0.0 && d_min >= 0.0) {
        return 0.0;
    }
    let t_min = d_min / cruise_m_s;
    ((d_min / d_actual) * (t_min / t_actual)).clamp(0.0, 1.0)
}

/// A path's length over its finite samples (a non-finite sample is skipped), metres.
fn finite_length(t: &Trajectory) -> f64 {
    let pts = ima_plot::finite(t.points.iter().map(|p| (p.1, p.2)));
    pts.windows(2)
        .map(|w| match w {
            [a, b] => (b.0 - a.0).hypot(b.1 - a.1),
            _ => 0.0,
        })
        .fold(0.0, |a, b| a + b)
}

/// An SVG of `world` (walls, obstacles, coloured objects, robots' final poses) with the
/// trajectories drawn over it in distinct colours, axes in metres, a scale bar and a legend
/// naming each robot's path (with its length), its start and its end; `title` on top.
pub fn svg(world: &World, trajectories: &[Trajectory], title: &str) -> String {
    use ima_plot::plotters::prelude::*;
    use ima_plot::plotters::style::text_anchor::{HPos, Pos, VPos};
    use ima_plot::{LegendRow, Mark};

    // Bounds: everything drawn.
    let mut pts: Vec<(f64, f64)> = Vec::new();
    for w in world.walls() {
        pts.extend([(w.from[0], w.from[1]), (w.to[0], w.to[1])]);
    }
    for o in world.objects() {
        pts.push((o.center[0], o.center[1]));
    }
    for c in world.circles() {
        pts.push((c.center[0], c.center[1]));
    }
    for r in world.robots() {
        pts.push((r.pose().x_m, r.pose().y_m));
    }
    for t in trajectories {
        pts.extend(t.points.iter().map(|p| (p.1, p.2)));
    }
    let frame = ima_plot::Frame::around(pts, 0.5)
        .unwrap_or_else(|| ima_plot::Frame::new(-5.0..5.0, -5.0..5.0));
    let px_per_m = (640.0 / frame.width().max(frame.height())).clamp(8.0, 80.0);
    let (cw, ch) = ima_plot::metric_chart_size(&frame, px_per_m);
    // A robot's colour: its path's, or grey for a robot without one.
    let colour_of = |name: &str| {
        trajectories
            .iter()
            .position(|t| t.robot == name)
            .map_or(ima_plot::MUTED, ima_plot::run_colour)
    };
    let mut rows = vec![LegendRow::Heading("Paths (ground truth)".into())];
    for (i, t) in trajectories.iter().enumerate() {
        rows.push(LegendRow::entry(
            Mark::Line,
            ima_plot::run_colour(i),
            format!("{}: {:.1} m", t.robot, finite_length(t)),
        ));
    }
    rows.extend([
        LegendRow::entry(Mark::Square, ima_plot::INK, "start (in the path's colour)"),
        LegendRow::entry(Mark::Ring, ima_plot::INK, "robot at the end, heading"),
        LegendRow::entry(Mark::Dot, RGBColor(220, 30, 30), "coloured post (name)"),
        LegendRow::entry(Mark::Swatch, RGBColor(150, 150, 150), "obstacle"),
        LegendRow::entry(Mark::Line, ima_plot::INK, "wall"),
        LegendRow::scale_bar(px_per_m),
    ]);
    let (lw, lh) = ima_plot::legend_size(&rows);
    ima_plot::render(cw + lw, ch.max(lh) + ima_plot::TITLE_H, |root| {
        let body = ima_plot::titled(root, title, None)?;
        let (plot, side) = body.split_horizontally(cw);
        let mut chart = ima_plot::metric_chart(&plot, &frame, "x (m)", "y (m)")?;
        for w in world.walls() {
            let line = [(w.from[0], w.from[1]), (w.to[0], w.to[1])];
            ima_plot::line(&mut chart, line, ima_plot::INK, 4, false)?;
        }
        for c in world.circles() {
            let grey = RGBColor(150, 150, 150).to_rgba();
            ima_plot::disc(
                &mut chart,
                (c.center[0], c.center[1]),
                c.radius_m,
                Some(grey),
                None,
            )?;
        }
        let small = ima_plot::text_style(11.0, ima_plot::INK);
        for o in world.objects() {
            let [r, g, b] = o.rgb;
            let at = (o.center[0], o.center[1]);
            let fill = RGBColor(r, g, b).to_rgba();
            let outline = ima_plot::INK.stroke_width(1);
            ima_plot::disc(
                &mut chart,
                at,
                o.radius_m.max(0.05),
                Some(fill),
                Some(outline),
            )?;
            let pos = Pos::new(HPos::Left, VPos::Bottom);
            ima_plot::label_backed(&mut chart, at, &o.color, (9, -7), &small, pos)?;
        }
        for (i, t) in trajectories.iter().enumerate() {
            let colour = ima_plot::run_colour(i);
            let line = t.points.iter().map(|p| (p.1, p.2));
            ima_plot::line(&mut chart, line, colour, 2, false)?;
            if let Some(&(_, x, y)) = t.points.first() {
                ima_plot::mark(&mut chart, (x, y), Mark::Square, colour)?;
            }
        }
        for r in world.robots() {
            let p = r.pose();
            let colour = colour_of(r.name());
            let at = (p.x_m, p.y_m);
            ima_plot::ring(&mut chart, at, r.radius_m(), colour, true)?;
            let (dx, dy) = (p.theta_rad.cos(), p.theta_rad.sin());
            let nose = (p.x_m + dx * r.radius_m(), p.y_m + dy * r.radius_m());
            ima_plot::line(&mut chart, [at, nose], colour, 2, false)?;
        }
        ima_plot::legend(&side, &rows)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn performance_index_is_one_for_the_ideal_run() {
        assert!((performance_index(3.0, 3.0, 10.0, 0.3) - 1.0).abs() < 1e-9);
        // Twice the distance at the same speed: d ratio ½, time ratio ½.
        assert!((performance_index(3.0, 6.0, 20.0, 0.3) - 0.25).abs() < 1e-9);
        assert_eq!(performance_index(3.0, 0.0, 10.0, 0.3), 0.0);
    }

    #[test]
    fn trajectory_length_and_svg() {
        let mut t = Trajectory::new("scooter");
        t.push(0.0, 0.0, 0.0);
        t.push(1.0, 0.001, 0.0); // too close: dropped
        t.push(2.0, 3.0, 4.0);
        t.push(3.0, 3.0, 5.0);
        assert_eq!(t.points.len(), 3);
        assert!((t.length() - 6.0).abs() < 1e-9);
        assert!((t.length_between(0.0, 2.5) - 5.0).abs() < 1e-9);
        // No sample in the window (the robot stood still): nothing driven, +0.
        let none = t.length_between(100.0, 101.0);
        assert!(none == 0.0 && none.is_sign_positive(), "{none}");
        let mut u = Trajectory::new("skeeter");
        u.push(0.0, 1.0, 1.0);
        u.push(1.0, f64::NAN, 1.0);
        u.push(2.0, 1.0, 2.0);
        let s = svg(&World::default_world(), &[t, u], "a <title>");
        let pic = ima_plot::inspect(&s).unwrap();
        for text in [
            "a <title>",
            "x (m)",
            "y (m)",
            "scooter: 6.0 m",
            "scale 1 m",
            "red",
            "wall",
            "start (in the path's colour)",
        ] {
            assert!(pic.has_text(text), "{text} missing: {:?}", pic.texts);
        }
        // The two paths (a NaN sample dropped, not drawn), in two colours.
        assert!(pic.has_text("skeeter: 1.0 m"), "{:?}", pic.texts);
        assert!(s.contains(r##"stroke="#0072B2""##) && s.contains(r##"stroke="#D55E00""##));
        // The red post in its own colour.
        assert!(s.contains(r##"fill="#DC1E1E""##), "{s}");
    }
}
