"""Language backends: text-capable embedders for queries and S_semantic.

* ``imagenet-minilm`` (``lite.py``, extra ``language``): EfficientNet-Lite0 ImageNet features
  and class probabilities on the image side, all-MiniLM-L6-v2 on the text side, grounded
  through the 1000 ImageNet class names; the default text embedder when installed.
* ``open-clip`` (``clip.py``, extra ``clip``): open_clip from a local checkpoint path.
* ``clip-onnx`` (``clip.py``): a CLIP image/text ONNX pair through onnxruntime.

Plus ``colors.py`` (colour words from pixel statistics) and ``crops.py`` (masks cropped
on white). Nothing here downloads anything. See ``base.py`` for what a backend provides.
"""
