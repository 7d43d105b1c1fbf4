"""Acquisition: light controllers, cameras, rig configuration and capture into sessions."""
