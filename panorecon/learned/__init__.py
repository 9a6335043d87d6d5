"""The learned depth teacher: a small U-Net (``model.py``) trained on crops of synthetic scene variants
(``data.py``) with MiDaS's scale-and-shift-invariant loss (``loss.py``), exported to ONNX (``export.py``) and
run only through the ``onnx:`` teacher. ``train.py``: ``panorecon teachers train``."""
