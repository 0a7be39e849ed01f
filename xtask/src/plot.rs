//! Log-log line charts to PNG, drawn by hand (axes, decade ticks, labels in an 8×8 bitmap
//! font, a legend), so the bench needs no font files or plotting stack.

use std::path::Path;

use anyhow::{Context, Result};
use font8x8::legacy::BASIC_LEGACY;

/// One line: a label and its (x, y) points, x ascending.
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
}

const PALETTE: [[u8; 3]; 8] = [
    [214, 96, 42],
    [41, 110, 180],
    [60, 150, 70],
    [150, 70, 160],
    [200, 160, 30],
    [40, 160, 170],
    [120, 120, 120],
    [190, 60, 90],
];

struct Image {
    w: usize,
    h: usize,
    px: Vec<[u8; 3]>,
}

impl Image {
    fn new(w: usize, h: usize) -> Self {
        Image {
            w,
            h,
            px: vec![[255, 255, 255]; w * h],
        }
    }

    fn set(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < self.w && (y as usize) < self.h {
            self.px[y as usize * self.w + x as usize] = c;
        }
    }

    fn rect(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, c: [u8; 3]) {
        for y in y0..=y1 {
            for x in x0..=x1 {
                self.set(x, y, c);
            }
        }
    }

    /// A line `width` pixels thick.
    fn line(&mut self, a: (f64, f64), b: (f64, f64), width: i64, c: [u8; 3]) {
        let n = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as usize).max(1);
        for i in 0..=n {
            let t = i as f64 / n as f64;
            let (x, y) = (a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t);
            let r = width / 2;
            self.rect(
                x as i64 - r,
                y as i64 - r,
                x as i64 - r + width - 1,
                y as i64 - r + width - 1,
                c,
            );
        }
    }

    /// Text in the 8×8 font, `scale` pixels per font pixel; `anchor` 0 left, 1 centre, 2 right.
    fn text(&mut self, x: i64, y: i64, s: &str, scale: i64, anchor: u8, c: [u8; 3]) {
        let width = s.chars().count() as i64 * 8 * scale;
        let x0 = match anchor {
            1 => x - width / 2,
            2 => x - width,
            _ => x,
        };
        for (i, ch) in s.chars().enumerate() {
            let glyph = BASIC_LEGACY
                .get(ch as usize)
                .copied()
                .unwrap_or(BASIC_LEGACY[b'?' as usize]);
            for (row, bits) in glyph.iter().enumerate() {
                for col in 0..8 {
                    if bits & (1 << col) != 0 {
                        let px = x0 + (i as i64 * 8 + col) * scale;
                        let py = y + row as i64 * scale;
                        self.rect(px, py, px + scale - 1, py + scale - 1, c);
                    }
                }
            }
        }
    }

    fn save(&self, path: &Path) -> Result<()> {
        let file =
            std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
        let mut enc =
            png::Encoder::new(std::io::BufWriter::new(file), self.w as u32, self.h as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut writer = enc.write_header()?;
        let data: Vec<u8> = self.px.iter().flatten().copied().collect();
        writer.write_image_data(&data)?;
        Ok(())
    }
}

fn si(v: f64) -> String {
    if v >= 1e9 {
        format!("{}G", v / 1e9)
    } else if v >= 1e6 {
        format!("{}M", v / 1e6)
    } else if v >= 1e3 {
        format!("{}k", v / 1e3)
    } else {
        format!("{v}")
    }
}

/// Draws `series` on log-log axes with decade gridlines and a legend.
pub fn line_chart(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
) -> Result<()> {
    let (w, h) = (900usize, 600usize);
    let (left, right, top, bottom) = (90.0, 230.0, 50.0, 70.0);
    let mut img = Image::new(w, h);
    let pts = series
        .iter()
        .flat_map(|s| s.points.iter())
        .filter(|p| p.0 > 0.0 && p.1 > 0.0);
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in pts {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    if x0 > x1 {
        (x0, x1, y0, y1) = (1.0, 10.0, 1.0, 10.0);
    }
    let (lx0, mut lx1) = (x0.log10().floor(), x1.log10().ceil());
    let (ly0, mut ly1) = (y0.log10().floor(), y1.log10().ceil());
    if lx1 <= lx0 {
        lx1 = lx0 + 1.0;
    }
    if ly1 <= ly0 {
        ly1 = ly0 + 1.0;
    }
    let (pw, ph) = (w as f64 - left - right, h as f64 - top - bottom);
    let map = |x: f64, y: f64| {
        (
            left + (x.log10() - lx0) / (lx1 - lx0) * pw,
            top + ph - (y.log10() - ly0) / (ly1 - ly0) * ph,
        )
    };
    let grey = [225, 225, 225];
    let ink = [40, 40, 40];
    for d in (lx0 as i32)..=(lx1 as i32) {
        let (x, _) = map(10f64.powi(d), 10f64.powf(ly0));
        img.line((x, top), (x, top + ph), 1, grey);
        img.text(
            x as i64,
            (top + ph + 10.0) as i64,
            &si(10f64.powi(d)),
            1,
            1,
            ink,
        );
    }
    for d in (ly0 as i32)..=(ly1 as i32) {
        let (_, y) = map(10f64.powf(lx0), 10f64.powi(d));
        img.line((left, y), (left + pw, y), 1, grey);
        img.text(
            (left - 8.0) as i64,
            y as i64 - 4,
            &si(10f64.powi(d)),
            1,
            2,
            ink,
        );
    }
    img.line((left, top), (left, top + ph), 2, ink);
    img.line((left, top + ph), (left + pw, top + ph), 2, ink);
    let title_scale = if title.chars().count() * 16 + 20 > w {
        1
    } else {
        2
    };
    img.text((w / 2) as i64, 8, title, title_scale, 1, ink);
    img.text(
        (left + pw / 2.0) as i64,
        (h - 35) as i64,
        x_label,
        2,
        1,
        ink,
    );
    img.text(10, (top - 16.0) as i64, y_label, 1, 0, ink);
    for (i, s) in series.iter().enumerate() {
        let c = PALETTE[i % PALETTE.len()];
        let pts: Vec<(f64, f64)> = s
            .points
            .iter()
            .filter(|p| p.0 > 0.0 && p.1 > 0.0)
            .map(|p| map(p.0, p.1))
            .collect();
        for pair in pts.windows(2) {
            img.line(pair[0], pair[1], 3, c);
        }
        for p in &pts {
            img.rect(
                p.0 as i64 - 4,
                p.1 as i64 - 4,
                p.0 as i64 + 4,
                p.1 as i64 + 4,
                c,
            );
        }
        let ly = top as i64 + 10 + i as i64 * 22;
        let lx = (left + pw + 15.0) as i64;
        img.rect(lx, ly, lx + 18, ly + 8, c);
        img.text(lx + 26, ly, &s.label, 1, 0, ink);
    }
    img.save(path)
}
