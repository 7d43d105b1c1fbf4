"""Simulated devices that the real drivers talk to: light firmware, PTP camera, scene."""
