"""Live detection: :class:`slipsense.streaming.detector.SlipDetector` over a model's stream
(:meth:`slipsense.models.base.SlipModel.stream`), the runners that execute a stream's modules on
PyTorch or ONNX Runtime (:mod:`slipsense.models.runners`), ONNX export
(:mod:`slipsense.streaming.export`) and annotated videos (:mod:`slipsense.streaming.annotate`).
"""
