"""A real, small DNN that can be cut between a robot and an off-board node (issue 48).

``DNNSPLIT.md`` 3.3: a MobileNet-v1-like network built from a seed without downloading
anything (:mod:`.network`), cut at every split point into a head and a tail
(:mod:`.split`), run in single-threaded onnxruntime sessions (:mod:`.runner`) and measured per
split point (:mod:`.profile`); ``python -m fogfleet.workload.dnn profile`` prints the
measurements as the SoftwareModule's ``dnn`` field.

Only this package imports onnx and onnxruntime (the ``dnn`` extra): the operator's image ships
neither, and this ``__init__`` imports nothing, so ``fogfleet.workload`` stays importable
without them.
"""
