"""The two-stage grasp generator: a BPS-conditioned CVAE sampler and an energy-based refinement."""
