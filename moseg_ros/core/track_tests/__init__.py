"""The default method's per-track tests, one module each: epipolar, cheirality, ground, footing."""
