//! A small software renderer for pictures people look at: a shaded mesh (optionally cut
//! away on the camera's side), particles and their trails as depth-tested splats, and a
//! legend in an 8×8 bitmap font, to PNG.

use std::path::Path;

use anyhow::{Context, Result};
use font8x8::legacy::BASIC_LEGACY;
use glam::{Mat3, Vec3};

/// An orthographic camera looking at `center` from yaw/pitch angles (radians).
pub struct Camera {
    rot: Mat3,
    center: Vec3,
    scale: f32,
    width: usize,
    height: usize,
}

impl Camera {
    /// Frames a sphere of `radius` around `center` in a `width × height` image.
    pub fn new(
        center: Vec3,
        radius: f32,
        yaw: f32,
        pitch: f32,
        width: usize,
        height: usize,
    ) -> Self {
        let rot = Mat3::from_rotation_x(pitch) * Mat3::from_rotation_y(yaw);
        let scale = 0.5 * width.min(height) as f32 / radius.max(1e-12);
        Camera {
            rot,
            center,
            scale,
            width,
            height,
        }
    }

    /// Pixel x, pixel y, depth (larger is nearer the camera).
    pub fn project(&self, p: Vec3) -> Vec3 {
        let q = self.rot * (p - self.center);
        Vec3::new(
            self.width as f32 * 0.5 + q.x * self.scale,
            self.height as f32 * 0.5 - q.y * self.scale,
            q.z,
        )
    }
}

/// An RGB image with a depth buffer.
pub struct Canvas {
    pub width: usize,
    pub height: usize,
    rgb: Vec<[f32; 3]>,
    depth: Vec<f32>,
}

impl Canvas {
    /// A canvas filled with a vertical gradient.
    pub fn new(width: usize, height: usize) -> Self {
        let mut rgb = Vec::with_capacity(width * height);
        for y in 0..height {
            let t = y as f32 / height as f32;
            let c = 0.97 - 0.12 * t;
            rgb.extend(std::iter::repeat_n([c, c, c + 0.02], width));
        }
        Canvas {
            width,
            height,
            rgb,
            depth: vec![f32::NEG_INFINITY; width * height],
        }
    }

    /// Draws a triangle with flat two-sided Lambert shading.
    pub fn triangle(&mut self, cam: &Camera, v: [Vec3; 3], base: [f32; 3]) {
        let n = (v[1] - v[0]).cross(v[2] - v[0]).normalize_or_zero();
        let light = Vec3::new(-0.4, 0.8, 0.45).normalize();
        let shade = 0.35 + 0.65 * n.dot(light).abs();
        let color = base.map(|c| c * shade);
        let p = v.map(|x| cam.project(x));
        let min_x = p
            .iter()
            .map(|q| q.x)
            .fold(f32::INFINITY, f32::min)
            .floor()
            .max(0.0) as usize;
        let max_x = p
            .iter()
            .map(|q| q.x)
            .fold(f32::NEG_INFINITY, f32::max)
            .ceil()
            .min(self.width as f32 - 1.0);
        let min_y = p
            .iter()
            .map(|q| q.y)
            .fold(f32::INFINITY, f32::min)
            .floor()
            .max(0.0) as usize;
        let max_y = p
            .iter()
            .map(|q| q.y)
            .fold(f32::NEG_INFINITY, f32::max)
            .ceil()
            .min(self.height as f32 - 1.0);
        if !(max_x >= 0.0 && max_y >= 0.0) {
            return;
        }
        let area = (p[1].x - p[0].x) * (p[2].y - p[0].y) - (p[2].x - p[0].x) * (p[1].y - p[0].y);
        if area.abs() < 1e-12 {
            return;
        }
        for y in min_y..=max_y as usize {
            for x in min_x..=max_x as usize {
                let (fx, fy) = (x as f32 + 0.5, y as f32 + 0.5);
                let w0 = ((p[1].x - fx) * (p[2].y - fy) - (p[2].x - fx) * (p[1].y - fy)) / area;
                let w1 = ((p[2].x - fx) * (p[0].y - fy) - (p[0].x - fx) * (p[2].y - fy)) / area;
                let w2 = 1.0 - w0 - w1;
                if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                    continue;
                }
                let z = w0 * p[0].z + w1 * p[1].z + w2 * p[2].z;
                let i = y * self.width + x;
                if z > self.depth[i] {
                    self.depth[i] = z;
                    self.rgb[i] = color;
                }
            }
        }
    }

    /// Draws a round, depth-tested splat blended with `alpha`.
    pub fn splat(&mut self, cam: &Camera, p: Vec3, radius: f32, color: [f32; 3], alpha: f32) {
        let q = cam.project(p);
        if !q.is_finite() {
            return;
        }
        let r = radius.max(0.5);
        let (x0, x1) = (
            (q.x - r).floor().max(0.0),
            (q.x + r).ceil().min(self.width as f32 - 1.0),
        );
        let (y0, y1) = (
            (q.y - r).floor().max(0.0),
            (q.y + r).ceil().min(self.height as f32 - 1.0),
        );
        if x1 < x0 || y1 < y0 {
            return;
        }
        for y in y0 as usize..=y1 as usize {
            for x in x0 as usize..=x1 as usize {
                let (dx, dy) = (x as f32 + 0.5 - q.x, y as f32 + 0.5 - q.y);
                if dx * dx + dy * dy > r * r {
                    continue;
                }
                let i = y * self.width + x;
                // A small bias lets particles resting on the surface show.
                if q.z + 1e-3 * r >= self.depth[i] - 1e-4 {
                    let c = &mut self.rgb[i];
                    for k in 0..3 {
                        c[k] = c[k] * (1.0 - alpha) + color[k] * alpha;
                    }
                }
            }
        }
    }

    /// Fills the pixel rectangle `[x0, x1) × [y0, y1)` (clipped to the canvas), over
    /// everything drawn.
    pub fn rect(&mut self, x0: usize, y0: usize, x1: usize, y1: usize, color: [f32; 3]) {
        for y in y0..y1.min(self.height) {
            for x in x0..x1.min(self.width) {
                self.rgb[y * self.width + x] = color;
            }
        }
    }

    /// Writes `text` in the 8×8 font with its top left corner at pixel `(x, y)`, `scale`
    /// pixels a font pixel, over everything drawn. Characters the font lacks print as `?`.
    pub fn text(&mut self, x: usize, y: usize, text: &str, scale: usize, color: [f32; 3]) {
        for (i, ch) in text.chars().enumerate() {
            let glyph = BASIC_LEGACY
                .get(ch as usize)
                .copied()
                .unwrap_or(BASIC_LEGACY[b'?' as usize]);
            for (row, bits) in glyph.iter().enumerate() {
                for col in 0..8 {
                    if bits & (1 << col) != 0 {
                        let px = x + (i * 8 + col) * scale;
                        let py = y + row * scale;
                        self.rect(px, py, px + scale, py + scale, color);
                    }
                }
            }
        }
    }

    /// A legend in the top left corner: a swatch and a label a line.
    pub fn legend(&mut self, entries: &[([f32; 3], &str)]) {
        let (x, mut y, scale) = (16, 16, 2);
        for (color, label) in entries {
            self.rect(x, y, x + 16, y + 16, *color);
            self.text(x + 26, y, label, scale, [0.2, 0.2, 0.22]);
            y += 24;
        }
    }

    /// Writes an 8-bit RGB PNG.
    pub fn save_png(&self, path: &Path) -> Result<()> {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        }
        let file =
            std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?;
        let mut enc = png::Encoder::new(
            std::io::BufWriter::new(file),
            self.width as u32,
            self.height as u32,
        );
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut writer = enc
            .write_header()
            .with_context(|| format!("writing {}", path.display()))?;
        let data: Vec<u8> = self
            .rgb
            .iter()
            .flat_map(|c| c.map(|v| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8))
            .collect();
        writer
            .write_image_data(&data)
            .with_context(|| format!("writing {}", path.display()))?;
        writer
            .finish()
            .with_context(|| format!("writing {}", path.display()))?;
        Ok(())
    }
}

/// Colour of front-side particles.
pub const FRONT: [f32; 3] = [0.93, 0.45, 0.12];
/// Colour of back-side particles.
pub const BACK: [f32; 3] = [0.15, 0.42, 0.85];
/// Colour of particles hit by a moving collider.
pub const HIT: [f32; 3] = [0.1, 0.68, 0.28];
