//! Grouped bar charts in one SVG file (drawn with plotters), for the benchmarks' figures:
//! one panel per unit, one group of bars per configuration.

use std::path::Path;

use plotters::prelude::*;

pub struct Bars {
    unit: String,
    series: Vec<String>,
    groups: Vec<(String, Vec<f64>)>,
}

impl Bars {
    pub fn new(unit: &str, series: &[&str]) -> Bars {
        Bars {
            unit: unit.to_string(),
            series: series.iter().map(|s| s.to_string()).collect(),
            groups: Vec::new(),
        }
    }

    /// One configuration's values, in series order (0 draws no bar).
    pub fn group(&mut self, label: &str, values: &[f64]) {
        self.groups.push((label.to_string(), values.to_vec()));
    }
}

pub fn draw(path: &Path, title: &str, panels: &[Bars]) -> Result<(), String> {
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let height = 420 * panels.len().max(1) as u32 + 40;
    let root = SVGBackend::new(path, (1500, height)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let root = root.titled(title, ("sans-serif", 22)).map_err(|x| e(&x))?;
    for (area, bars) in root
        .split_evenly((panels.len().max(1), 1))
        .iter()
        .zip(panels)
    {
        let n = bars.groups.len().max(1);
        let top = bars
            .groups
            .iter()
            .flat_map(|g| g.1.iter().copied())
            .fold(1.0f64, f64::max)
            * 1.15;
        let mut chart = ChartBuilder::on(area)
            .margin(14)
            .x_label_area_size(36)
            .y_label_area_size(64)
            // Group i is centred on x = i, so the axis' whole-number ticks fall on the groups.
            .build_cartesian_2d(-0.5f64..n as f64 - 0.5, 0f64..top)
            .map_err(|x| e(&x))?;
        let label = |x: &f64| match ((x.round() - x).abs() < 1e-6, x.round()) {
            (true, i) if i >= 0.0 => bars
                .groups
                .get(i as usize)
                .map(|g| g.0.clone())
                .unwrap_or_default(),
            _ => String::new(),
        };
        chart
            .configure_mesh()
            .disable_x_mesh()
            .y_desc(bars.unit.as_str())
            .x_labels(n + 1)
            .x_label_formatter(&label)
            .x_label_style(("sans-serif", 11))
            .draw()
            .map_err(|x| e(&x))?;
        let width = 0.8 / bars.series.len().max(1) as f64;
        for (s, name) in bars.series.iter().enumerate() {
            let color = Palette99::pick(s).to_rgba();
            let rects = bars
                .groups
                .iter()
                .enumerate()
                .filter(|(_, g)| g.1.get(s).copied().unwrap_or(0.0) > 0.0)
                .map(move |(i, g)| {
                    let x0 = i as f64 - 0.4 + s as f64 * width;
                    Rectangle::new([(x0, 0.0), (x0 + width, g.1[s])], color.filled())
                });
            chart
                .draw_series(rects)
                .map_err(|x| e(&x))?
                .label(name.as_str())
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 10, y + 5)], color.filled())
                });
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .border_style(BLACK)
            .background_style(WHITE.mix(0.85))
            .draw()
            .map_err(|x| e(&x))?;
    }
    root.present().map_err(|x| e(&x))
}
