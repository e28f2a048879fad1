"""Thin entry points: the `replanner` command. Only these read config files and set up logging."""
