"""ONNX Runtime sessions for the detector's networks: one per thread, one thread each."""

from __future__ import annotations

__all__ = ["SessionFactory"]


class SessionFactory:
    """Makes one ONNX Runtime session of ``onnx`` (bytes) per call, on the CPU with one intra-op thread (the
    pipeline parallelises over cameras); for :class:`checks.per_thread.PerThread`. A module-level class: it
    pickles as its bytes."""

    def __init__(self, onnx: bytes):
        self.onnx = onnx

    def __call__(self):
        import onnxruntime as ort

        so = ort.SessionOptions()
        so.intra_op_num_threads = 1
        so.inter_op_num_threads = 1
        so.log_severity_level = 3
        return ort.InferenceSession(self.onnx, so, providers=["CPUExecutionProvider"])
