"""Benchmarks: one module per data set, each a `moseg eval` sub-command."""
