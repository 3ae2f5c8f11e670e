"""colonlight benchmarks: `python -m benchmarks [name ...]` runs them and prints ratio tables (medians)."""
