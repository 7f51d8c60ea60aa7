"""Evaluation collector: runs one skill on request and reports what it achieved (no replay)."""
