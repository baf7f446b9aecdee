"""Small helpers shared by the simulation tests."""

from __future__ import annotations

from armvision.config import Config, SimConfig


def config_with(**sim: object) -> Config:
    """Default config with some ``sim`` keys changed."""
    return Config(sim=SimConfig(**sim))
