"""Tests: bus."""
