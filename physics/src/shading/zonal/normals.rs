//! Per image: the pixels' normals in polar coordinates ([`PolarNormals`]) and the radiance of
//! every grid normal they need (the normal tables), interpolated per pixel.

use super::*;

/// Pixel normals in polar coordinates about the view axis, after the [normal
/// policy](shading_normal): computed once per image and shared by every material shaded on it.
pub struct PolarNormals {
    /// θ from the view (NaN: no usable normal, the pixel shades to black).
    pub(super) theta: Vec<f32>,
    /// φ about the view, in [0, 2π).
    pub(super) phi: Vec<f32>,
}

impl PolarNormals {
    /// Converts the pixels with `mask > 0`.
    pub fn new(normals: &[[f32; 3]], mask: &[f32]) -> Self {
        let (theta, phi) = normals
            .par_iter()
            .zip(mask.par_iter())
            .map(|(n, &m)| polar(n, m))
            .unzip();
        Self { theta, phi }
    }

    /// Which normal rows of `grid` the pixels with `mask > 0` interpolate from.
    pub(super) fn rows_needed(&self, grid: &ZonalGrid, mask: &[f32]) -> Vec<bool> {
        let mut need = vec![false; grid.rows + 1];
        let coords = grid.normal_coords();
        for (t, &m) in self.theta.iter().zip(mask) {
            if m > 0.0 && !t.is_nan() {
                let i = row_of(*t as f64, &coords, grid.rows);
                // Rows i−1..=i+2; row −1 is row 1 across the pole, rows beyond the last are
                // extrapolated from the last two.
                let (lo, hi) = (i.saturating_sub(1), (i + 2).min(grid.rows));
                need[lo..=hi].fill(true);
                need[1.min(grid.rows)] |= i == 0;
                need[grid.rows - 1] |= i + 2 > grid.rows;
            }
        }
        need
    }
}

/// A pixel's shading normal in polar coordinates about the view (θ NaN: shades to black).
pub(super) fn polar(n: &[f32; 3], m: f32) -> (f32, f32) {
    match (m > 0.0).then(|| shading_normal(*n)).flatten() {
        Some(d) => (
            d.z.clamp(-1.0, 1.0).acos() as f32,
            d.y.atan2(d.x).rem_euclid(2.0 * PI) as f32,
        ),
        None => (f32::NAN, 0.0),
    }
}

/// The interval of angle θ among a grid's normal rows.
pub(super) fn row_of(theta: f64, coords: &BandCoords, rows: usize) -> usize {
    (coords.coord(theta).clamp(0.0, rows as f64).floor() as usize).min(rows - 1)
}

/// Radiance at the normals of the grid, `[row][column]`, for the rows `need` marks (the others
/// stay 0) (step 3 of the module docs).
pub(super) fn normal_table(kernel: &ZonalKernel, env: &ZonalEnv, need: &[bool]) -> Vec<Vec<[f32; 3]>> {
    normal_table_with(kernel, env, need, true)
}

/// [`normal_table`] on rayon's threads or (`parallel` false: inside a kernel build, where a
/// nested parallel loop could wait on the cell being built) on this one; the same bits.
pub(super) fn normal_table_with(
    kernel: &ZonalKernel,
    env: &ZonalEnv,
    need: &[bool],
    parallel: bool,
) -> Vec<Vec<[f32; 3]>> {
    let grid = kernel.grid;
    let (n, m) = (grid.phi, grid.harmonics());
    let ifft = inverse_plan(n);
    let scale = 1.0 / n as f32;
    // Σ_r K̂ Ŵ for one row: per channel, (re, im) of harmonics 0..m.
    let accumulate = |a: usize| -> [(Vec<f32>, Vec<f32>); 3] {
        let mut acc: [(Vec<f32>, Vec<f32>); 3] = Default::default();
        for slot in acc.iter_mut() {
            *slot = (vec![0.0; m], vec![0.0; m]);
        }
        let coeffs = &kernel.coeffs[a];
        for e in &kernel.entries[a] {
            let (c, len) = (e.channel as usize, e.len as usize);
            let k = &coeffs[e.start as usize..e.start as usize + len];
            let off = (e.env_row as usize * 3 + c) * m;
            let (wr, wi) = (&env.re[off..off + len], &env.im[off..off + len]);
            let (ar, ai) = &mut acc[c];
            for (((ar, ai), kk), (xr, xi)) in ar[..len]
                .iter_mut()
                .zip(ai[..len].iter_mut())
                .zip(k)
                .zip(wr.iter().zip(wi))
            {
                *ar += kk * xr;
                *ai += kk * xi;
            }
        }
        acc
    };
    // Rows in pairs, so the six real results take three inverse transforms (x + iy).
    let buffers = || {
        (
            vec![Complex32::default(); n],
            vec![Complex32::default(); ifft.get_inplace_scratch_len()],
        )
    };
    let pair = |(buf, scratch): &mut (Vec<Complex32>, Vec<Complex32>), p: usize| -> [Vec<[f32; 3]>; 2] {
        let rows = [2 * p, 2 * p + 1];
        let live = rows.map(|a| a <= grid.rows && need[a]);
        let mut out = [vec![[0.0_f32; 3]; n], vec![[0.0_f32; 3]; n]];
        if !live[0] && !live[1] {
            return out;
        }
        let acc = rows.map(|a| {
            if a <= grid.rows && need[a] {
                Some(accumulate(a))
            } else {
                None
            }
        });
        for (x, y) in [((0, 0), Some((0, 1))), ((0, 2), Some((1, 2))), ((1, 0), Some((1, 1)))] {
            let spectrum = |(row, c): (usize, usize)| acc[row].as_ref().map(|a| &a[c]);
            let (sx, sy) = (spectrum(x), y.and_then(spectrum));
            if sx.is_none() && sy.is_none() {
                continue;
            }
            for f in 0..m {
                let real_only = f == 0 || 2 * f == n;
                let get = |s: Option<&(Vec<f32>, Vec<f32>)>| {
                    s.map_or(Complex32::default(), |(re, im)| {
                        Complex32::new(re[f], if real_only { 0.0 } else { im[f] })
                    })
                };
                let (zx, zy) = (get(sx), get(sy));
                buf[f] = zx + Complex32::new(-zy.im, zy.re);
                if f > 0 && f < n - f {
                    buf[n - f] = zx.conj() + Complex32::new(zy.im, zy.re);
                }
            }
            ifft.process_with_scratch(buf, scratch);
            for (j, z) in buf.iter().enumerate() {
                out[x.0][j][x.1] = z.re * scale;
                if let Some((row, c)) = y {
                    out[row][j][c] = z.im * scale;
                }
            }
        }
        out
    };
    let pairs: Vec<[Vec<[f32; 3]>; 2]> = if parallel {
        (0..=grid.rows / 2).into_par_iter().map_init(buffers, pair).collect()
    } else {
        let mut b = buffers();
        (0..=grid.rows / 2).map(|p| pair(&mut b, p)).collect()
    };
    let mut rows: Vec<Vec<[f32; 3]>> = pairs.into_iter().flatten().collect();
    rows.truncate(grid.rows + 1);
    rows
}

/// The normal table with a border, so that every pixel's 4×4 neighbourhood is a plain
/// rectangle: row −1 (row 1 half a turn round, across the pole), row `rows + 1` (extrapolated
/// linearly from the last two), and columns −1, `phi`, `phi + 1` (wrapped).
pub(super) struct Padded {
    pub(super) width: usize,
    pub(super) values: Vec<[f32; 3]>,
    pub(super) coords: BandCoords,
}

impl Padded {
    pub(super) fn new(rows: &[Vec<[f32; 3]>], grid: &ZonalGrid) -> Self {
        let n = grid.phi;
        let width = n + 3;
        let last = grid.rows;
        let mut values = Vec::with_capacity((last + 3) * width);
        for a in -1..=(last as i64 + 1) {
            for col in -1..=(n as i64 + 1) {
                let v = if a < 0 {
                    rows[1.min(last)][(col + n as i64 / 2).rem_euclid(n as i64) as usize]
                } else if a as usize > last {
                    let c = col.rem_euclid(n as i64) as usize;
                    let (x, y) = (rows[last][c], rows[last - 1][c]);
                    [0, 1, 2].map(|k| 2.0 * x[k] - y[k])
                } else {
                    rows[a as usize][col.rem_euclid(n as i64) as usize]
                };
                values.push(v);
            }
        }
        Self {
            width,
            values,
            coords: grid.normal_coords(),
        }
    }

    /// Bicubic (Catmull–Rom) value at polar angles (θ, φ), negative values clamped to 0 (the
    /// interpolant may undershoot next to a sharp peak).
    pub(super) fn at(&self, grid: &ZonalGrid, theta: f32, phi: f32) -> [f32; 3] {
        let u = self.coords.coord(theta as f64).clamp(0.0, grid.rows as f64);
        let i = (u.floor() as usize).min(grid.rows - 1);
        let s = (phi as f64 / (2.0 * PI) * grid.phi as f64).clamp(0.0, grid.phi as f64);
        let j = (s.floor() as usize).min(grid.phi - 1);
        let (wr, wc) = (catmull_rom(u - i as f64), catmull_rom(s - j as f64));
        let wc = wc.map(|w| w as f32);
        // Padded row i − 1 + 1 = i, column j − 1 + 1 = j.
        let mut acc = [0.0_f32; 3];
        for (dr, &wr) in wr.iter().enumerate() {
            let base = (i + dr) * self.width + j;
            let mut row = [0.0_f32; 3];
            for (dc, &wc) in wc.iter().enumerate() {
                let v = self.values[base + dc];
                for c in 0..3 {
                    row[c] += wc * v[c];
                }
            }
            for c in 0..3 {
                acc[c] += wr as f32 * row[c];
            }
        }
        // Not `max`, which would turn NaN (an overflow, absurd input) into a silent 0:
        // `sanitize` replaces and counts it.
        acc.map(|v| if v < 0.0 { 0.0 } else { v })
    }
}
