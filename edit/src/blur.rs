//! A Gaussian blur over an image's valid pixels only, which the composites use to part a photo's
//! large-scale shading from its detail ([`crate::composite`]).

/// A Gaussian blur (σ in pixels) of `values` over the `valid` pixels of a `w`×`h` image only:
/// each output is the weighted mean of the valid pixels near it (the weights are blurred
/// alongside and divided out). Three box passes per axis approximate the Gaussian (Wells 1986),
/// so the cost is a few operations per pixel whatever σ (a 12-megapixel photo's σ is 100+
/// pixels). Invalid pixels come back 0.
pub fn masked_blur(values: &[f32], valid: &[bool], w: usize, h: usize, sigma: f64) -> Vec<f32> {
    // Three boxes of width 2r + 1 have variance 3((2r+1)² − 1)/12 = r(r + 1).
    let r = ((0.25 + sigma * sigma).sqrt() - 0.5).round().max(0.0) as usize;
    let mut a: Vec<f64> = values
        .iter()
        .zip(valid)
        .map(|(&v, &ok)| if ok { v as f64 } else { 0.0 })
        .collect();
    let mut b: Vec<f64> = valid.iter().map(|&ok| f64::from(u8::from(ok))).collect();
    if r > 0 {
        let rows = Lines {
            len: w,
            count: h,
            step: 1,
            stride: w,
        };
        let columns = Lines {
            len: h,
            count: w,
            step: w,
            stride: 1,
        };
        let mut boxes = BoxFilter::new(r);
        for img in [&mut a, &mut b] {
            for _ in 0..3 {
                boxes.pass(img, rows);
                boxes.pass(img, columns);
            }
        }
    }
    a.iter()
        .zip(&b)
        .zip(valid)
        .map(|((&a, &b), &ok)| if ok && b > 1e-12 { (a / b) as f32 } else { 0.0 })
        .collect()
}

/// The lines of an image a box pass runs along: `count` lines `stride` apart, each `len` pixels
/// `step` apart (rows: step 1, stride w; columns: step w, stride 1).
#[derive(Clone, Copy)]
struct Lines {
    len: usize,
    count: usize,
    step: usize,
    stride: usize,
}

/// A box filter of radius `r` with its scratch lines, reused over every pass of a blur.
struct BoxFilter {
    r: usize,
    line: Vec<f64>,
    sums: Vec<f64>,
}

impl BoxFilter {
    fn new(r: usize) -> Self {
        BoxFilter {
            r,
            line: Vec::new(),
            sums: Vec::new(),
        }
    }

    /// One box filter along every line of `img`; windows are cut at the ends (sums, not means:
    /// the weights blurred the same way divide them out).
    fn pass(&mut self, img: &mut [f64], lines: Lines) {
        let Lines {
            len,
            count,
            step,
            stride,
        } = lines;
        for l in 0..count {
            self.line.clear();
            self.line.extend((0..len).map(|i| img[l * stride + i * step]));
            self.sums.clear();
            self.sums.push(0.0);
            for &v in self.line.iter() {
                let last = *self.sums.last().unwrap_or(&0.0);
                self.sums.push(last + v);
            }
            for i in 0..len {
                let (lo, hi) = (i.saturating_sub(self.r), (i + self.r + 1).min(len));
                img[l * stride + i * step] = self.sums[hi] - self.sums[lo];
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_masked_blur_averages_over_the_valid_pixels_only() {
        // A constant over the valid pixels stays that constant whatever lies outside them, at
        // every σ; a step blurs to values between its sides, monotonic across it.
        let (w, h) = (40, 30);
        let valid: Vec<bool> = (0..w * h).map(|k| (k % w) % 7 != 3 && k / w != 11).collect();
        let values: Vec<f32> = (0..w * h).map(|k| if valid[k] { 2.5 } else { 1e9 }).collect();
        for sigma in [0.3, 1.0, 4.0, 50.0] {
            let b = masked_blur(&values, &valid, w, h, sigma);
            for k in 0..w * h {
                let want = if valid[k] { 2.5 } else { 0.0 };
                assert!((b[k] - want).abs() < 1e-4, "σ {sigma} pixel {k}: {}", b[k]);
            }
        }
        let all = vec![true; w * h];
        let step: Vec<f32> = (0..w * h).map(|k| if k % w < w / 2 { 1.0 } else { 3.0 }).collect();
        let b = masked_blur(&step, &all, w, h, 3.0);
        let row: Vec<f32> = b[5 * w..6 * w].to_vec();
        assert!(row.windows(2).all(|p| p[1] >= p[0] - 1e-6), "{row:?}");
        assert!(row[0] < 1.001 && row[w - 1] > 2.999 && row[w / 2] > 1.5 && row[w / 2] < 2.5);
        // An impulse spreads with the variance asked for (to the boxes' integer radius).
        let (w, h) = (301, 1);
        for sigma in [2.5, 8.0, 20.0] {
            let impulse: Vec<f32> = (0..w).map(|x| f32::from(u8::from(x == 150))).collect();
            let valid = vec![true; w];
            let b = masked_blur(&impulse, &valid, w, h, sigma);
            let total: f64 = b.iter().map(|&v| v as f64).sum();
            let var: f64 = b
                .iter()
                .enumerate()
                .map(|(x, &v)| v as f64 * (x as f64 - 150.0).powi(2))
                .sum::<f64>()
                / total;
            assert!((var.sqrt() / sigma - 1.0).abs() < 0.15, "σ {sigma}: {}", var.sqrt());
        }
    }
}
