"""Benchmarks: functions that take plain arguments and return JSON-ready figures (median, p95, n)."""
