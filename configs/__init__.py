"""Shipped robot profiles, installed as the package data `replanner_configs` so `--config panda` works anywhere."""
