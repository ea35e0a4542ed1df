"""Command-line tools over bags: process, replay, demo, bench."""
