"""Benchmarks (not tests): side-by-side throughput ratios measured in one run. See BENCHMARKS.md."""
