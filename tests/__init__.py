"""Test suite (not installed)."""
