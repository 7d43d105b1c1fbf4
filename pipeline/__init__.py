"""psrig processing pipeline: session folders, image I/O, photometric stereo, integration."""

__version__ = "0.1.0"
