"""Light calibration: chrome-sphere light directions, positions and intensities."""
