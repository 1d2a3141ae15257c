"""Fuzz targets (fuzz_swarmd.py); see docs/testing.md."""
