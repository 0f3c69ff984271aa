"""The project's own models: training code (optional ``train`` extra: torch, onnx) and exported ONNX files.

Runtime code never imports this package's training modules; it loads the exported ``*.onnx`` files with
``rsu.detect.OnnxDetector``. ``python -m models.train_all`` (``make models``) rebuilds everything.
"""
