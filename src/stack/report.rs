//! Mission reporting: trajectories from the world's ground truth, the performance index per
//! target, and a hand-written SVG of the world with both robots' paths.

use std::fmt::Write as _;

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
            .sum()
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

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// An SVG of `world` (walls, obstacles, coloured objects, robots' start poses) with the
/// trajectories drawn over it; `title` goes in the top-left corner.
pub fn svg(world: &World, trajectories: &[Trajectory], title: &str) -> String {
    // Bounds: everything drawn.
    let mut xs: Vec<f64> = Vec::new();
    let mut ys: Vec<f64> = Vec::new();
    for w in world.walls() {
        xs.extend([w.from[0], w.to[0]]);
        ys.extend([w.from[1], w.to[1]]);
    }
    for o in world.objects() {
        xs.push(o.center[0]);
        ys.push(o.center[1]);
    }
    for t in trajectories {
        for p in &t.points {
            xs.push(p.1);
            ys.push(p.2);
        }
    }
    let min = |v: &[f64]| v.iter().copied().fold(f64::INFINITY, f64::min);
    let max = |v: &[f64]| v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let (mut x0, mut x1, mut y0, mut y1) = (min(&xs), max(&xs), min(&ys), max(&ys));
    if !(x0.is_finite() && x1.is_finite() && y0.is_finite() && y1.is_finite()) {
        (x0, x1, y0, y1) = (-5.0, 5.0, -5.0, 5.0);
    }
    let margin = 0.5;
    let (x0, x1, y0, y1) = (x0 - margin, x1 + margin, y0 - margin, y1 + margin);
    let scale = 60.0; // pixels per metre
    let (w, h) = ((x1 - x0) * scale, (y1 - y0) * scale);
    // World y up, SVG y down.
    let px = |x: f64| (x - x0) * scale;
    let py = |y: f64| (y1 - y) * scale;
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w:.0}" height="{h:.0}" viewBox="0 0 {w:.0} {h:.0}">"#
    );
    let _ = writeln!(
        s,
        r##"<rect x="0" y="0" width="{w:.0}" height="{h:.0}" fill="#fafafa"/>"##
    );
    // 1 m grid.
    let mut gx = x0.ceil();
    while gx <= x1 {
        let _ = writeln!(
            s,
            r##"<line x1="{0:.1}" y1="0" x2="{0:.1}" y2="{h:.0}" stroke="#e4e4e4" stroke-width="1"/>"##,
            px(gx)
        );
        gx += 1.0;
    }
    let mut gy = y0.ceil();
    while gy <= y1 {
        let _ = writeln!(
            s,
            r##"<line x1="0" y1="{0:.1}" x2="{w:.0}" y2="{0:.1}" stroke="#e4e4e4" stroke-width="1"/>"##,
            py(gy)
        );
        gy += 1.0;
    }
    for wl in world.walls() {
        let _ = writeln!(
            s,
            r##"<line x1="{:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="#333" stroke-width="4"/>"##,
            px(wl.from[0]),
            py(wl.from[1]),
            px(wl.to[0]),
            py(wl.to[1])
        );
    }
    for c in world.circles() {
        let _ = writeln!(
            s,
            r##"<circle cx="{:.1}" cy="{:.1}" r="{:.1}" fill="#999"/>"##,
            px(c.center[0]),
            py(c.center[1]),
            c.radius_m * scale
        );
    }
    for o in world.objects() {
        let [r, g, b] = o.rgb;
        let _ = writeln!(
            s,
            r##"<circle cx="{:.1}" cy="{:.1}" r="{:.1}" fill="rgb({r},{g},{b})" stroke="#222"/><text x="{:.1}" y="{:.1}" font-family="sans-serif" font-size="12">{}</text>"##,
            px(o.center[0]),
            py(o.center[1]),
            (o.radius_m * scale).max(3.0),
            px(o.center[0]) + 10.0,
            py(o.center[1]) - 10.0,
            esc(&o.color)
        );
    }
    let palette = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd"];
    for (i, t) in trajectories.iter().enumerate() {
        let colour = palette.get(i % palette.len()).copied().unwrap_or("#000");
        if t.points.len() >= 2 {
            let pts: Vec<String> = t
                .points
                .iter()
                .map(|p| format!("{:.1},{:.1}", px(p.1), py(p.2)))
                .collect();
            let _ = writeln!(
                s,
                r#"<polyline points="{}" fill="none" stroke="{colour}" stroke-width="2"/>"#,
                pts.join(" ")
            );
        }
        if let Some(&(_, x, y)) = t.points.first() {
            let _ = writeln!(
                s,
                r#"<circle cx="{:.1}" cy="{:.1}" r="5" fill="{colour}"/><text x="{:.1}" y="{:.1}" font-family="sans-serif" font-size="13" fill="{colour}">{}</text>"#,
                px(x),
                py(y),
                px(x) + 8.0,
                py(y) + 16.0,
                esc(&t.robot)
            );
        }
    }
    for r in world.robots() {
        let p = r.pose();
        let (dx, dy) = (p.theta_rad.cos(), p.theta_rad.sin());
        let _ = writeln!(
            s,
            r##"<circle cx="{:.1}" cy="{:.1}" r="{:.1}" fill="none" stroke="#555" stroke-dasharray="4 3"/><line x1="{:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="#555"/>"##,
            px(p.x_m),
            py(p.y_m),
            r.radius_m() * scale,
            px(p.x_m),
            py(p.y_m),
            px(p.x_m + dx * r.radius_m()),
            py(p.y_m + dy * r.radius_m())
        );
    }
    let _ = writeln!(
        s,
        r#"<text x="10" y="20" font-family="sans-serif" font-size="14">{}</text>"#,
        esc(title)
    );
    s.push_str("</svg>\n");
    s
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
        let s = svg(&World::default_world(), &[t], "a <title>");
        assert!(s.starts_with("<svg"));
        assert!(s.contains("<polyline"));
        assert!(s.contains("a &lt;title&gt;"));
        assert!(s.contains("rgb(220,30,30)"));
        assert!(s.trim_end().ends_with("</svg>"));
    }
}
