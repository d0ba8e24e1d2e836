//! Legends drawn outside the data, and the geometry of a drawn figure.
//!
//! Every nlsim figure draws its legend once, in a band of its own between the title and the
//! panels, so that no legend can cover a curve or a marker whatever the data. The figure
//! records where it drew: the legend band and, per panel, the plotting area and the pixel
//! position of every plotted point ([`Layout`]). The SVG files carry that geometry (in a
//! `<metadata id="nlsim-layout">` element), so a test can check from the file alone that no
//! plotted point lies under a legend.

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// A rectangle in pixels of the whole figure: `x0..x1` across, `y0..y1` down.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Rect {
    /// Left edge (px).
    pub x0: i32,
    /// Top edge (px).
    pub y0: i32,
    /// Right edge (px).
    pub x1: i32,
    /// Bottom edge (px).
    pub y1: i32,
}

impl Rect {
    /// Whether the point `(x, y)` lies inside (edges included).
    pub fn contains(&self, (x, y): (i32, i32)) -> bool {
        (self.x0..=self.x1).contains(&x) && (self.y0..=self.y1).contains(&y)
    }

    /// Whether the two rectangles share any pixel.
    pub fn overlaps(&self, o: &Rect) -> bool {
        self.x0 <= o.x1 && o.x0 <= self.x1 && self.y0 <= o.y1 && o.y0 <= self.y1
    }

    /// The pixel rectangle of a drawing area.
    pub fn of<DB: DrawingBackend, CT: plotters::coord::CoordTranslate>(
        area: &DrawingArea<DB, CT>,
    ) -> Rect {
        let (x, y) = area.get_pixel_range();
        Rect {
            x0: x.start,
            y0: y.start,
            x1: x.end - 1,
            y1: y.end - 1,
        }
    }
}

/// Where one panel of a figure plots: its plotting area and the pixel of every finite plotted
/// point (curve vertices and marker centres, duplicates removed).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PanelLayout {
    /// The plotting area (inside the axes).
    pub area: Option<Rect>,
    /// Plotted points (px), sorted.
    pub points: Vec<(i32, i32)>,
}

/// Where a figure drew: its legends and its panels.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Layout {
    /// Width and height (px).
    pub size: (u32, u32),
    /// Every legend box drawn.
    pub legends: Vec<Rect>,
    /// Every panel, in drawing order.
    pub panels: Vec<PanelLayout>,
}

impl Layout {
    /// Records a panel: its plotting area and the pixels of `points` (in its coordinates;
    /// non-finite ones skipped).
    pub fn panel<'a, DB, CT>(
        &mut self,
        chart: &ChartContext<'a, DB, CT>,
        points: impl IntoIterator<Item = CT::From>,
    ) where
        DB: DrawingBackend + 'a,
        CT: plotters::coord::CoordTranslate,
    {
        let mut px: Vec<(i32, i32)> = points
            .into_iter()
            .map(|p| chart.plotting_area().map_coordinate(&p))
            .filter(|&(x, y)| x.abs() < 1 << 24 && y.abs() < 1 << 24)
            .collect();
        px.sort_unstable();
        px.dedup();
        self.panels.push(PanelLayout {
            area: Some(Rect::of(chart.plotting_area())),
            points: px,
        });
    }

    /// The plotted points that lie under a legend, with the legend they lie under.
    pub fn covered(&self) -> Vec<((i32, i32), Rect)> {
        let mut out = Vec::new();
        for l in &self.legends {
            for p in self.panels.iter().flat_map(|q| &q.points) {
                if l.contains(*p) {
                    out.push((*p, *l));
                }
            }
        }
        out
    }

    /// The geometry as text for an SVG `<metadata>` element: a `size W H` line, a
    /// `legend X0 Y0 X1 Y1` line per legend, and per panel a `panel X0 Y0 X1 Y1` line
    /// followed by a `points X,Y X,Y …` line.
    pub fn to_text(&self) -> String {
        let r = |r: &Rect| format!("{} {} {} {}", r.x0, r.y0, r.x1, r.y1);
        let mut s = format!("size {} {}\n", self.size.0, self.size.1);
        for l in &self.legends {
            s += &format!("legend {}\n", r(l));
        }
        for p in &self.panels {
            if let Some(a) = &p.area {
                s += &format!("panel {}\n", r(a));
            }
            let pts: Vec<String> = p.points.iter().map(|(x, y)| format!("{x},{y}")).collect();
            s += &format!("points {}\n", pts.join(" "));
        }
        s
    }
}

/// What a legend entry shows beside its label.
#[derive(Debug, Clone, Copy)]
pub enum Swatch {
    /// A line of a colour and width (px).
    Line(RGBColor, u32),
    /// A filled circle (a fold marker).
    Dot(RGBColor),
    /// A filled triangle (a jump marker).
    Triangle(RGBColor),
    /// A filled patch (a band).
    Patch(RGBColor),
}

/// One entry of a legend.
#[derive(Debug, Clone)]
pub struct Entry {
    /// The text.
    pub label: String,
    /// What is drawn beside it.
    pub swatch: Swatch,
}

impl Entry {
    /// An entry.
    pub fn new(label: impl Into<String>, swatch: Swatch) -> Entry {
        Entry {
            label: label.into(),
            swatch,
        }
    }
}

/// Height of one row of a legend band (px).
const ROW: i32 = 22;
/// Width of a swatch (px).
const SWATCH: i32 = 26;

/// Draws `entries` in a band at the top of `area`, centred, in as many rows as the width
/// needs, and returns the area below it for the panels (all of `area` when there is nothing
/// to show). The band is recorded in `layout`.
pub fn legend_band<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    entries: &[Entry],
    layout: &mut Layout,
) -> Result<DrawingArea<DB, Shift>, Box<dyn std::error::Error>>
where
    DB::ErrorType: 'static,
{
    let entries: Vec<&Entry> = entries.iter().filter(|e| !e.label.is_empty()).collect();
    if entries.is_empty() {
        return Ok(area.clone());
    }
    let font: TextStyle<'_> = ("sans-serif", crate::present::axis::TICK_FONT).into();
    let (w, _) = area.dim_in_pixel();
    let avail = w as i32 - 40;
    // Each entry's width: swatch, gap, text, gap to the next.
    let widths: Vec<i32> = entries
        .iter()
        .map(|e| {
            let tw = area
                .estimate_text_size(&e.label, &font)
                .map(|(x, _)| x as i32)
                .unwrap_or(8 * e.label.chars().count() as i32);
            SWATCH + 6 + tw + 22
        })
        .collect();
    let mut rows: Vec<Vec<usize>> = vec![Vec::new()];
    let mut used = 0;
    for (i, &wi) in widths.iter().enumerate() {
        if used + wi > avail && !rows.last().is_some_and(|r| r.is_empty()) {
            rows.push(Vec::new());
            used = 0;
        }
        rows.last_mut().expect("one row").push(i);
        used += wi;
    }
    let height = ROW * rows.len() as i32 + 10;
    let (band, rest) = area.split_vertically(height);
    let style = font
        .clone()
        .color(&BLACK)
        .pos(Pos::new(HPos::Left, VPos::Center));
    let mut x_min = i32::MAX;
    let mut x_max = i32::MIN;
    for (r, row) in rows.iter().enumerate() {
        let row_w: i32 = row.iter().map(|&i| widths[i]).sum::<i32>() - 22;
        let mut x = (w as i32 - row_w) / 2;
        let y = 5 + ROW * r as i32 + ROW / 2;
        x_min = x_min.min(x);
        x_max = x_max.max(x + row_w);
        for &i in row {
            match entries[i].swatch {
                Swatch::Line(c, width) => {
                    band.draw(&PathElement::new(
                        vec![(x, y), (x + SWATCH, y)],
                        c.stroke_width(width),
                    ))?;
                }
                Swatch::Dot(c) => {
                    band.draw(&Circle::new((x + SWATCH / 2, y), 5, c.filled()))?;
                }
                Swatch::Triangle(c) => {
                    band.draw(&TriangleMarker::new((x + SWATCH / 2, y), 6, c.filled()))?;
                }
                Swatch::Patch(c) => {
                    band.draw(&Rectangle::new(
                        [(x, y - 6), (x + SWATCH, y + 6)],
                        c.filled(),
                    ))?;
                }
            }
            band.draw(&Text::new(
                entries[i].label.clone(),
                (x + SWATCH + 6, y),
                style.clone(),
            ))?;
            x += widths[i];
        }
    }
    let (bx, by) = band.get_base_pixel();
    layout.legends.push(Rect {
        x0: bx + x_min,
        y0: by,
        x1: bx + x_max,
        y1: by + height - 1,
    });
    Ok(rest)
}

#[cfg(test)]
mod tests {
    use super::{Layout, PanelLayout, Rect};

    #[test]
    fn covered_points_are_found_and_the_text_round_trips_its_numbers() {
        let legend = Rect {
            x0: 10,
            y0: 0,
            x1: 100,
            y1: 20,
        };
        let l = Layout {
            size: (200, 100),
            legends: vec![legend],
            panels: vec![PanelLayout {
                area: Some(Rect {
                    x0: 0,
                    y0: 25,
                    x1: 199,
                    y1: 99,
                }),
                points: vec![(5, 5), (50, 10), (50, 30)],
            }],
        };
        assert_eq!(l.covered(), vec![((50, 10), legend)]);
        assert_eq!(
            l.to_text(),
            "size 200 100\nlegend 10 0 100 20\npanel 0 25 199 99\npoints 5,5 50,10 50,30\n"
        );
        assert!(legend.overlaps(&Rect {
            x0: 100,
            y0: 20,
            x1: 120,
            y1: 40
        }));
        assert!(!legend.overlaps(&Rect {
            x0: 101,
            y0: 0,
            x1: 120,
            y1: 40
        }));
    }
}
