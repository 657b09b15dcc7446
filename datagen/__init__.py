"""Embedded synthetic data generator: hand, probe, arm, grasps, cameras, scene, renderer, writer."""
