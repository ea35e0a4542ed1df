"""Benchmarks that print numbers: `moseg bench pipeline`, `moseg bench synth`."""
