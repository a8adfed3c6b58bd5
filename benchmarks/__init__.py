"""Speed and accuracy benchmarks, printed as tables (``python -m benchmarks``)."""
