"""Emulated node controllers (left/right hip and knee boards) that drive the simulation over CAN."""
