"""Benchmarks: `python -m itg_vision.bench speed|noise ...`."""
