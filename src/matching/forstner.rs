//! Förstner interest operator: the structure tensor N = Σ ∇g ∇gᵀ over a window gives
//! the interest value w = det N / tr N (the inverse of the size of the point's error
//! ellipse) and the roundness q = 4 det N / (tr N)² (1 for a circular ellipse, 0 for an
//! edge). Points are local maxima of w above a threshold relative to the mean w, with
//! q above its threshold, thinned to an even distribution over a grid so that every part
//! of the photo contributes tie points.

use super::GreyImage;
use serde::Serialize;

#[derive(Debug, Clone)]
pub struct ForstnerOptions {
    /// Half-size of the summation window (window is 2·r + 1).
    pub window_radius: usize,
    /// w must exceed this multiple of the mean w (Förstner: 0.5–1.5).
    pub w_factor: f64,
    /// Minimum roundness q (0.5–0.75 usual).
    pub q_min: f64,
    /// Non-maximum suppression radius (px).
    pub nms_radius: usize,
    /// Grid cells across and down for the even distribution, and points kept per cell.
    pub grid: (usize, usize),
    pub per_cell: usize,
    /// Keep this far from the image border (px), e.g. the half template size.
    pub border: usize,
}

impl Default for ForstnerOptions {
    fn default() -> Self {
        Self {
            window_radius: 2,
            w_factor: 1.0,
            q_min: 0.5,
            nms_radius: 4,
            grid: (8, 8),
            per_cell: 4,
            border: 16,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct InterestPoint {
    /// Pixel centre of the maximum (corner-origin coordinates).
    pub x: f64,
    pub y: f64,
    pub w: f64,
    pub q: f64,
}

/// Interest points of `img`, strongest first within each grid cell, cells in row order.
pub fn forstner(img: &GreyImage, opts: &ForstnerOptions) -> Vec<InterestPoint> {
    let (w, h) = (img.width, img.height);
    if w < 5 || h < 5 {
        return Vec::new();
    }
    // Gradients by central differences; products summed with a box filter (integral
    // images, so the window size costs nothing).
    let mut gxx = vec![0.0f64; w * h];
    let mut gyy = vec![0.0f64; w * h];
    let mut gxy = vec![0.0f64; w * h];
    for r in 1..h - 1 {
        for c in 1..w - 1 {
            let gx = 0.5 * (img.at(c + 1, r) - img.at(c - 1, r)) as f64;
            let gy = 0.5 * (img.at(c, r + 1) - img.at(c, r - 1)) as f64;
            let i = r * w + c;
            gxx[i] = gx * gx;
            gyy[i] = gy * gy;
            gxy[i] = gx * gy;
        }
    }
    let integral = |a: &[f64]| {
        let mut s = vec![0.0f64; (w + 1) * (h + 1)];
        for r in 0..h {
            let mut acc = 0.0;
            for c in 0..w {
                acc += a[r * w + c];
                s[(r + 1) * (w + 1) + c + 1] = s[r * (w + 1) + c + 1] + acc;
            }
        }
        s
    };
    let (sxx, syy, sxy) = (integral(&gxx), integral(&gyy), integral(&gxy));
    let rad = opts.window_radius.max(1);
    let margin = (rad + 1).max(opts.border);
    if w <= 2 * margin || h <= 2 * margin {
        return Vec::new();
    }
    let boxs = |s: &[f64], c: usize, r: usize| {
        let (c0, r0, c1, r1) = (c - rad, r - rad, c + rad + 1, r + rad + 1);
        s[r1 * (w + 1) + c1] - s[r0 * (w + 1) + c1] - s[r1 * (w + 1) + c0] + s[r0 * (w + 1) + c0]
    };
    let mut wv = vec![0.0f64; w * h];
    let mut qv = vec![0.0f64; w * h];
    let (mut sum, mut n) = (0.0, 0usize);
    for r in margin..h - margin {
        for c in margin..w - margin {
            let (a, b, d) = (boxs(&sxx, c, r), boxs(&syy, c, r), boxs(&sxy, c, r));
            let det = a * b - d * d;
            let tr = a + b;
            if tr > 1e-12 {
                let i = r * w + c;
                wv[i] = det / tr;
                qv[i] = 4.0 * det / (tr * tr);
                sum += wv[i];
                n += 1;
            }
        }
    }
    if n == 0 || sum <= 0.0 {
        return Vec::new();
    }
    let w_min = opts.w_factor * sum / n as f64;
    let nms = opts.nms_radius.max(1);
    let mut pts = Vec::new();
    for r in margin..h - margin {
        for c in margin..w - margin {
            let i = r * w + c;
            let v = wv[i];
            if v <= w_min || qv[i] < opts.q_min {
                continue;
            }
            let (r0, r1) = (r.saturating_sub(nms), (r + nms + 1).min(h));
            let (c0, c1) = (c.saturating_sub(nms), (c + nms + 1).min(w));
            // Ties broken by position so equal plateaus keep exactly one maximum.
            let is_max = (r0..r1).all(|rr| {
                (c0..c1).all(|cc| {
                    let u = wv[rr * w + cc];
                    u < v || (u == v && (rr, cc) >= (r, c))
                })
            });
            if is_max {
                // Förstner's optimal point: the least-squares intersection of the edge
                // lines through the window, x̂ = N⁻¹ Σ ∇g∇gᵀ x (a corner to sub-pixel).
                let (mut n11, mut n12, mut n22, mut b1, mut b2) = (0.0, 0.0, 0.0, 0.0, 0.0);
                for rr in r - rad..=r + rad {
                    for cc in c - rad..=c + rad {
                        let k = rr * w + cc;
                        let (x, y) = (cc as f64 + 0.5, rr as f64 + 0.5);
                        n11 += gxx[k];
                        n12 += gxy[k];
                        n22 += gyy[k];
                        b1 += gxx[k] * x + gxy[k] * y;
                        b2 += gxy[k] * x + gyy[k] * y;
                    }
                }
                let det = n11 * n22 - n12 * n12;
                let (mut px, mut py) = (c as f64 + 0.5, r as f64 + 0.5);
                if det > 0.0 {
                    let (qx, qy) = ((n22 * b1 - n12 * b2) / det, (n11 * b2 - n12 * b1) / det);
                    if (qx - px).abs() <= 1.5 && (qy - py).abs() <= 1.5 {
                        (px, py) = (qx, qy);
                    }
                }
                pts.push(InterestPoint {
                    x: px,
                    y: py,
                    w: v,
                    q: qv[i],
                });
            }
        }
    }
    // Even distribution: the strongest `per_cell` points of each grid cell.
    let (gx, gy) = (opts.grid.0.max(1), opts.grid.1.max(1));
    let mut cells: Vec<Vec<InterestPoint>> = vec![Vec::new(); gx * gy];
    for p in pts {
        let cx = ((p.x / w as f64) * gx as f64) as usize;
        let cy = ((p.y / h as f64) * gy as f64) as usize;
        cells[cy.min(gy - 1) * gx + cx.min(gx - 1)].push(p);
    }
    let mut out = Vec::new();
    for mut c in cells {
        c.sort_by(|a, b| {
            b.w.total_cmp(&a.w)
                .then(a.y.total_cmp(&b.y))
                .then(a.x.total_cmp(&b.x))
        });
        out.extend(c.into_iter().take(opts.per_cell));
    }
    out
}
