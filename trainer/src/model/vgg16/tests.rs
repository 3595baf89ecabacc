//! VGG16 weights from the two file layouts a user has: a torchvision state dict saved by
//! `torch.save` (a zip archive holding a pickle whose tensors point at raw storages) and its
//! safetensors export. The files are written here from first principles (pickle opcodes, zip
//! entries, safetensors' header), independently of Burn's readers, with every torchvision key —
//! block 5 and the classifier included, which the module must ignore.

use super::*;
use burn::tensor::TensorData;
use std::collections::BTreeMap;
use std::io::Write;

/// torchvision's `vgg16()` convolutions: (features index, in, out), block 5 included.
fn torchvision_convs() -> Vec<(usize, usize, usize)> {
    let mut v = Vec::new();
    let (mut idx, mut cin) = (0, 3);
    for (c, n) in [(64, 2), (128, 2), (256, 3), (512, 3), (512, 3)] {
        for _ in 0..n {
            v.push((idx, cin, c));
            idx += 2;
            cin = c;
        }
        idx += 1; // the max pool
    }
    v
}

/// A state dict in torchvision's key order: name → (shape, values).
fn state_dict(skip: Option<&str>) -> Vec<(String, Vec<usize>, Vec<f32>)> {
    let mut out = Vec::new();
    for (layer, (idx, cin, cout)) in torchvision_convs().into_iter().enumerate() {
        let w: Vec<f32> = (0..cout * cin * 9)
            .map(|k| 0.05 * ((k as f32 * 0.37 + layer as f32).sin()))
            .collect();
        let b: Vec<f32> = (0..cout).map(|k| 0.01 * (k as f32 - layer as f32)).collect();
        out.push((format!("features.{idx}.weight"), vec![cout, cin, 3, 3], w));
        out.push((format!("features.{idx}.bias"), vec![cout], b));
    }
    // A (shrunken) classifier: present in every torchvision file, unknown to the module.
    out.push(("classifier.0.weight".into(), vec![4, 6], vec![0.5; 24]));
    out.push(("classifier.0.bias".into(), vec![4], vec![0.1; 4]));
    out.retain(|(k, _, _)| Some(k.as_str()) != skip);
    out
}

fn bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn write_safetensors(path: &Path, sd: &[(String, Vec<usize>, Vec<f32>)]) {
    write_safetensors_with(path, sd, None)
}

fn write_safetensors_with(
    path: &Path,
    sd: &[(String, Vec<usize>, Vec<f32>)],
    metadata: Option<std::collections::HashMap<String, String>>,
) {
    let raw: Vec<(String, Vec<usize>, Vec<u8>)> = sd.iter().map(|(k, s, v)| (k.clone(), s.clone(), bytes(v))).collect();
    let views: Vec<(String, safetensors::tensor::TensorView)> = raw
        .iter()
        .map(|(k, s, b)| {
            let view = safetensors::tensor::TensorView::new(safetensors::Dtype::F32, s.clone(), b).unwrap();
            (k.clone(), view)
        })
        .collect();
    std::fs::write(path, safetensors::serialize(views, metadata).unwrap()).unwrap();
}

/// Pickle (protocol 2) of an `OrderedDict` of `_rebuild_tensor_v2` calls on persistent storages
/// `"0"`, `"1"`, …: what `torch.save(model.state_dict())` writes as `data.pkl`.
fn state_dict_pickle(sd: &[(String, Vec<usize>, Vec<f32>)]) -> Vec<u8> {
    let mut p = vec![0x80, 2];
    let global = |p: &mut Vec<u8>, module: &str, name: &str| {
        p.push(b'c');
        p.extend(format!("{module}\n{name}\n").as_bytes());
    };
    let text = |p: &mut Vec<u8>, s: &str| {
        p.push(b'X');
        p.extend((s.len() as u32).to_le_bytes());
        p.extend(s.as_bytes());
    };
    let int = |p: &mut Vec<u8>, v: usize| {
        p.push(b'J');
        p.extend((v as i32).to_le_bytes());
    };
    let tuple = |p: &mut Vec<u8>, vs: &[usize]| {
        p.push(b'(');
        for &v in vs {
            int(p, v);
        }
        p.push(b't');
    };
    global(&mut p, "collections", "OrderedDict");
    p.extend([b')', b'R', b'(']);
    for (key, (name, shape, values)) in sd.iter().enumerate() {
        text(&mut p, name);
        global(&mut p, "torch._utils", "_rebuild_tensor_v2");
        p.push(b'(');
        // Persistent id ('storage', FloatStorage, key, 'cpu', numel).
        p.push(b'(');
        text(&mut p, "storage");
        global(&mut p, "torch", "FloatStorage");
        text(&mut p, &key.to_string());
        text(&mut p, "cpu");
        int(&mut p, values.len());
        p.extend([b't', b'Q']);
        int(&mut p, 0);
        tuple(&mut p, shape);
        let strides: Vec<usize> = (0..shape.len()).map(|i| shape[i + 1..].iter().product()).collect();
        tuple(&mut p, &strides);
        p.push(0x89); // False: requires_grad
        global(&mut p, "collections", "OrderedDict");
        p.extend([b')', b'R', b't', b'R']);
    }
    p.extend([b'u', b'.']);
    p
}

fn write_pth(path: &Path, sd: &[(String, Vec<usize>, Vec<f32>)]) {
    let file = std::fs::File::create(path).unwrap();
    let mut zip = zip::ZipWriter::new(file);
    let opts = zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    let mut entry = |name: &str, data: &[u8]| {
        zip.start_file(format!("vgg16/{name}"), opts).unwrap();
        zip.write_all(data).unwrap();
    };
    entry("data.pkl", &state_dict_pickle(sd));
    entry("byteorder", b"little");
    for (key, (_, _, values)) in sd.iter().enumerate() {
        entry(&format!("data/{key}"), &bytes(values));
    }
    entry("version", b"3\n");
    zip.finish().unwrap();
}

/// A scratch folder of one test (its weight files are 50 MB), removed when the test ends.
fn dir() -> tempfile::TempDir {
    tempfile::Builder::new().prefix("matedit-vgg16-").tempdir().unwrap()
}

fn values(t: Tensor<4>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().unwrap()
}

/// Every loaded convolution holds the file's tensors of its torchvision index.
fn assert_loaded(net: &Vgg16, sd: &[(String, Vec<usize>, Vec<f32>)]) {
    let by_name: BTreeMap<&str, &Vec<f32>> = sd.iter().map(|(k, _, v)| (k.as_str(), v)).collect();
    assert_eq!(net.features.len(), TORCHVISION_INDICES.len());
    for (conv, idx) in net.features.iter().zip(TORCHVISION_INDICES) {
        let w = values(conv.weight.val());
        assert_eq!(
            &w,
            by_name[format!("features.{idx}.weight").as_str()],
            "conv features.{idx}"
        );
        let b = conv
            .bias
            .as_ref()
            .map(|b| b.val().into_data().try_to_vec::<f32>().unwrap());
        assert_eq!(
            b.as_ref(),
            Some(by_name[format!("features.{idx}.bias").as_str()]),
            "bias {idx}"
        );
    }
}

#[test]
fn torchvision_checkpoints_and_safetensors_load_into_the_right_layers() {
    let device = Device::flex();
    let sd = state_dict(None);
    let tmp = dir();
    let d = tmp.path();
    let (pth, st) = (d.join("vgg16.pth"), d.join("vgg16.safetensors"));
    write_pth(&pth, &sd);
    write_safetensors(&st, &sd);
    for path in [&pth, &st] {
        let net = Vgg16::load(path, &device).unwrap_or_else(|e| panic!("{}: {e:#}", path.display()));
        assert_loaded(&net, &sd);
        // Frozen: a perceptual loss must not train VGG16.
        assert!(!net.features[0].weight.val().is_require_grad());
    }
}

#[test]
fn a_file_without_a_vgg16_tensor_is_refused_naming_it() {
    let device = Device::flex();
    let tmp = dir();
    let d = tmp.path();
    let sd = state_dict(Some("features.19.weight"));
    let (pth, st) = (d.join("partial.pth"), d.join("partial.safetensors"));
    write_pth(&pth, &sd);
    write_safetensors(&st, &sd);
    for path in [&pth, &st] {
        let e = Vgg16::load(path, &device)
            .err()
            .map(|e| format!("{e:#}"))
            .unwrap_or_default();
        assert!(e.contains(&path.display().to_string()) && e.contains("missing"), "{e}");
    }
    let junk = d.join("junk.pth");
    std::fs::write(&junk, b"not a checkpoint").unwrap();
    let e = Vgg16::load(&junk, &device)
        .err()
        .map(|e| format!("{e:#}"))
        .unwrap_or_default();
    assert!(e.contains("junk.pth"), "{e}");
    let e = Vgg16::load(&d.join("absent.pth"), &device)
        .err()
        .map(|e| format!("{e:#}"))
        .unwrap_or_default();
    assert!(e.contains("absent.pth") && e.contains("no such"), "{e}");
    let e = Vgg16::load(&d.join("weights.onnx"), &device)
        .err()
        .map(|e| format!("{e:#}"))
        .unwrap_or_default();
    assert!(e.contains("weights.onnx"), "{e}");
}

#[test]
fn features_have_the_block_shapes_and_identical_images_give_zero_loss() {
    let device = Device::flex();
    let net = Vgg16::new(&device);
    let x = Tensor::<4>::from_data(TensorData::new(vec![0.5f32; 2 * 3 * 32 * 32], [2, 3, 32, 32]), &device);
    let f = net.features(x, &[Layer::Relu4_3, Layer::Relu1_2, Layer::Relu2_2, Layer::Relu3_3]);
    let dims: Vec<[usize; 4]> = f.iter().map(|t| t.dims()).collect();
    assert_eq!(
        dims,
        vec![[2, 64, 32, 32], [2, 128, 16, 16], [2, 256, 8, 8], [2, 512, 4, 4]]
    );
    let loss = crate::train::loss::perceptual::Perceptual::Vgg16 {
        net: Box::new(net),
        layers: crate::train::loss::perceptual::DEFAULT_LAYERS.to_vec(),
        source: "random weights".into(),
        checksum: String::new(),
    };
    let img: Vec<f32> = (0..2 * 3 * 32 * 32)
        .map(|k| 0.3 + 0.25 * (k as f32 * 0.11).sin())
        .collect();
    let a = Tensor::<4>::from_data(TensorData::new(img.clone(), [2, 3, 32, 32]), &device);
    let b = Tensor::<4>::from_data(
        TensorData::new(img.iter().map(|v| v * 3.0).collect::<Vec<_>>(), [2, 3, 32, 32]),
        &device,
    );
    let mask = Tensor::<4>::ones([2, 1, 32, 32], &device);
    let same = crate::rendering_layer::op::host(&loss.loss(a.clone(), a.clone(), mask.clone()))[0];
    let diff = crate::rendering_layer::op::host(&loss.loss(b, a, mask))[0];
    assert_eq!(same, 0.0);
    assert!(diff.is_finite() && diff > 0.0, "{diff}");
}

fn metadata(preprocessing: &str) -> Option<std::collections::HashMap<String, String>> {
    Some([("preprocessing".to_string(), preprocessing.to_string())].into())
}

/// A file that says `caffe` computes VGG16 on 255 x − mean₂₅₅: the same activations as the
/// torchvision convention on the image x' with (x' − mean) / std = 255 x − mean₂₅₅.
#[test]
fn caffe_preprocessing_is_read_from_the_metadata_and_applied() {
    let device = Device::flex();
    let sd = state_dict(None);
    let tmp = dir();
    let d = tmp.path();
    let (caffe, tv, bad) = (
        d.join("caffe.safetensors"),
        d.join("tv.safetensors"),
        d.join("bad.safetensors"),
    );
    write_safetensors_with(&caffe, &sd, metadata("caffe"));
    write_safetensors_with(&tv, &sd, metadata("torchvision"));
    write_safetensors_with(&bad, &sd, metadata("keras-bgr"));
    let caffe_net = Vgg16::load(&caffe, &device).unwrap();
    let tv_net = Vgg16::load(&tv, &device).unwrap();
    assert_eq!(caffe_net.preprocessing(), Preprocessing::Caffe);
    assert_eq!(tv_net.preprocessing(), Preprocessing::Torchvision);
    let e = Vgg16::load(&bad, &device)
        .err()
        .map(|e| format!("{e:#}"))
        .unwrap_or_default();
    assert!(e.contains("bad.safetensors") && e.contains("keras-bgr"), "{e}");
    // Headers that are not safetensors': too short, a length past any header, not JSON.
    for (name, bytes) in [
        ("short.safetensors", vec![1u8, 2, 3]),
        ("huge.safetensors", u64::MAX.to_le_bytes().to_vec()),
        (
            "cut.safetensors",
            [16u64.to_le_bytes().to_vec(), b"{\"a\"".to_vec()].concat(),
        ),
        (
            "junk.safetensors",
            [4u64.to_le_bytes().to_vec(), b"}}}}".to_vec()].concat(),
        ),
    ] {
        let p = d.join(name);
        std::fs::write(&p, bytes).unwrap();
        let e = Vgg16::load(&p, &device)
            .err()
            .map(|e| format!("{e:#}"))
            .unwrap_or_default();
        assert!(e.contains(name) && e.contains("safetensors"), "{name}: {e}");
    }

    let (h, w) = (16, 16);
    let x: Vec<f32> = (0..3 * h * w).map(|k| 0.5 + 0.45 * (k as f32 * 0.23).sin()).collect();
    let x_tv: Vec<f32> = x
        .iter()
        .enumerate()
        .map(|(k, v)| {
            let c = k / (h * w);
            STD[c] * (255.0 * v - CAFFE_MEAN[c]) + MEAN[c]
        })
        .collect();
    let t = |v: Vec<f32>| Tensor::<4>::from_data(TensorData::new(v, [1, 3, h, w]), &device);
    let layers = [Layer::Relu1_2, Layer::Relu3_3];
    let a = caffe_net.features(t(x), &layers);
    let b = tv_net.features(t(x_tv), &layers);
    for (a, b) in a.into_iter().zip(b) {
        let (a, b) = (values(a), values(b));
        let scale = b.iter().fold(0f32, |m, v| m.max(v.abs()));
        let err = a.iter().zip(&b).fold(0f32, |m, (x, y)| m.max((x - y).abs()));
        assert!(scale > 0.0 && err <= 1e-4 * scale, "max error {err} of {scale}");
    }
}

/// Where `scripts/fetch_vgg16.sh` put the converted weights and onnxruntime's reference:
/// `$VGG16_WEIGHTS` (the reference beside it), or the script's default folder.
fn fetched_vgg16() -> Option<(std::path::PathBuf, std::path::PathBuf)> {
    let weights = match std::env::var_os("VGG16_WEIGHTS").filter(|v| !v.is_empty()) {
        Some(p) => std::path::PathBuf::from(p),
        None => {
            let cache = std::env::var_os("MATEDIT_CACHE")
                .map(std::path::PathBuf::from)
                .or_else(|| std::env::var_os("HOME").map(|h| std::path::PathBuf::from(h).join(".cache/matedit")))?;
            cache.join("vgg16/vgg16-imagenet.safetensors")
        }
    };
    let reference = weights.with_file_name("vgg16-reference.safetensors");
    (weights.is_file() && reference.is_file()).then_some((weights, reference))
}

/// The real ImageNet VGG16 (Keras' weights, converted by `scripts/vgg16_from_onnx.py`) gives
/// onnxruntime's activations of the original ONNX graph on a real photo, at every layer the
/// perceptual loss compares: relative error ≤ 1e-4 of each layer's largest activation.
#[test]
fn onnxruntime_reference() {
    let Some((weights, reference)) = fetched_vgg16() else {
        assert!(
            std::env::var_os("MATEDIT_REQUIRE_VGG16").is_none(),
            "MATEDIT_REQUIRE_VGG16 is set but no fetched VGG16 weights and reference were found"
        );
        eprintln!(
            "skipped: no VGG16 weights and reference (run scripts/fetch_vgg16.sh, or set VGG16_WEIGHTS \
             to its output; CI fetches them)"
        );
        return;
    };
    let device = Device::flex();
    let net = Vgg16::load(&weights, &device).unwrap_or_else(|e| panic!("{e:#}"));
    assert_eq!(net.preprocessing(), Preprocessing::Caffe, "{}", weights.display());
    let bytes = std::fs::read(&reference).unwrap();
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let input = st.tensor("input_rgb").unwrap();
    let (h, w) = (input.shape()[0], input.shape()[1]);
    assert_eq!(input.shape(), &[h, w, 3]);
    let mut x = vec![0f32; 3 * h * w];
    for (k, &v) in input.data().iter().enumerate() {
        let (pixel, c) = (k / 3, k % 3);
        x[c * h * w + pixel] = v as f32 / 255.0;
    }
    let x = Tensor::<4>::from_data(TensorData::new(x, [1, 3, h, w]), &device);
    let layers = [Layer::Relu1_2, Layer::Relu2_2, Layer::Relu3_3, Layer::Relu4_3];
    let ours = net.features(x, &layers);
    for (name, ours) in ["relu1_2", "relu2_2", "relu3_3", "relu4_3"].into_iter().zip(ours) {
        let r = st.tensor(name).unwrap();
        assert_eq!(r.shape(), &ours.dims()[..], "{name}");
        let theirs: Vec<f32> = r
            .data()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        let ours = values(ours);
        let scale = theirs.iter().fold(0f32, |m, v| m.max(v.abs()));
        let err = ours.iter().zip(&theirs).fold(0f32, |m, (a, b)| m.max((a - b).abs()));
        let (mut num, mut den) = (0f64, 0f64);
        for (a, b) in ours.iter().zip(&theirs) {
            num += f64::from(a - b).powi(2);
            den += f64::from(*b).powi(2);
        }
        eprintln!(
            "{name}: max |ours − onnxruntime| {err:.3e} of max {scale:.4e} ({:.2e}); relative L2 {:.2e}",
            err / scale,
            (num / den).sqrt()
        );
        assert!(scale > 0.0 && err <= 1e-4 * scale, "{name}: max error {err} of {scale}");
    }
}
