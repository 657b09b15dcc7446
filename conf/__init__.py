"""Hydra configs, shipped inside the package as hupbench.conf."""
