//! The reductions every term ends with: sums and means that are exact on a GPU device too, and
//! that inside a data-parallel step are this rank's share of the global batch's.

use crate::parallel::share;
use burn::tensor::Tensor;

/// The sum of each row of `x` (`[B, N]` → `[B]`). On a CubeCL device Burn 0.22.1's reduction
/// kernels are wrong once a reduction spans more than 65,535 workgroups (measured on lavapipe:
/// the row sums of a `[16, 65534]` tensor of ones came out 65520, 0, 0, …; `trainer gpu-info`
/// probes a device), so there the sum is a matrix product with a column of ones, whose kernels
/// tile the output instead; the host keeps Burn's reduction.
pub fn row_sums(x: Tensor<2>) -> Tensor<1> {
    let [b, n] = x.dims();
    let device = x.device();
    if crate::device::on_cube(&device) {
        // Burn's matrix product is wrong there too for long enough rows (a `[1, 3·2²⁰]` row of
        // ones summed to 262140 on lavapipe): rows longer than CHUNK are summed in pieces of
        // CHUNK (zero padded), then the pieces' sums.
        const CHUNK: usize = 4096;
        if n <= CHUNK {
            return x.matmul(Tensor::ones([n, 1], &device)).reshape([b]);
        }
        let k = n.div_ceil(CHUNK);
        let x = if k * CHUNK > n {
            Tensor::cat(vec![x, Tensor::zeros([b, k * CHUNK - n], &device)], 1)
        } else {
            x
        };
        row_sums(
            x.reshape([b * k, CHUNK])
                .matmul(Tensor::ones([CHUNK, 1], &device))
                .reshape([b, k]),
        )
    } else {
        x.sum_dim(1).reshape([b])
    }
}

/// The sum of every value of `x`, as `[1]` (see [`row_sums`]; the host keeps Burn's `sum`).
pub fn sum_all<const D: usize>(x: Tensor<D>) -> Tensor<1> {
    if crate::device::on_cube(&x.device()) {
        let n = x.shape().num_elements();
        row_sums(x.reshape([1, n]))
    } else {
        x.sum()
    }
}

/// The mean of every value of `x`, as `[1]` (see [`row_sums`]; the host keeps Burn's `mean`).
/// Inside a data-parallel step `x` is this rank's part of the global batch, and the mean is
/// this rank's share of the global batch's: its sum over the global count.
pub fn mean<const D: usize>(x: Tensor<D>) -> Tensor<1> {
    if let Some(n) = share::batch_count(x.shape().num_elements()) {
        return sum_all(x).div_scalar(n.max(1.0));
    }
    if crate::device::on_cube(&x.device()) {
        let n = x.shape().num_elements();
        sum_all(x).div_scalar(n.max(1) as f64)
    } else {
        x.mean()
    }
}

#[cfg(all(test, feature = "wgpu"))]
mod tests {
    use super::*;
    use burn::tensor::TensorData;

    /// The losses' sums on the GPU device are exact where Burn's reductions are not (lavapipe,
    /// 2026-11-27: Burn's row sums of `[16, 65534]` ones gave 65520, 0, 0, …).
    #[test]
    fn the_losses_sums_on_the_gpu_device_are_exact_at_training_sizes() {
        let Some(gpu) = crate::rendering_layer::gpu::tests::device() else {
            return;
        };
        for (b, n) in [
            (1, 3),
            (2, 4097),
            (1, 65535),
            (16, 65534),
            (16, 196_608),
            (4, 1 << 20),
            (1, 3 << 20),
        ] {
            let sums: Vec<f32> = row_sums(Tensor::<2>::ones([b, n], &gpu))
                .into_data()
                .try_to_vec()
                .expect("f32");
            assert_eq!(sums, vec![n as f32; b], "[{b}, {n}]");
        }
        let all = |t: Tensor<1>| t.into_data().try_to_vec::<f32>().expect("f32")[0];
        assert_eq!(
            all(sum_all(Tensor::<4>::ones([16, 3, 256, 256], &gpu))),
            (16 * 3 * 65536) as f32
        );
        assert_eq!(all(mean(Tensor::<4>::ones([16, 3, 256, 256], &gpu))), 1.0);
        // Not only ones: a ramp whose sum is exact in f32.
        let ramp: Vec<f32> = (0..2 * 65536).map(|i| (i % 256) as f32).collect();
        let t = Tensor::<2>::from_data(TensorData::new(ramp, [2, 65536]), &gpu);
        assert_eq!(
            row_sums(t).into_data().try_to_vec::<f32>().expect("f32"),
            vec![255.0 * 128.0 * 256.0; 2]
        );
    }
}
