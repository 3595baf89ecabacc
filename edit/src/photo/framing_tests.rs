//! [`Framing::area_average`] against the direct sum over every lattice point of the crop, and
//! on a thin photo, whose crop is a square of its long side.

use super::Framing;

/// The direct definition: every lattice point of the crop, padding included, in row order.
fn reference<const C: usize>(
    f: &Framing,
    width: usize,
    height: usize,
    value: impl Fn(usize) -> [f32; C],
) -> Vec<[f32; C]> {
    let n = f.size;
    let mut sum = vec![[0.0_f64; C]; n * n];
    let mut count = vec![0_u32; n * n];
    let (xs, ys) = (f.x0.floor() as i64, f.y0.floor() as i64);
    let (xe, ye) = ((f.x0 + f.side).ceil() as i64, (f.y0 + f.side).ceil() as i64);
    for y in ys..ye {
        for x in xs..xe {
            let (u, v) = f.to_net(x as f64 + 0.5, y as f64 + 0.5);
            if u < 0.0 || v < 0.0 || u >= n as f64 || v >= n as f64 {
                continue;
            }
            let k = v as usize * n + u as usize;
            count[k] += 1;
            if x >= 0 && y >= 0 && (x as usize) < width && (y as usize) < height {
                let val = value(y as usize * width + x as usize);
                for c in 0..C {
                    sum[k][c] += val[c] as f64;
                }
            }
        }
    }
    let scale = f.side / n as f64;
    (0..n * n)
        .map(|k| {
            if count[k] > 0 {
                sum[k].map(|s| (s / count[k] as f64) as f32)
            } else {
                let (u, v) = ((k % n) as f64 + 0.5, (k / n) as f64 + 0.5);
                let (x, y) = (f.x0 + u * scale, f.y0 + v * scale);
                if x >= 0.0 && y >= 0.0 && (x as usize) < width && (y as usize) < height {
                    value(y as usize * width + x as usize)
                } else {
                    [0.0; C]
                }
            }
        })
        .collect()
}

#[test]
fn the_area_average_equals_the_sum_over_every_lattice_point_bit_for_bit() {
    let mut seed = 0x9e37_79b9_7f4a_7c15_u64;
    let mut next = move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 11) as f64 / (1u64 << 53) as f64
    };
    for case in 0..300 {
        let (w, h) = (1 + (next() * 90.0) as usize, 1 + (next() * 90.0) as usize);
        let size = [1, 2, 3, 16, 64][case % 5];
        // Crops inside, across and beyond the photo, larger and smaller than the input.
        let side = 0.3 + next() * 1.6 * w.max(h) as f64;
        let f = Framing {
            x0: (next() - 0.4) * w as f64,
            y0: (next() - 0.4) * h as f64,
            side,
            size,
        };
        let values: Vec<[f32; 2]> = (0..w * h).map(|_| [next() as f32, -(next() as f32) * 1e3]).collect();
        let got = f.area_average(w, h, |k| values[k]);
        let want = reference(&f, w, h, |k| values[k]);
        assert!(
            got.iter()
                .zip(&want)
                .all(|(a, b)| a.map(f32::to_bits) == b.map(f32::to_bits)),
            "case {case}: {w}×{h}, {f:?}"
        );
    }
}

#[test]
fn a_thin_photo_is_framed_in_time_linear_in_its_pixels() {
    // 4 × 1,000,000 pixels: the crop around the object is a square of about 1.25 million pixels
    // a side, 1.6 × 10^12 lattice points, all but 4 million of them padding. Counted per row and
    // column it takes a moment; point by point it took hours.
    let (w, h) = (4, 1_000_000);
    let coverage: Vec<f32> = (0..w * h).map(|k| if k % w == 1 { 1.0 } else { 0.0 }).collect();
    let t = std::time::Instant::now();
    let f = Framing::around(&coverage, w, h, 256);
    let out = f.area_average(w, h, |k| [coverage[k]]);
    assert!(t.elapsed().as_secs_f64() < 5.0, "{:?}", t.elapsed());
    assert_eq!(out.len(), 256 * 256);
    assert!(
        out.iter().all(|v| v[0] < 0.5),
        "the object is far thinner than one input pixel"
    );
}
