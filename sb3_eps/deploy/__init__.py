"""Deployment: run an exported policy without torch (:class:`OnnxPolicy`, in the self-contained file
``onnx_runner.py``, which a robot can take alone)."""

from sb3_eps.deploy.onnx_runner import OnnxPolicy

__all__ = ["OnnxPolicy"]
