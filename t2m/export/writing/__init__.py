"""Writing bundles: files + manifest (bundle.py), verification (verify.py), int8 requantisation of a bundle
(int8.py, quantize.py) and the index of training captions (caption_index.py)."""
