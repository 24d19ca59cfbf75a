"""Pure perception: a face on video -> expression probabilities -> debounced binary feedback.

No transport here (the live service wraps these). Modules: ``assets`` (packaged model and test clips),
``convert`` (Keras HDF5 -> ONNX), ``faces`` (Haar face detection and tracking), ``models``
(``ExpressionModel`` and implementations, label -> feedback), ``reaction`` (``ReactionDetector``),
``pipeline`` (``PerceptionPipeline``), ``media`` (reading files), ``evaluate`` (accuracy and timing),
``reference`` (torch mini-Xception used to check the conversion). See docs/perception.md.
"""
