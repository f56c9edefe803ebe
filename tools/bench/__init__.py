"""Benchmarks behind ``aider-exo bench``: each prints figures beside a baseline measured in the same run."""
